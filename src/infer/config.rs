//! One configuration of an inference run: every choice `grainforce infer`,
//! the Python package and a JSON/TOML file can make, with its default and
//! its check ([`InferConfig::validate`], whose errors name the field).
//!
//! The configuration is what a user states; [`InferConfig::options`] turns
//! it into the solver's [`InferOptions`] (and the grains to infer), and
//! [`InferConfig::sequence_plan`] into the steps a sequence takes first.
//! The CLI maps its flags onto these fields one to one (`--lambda-rule` is
//! `lambda_rule`), so a field's name is its flag's without the dashes.

use super::dynamic::LambdaRule;
use super::kinematics::Smoother;
use super::{
    ConeModel, ConstrainedSolver, InferOptions, LambdaPrecision, Method, OnCollapse, StressNoise,
};
use crate::error::Error;
use crate::scene::Selection;
use crate::solver::sparse_ls::Ordering;

/// Fill-reducing ordering of the sparse factorisation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum OrderingChoice {
    /// Nested dissection in 3D, AMD in 2D.
    #[default]
    Auto,
    Amd,
    NestedDissection,
}

/// How the dynamic momentum weight λ is chosen (the rules of
/// [`LambdaRule`], whose values come from other fields).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum RuleChoice {
    /// λ = (σ_s/σ_m)² from `stress_sd` and `accel_sd`.
    #[default]
    Weights,
    /// Maximum curvature of the Pareto front.
    Knee,
    /// Momentum as an exact constraint.
    Hard,
    /// `lambda` (dimensionless).
    Fixed,
    /// Variance components estimated from the residuals.
    Variance,
}

/// How tracks are smoothed before differentiation (the filters of
/// [`Smoother`], whose parameters come from other fields).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum SmootherChoice {
    /// Low-pass FIR with a Hamming window (`fir_order`, `cutoff`).
    #[default]
    Fir,
    /// Savitzky–Golay (`savgol_window`, `savgol_degree`).
    Savgol,
    /// Penalised least squares (`cutoff`).
    Whittaker,
}

/// Frame by frame, or all frames at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum TimeFitChoice {
    /// Each frame its own problem.
    #[default]
    Frames,
    /// Forces, positions and velocities fitted to the raw tracks at once.
    Joint,
}

