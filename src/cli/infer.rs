//! `grainforce infer`: scene → forces.csv (+ summary on stderr, JSON report).

use grainforce::error::{Error, Result};
use grainforce::infer::kinematics::{self, Smoother};
use grainforce::infer::sequence::{self, FrameOutcome, OnFrameFailure};
use grainforce::infer::time_fit;
use grainforce::infer::uncertainty::{
    frames_uncertainty, NoiseEstimate, Uncertainty, UncertaintyOptions,
};
use grainforce::infer::{
    self, ConeModel, ConstrainedSolver, InferOptions, LambdaPrecision, LambdaRule, Method,
    OnCollapse, StressNoise,
};
use grainforce::scene::{self, Forces, Selection};
use grainforce::solver::sparse_ls::Ordering;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Scene folder (grains.csv, contacts.csv, optional walls.csv and scene.json).
    pub scene: PathBuf,
    /// Where to write the forces (forces.csv format; force on grain `a` by `b`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Formulation: qs (least squares on stresses, hard equilibrium, friction);
    /// tikhonov (adds λ²‖f‖², λ from --lambda or matched to walls.csv);
    /// scaled (estimates a global stress scale from walls.csv);
    /// ls (equalities only, no friction: the fast floor);
    /// dynamic (stress and momentum rows weighted by λ, see --lambda-rule);
    /// soft (static data that do not balance: momentum as a penalty, λ by
    /// variance components unless --lambda-rule knee/fixed).
    /// Default: qs, switching to soft (and saying so) when the forces collapse
    /// because the data do not balance; an explicit hard-balance method fails
    /// instead unless --accept-degenerate.
    #[arg(short, long, value_enum)]
    pub method: Option<MethodArg>,
    /// Noise model of the stresses, i.e. how the stress rows are weighted:
    /// absolute (every component the same sd), relative (sd ∝ the component,
    /// as photoelastic and strain-gauge stresses and eq. 2.16; iteratively
    /// reweighted), columns (the sd_s_* columns of grains.csv).
    #[arg(long, value_enum, default_value_t = StressNoiseArg::Absolute)]
    pub stress_noise: StressNoiseArg,
    /// Keep a collapsed hard-balance answer (flagged in the report) instead of failing.
    #[arg(long)]
    pub accept_degenerate: bool,
    /// Friction coefficient for contacts without a `mu` column value (overrides
    /// scene.json). Without any μ only f_n ≥ 0 is imposed.
    #[arg(long, allow_negative_numbers = true)]
    pub mu: Option<f64>,
    /// Tikhonov λ in the units of the equation (a length, e.g. metres); without
    /// it `tikhonov` chooses λ so inferred wall forces match walls.csv.
    #[arg(long, allow_negative_numbers = true)]
    pub lambda: Option<f64>,
    /// Dimensionless range of the automatic λ search (λ / grain radius), MIN..MAX.
    #[arg(long, value_name = "MIN..MAX")]
    pub lambda_range: Option<String>,
    /// Precision of the automatic λ: fine (the friction-constrained wall
    /// mismatch minimised, up to 6 constrained solves) or coarse (one
    /// constrained solve at the unconstrained least squares' optimum: 1.9–3.6×
    /// faster measured in 3D, forces within 1 % of fine's; see the README).
    #[arg(long, value_enum, default_value_t = LambdaPrecisionArg::Fine)]
    pub lambda_precision: LambdaPrecisionArg,
    /// Gravity vector gx,gy[,gz] in m/s² (overrides scene.json); grains then need `mass`.
    #[arg(long, value_name = "GX,GY[,GZ]", allow_hyphen_values = true)]
    pub gravity: Option<String>,
    /// Infer locally on these grains only (comma-separated ids).
    #[arg(long, value_name = "ID,ID,...", conflicts_with = "region")]
    pub grains: Option<String>,
    /// Infer locally on the grains whose centroid lies in this box.
    #[arg(
        long,
        value_name = "XMIN,XMAX,YMIN,YMAX[,ZMIN,ZMAX]",
        allow_hyphen_values = true
    )]
    pub region: Option<String>,
    /// 3D friction cone: exact (second-order cone) or an inscribed pyramid with
    /// 4, 8 or 16 facets (a linear QP, slightly stricter than Coulomb; faster
    /// only in some cases — see the README's speed section).
    #[arg(long, value_enum, default_value_t = ConeArg::Exact)]
    pub cone: ConeArg,
    /// Algorithm for friction-constrained problems: active-set (primal–dual
    /// active set on the sparse factorisation, warm-started from the
    /// unconstrained answer; stops at the KKT conditions to 1e-10; when it does
    /// not settle, a primal–dual interior point on the same sparse
    /// factorisation, then clarabel) or interior-point (clarabel, to
    /// --tolerance, then polished). Pyramids skip the active set.
    #[arg(long, value_enum, default_value_t = SolverArg::ActiveSet)]
    pub solver: SolverArg,
    /// Fill-reducing ordering of the sparse factorisation: auto (nested
    /// dissection in 3D, AMD in 2D), amd or nested-dissection. Speed and memory
    /// only; the forces are the same.
    #[arg(long, value_enum, default_value_t = OrderingArg::Auto)]
    pub ordering: OrderingArg,
    /// Interior-point tolerance (gap and feasibility): of the interior point on
    /// the sparse factorisation (when the active set does not settle) and of
    /// clarabel's first attempt. Looser is faster and less exact. Without it
    /// (1e-8) the sparse interior point stops sooner when its certified
    /// distance to the optimum is a hundredth of what the stress residual
    /// says the noise moves the forces by (docs/bench.md, data's accuracy);
    /// given, it solves to this tolerance.
    #[arg(long)]
    pub tolerance: Option<f64>,
    /// On infeasible data, return the least-violation answer (momentum softened)
    /// instead of an error.
    #[arg(long)]
    pub allow_infeasible: bool,
    /// Weight of the wall rows relative to the stress rows (method scaled).
    #[arg(long, default_value_t = 100.0)]
    pub wall_weight: f64,
    /// Dynamic: how the momentum weight λ is chosen. weights: λ = (σ_s/σ_m)²
    /// from --stress-sd and --accel-sd (momentum exact when --accel-sd is 0);
    /// knee: maximum curvature of the Pareto front (the original study's rule);
    /// hard: momentum as an exact constraint; fixed: --lambda (dimensionless);
    /// variance: λ = σ̂_s²/σ̂_m² estimated from the residuals (variance
    /// components; the rule of --method soft, which treats weights and hard as it).
    #[arg(long, value_enum, default_value_t = RuleArg::Weights)]
    pub lambda_rule: RuleArg,
    /// Dynamic, rule weights: relative noise of the stresses.
    #[arg(long, default_value_t = 0.1)]
    pub stress_sd: f64,
    /// Dynamic, rule weights: relative noise of m·a (0 = accelerations exact).
    /// Default: 0 for accelerations read from grains.csv (trusted, momentum
    /// exact); for accelerations derived here from tracks, per frame, twice the
    /// position noise (estimated from the tracks) propagated through the
    /// filter (measured best on the impact preset; see the README).
    #[arg(long)]
    pub accel_sd: Option<f64>,
    /// Dynamic: dimensionless λ range of the Pareto sweep, MIN..MAX.
    #[arg(long, value_name = "MIN..MAX", default_value = "1e-4..1e6")]
    pub sweep: String,
    /// Dynamic: number of λ values in the sweep.
    #[arg(long, default_value_t = 31)]
    pub sweep_points: usize,
    /// Dynamic: write the Pareto front (lambda, stress_residual,
    /// momentum_residual, knee) to this CSV (sweeps even when the rule is not knee).
    #[arg(long, value_name = "PARETO.csv")]
    pub pareto: Option<PathBuf>,
    /// Sequences: infer only frames A..B (inclusive), e.g. to split a long
    /// experiment across a cluster job array. Only those frames are read,
    /// with the filter's margin when accelerations are derived from the
    /// tracks, so a range gets the forces a full run gives it. Deriving with
    /// the Whittaker smoother, or weighting by a position noise estimated
    /// from the tracks (no --position-sd or --accel-sd), reads every frame.
    #[arg(long, value_name = "A..B")]
    pub frames: Option<String>,
    /// Sequences: stop at the first frame whose inference fails, writing
    /// nothing (exit status 1). Default: infer every other frame, write their
    /// forces, list the failed frames on stderr and in the report, and exit
    /// with status 3.
    #[arg(long)]
    pub stop_on_failure: bool,
    /// Sequences: frames per second. Needed to derive accelerations from the
    /// centroid tracks (done when grains.csv has no a_x column, or with
    /// --derive-accelerations) and for --impulse.
    #[arg(long)]
    pub fps: Option<f64>,
    /// Recompute accelerations from the tracks even when grains.csv has them.
    #[arg(long)]
    pub derive_accelerations: bool,
    /// How tracks are smoothed before differentiation: fir (low-pass with a
    /// Hamming window, as the original experiments), savgol (Savitzky–Golay)
    /// or whittaker (penalised least squares with the same --cutoff, holding
    /// a grain that touches nothing at gravity, so free flights pin the
    /// velocities around a collision).
    #[arg(long, value_enum, default_value_t = SmootherArg::Fir)]
    pub smoother: SmootherArg,
    /// FIR filter order (even; order + 1 taps).
    #[arg(long, default_value_t = 20)]
    pub fir_order: usize,
    /// FIR (and whittaker) cut-off as a fraction of the Nyquist frequency (fps/2).
    #[arg(long, default_value_t = 0.15)]
    pub cutoff: f64,
    /// Savitzky–Golay window (odd number of frames).
    #[arg(long, default_value_t = 11)]
    pub savgol_window: usize,
    /// Savitzky–Golay polynomial degree.
    #[arg(long, default_value_t = 3)]
    pub savgol_degree: usize,
    /// Sequences, dynamic: frames (each frame its own problem, momentum from
    /// accelerations differentiated from the filtered tracks) or joint (all
    /// frames at once: forces, positions and velocities fitted to the raw
    /// tracks through the integrator and to the stresses, each contact's force
    /// smooth in time — see --roughness; more accurate and the impulses follow
    /// the tracks; one larger problem, see the README). Needs --fps.
    #[arg(long, value_enum, default_value_t = TimeFitArg::Frames)]
    pub time_fit: TimeFitArg,
    /// Joint time fit: σ_r, the standard deviation of the second difference
    /// of a contact force component from frame to frame [N]. Default: three
    /// times its rms in the frame-by-frame answer.
    #[arg(long, value_name = "NEWTONS", allow_negative_numbers = true)]
    pub roughness: Option<f64>,
    /// Sequences: write the impulse check (table 3.1) to this CSV, one row per
    /// grain tracked over at least --impulse-window + 1 consecutive frames.
    /// Columns: grain, first_frame, last_frame; start_window, end_window: the
    /// frames of the two end windows (--impulse-window, or the whole
    /// contact-free stretch at an end where the grain flies freely);
    /// dv_x_measured, dv_x_inferred (and y, z): the change of velocity
    /// between the two windows, measured = least-squares slopes of the track,
    /// inferred = the same slopes of the track integrated twice from
    /// (Σ inferred contact forces)/m + g; dv_sd: standard deviation of each
    /// measured component due to the position noise; disagreement:
    /// |Δv inferred − Δv measured| / |Δv measured|; gap_in_sd: that gap over
    /// dv_sd (a few units is noise); moves: 1 when |Δv measured| ≥ 20 dv_sd.
    #[arg(long, value_name = "IMPULSE.csv")]
    pub impulse: Option<PathBuf>,
    /// Frames in each end window of the impulse check (odd), at least; an end
    /// where the grain touches nothing widens over that contact-free stretch
    /// (up to half the track). Longer windows give quieter velocities.
    #[arg(long, default_value_t = 21)]
    pub impulse_window: usize,
    /// Standard deviation of each tracked coordinate (metres), which weights
    /// accelerations derived from the tracks and the impulse check's dv_sd;
    /// estimated from the tracks when not given.
    #[arg(long, value_name = "METRES")]
    pub position_sd: Option<f64>,
    /// Also draw the force chains of the (first) frame to this PNG.
    #[arg(long, value_name = "FORCES.png")]
    pub plot: Option<PathBuf>,
    /// Write the report (sizes, residuals, λ, solver status, warnings) as JSON.
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    /// Estimate a standard deviation per force component from N bootstrap
    /// draws (noisy stresses re-inferred) and write sd_x, sd_y[, sd_z] columns.
    #[arg(long, value_name = "N")]
    pub uncertainty: Option<u32>,
    /// Relative noise of each stress component for --uncertainty (0.1 = 10 %);
    /// estimated from the stress residual when not given.
    #[arg(long, value_name = "SIGMA", requires = "uncertainty")]
    pub noise_level: Option<f64>,
    /// Seed of the --uncertainty draws.
    #[arg(long, default_value_t = 1)]
    pub uncertainty_seed: u32,
    /// The global -q/--quiet: print no report, summary or progress on stderr.
    #[arg(skip)]
    pub quiet: bool,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum MethodArg {
    Qs,
    Tikhonov,
    Scaled,
    Ls,
    Dynamic,
    Soft,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum StressNoiseArg {
    Absolute,
    Relative,
    Columns,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RuleArg {
    Weights,
    Knee,
    Hard,
    Fixed,
    Variance,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum SmootherArg {
    Fir,
    Savgol,
    Whittaker,
}

#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum TimeFitArg {
    Frames,
    Joint,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum SolverArg {
    ActiveSet,
    InteriorPoint,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum OrderingArg {
    Auto,
    Amd,
    NestedDissection,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum LambdaPrecisionArg {
    Fine,
    Coarse,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum ConeArg {
    Exact,
    Pyramid4,
    Pyramid8,
    Pyramid16,
}

fn numbers(flag: &str, text: &str) -> Result<Vec<f64>> {
    text.split(',')
        .map(|s| {
            s.trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| Error::Invalid(format!("{flag}: `{s}` is not a finite number")))
        })
        .collect()
}

pub fn range(flag: &str, text: &str) -> Result<(f64, f64)> {
    let parts: Vec<&str> = text.split("..").collect();
    if parts.len() != 2 {
        return Err(Error::Invalid(format!(
            "{flag}: expected MIN..MAX, got `{text}`"
        )));
    }
    let lo = numbers(flag, parts[0])?[0];
    let hi = numbers(flag, parts[1])?[0];
    Ok((lo, hi))
}

/// The sequence steps the flags ask for (`--frames`, `--derive-accelerations`,
/// `--fps`, the smoother, the region, `--accel-sd`).
pub fn sequence_plan(args: &Args, selection: Selection) -> Result<sequence::SequencePlan> {
    let frame_range = match &args.frames {
        Some(r) => Some(range("--frames", r)?),
        None => None,
    };
    let smoother = match args.smoother {
        SmootherArg::Fir => Smoother::Fir {
            order: args.fir_order,
            cutoff: args.cutoff,
        },
        SmootherArg::Savgol => Smoother::SavitzkyGolay {
            window: args.savgol_window,
            degree: args.savgol_degree,
        },
        SmootherArg::Whittaker => Smoother::Whittaker {
            cutoff: args.cutoff,
        },
    };
    Ok(sequence::SequencePlan {
        frame_range,
        derive_accelerations: args.derive_accelerations,
        fps: args.fps,
        smoother,
        selection,
        acceleration_sd_given: args.accel_sd.is_some(),
        position_sd: args.position_sd,
    })
}

pub fn options(args: &Args) -> Result<(InferOptions, Selection)> {
    let mut opts = InferOptions {
        method: match args.method.unwrap_or(MethodArg::Qs) {
            MethodArg::Qs => Method::Qs,
            MethodArg::Tikhonov => Method::Tikhonov,
            MethodArg::Scaled => Method::Scaled,
            MethodArg::Ls => Method::Ls,
            MethodArg::Dynamic => Method::Dynamic,
            MethodArg::Soft => Method::Soft,
        },
        cone: match args.cone {
            ConeArg::Exact => ConeModel::Exact,
            ConeArg::Pyramid4 => ConeModel::Pyramid(4),
            ConeArg::Pyramid8 => ConeModel::Pyramid(8),
            ConeArg::Pyramid16 => ConeModel::Pyramid(16),
        },
        lambda: args.lambda,
        allow_infeasible: args.allow_infeasible,
        wall_weight: args.wall_weight,
        stress_noise: match args.stress_noise {
            StressNoiseArg::Absolute => StressNoise::Absolute,
            StressNoiseArg::Relative => StressNoise::Relative,
            StressNoiseArg::Columns => StressNoise::Columns,
        },
        on_collapse: match (args.method, args.accept_degenerate) {
            (_, true) => OnCollapse::Accept,
            (None, false) => OnCollapse::Switch,
            (Some(_), false) => OnCollapse::Fail,
        },
        ..InferOptions::default()
    };
    if let Some(l) = args.lambda {
        if !(l >= 0.0 && l.is_finite()) {
            return Err(Error::Invalid(format!(
                "--lambda must be finite and ≥ 0, got {l}"
            )));
        }
    }
    if let Some(tolerance) = args.tolerance {
        if !(tolerance > 0.0 && tolerance < 1.0) {
            return Err(Error::Invalid(format!(
                "--tolerance must lie in (0, 1), got {tolerance}"
            )));
        }
        opts.conic.tolerance = tolerance;
        opts.conic.noise_share = None;
    }
    if !(args.wall_weight > 0.0 && args.wall_weight.is_finite()) {
        return Err(Error::Invalid("--wall-weight must be positive".into()));
    }
    opts.solver = match args.solver {
        SolverArg::ActiveSet => ConstrainedSolver::ActiveSet,
        SolverArg::InteriorPoint => ConstrainedSolver::InteriorPoint,
    };
    opts.ordering = match args.ordering {
        OrderingArg::Auto => None,
        OrderingArg::Amd => Some(Ordering::Amd),
        OrderingArg::NestedDissection => Some(Ordering::NestedDissection),
    };
    opts.assemble.mu = args.mu;
    if let Some(g) = &args.gravity {
        let v = numbers("--gravity", g)?;
        if !(2..=3).contains(&v.len()) {
            return Err(Error::Invalid("--gravity takes 2 or 3 components".into()));
        }
        let mut g = [0.0; 3];
        g[..v.len()].copy_from_slice(&v);
        opts.assemble.gravity = Some(g);
    }
    if let Some(r) = &args.lambda_range {
        let (lo, hi) = range("--lambda-range", r)?;
        opts.lambda_search.min = lo;
        opts.lambda_search.max = hi;
    }
    opts.lambda_search.precision = match args.lambda_precision {
        LambdaPrecisionArg::Fine => LambdaPrecision::Fine,
        LambdaPrecisionArg::Coarse => LambdaPrecision::Coarse,
    };
    let accel_sd = args.accel_sd.unwrap_or(0.0);
    if !(args.stress_sd >= 0.0
        && accel_sd >= 0.0
        && args.stress_sd.is_finite()
        && accel_sd.is_finite())
    {
        return Err(Error::Invalid(
            "--stress-sd and --accel-sd must be finite and ≥ 0".into(),
        ));
    }
    opts.dynamic.rule = match args.lambda_rule {
        RuleArg::Weights => LambdaRule::Weights {
            stress_sd: args.stress_sd,
            momentum_sd: accel_sd,
        },
        RuleArg::Knee => LambdaRule::Knee,
        RuleArg::Variance => LambdaRule::Variance,
        RuleArg::Hard => LambdaRule::Hard,
        RuleArg::Fixed => LambdaRule::Fixed(
            args.lambda
                .ok_or_else(|| Error::Invalid("--lambda-rule fixed needs --lambda".into()))?,
        ),
    };
    if args.pareto.is_some()
        && args.lambda_rule != RuleArg::Knee
        && matches!(opts.method, Method::Dynamic | Method::Soft)
    {
        // The front is still wanted: sweep it, but keep the chosen rule's λ.
        opts.dynamic_front = true;
    }
    let (lo, hi) = range("--sweep", &args.sweep)?;
    opts.dynamic.sweep_min = lo;
    opts.dynamic.sweep_max = hi;
    opts.dynamic.sweep_points = args.sweep_points;
    let selection = if let Some(ids) = &args.grains {
        Selection::Grains(
            ids.split(',')
                .map(|s| s.trim().to_owned())
                .filter(|s| !s.is_empty())
                .collect(),
        )
    } else if let Some(r) = &args.region {
        let v = numbers("--region", r)?;
        if v.len() % 2 != 0 || v.len() < 4 {
            return Err(Error::Invalid(
                "--region takes min,max pairs per axis".into(),
            ));
        }
        Selection::Region(v.chunks(2).map(|c| (c[0], c[1])).collect())
    } else {
        Selection::All
    };
    Ok((opts, selection))
}

/// Bootstrap standard deviations per frame (frames and draws in parallel).
fn uncertainty(
    args: &Args,
    draws: usize,
    frames: &[scene::Scene],
    per_frame: &[InferOptions],
    results: &[infer::Inference],
) -> Result<Vec<Uncertainty>> {
    if draws < 2 {
        return Err(Error::Invalid(format!(
            "--uncertainty needs at least 2 draws, got {draws}"
        )));
    }
    let noise = match args.noise_level {
        Some(s) if s.is_finite() && s >= 0.0 => NoiseEstimate::Relative(s),
        Some(s) => {
            return Err(Error::Invalid(format!(
                "--noise-level must be finite and ≥ 0, got {s}"
            )))
        }
        None => NoiseEstimate::FromResidual,
    };
    let options = UncertaintyOptions {
        draws,
        seed: args.uncertainty_seed as u64,
        noise,
    };
    frames_uncertainty(frames, per_frame, results, &options)
}

/// What `--time-fit joint` needs, checked before any frame is inferred.
fn check_time_fit(args: &Args, opts: &InferOptions, selection: &Selection) -> Result<f64> {
    if opts.method != Method::Dynamic {
        return Err(Error::Invalid(
            "--time-fit joint fits momentum over time: use it with --method dynamic".into(),
        ));
    }
    if *selection != Selection::All {
        return Err(Error::Invalid(
            "--time-fit joint infers whole frames: drop --grains/--region".into(),
        ));
    }
    if args.uncertainty.is_some() {
        return Err(Error::Invalid(
            "--uncertainty resamples frame by frame; it does not combine with --time-fit joint"
                .into(),
        ));
    }
    // The library checks these too, but only after the frame-by-frame pass.
    if args.stress_sd <= 0.0 {
        return Err(Error::Invalid(format!(
            "--time-fit joint weighs the stresses by 1/σ_s: --stress-sd must be positive, got {}",
            args.stress_sd
        )));
    }
    if let Some(r) = args.roughness.filter(|r| !(*r > 0.0 && r.is_finite())) {
        return Err(Error::Invalid(format!(
            "--roughness must be positive and finite, got {r}"
        )));
    }
    args.fps
        .ok_or_else(|| Error::Invalid("--time-fit joint needs the frame rate: give --fps".into()))
}

/// The joint time fit of `--time-fit joint`, from the frame-by-frame answer.
fn time_fit(
    args: &Args,
    opts: &InferOptions,
    fps: f64,
    frames: &[scene::Scene],
    results: &[infer::Inference],
) -> Result<time_fit::TimeFit> {
    let fit = time_fit::TimeFitOptions {
        fps,
        position_sd: args.position_sd,
        stress_sd: args.stress_sd,
        roughness: args.roughness,
    };
    let frame_by_frame: Vec<Vec<Option<grainforce::scene::Vec3>>> =
        results.iter().map(|r| r.forces.clone()).collect();
    time_fit::infer_time_fit(frames, opts, &fit, Some(&frame_by_frame))
}

/// The bar drawn on stderr while the frames of a sequence are inferred.
fn frame_bar(frames: usize) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} frames, {elapsed} elapsed, ETA {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

pub fn run(args: Args) -> Result<Finished> {
    let (opts, selection) = options(&args)?;
    let joint_fps = match args.time_fit {
        TimeFitArg::Frames => None,
        TimeFitArg::Joint => Some(check_time_fit(&args, &opts, &selection)?),
    };
    let plan = sequence_plan(&args, selection)?;
    let (frames, scope) = sequence::read(&args.scene, &opts, &plan)?;
    if let (Some(reason), false) = (scope.whole_because, args.quiet) {
        eprintln!("note: --frames reads every frame: {reason} (--position-sd or --accel-sd)");
    }
    let prepared = sequence::prepare(frames, &opts, &plan)?;
    if let (Some(k), false) = (&prepared.derived, args.quiet) {
        eprintln!(
            "accelerations derived from {} tracks ({} partial, {} too short: zero); position noise {:.3e} m {}",
            k.tracks,
            k.partial_tracks,
            k.short_tracks.len(),
            k.position_sd,
            if args.position_sd.is_some() {
                "(stated)"
            } else {
                "estimated from the tracks"
            }
        );
    }
    let sequence::PreparedSequence {
        frames,
        options: per_frame,
        ..
    } = prepared;
    let outcomes = if frames.len() == 1 {
        vec![FrameOutcome::Inferred(Box::new(infer::infer(
            &frames[0],
            &per_frame[0],
        )?))]
    } else {
        let bar = (!args.quiet).then(|| frame_bar(frames.len()));
        let advance = |p: infer::Progress| {
            if let Some(bar) = &bar {
                bar.set_position(p.done as u64);
            }
        };
        let on_failure = if args.stop_on_failure {
            OnFrameFailure::Stop
        } else {
            OnFrameFailure::Continue
        };
        let outcomes = sequence::solve_frames(&frames, &per_frame, on_failure, Some(&advance));
        if let Some(bar) = bar {
            bar.finish_and_clear();
        }
        outcomes?
    };
    let single_frame = frames.len() == 1;
    let sequence::Solved {
        frames,
        per_frame,
        mut results,
        failures,
        entries,
    } = sequence::split_outcomes(args.stop_on_failure, frames, per_frame, outcomes)?;
    for (_, error) in &failures {
        eprintln!("not written: {error}");
    }
    if !failures.is_empty() && joint_fps.is_some() {
        return Err(Error::Invalid(format!(
            "--time-fit joint fits every frame at once, and {} frames failed (listed above)",
            failures.len()
        )));
    }
    let time_fit = match joint_fps {
        None => None,
        Some(fps) => {
            let fit = time_fit(&args, &opts, fps, &frames, &results)?;
            for (result, forces) in results.iter_mut().zip(fit.forces) {
                result.forces = forces;
            }
            Some(fit.report)
        }
    };
    let uncertainties = match args.uncertainty {
        Some(draws) => Some(uncertainty(
            &args,
            draws as usize,
            &frames,
            &per_frame,
            &results,
        )?),
        None => None,
    };
    let mut rows = Vec::new();
    for (i, (frame, result)) in frames.iter().zip(&results).enumerate() {
        for (c, f) in result.forces.iter().enumerate() {
            if let Some(f) = f {
                rows.push(scene::ForceRow {
                    contact: frame.contacts[c].id.clone(),
                    frame: frame.frame,
                    force: *f,
                    // A contact every draw left out has no spread: write zero.
                    sd: uncertainties
                        .as_ref()
                        .map(|u| u[i].sd[c].unwrap_or([0.0; 3])),
                });
            }
        }
    }
    let forces = Forces {
        dim: frames[0].dim,
        rows,
    };
    // Outputs are gathered first and written once nothing can fail any more,
    // so a failed run leaves no file behind.
    let mut pending: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    let mut impulse_summary = None;
    if let Some(path) = &args.report {
        let reports: Vec<&infer::InferenceReport> = results.iter().map(|r| &r.report).collect();
        let json = if let Some(fit) = &time_fit {
            // The frames' reports describe the frame-by-frame start.
            serde_json::to_string_pretty(&serde_json::json!({
                "time_fit": fit,
                "frame_by_frame": reports,
            }))
        } else if single_frame {
            serde_json::to_string_pretty(reports[0])
        } else {
            serde_json::to_string_pretty(&sequence::sequence_report(&entries, &reports))
        }
        .map_err(|e| Error::Invalid(e.to_string()))?;
        pending.push((path.clone(), json.into_bytes()));
    }
    if let (Some(path), false) = (&args.impulse, failures.is_empty()) {
        eprintln!(
            "impulse check not written to {}: it integrates every frame's forces, and {} frames failed",
            path.display(),
            failures.len()
        );
    } else if let Some(path) = &args.impulse {
        let fps = args
            .fps
            .ok_or_else(|| Error::Invalid("--impulse needs the frame rate: give --fps".into()))?;
        let gravity = opts.assemble.gravity.unwrap_or_else(|| frames[0].gravity());
        let forces: Vec<Vec<Option<grainforce::scene::Vec3>>> =
            results.iter().map(|r| r.forces.clone()).collect();
        let options = kinematics::ImpulseOptions {
            window: args.impulse_window,
            position_sd: args.position_sd,
            ..Default::default()
        };
        let check = kinematics::impulse_check(&frames, &forces, fps, gravity, &options)?;
        let dim = frames[0].dim;
        let axes = &["x", "y", "z"][..dim];
        let mut text = String::from("grain,first_frame,last_frame,start_window,end_window");
        for a in axes {
            text.push_str(&format!(",dv_{a}_measured,dv_{a}_inferred"));
        }
        text.push_str(",dv_sd,disagreement,gap_in_sd,moves\n");
        for r in &check.rows {
            text.push_str(&format!(
                "{},{},{},{},{}",
                r.grain, r.first_frame, r.last_frame, r.start_window, r.end_window
            ));
            for k in 0..dim {
                text.push_str(&format!(",{},{}", r.measured[k], r.inferred[k]));
            }
            text.push_str(&format!(
                ",{},{},{},{}\n",
                r.measured_sd,
                r.disagreement,
                r.gap_in_sd,
                u8::from(r.moves)
            ));
        }
        impulse_summary = Some(check);
        pending.push((path.clone(), text.into_bytes()));
    }
    let mut front_to_write = None;
    if let Some(path) = &args.pareto {
        let front = results
            .first()
            .and_then(|r| r.report.pareto.as_ref())
            .ok_or_else(|| Error::Invalid("--pareto needs --method dynamic or soft".into()))?;
        if results.len() > 1 {
            eprintln!("note: --pareto writes the front of the first frame");
        }
        front_to_write = Some((path, front));
    }
    // Everything that can fail is done before the forces file is written.
    let picture = match &args.plot {
        Some(_) => {
            let first = &results[0];
            let title = format!("{} - {} forces", args.scene.display(), first.report.method);
            let opts = grainforce::report::forcechain::ForceChainOptions {
                title: Some(title),
                ..Default::default()
            };
            let sd: Option<Vec<grainforce::scene::Vec3>> = uncertainties
                .as_ref()
                .map(|u| u[0].sd.iter().map(|s| s.unwrap_or([0.0; 3])).collect());
            Some(grainforce::report::forcechain::draw_force_chains_with_sd(
                &frames[0],
                &first.forces_or_zero(),
                sd.as_deref(),
                &opts,
            )?)
        }
        None => None,
    };
    scene::write_forces(&args.output, &forces)?;
    for (path, bytes) in &pending {
        scene::write_file_atomically(path, bytes)?;
    }
    if let Some((path, front)) = front_to_write {
        grainforce::report::pareto::write_pareto_csv(path, &front.points, front.knee)?;
    }
    if let (Some(path), Some(img)) = (&args.plot, &picture) {
        grainforce::report::chart::save_png(path, img)?;
    }
    if !args.quiet {
        match &time_fit {
            Some(fit) => eprint!("{fit}"),
            None => {
                for r in &results {
                    eprint!("{}", r.report);
                }
            }
        }
        for u in uncertainties.iter().flatten() {
            eprintln!(
                "uncertainty {} draws ({} failed), stress noise {:.3} ({}), {:.3} s",
                u.draws,
                u.failed_draws,
                u.noise_level,
                if u.estimated {
                    "from the residual"
                } else {
                    "stated"
                },
                u.time
            );
        }
        if let Some(check) = &impulse_summary {
            let moving: Vec<f64> = check.moving().map(|r| r.disagreement).collect();
            eprintln!(
                "impulse check: {} grains ({} skipped, tracks shorter than {} frames), position sd {:.3e} m ({}), {} move (|Δv| ≥ {} sd); worst disagreement of a moving grain {:.1} %",
                check.rows.len(),
                check.skipped.len(),
                check.options.window + 1,
                check.position_sd,
                if check.position_sd_estimated {
                    "estimated from the tracks"
                } else {
                    "stated"
                },
                moving.len(),
                check.options.moving_factor,
                100.0 * check.worst_moving_disagreement()
            );
        }
        eprintln!(
            "wrote {} forces to {}",
            forces.rows.len(),
            args.output.display()
        );
    }
    if failures.is_empty() {
        Ok(Finished::AllFrames)
    } else {
        eprintln!(
            "{} of {} frames failed (listed above); the others were written",
            failures.len(),
            failures.len() + results.len()
        );
        Ok(Finished::FramesFailed)
    }
}

/// How `infer` ended when it wrote its outputs.
pub enum Finished {
    AllFrames,
    /// Some frames failed and the others were written (exit status
    /// [`FRAMES_FAILED_EXIT`]).
    FramesFailed,
}

/// Exit status when some frames of a sequence failed and the others were written.
pub const FRAMES_FAILED_EXIT: u8 = 3;