/// Everything an inference run can be asked. Each field is a flag of
/// `grainforce infer` (its name with dashes: `lambda_rule` is
/// `--lambda-rule`) and a key of a configuration file or of the Python
/// package's keyword arguments; the defaults are [`InferConfig::default`]'s.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(default, deny_unknown_fields)]
pub struct InferConfig {
    /// Formulation: qs (least squares on stresses, hard equilibrium, friction);
    /// tikhonov (adds λ²‖f‖², λ from `lambda` or matched to walls.csv);
    /// scaled (estimates a global stress scale from walls.csv);
    /// ls (equalities only, no friction: the fast floor);
    /// dynamic (stress and momentum rows weighted by λ, see `lambda_rule`);
    /// soft (static data that do not balance: momentum as a penalty, λ by
    /// variance components unless `lambda_rule` knee/fixed).
    /// Default: qs, switching to soft (and saying so) when the forces collapse
    /// because the data do not balance; an explicit hard-balance method fails
    /// instead unless `accept_degenerate`.
    #[cfg_attr(feature = "cli", arg(short, long, value_enum))]
    pub method: Option<Method>,
    /// Noise model of the stresses, i.e. how the stress rows are weighted:
    /// absolute (every component the same sd), relative (sd ∝ the component,
    /// as photoelastic and strain-gauge stresses and eq. 2.16; iteratively
    /// reweighted), columns (the sd_s_* columns of grains.csv).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = StressNoise::Absolute))]
    pub stress_noise: StressNoise,
    /// Keep a collapsed hard-balance answer (flagged in the report) instead of failing.
    #[cfg_attr(feature = "cli", arg(long))]
    pub accept_degenerate: bool,
    /// Friction coefficient for contacts without a `mu` column value (overrides
    /// scene.json). Without any μ only f_n ≥ 0 is imposed.
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub mu: Option<f64>,
    /// Friction coefficient of grain–wall contacts without a `mu` column
    /// value (overrides `mu` and scene.json there), e.g. 0 for lubricated walls.
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub wall_mu: Option<f64>,
    /// Tikhonov λ in the units of the equation (a length, e.g. metres); without
    /// it `tikhonov` chooses λ so inferred wall forces match walls.csv.
    #[cfg_attr(feature = "cli", arg(long, allow_negative_numbers = true))]
    pub lambda: Option<f64>,
    /// Dimensionless range of the automatic λ search (λ / grain radius), MIN..MAX.
    #[cfg_attr(feature = "cli", arg(long, value_name = "MIN..MAX", value_parser = parse_range))]
    pub lambda_range: Option<[f64; 2]>,
    /// Precision of the automatic λ: coarse (one constrained solve at the
    /// unconstrained least squares' optimum; the default) or fine (the
    /// friction-constrained wall mismatch minimised, up to 6 constrained
    /// solves: 1.9–3.6× slower measured in 3D, forces within 1 % of coarse's
    /// and no closer to the truth; see docs/bench.md).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = LambdaPrecision::Coarse))]
    pub lambda_precision: LambdaPrecision,
    /// Gravity vector gx,gy[,gz] in m/s² (overrides scene.json); grains then need `mass`.
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            value_name = "GX,GY[,GZ]",
            value_delimiter = ',',
            allow_hyphen_values = true
        )
    )]
    pub gravity: Option<Vec<f64>>,
    /// Infer locally on these grains only (comma-separated ids).
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            value_name = "ID,ID,...",
            value_delimiter = ',',
            conflicts_with = "region"
        )
    )]
    pub grains: Option<Vec<String>>,
    /// Infer locally on the grains whose centroid lies in this box.
    #[cfg_attr(
        feature = "cli",
        arg(
            long,
            value_name = "XMIN,XMAX,YMIN,YMAX[,ZMIN,ZMAX]",
            value_delimiter = ',',
            allow_hyphen_values = true
        )
    )]
    pub region: Option<Vec<f64>>,
    /// 3D friction cone: exact (second-order cone) or an inscribed pyramid with
    /// 4, 8 or 16 facets (a linear QP, slightly stricter than Coulomb; faster
    /// only in some cases — see the README's speed section).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = ConeModel::Exact))]
    pub cone: ConeModel,
    /// Algorithm for friction-constrained problems: active-set (primal–dual
    /// active set on the sparse factorisation, warm-started from the
    /// unconstrained answer; stops at the KKT conditions to 1e-10; when it does
    /// not settle, a primal–dual interior point on the same sparse
    /// factorisation, then clarabel) or interior-point (clarabel, to
    /// `tolerance`, then polished). Pyramids skip the active set.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = ConstrainedSolver::ActiveSet))]
    pub solver: ConstrainedSolver,
    /// Fill-reducing ordering of the sparse factorisation: auto (nested
    /// dissection in 3D, AMD in 2D), amd or nested-dissection. Speed and memory
    /// only; the forces are the same.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = OrderingChoice::Auto))]
    pub ordering: OrderingChoice,
    /// Interior-point tolerance (gap and feasibility): of the interior point on
    /// the sparse factorisation (when the active set does not settle) and of
    /// clarabel's first attempt. Looser is faster and less exact. Without it
    /// (1e-8) the sparse interior point stops sooner, when its certified
    /// distance to the optimum is a hundredth of what the stress residual
    /// says the noise moves the forces by (docs/bench.md, the data's
    /// accuracy); given, it solves to this tolerance.
    #[cfg_attr(feature = "cli", arg(long))]
    pub tolerance: Option<f64>,
    /// On infeasible data, return the least-violation answer (momentum softened)
    /// instead of an error.
    #[cfg_attr(feature = "cli", arg(long))]
    pub allow_infeasible: bool,
    /// Check that the data determine the forces (N(K_st) ∩ N(K_eq) = {0},
    /// reported as `unique`) when the problem has at most this many
    /// unknowns; 0 skips the check. It runs beside the solve on its own
    /// factorisation: on a busy machine it costs time (bench's `-nocheck`).
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "UNKNOWNS", default_value_t = 200_000)
    )]
    pub uniqueness_limit: usize,
    /// Weight of the wall rows relative to the stress rows (method scaled).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 100.0))]
    pub wall_weight: f64,
    /// Dynamic: how the momentum weight λ is chosen. weights: λ = (σ_s/σ_m)²
    /// from `stress_sd` and `accel_sd` (momentum exact when `accel_sd` is 0);
    /// knee: maximum curvature of the Pareto front (the original study's rule);
    /// hard: momentum as an exact constraint; fixed: `lambda` (dimensionless);
    /// variance: λ = σ̂_s²/σ̂_m² estimated from the residuals (variance
    /// components; the rule of `method` soft, which treats weights and hard as it).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = RuleChoice::Weights))]
    pub lambda_rule: RuleChoice,
    /// Dynamic, rule weights: relative noise of the stresses.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.1))]
    pub stress_sd: f64,
    /// Dynamic, rule weights: relative noise of m·a (0 = accelerations exact).
    /// Default: 0 for accelerations read from grains.csv (trusted, momentum
    /// exact); for accelerations derived here from tracks, per frame, twice the
    /// position noise (estimated from the tracks) propagated through the
    /// filter (measured best on the impact preset; see the README).
    #[cfg_attr(feature = "cli", arg(long))]
    pub accel_sd: Option<f64>,
    /// Dynamic: dimensionless λ range of the Pareto sweep, MIN..MAX.
    #[cfg_attr(feature = "cli", arg(long, value_name = "MIN..MAX", value_parser = parse_range, default_value = "1e-4..1e6"))]
    pub sweep: [f64; 2],
    /// Dynamic: number of λ values in the sweep.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 31))]
    pub sweep_points: usize,
    /// Dynamic and soft: sweep the Pareto front even when the rule is not
    /// knee ([`Run::pareto`](super::run::Run::pareto); the CLI's `--pareto FILE`).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub pareto: bool,
    /// Sequences: infer only frames A..B (inclusive), e.g. to split a long
    /// experiment across a cluster job array. Only those frames are read,
    /// with the filter's margin when accelerations are derived from the
    /// tracks, so a range gets the forces a full run gives it. Deriving with
    /// the Whittaker smoother, or weighting by a position noise estimated
    /// from the tracks (no `position_sd` or `accel_sd`), reads every frame.
    #[cfg_attr(feature = "cli", arg(long, value_name = "A..B", value_parser = parse_range))]
    pub frames: Option<[f64; 2]>,
    /// Sequences: stop at the first frame whose inference fails, writing
    /// nothing (exit status 1). Default: infer every other frame, write their
    /// forces, list the failed frames on stderr and in the report, and exit
    /// with status 3.
    #[cfg_attr(feature = "cli", arg(long))]
    pub stop_on_failure: bool,
    /// Sequences: frames per second. Needed to derive accelerations from the
    /// centroid tracks (done when grains.csv has no a_x column, or with
    /// `derive_accelerations`) and for `impulse`.
    #[cfg_attr(feature = "cli", arg(long))]
    pub fps: Option<f64>,
    /// Recompute accelerations from the tracks even when grains.csv has them.
    #[cfg_attr(feature = "cli", arg(long))]
    pub derive_accelerations: bool,
    /// How tracks are smoothed before differentiation: fir (low-pass with a
    /// Hamming window, as the original experiments), savgol (Savitzky–Golay)
    /// or whittaker (penalised least squares with the same `cutoff`, holding
    /// a grain that touches nothing at gravity, so free flights pin the
    /// velocities around a collision).
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = SmootherChoice::Fir))]
    pub smoother: SmootherChoice,
    /// FIR filter order (even; order + 1 taps).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 20))]
    pub fir_order: usize,
    /// FIR (and whittaker) cut-off as a fraction of the Nyquist frequency (fps/2).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 0.15))]
    pub cutoff: f64,
    /// Savitzky–Golay window (odd number of frames).
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 11))]
    pub savgol_window: usize,
    /// Savitzky–Golay polynomial degree.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 3))]
    pub savgol_degree: usize,
    /// Sequences, dynamic: frames (each frame its own problem, momentum from
    /// accelerations differentiated from the filtered tracks) or joint (all
    /// frames at once: forces, positions and velocities fitted to the raw
    /// tracks through the integrator and to the stresses, each contact's force
    /// smooth in time — see `roughness`; more accurate and the impulses follow
    /// the tracks; one larger problem, see the README). Needs `fps`.
    #[cfg_attr(feature = "cli", arg(long, value_enum, default_value_t = TimeFitChoice::Frames))]
    pub time_fit: TimeFitChoice,
    /// Joint time fit: σ_r, the standard deviation of the second difference
    /// of a contact force component from frame to frame [N]. Default: three
    /// times its rms in the frame-by-frame answer.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "NEWTONS", allow_negative_numbers = true)
    )]
    pub roughness: Option<f64>,
    /// Sequences: the impulse check (table 3.1), Δv from the integrated
    /// inferred forces against Δv measured on the tracks, per grain tracked
    /// over at least `impulse_window` + 1 frames (the CLI's `--impulse FILE`).
    #[cfg_attr(feature = "cli", arg(skip))]
    pub impulse: bool,
    /// Frames in each end window of the impulse check (odd), at least; an end
    /// where the grain touches nothing widens over that contact-free stretch
    /// (up to half the track). Longer windows give quieter velocities.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 21))]
    pub impulse_window: usize,
    /// Standard deviation of each tracked coordinate (metres), which weights
    /// accelerations derived from the tracks and the impulse check's dv_sd;
    /// estimated from the tracks when not given.
    #[cfg_attr(feature = "cli", arg(long, value_name = "METRES"))]
    pub position_sd: Option<f64>,
    /// Estimate a standard deviation per force component from N bootstrap
    /// draws (noisy stresses re-inferred) and write sd_x, sd_y[, sd_z] columns.
    #[cfg_attr(feature = "cli", arg(long, value_name = "N"))]
    pub uncertainty: Option<u32>,
    /// Relative noise of each stress component for `uncertainty` (0.1 = 10 %);
    /// estimated from the stress residual when not given.
    #[cfg_attr(
        feature = "cli",
        arg(long, value_name = "SIGMA", requires = "uncertainty")
    )]
    pub noise_level: Option<f64>,
    /// Seed of the `uncertainty` draws.
    #[cfg_attr(feature = "cli", arg(long, default_value_t = 1))]
    pub uncertainty_seed: u32,
}

impl Default for InferConfig {
    fn default() -> Self {
        InferConfig {
            method: None,
            stress_noise: StressNoise::Absolute,
            accept_degenerate: false,
            mu: None,
            wall_mu: None,
            lambda: None,
            lambda_range: None,
            lambda_precision: LambdaPrecision::Coarse,
            gravity: None,
            grains: None,
            region: None,
            cone: ConeModel::Exact,
            solver: ConstrainedSolver::ActiveSet,
            ordering: OrderingChoice::Auto,
            tolerance: None,
            allow_infeasible: false,
            uniqueness_limit: 200_000,
            wall_weight: 100.0,
            lambda_rule: RuleChoice::Weights,
            stress_sd: 0.1,
            accel_sd: None,
            sweep: [1e-4, 1e6],
            sweep_points: 31,
            pareto: false,
            frames: None,
            stop_on_failure: false,
            fps: None,
            derive_accelerations: false,
            smoother: SmootherChoice::Fir,
            fir_order: 20,
            cutoff: 0.15,
            savgol_window: 11,
            savgol_degree: 3,
            time_fit: TimeFitChoice::Frames,
            roughness: None,
            impulse: false,
            impulse_window: 21,
            position_sd: None,
            uncertainty: None,
            noise_level: None,
            uncertainty_seed: 1,
        }
    }
}

/// A configuration that cannot be used: the field at fault and why. The
/// message names fields in backticks (`` `fps` ``), so a front end can
/// spell them its own way ([`ConfigError::spelled`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigError {
    pub field: &'static str,
    pub message: String,
}

impl std::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

impl std::error::Error for ConfigError {}

impl From<ConfigError> for Error {
    fn from(e: ConfigError) -> Self {
        Error::Invalid(e.message)
    }
}

impl ConfigError {
    fn new(field: &'static str, message: impl Into<String>) -> Self {
        ConfigError {
            field,
            message: message.into(),
        }
    }

    /// The message with each `` `field` `` (or `` `field` = value ``) of the
    /// configuration written by `spell(field, value)`: the CLI turns
    /// `` `time_fit` = joint `` into `--time-fit joint`.
    pub fn spelled(&self, spell: impl Fn(&str, Option<&str>) -> String) -> String {
        spell_fields(&self.message, spell)
    }
}

/// The names of [`InferConfig`]'s fields, in declaration order.
pub const FIELDS: &[&str] = &[
    "method",
    "stress_noise",
    "accept_degenerate",
    "mu",
    "wall_mu",
    "lambda",
    "lambda_range",
    "lambda_precision",
    "gravity",
    "grains",
    "region",
    "cone",
    "solver",
    "ordering",
    "tolerance",
    "allow_infeasible",
    "uniqueness_limit",
    "wall_weight",
    "lambda_rule",
    "stress_sd",
    "accel_sd",
    "sweep",
    "sweep_points",
    "pareto",
    "frames",
    "stop_on_failure",
    "fps",
    "derive_accelerations",
    "smoother",
    "fir_order",
    "cutoff",
    "savgol_window",
    "savgol_degree",
    "time_fit",
    "roughness",
    "impulse",
    "impulse_window",
    "position_sd",
    "uncertainty",
    "noise_level",
    "uncertainty_seed",
];

/// Rewrites `` `field` `` and `` `field` = value `` (value up to the next
/// space, comma or colon) for the configuration's fields; other backticked
/// text stays as it is.
pub fn spell_fields(text: &str, spell: impl Fn(&str, Option<&str>) -> String) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(open) = rest.find('`') {
        out.push_str(&rest[..open]);
        let after = &rest[open + 1..];
        let Some(close) = after.find('`') else {
            rest = &rest[open..];
            break;
        };
        let name = &after[..close];
        let mut tail = &after[close + 1..];
        if !FIELDS.contains(&name) {
            out.push('`');
            out.push_str(name);
            out.push('`');
            rest = tail;
            continue;
        }
        let mut value = None;
        if let Some(v) = tail.strip_prefix(" = ") {
            let end = v
                .find(|c: char| c.is_whitespace() || c == ',' || c == ':' || c == ')')
                .unwrap_or(v.len());
            value = Some(&v[..end]);
            tail = &v[end..];
        }
        out.push_str(&spell(name, value));
        rest = tail;
    }
    out.push_str(rest);
    out
}

/// A `MIN..MAX` range's two ends (the CLI's spelling of a range field).
pub fn parse_range(text: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = text.split("..").collect();
    let end = |s: &str| {
        s.trim()
            .parse::<f64>()
            .map_err(|_| format!("`{s}` is not a number (expected MIN..MAX)"))
    };
    match parts[..] {
        [lo, hi] => Ok([end(lo)?, end(hi)?]),
        _ => Err(format!("expected MIN..MAX, got `{text}`")),
    }
}

fn finite(field: &'static str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ConfigError::new(
            field,
            format!("`{field}` must be a finite number, got {v}"),
        ))
    }
}

fn range(field: &'static str, r: [f64; 2]) -> Result<(f64, f64), ConfigError> {
    Ok((finite(field, r[0])?, finite(field, r[1])?))
}

impl InferConfig {
    /// A configuration from JSON text (unknown fields are errors).
    pub fn from_json(text: &str) -> crate::error::Result<Self> {
        let value: serde_json::Value = serde_json::from_str(text)
            .map_err(|e| Error::Invalid(format!("infer configuration: {e}")))?;
        Self::from_value(value).map_err(|e| Error::Invalid(format!("infer configuration: {e}")))
    }

    /// A configuration from a JSON value (e.g. a parsed file); an error
    /// names the field at fault (serde's own message does not).
    pub fn from_value(value: serde_json::Value) -> std::result::Result<Self, String> {
        if let serde_json::Value::Object(fields) = &value {
            for (name, v) in fields {
                let one =
                    serde_json::Value::Object([(name.clone(), v.clone())].into_iter().collect());
                if let Err(e) = serde_json::from_value::<InferConfig>(one) {
                    return Err(format!("field `{name}`: {e}"));
                }
            }
        }
        serde_json::from_value(value).map_err(|e| e.to_string())
    }

    /// Checks every field and their combinations; the error names the field.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.options()?;
        self.sequence_plan()?;
        let method = self.method.unwrap_or(Method::Qs);
        if self.time_fit == TimeFitChoice::Joint {
            let field = "time_fit";
            if method != Method::Dynamic {
                return Err(ConfigError::new(
                    field,
                    "`time_fit` = joint fits momentum over time: use it with `method` = dynamic",
                ));
            }
            if self.grains.is_some() || self.region.is_some() {
                return Err(ConfigError::new(
                    field,
                    "`time_fit` = joint infers whole frames: drop `grains`/`region`",
                ));
            }
            if self.uncertainty.is_some() {
                return Err(ConfigError::new(
                    "uncertainty",
                    "`uncertainty` resamples frame by frame; it does not combine with `time_fit` = joint",
                ));
            }
            if self.stress_sd <= 0.0 {
                return Err(ConfigError::new(
                    "stress_sd",
                    format!(
                        "`time_fit` = joint weighs the stresses by 1/σ_s: `stress_sd` must be positive, got {}",
                        self.stress_sd
                    ),
                ));
            }
            if let Some(r) = self.roughness.filter(|r| !(*r > 0.0 && r.is_finite())) {
                return Err(ConfigError::new(
                    "roughness",
                    format!("`roughness` must be positive and finite, got {r}"),
                ));
            }
            if self.fps.is_none() {
                return Err(ConfigError::new(
                    "fps",
                    "`time_fit` = joint needs the frame rate: give `fps`",
                ));
            }
        }
        if let Some(draws) = self.uncertainty.filter(|d| *d < 2) {
            return Err(ConfigError::new(
                "uncertainty",
                format!("`uncertainty` needs at least 2 draws, got {draws}"),
            ));
        }
        if let Some(s) = self.noise_level.filter(|s| !(s.is_finite() && *s >= 0.0)) {
            return Err(ConfigError::new(
                "noise_level",
                format!("`noise_level` must be finite and ≥ 0, got {s}"),
            ));
        }
        if self.noise_level.is_some() && self.uncertainty.is_none() {
            return Err(ConfigError::new(
                "noise_level",
                "`noise_level` is the noise of the `uncertainty` draws: set `uncertainty` too",
            ));
        }
        if self.impulse && self.fps.is_none() {
            return Err(ConfigError::new(
                "fps",
                "`impulse` needs the frame rate: give `fps`",
            ));
        }
        if self.pareto && !matches!(method, Method::Dynamic | Method::Soft) {
            return Err(ConfigError::new(
                "pareto",
                "`pareto` needs `method` = dynamic or soft",
            ));
        }
        Ok(())
    }

    /// The solver's options and the grains to infer (every field checked
    /// that they depend on).
    pub fn options(&self) -> Result<(InferOptions, Selection), ConfigError> {
        let method = self.method.unwrap_or(Method::Qs);
        let mut opts = InferOptions {
            method,
            cone: self.cone,
            lambda: self.lambda,
            allow_infeasible: self.allow_infeasible,
            wall_weight: self.wall_weight,
            stress_noise: self.stress_noise,
            on_collapse: match (self.method, self.accept_degenerate) {
                (_, true) => OnCollapse::Accept,
                (None, false) => OnCollapse::Switch,
                (Some(_), false) => OnCollapse::Fail,
            },
            ..InferOptions::default()
        };
        if let ConeModel::Pyramid(facets) = self.cone {
            if facets < 3 {
                return Err(ConfigError::new(
                    "cone",
                    format!("a pyramid `cone` needs at least 3 facets, got {facets}"),
                ));
            }
        }
        if let Some(l) = self.lambda {
            if !(l >= 0.0 && l.is_finite()) {
                return Err(ConfigError::new(
                    "lambda",
                    format!("`lambda` must be finite and ≥ 0, got {l}"),
                ));
            }
        }
        if let Some(tolerance) = self.tolerance {
            if !(tolerance > 0.0 && tolerance < 1.0) {
                return Err(ConfigError::new(
                    "tolerance",
                    format!("`tolerance` must lie in (0, 1), got {tolerance}"),
                ));
            }
            opts.conic.tolerance = tolerance;
            opts.conic.noise_share = None;
        }
        if !(self.wall_weight > 0.0 && self.wall_weight.is_finite()) {
            return Err(ConfigError::new(
                "wall_weight",
                format!("`wall_weight` must be positive, got {}", self.wall_weight),
            ));
        }
        opts.solver = self.solver;
        opts.identifiability_limit = self.uniqueness_limit;
        opts.ordering = match self.ordering {
            OrderingChoice::Auto => None,
            OrderingChoice::Amd => Some(Ordering::Amd),
            OrderingChoice::NestedDissection => Some(Ordering::NestedDissection),
        };
        for (field, mu) in [("mu", self.mu), ("wall_mu", self.wall_mu)] {
            if let Some(mu) = mu.filter(|mu| !(*mu >= 0.0 && mu.is_finite())) {
                return Err(ConfigError::new(
                    field,
                    format!("`{field}` must be a finite non-negative number, got {mu}"),
                ));
            }
        }
        opts.assemble.mu = self.mu;
        opts.assemble.wall_mu = self.wall_mu;
        if let Some(g) = &self.gravity {
            if !(2..=3).contains(&g.len()) {
                return Err(ConfigError::new(
                    "gravity",
                    format!("`gravity` takes 2 or 3 components, got {}", g.len()),
                ));
            }
            let mut v = [0.0; 3];
            for (k, x) in g.iter().enumerate() {
                v[k] = finite("gravity", *x)?;
            }
            opts.assemble.gravity = Some(v);
        }
        if let Some(r) = self.lambda_range {
            let (lo, hi) = range("lambda_range", r)?;
            opts.lambda_search.min = lo;
            opts.lambda_search.max = hi;
        }
        opts.lambda_search.precision = self.lambda_precision;
        let accel_sd = self.accel_sd.unwrap_or(0.0);
        for (field, v) in [("stress_sd", self.stress_sd), ("accel_sd", accel_sd)] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(ConfigError::new(
                    field,
                    format!("`{field}` must be finite and ≥ 0, got {v}"),
                ));
            }
        }
        opts.dynamic.rule = match self.lambda_rule {
            RuleChoice::Weights => LambdaRule::Weights {
                stress_sd: self.stress_sd,
                momentum_sd: accel_sd,
            },
            RuleChoice::Knee => LambdaRule::Knee,
            RuleChoice::Variance => LambdaRule::Variance,
            RuleChoice::Hard => LambdaRule::Hard,
            RuleChoice::Fixed => LambdaRule::Fixed(self.lambda.ok_or_else(|| {
                ConfigError::new("lambda", "`lambda_rule` = fixed needs `lambda`")
            })?),
        };
        if self.pareto
            && self.lambda_rule != RuleChoice::Knee
            && matches!(method, Method::Dynamic | Method::Soft)
        {
            // The front is still wanted: sweep it, but keep the chosen rule's λ.
            opts.dynamic_front = true;
        }
        let (lo, hi) = range("sweep", self.sweep)?;
        opts.dynamic.sweep_min = lo;
        opts.dynamic.sweep_max = hi;
        opts.dynamic.sweep_points = self.sweep_points;
        let selection = match (&self.grains, &self.region) {
            (Some(_), Some(_)) => {
                return Err(ConfigError::new(
                    "region",
                    "`grains` and `region` each choose the grains: give one",
                ))
            }
            (Some(ids), None) => Selection::Grains(
                ids.iter()
                    .map(|s| s.trim().to_owned())
                    .filter(|s| !s.is_empty())
                    .collect(),
            ),
            (None, Some(v)) => {
                if v.len() % 2 != 0 || v.len() < 4 {
                    return Err(ConfigError::new(
                        "region",
                        "`region` takes min,max pairs per axis",
                    ));
                }
                for x in v {
                    finite("region", *x)?;
                }
                Selection::Region(v.chunks(2).map(|c| (c[0], c[1])).collect())
            }
            (None, None) => Selection::All,
        };
        Ok((opts, selection))
    }

    /// The steps a sequence takes before its frames are inferred.
    pub fn sequence_plan(&self) -> Result<super::sequence::SequencePlan, ConfigError> {
        let frame_range = match self.frames {
            Some(r) => Some(range("frames", r)?),
            None => None,
        };
        let smoother = match self.smoother {
            SmootherChoice::Fir => Smoother::Fir {
                order: self.fir_order,
                cutoff: self.cutoff,
            },
            SmootherChoice::Savgol => Smoother::SavitzkyGolay {
                window: self.savgol_window,
                degree: self.savgol_degree,
            },
            SmootherChoice::Whittaker => Smoother::Whittaker {
                cutoff: self.cutoff,
            },
        };
        let (_, selection) = self.options()?;
        Ok(super::sequence::SequencePlan {
            frame_range,
            derive_accelerations: self.derive_accelerations,
            fps: self.fps,
            smoother,
            selection,
            acceleration_sd_given: self.accel_sd.is_some(),
            position_sd: self.position_sd,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[cfg(feature = "cli")]
    #[test]
    fn the_flags_defaults_are_the_configurations() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Flags {
            #[command(flatten)]
            config: InferConfig,
        }
        let parsed = Flags::try_parse_from(["infer"]).unwrap();
        assert_eq!(parsed.config, InferConfig::default());
        let parsed =
            Flags::try_parse_from(["infer", "--sweep", "1e-2..1e3", "--cone", "pyramid8"]).unwrap();
        assert_eq!(parsed.config.sweep, [1e-2, 1e3]);
        assert_eq!(parsed.config.cone, ConeModel::Pyramid(8));
    }

    #[test]
    fn every_field_is_listed_once() {
        let json = serde_json::to_value(InferConfig::default()).unwrap();
        let keys: Vec<&str> = json
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        let mut listed = FIELDS.to_vec();
        listed.sort_unstable();
        let mut keys = keys;
        keys.sort_unstable();
        assert_eq!(keys, listed);
    }

    #[test]
    fn spelling_rewrites_only_fields() {
        let spell = |f: &str, v: Option<&str>| match v {
            Some(v) => format!("--{} {v}", f.replace('_', "-")),
            None => format!("--{}", f.replace('_', "-")),
        };
        assert_eq!(
            spell_fields(
                "`time_fit` = joint needs `fps`, column `mu_x` of `grains`: ok",
                spell
            ),
            "--time-fit joint needs --fps, column `mu_x` of --grains: ok"
        );
        assert_eq!(spell_fields("open ` quote", spell), "open ` quote");
    }
}
