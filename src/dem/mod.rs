//! A discrete element method (DEM) simulator that writes ground-truth scenes:
//! soft disks (2D) or spheres (3D), linear or Hertz–Mindlin contacts with a
//! Coulomb-capped tangential spring, plane and ball walls (fixed, moving,
//! free or servo-controlled), gravity, velocity-Verlet integration and a
//! cell-grid Verlet neighbour list (O(N) per step).
//!
//! [`simulate`] runs a [`Preset`] described by a [`DemConfig`] and returns the
//! frames (scenes in the data contract) with the exact contact forces the
//! integrator used; [`write_run`] writes them as a scene folder plus
//! forces.csv. Quasi-static presets relax until the out-of-balance gate is met
//! (see [`GateReport`]); dynamic presets record frames with the kinematic
//! accelerations, so Σ f = m (a − g) and Σ r × f = I α hold to round-off.

// Index loops over x, y, z read more plainly than iterator chains in numeric code.
#![allow(clippy::needless_range_loop)]

pub mod law;
mod output;
pub mod perturb;
mod presets;
pub mod sim;

pub use law::ContactLaw;
pub use output::{balance_residuals, stress_residual, BalanceResiduals};

use crate::error::{Error, Result};
use crate::scene::{self, Scene, Vec3};
use std::path::Path;

/// The prepared scenes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Preset {
    /// Oedometric compression: fixed side and bottom walls (frictionless), a
    /// servo top wall loaded to the target stress, no gravity. 2D default: the
    /// original study's 58 disks; 3D default: 77 quartz-like spheres under 70 N.
    Oedometer,
    /// Isotropic compression of N grains by servo walls on every side (the scale test).
    Box,
    /// Six disks in a corner struck by a heavy impactor (dynamic, 2D).
    Impact,
    /// A gravity-settled bidisperse bed hit by a heavy intruder (dynamic, 2D).
    BedImpact,
}

impl Preset {
    pub fn name(self) -> &'static str {
        match self {
            Preset::Oedometer => "oedometer",
            Preset::Box => "box",
            Preset::Impact => "impact",
            Preset::BedImpact => "bed-impact",
        }
    }

    pub fn is_dynamic(self) -> bool {
        matches!(self, Preset::Impact | Preset::BedImpact)
    }
}

/// Grain size distribution (radii).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum SizeDistribution {
    /// Radii uniform in [min, max].
    Uniform { min: f64, max: f64 },
    /// Two radii; each grain is small with probability `fraction_small`.
    Bidisperse {
        small: f64,
        large: f64,
        fraction_small: f64,
    },
    /// p(R) ∝ 1/R² on [min, max].
    InverseSquare { min: f64, max: f64 },
}

impl SizeDistribution {
    pub fn min_radius(&self) -> f64 {
        match *self {
            SizeDistribution::Uniform { min, .. } | SizeDistribution::InverseSquare { min, .. } => {
                min
            }
            SizeDistribution::Bidisperse { small, large, .. } => small.min(large),
        }
    }

    pub fn max_radius(&self) -> f64 {
        match *self {
            SizeDistribution::Uniform { max, .. } | SizeDistribution::InverseSquare { max, .. } => {
                max
            }
            SizeDistribution::Bidisperse { small, large, .. } => small.max(large),
        }
    }

    /// Draws a radius from a uniform variate u in [0, 1).
    pub fn sample(&self, u: f64) -> f64 {
        match *self {
            SizeDistribution::Uniform { min, max } => min + u * (max - min),
            SizeDistribution::Bidisperse {
                small,
                large,
                fraction_small,
            } => {
                if u < fraction_small {
                    small
                } else {
                    large
                }
            }
            // Inverse CDF of p ∝ 1/R²: 1/R is uniform between 1/max and 1/min.
            SizeDistribution::InverseSquare { min, max } => {
                1.0 / (1.0 / min - u * (1.0 / min - 1.0 / max))
            }
        }
    }

    fn validate(&self) -> Result<()> {
        let (a, b) = (self.min_radius(), self.max_radius());
        if !(a > 0.0 && b.is_finite() && a <= b) {
            return Err(Error::Invalid(format!(
                "grain radii must be positive and finite with min ≤ max (got {a} and {b})"
            )));
        }
        if let SizeDistribution::Bidisperse { fraction_small, .. } = *self {
            if !(0.0..=1.0).contains(&fraction_small) {
                return Err(Error::Invalid(format!(
                    "the fraction of small grains must lie in [0, 1] (got {fraction_small})"
                )));
            }
        }
        Ok(())
    }
}

/// Material of grains or walls. The linear law uses `kn`, `kt`; Hertz–Mindlin
/// uses `young`, `poisson`. In 2D the laws give the force on a disk of
/// thickness `DemConfig::thickness`, divided by it (everything per unit thickness).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Material {
    /// Normal stiffness [N/m] (linear law).
    pub kn: f64,
    /// Tangential stiffness [N/m] (linear law).
    pub kt: f64,
    /// Young's modulus [Pa] (Hertz); infinite for a rigid wall.
    pub young: f64,
    pub poisson: f64,
    /// Coefficient of restitution of the normal dashpot (1: none).
    pub restitution: f64,
    /// Coulomb friction coefficient (0: frictionless).
    pub mu: f64,
    /// Tangential dashpot as a fraction of the normal one's dimensionless
    /// coefficient (0: none).
    pub tangential_damping: f64,
}

/// Everything a run needs. Build with [`DemConfig::preset`] and adjust fields
/// or use the builder methods.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DemConfig {
    pub preset: Preset,
    pub dim: usize,
    pub grains: usize,
    pub seed: u64,
    /// Quasi-static gate: both out-of-balance ratios (force and moment) and
    /// kinetic/elastic energy must fall below it.
    pub gate: f64,
    pub law: ContactLaw,
    /// 2D out-of-plane thickness [m]; laws are evaluated for a disk this thick
    /// and divided by it, and it is recorded in scene.json.
    pub thickness: f64,
    pub sizes: SizeDistribution,
    /// Grain density [kg/m³].
    pub density: f64,
    pub grain: Material,
    pub wall: Material,
    /// Target stress of the servo walls [Pa] (static presets).
    pub pressure: f64,
    /// Box preset: the `top` and `bottom` walls load to `deviator` × `pressure`
    /// (a triaxial state; 1 is isotropic). A deviatoric load near the
    /// packing's strength mobilises friction: many contacts slide.
    pub deviator: f64,
    /// Uniform body acceleration; None for none.
    pub gravity: Option<Vec3>,
    /// Time step as a fraction of √(m_min / k_max).
    pub safety: f64,
    /// For Hertz: the overlap (relative to the smallest radius) at which the
    /// contact stiffness is evaluated for the time step.
    pub overlap_ref: f64,
    /// Cundall local damping used while relaxing (never in recorded dynamics).
    pub local_damping: f64,
    /// Largest relative error of a servo wall's load before the walls are frozen.
    pub stress_tolerance: f64,
    /// Step limit of the relaxation phases together.
    pub max_steps: u64,
    /// Dynamic presets: simulated time after the impact [s].
    pub duration: f64,
    /// Dynamic presets: frames per second.
    pub frame_rate: f64,
    /// Dynamic presets: steps between frames (None: from `frame_rate`; the
    /// time step is then shrunk so a whole number of steps spans a frame).
    pub frames_every: Option<u64>,
    /// Dynamic presets: impactor / intruder velocity [m/s].
    pub impact_velocity: Vec3,
    /// Dynamic presets: impactor / intruder radius [m] and mass (per unit thickness in 2D).
    pub impactor_radius: f64,
    pub impactor_mass: f64,
    /// [`simulate`] prints progress to stderr (a library user passes a
    /// callback to [`simulate_with_progress`] instead).
    pub verbose: bool,
}

impl DemConfig {
    /// The preset's defaults in dimension `dim` (validated by [`simulate`]).
    pub fn preset(preset: Preset, dim: usize) -> DemConfig {
        presets::defaults(preset, dim)
    }

    pub fn grains(mut self, n: usize) -> Self {
        self.grains = n;
        self
    }
    pub fn seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }
    pub fn gate(mut self, gate: f64) -> Self {
        self.gate = gate;
        self
    }
    pub fn law(mut self, law: ContactLaw) -> Self {
        self.law = law;
        self
    }
    pub fn thickness(mut self, t: f64) -> Self {
        self.thickness = t;
        self
    }
    pub fn frames_every(mut self, steps: u64) -> Self {
        self.frames_every = Some(steps);
        self
    }
    pub fn duration(mut self, seconds: f64) -> Self {
        self.duration = seconds;
        self
    }
    pub fn max_steps(mut self, steps: u64) -> Self {
        self.max_steps = steps;
        self
    }
    pub fn verbose(mut self, on: bool) -> Self {
        self.verbose = on;
        self
    }

    /// Checks every value; errors name the offending setting.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, v: f64| Error::Invalid(format!("{what} is out of range: {v}"));
        if self.dim != 2 && self.dim != 3 {
            return Err(Error::Invalid(format!(
                "dimension must be 2 or 3 (got {})",
                self.dim
            )));
        }
        if self.preset.is_dynamic() && self.dim != 2 {
            return Err(Error::Invalid(format!(
                "the `{}` preset is two-dimensional (disks); use --dim 2",
                self.preset.name()
            )));
        }
        if self.grains == 0 {
            return Err(Error::Invalid(
                "the number of grains must be at least 1".into(),
            ));
        }
        if self.grains > 50_000_000 {
            return Err(Error::Invalid(format!(
                "{} grains is more than this simulator handles (50 million)",
                self.grains
            )));
        }
        if !(self.gate > 0.0 && self.gate < 1.0) {
            return Err(bad("the gate (must lie in (0, 1))", self.gate));
        }
        if !(self.thickness > 0.0 && self.thickness.is_finite()) {
            return Err(bad("the thickness (must be positive)", self.thickness));
        }
        self.sizes.validate()?;
        if !(self.density > 0.0 && self.density.is_finite()) {
            return Err(bad("the density", self.density));
        }
        for (who, m) in [("grain", &self.grain), ("wall", &self.wall)] {
            match self.law {
                ContactLaw::Linear => {
                    if !(m.kn > 0.0 && m.kn.is_finite() && m.kt >= 0.0 && m.kt.is_finite()) {
                        return Err(Error::Invalid(format!(
                            "{who} stiffnesses must be finite with k_n > 0 and k_t ≥ 0 (got {} and {})",
                            m.kn, m.kt
                        )));
                    }
                }
                ContactLaw::Hertz => {
                    if !(m.young > 0.0 && m.poisson > -1.0 && m.poisson < 0.5 + 1e-12) {
                        return Err(Error::Invalid(format!(
                            "{who} Young's modulus must be positive and Poisson's ratio in (−1, 0.5] (got {} and {})",
                            m.young, m.poisson
                        )));
                    }
                }
            }
            if !(m.restitution > 0.0 && m.restitution <= 1.0) {
                return Err(bad(
                    &format!("the {who} restitution (must lie in (0, 1])"),
                    m.restitution,
                ));
            }
            if !(m.mu >= 0.0 && m.mu.is_finite()) {
                return Err(bad(&format!("the {who} friction coefficient"), m.mu));
            }
            if !(m.tangential_damping >= 0.0 && m.tangential_damping.is_finite()) {
                return Err(bad(
                    &format!("the {who} tangential damping"),
                    m.tangential_damping,
                ));
            }
        }
        if !(self.pressure > 0.0 && self.pressure.is_finite()) {
            return Err(bad("the pressure", self.pressure));
        }
        if !(self.deviator >= 1.0 && self.deviator <= 100.0) {
            return Err(bad(
                "the deviator ratio (must lie in [1, 100])",
                self.deviator,
            ));
        }
        if let Some(g) = self.gravity {
            if g.iter().any(|x| !x.is_finite()) || (self.dim == 2 && g[2] != 0.0) {
                return Err(Error::Invalid(format!(
                    "gravity must be finite and in-plane in 2D (got {g:?})"
                )));
            }
        }
        if !(self.safety > 0.0 && self.safety <= 0.5) {
            return Err(bad(
                "the time-step safety fraction (must lie in (0, 0.5])",
                self.safety,
            ));
        }
        if !(self.overlap_ref > 0.0 && self.overlap_ref < 1.0) {
            return Err(bad("the reference overlap", self.overlap_ref));
        }
        if !(0.0..1.0).contains(&self.local_damping) {
            return Err(bad(
                "the local damping (must lie in [0, 1))",
                self.local_damping,
            ));
        }
        if !(self.stress_tolerance > 0.0 && self.stress_tolerance < 1.0) {
            return Err(bad("the stress tolerance", self.stress_tolerance));
        }
        if self.max_steps == 0 {
            return Err(Error::Invalid("the step limit must be at least 1".into()));
        }
        if self.preset.is_dynamic() {
            if !(self.duration > 0.0 && self.duration.is_finite()) {
                return Err(bad("the duration", self.duration));
            }
            if !(self.frame_rate > 0.0 && self.frame_rate.is_finite()) {
                return Err(bad("the frame rate", self.frame_rate));
            }
            if self.frames_every == Some(0) {
                return Err(Error::Invalid("--frames-every must be at least 1".into()));
            }
            if !(self.impactor_radius > 0.0 && self.impactor_mass > 0.0) {
                return Err(Error::Invalid(
                    "the impactor needs a positive radius and mass".into(),
                ));
            }
            if self.impact_velocity.iter().any(|x| !x.is_finite()) {
                return Err(Error::Invalid("the impact velocity must be finite".into()));
            }
        }
        Ok(())
    }
}

/// What the run reached (written to dem_report.json beside the scene).
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct GateReport {
    pub preset: String,
    pub dim: usize,
    pub grains: usize,
    /// Contacts in the (last) written frame.
    pub contacts: usize,
    /// The requested gate.
    pub gate: f64,
    /// Whether the quasi-static state met the gate (for dynamic presets: the
    /// settled state before the impact).
    pub passed: bool,
    /// Mean |Σ f + m g| over grains / mean |f| over contacts (YADE's measure).
    pub unbalanced_ratio: f64,
    /// Mean |Σ r × f| over grains / (mean |f| · mean radius).
    pub moment_ratio: f64,
    /// Kinetic energy and its ratio to the elastic energy in the contacts.
    pub kinetic_energy: f64,
    pub kinetic_ratio: f64,
    /// Total steps and the time step [s].
    pub steps: u64,
    pub time_step: f64,
    pub simulated_time: f64,
    /// Largest per-grain |Σ f − m (a − g)| / mean |f| over the written frames
    /// (quasi-static: a = 0).
    pub max_momentum_residual: f64,
    /// Largest per-grain |Σ r × f − I α| / (mean |f| · mean radius).
    pub max_moment_residual: f64,
    /// Largest overlap relative to the smaller radius.
    pub max_overlap: f64,
    /// Normal stress each servo-controlled (or loaded) plane wall carries at the
    /// end, and its target.
    pub wall_stress: Vec<(String, f64)>,
    pub target_stress: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// The frames of a run and their exact contact forces.
#[derive(Debug, Clone)]
pub struct DemRun {
    pub frames: Vec<Scene>,
    /// Per frame, per contact in that frame's order: force on grain `a` by `b`.
    pub forces: Vec<Vec<Vec3>>,
    pub report: GateReport,
}

impl DemRun {
    /// The true forces in the shape inference returns them (every contact known).
    pub fn force_sets(&self) -> Vec<Vec<Option<Vec3>>> {
        self.forces
            .iter()
            .map(|f| f.iter().map(|&x| Some(x)).collect())
            .collect()
    }
}

/// Runs the configured preset.
pub fn simulate(config: &DemConfig) -> Result<DemRun> {
    if config.verbose {
        simulate_with_progress(config, &mut |p| eprintln!("{p}"))
    } else {
        simulate_with_progress(config, &mut |_| {})
    }
}

/// As [`simulate`], telling `on_progress` how the run goes (the packing
/// built, the relaxation every 20 000 steps, every 20th frame of an impact)
/// instead of printing it; `verbose` is ignored.
pub fn simulate_with_progress(
    config: &DemConfig,
    on_progress: &mut dyn FnMut(&DemProgress),
) -> Result<DemRun> {
    config.validate()?;
    presets::run(config, on_progress)
}

/// What a DEM run reports while it runs.
#[derive(Debug, Clone, PartialEq)]
pub enum DemProgress {
    /// The packing is built; relaxation starts.
    Built {
        preset: &'static str,
        grains: usize,
        dim: usize,
        time_step: f64,
    },
    /// Relaxation towards the gate (`phase`: `servo` while the walls hold the
    /// target load, `relax` after), with the gate figures so far.
    Relaxing {
        phase: &'static str,
        step: u64,
        unbalanced: f64,
        moment: f64,
        servo_error: f64,
        seconds: f64,
    },
    /// A frame of a dynamic preset recorded.
    Frame {
        frame: u64,
        total: u64,
        contacts: usize,
    },
}

impl std::fmt::Display for DemProgress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DemProgress::Built {
                preset,
                grains,
                dim,
                time_step,
            } => write!(
                f,
                "grainforce dem {preset}: {grains} grains in {dim}D, time step {time_step:.3e} s"
            ),
            DemProgress::Relaxing {
                phase,
                step,
                unbalanced,
                moment,
                servo_error,
                seconds,
            } => write!(
                f,
                "  {phase}: step {step:>9}, unbalanced {unbalanced:.3e}, moment {moment:.3e}, servo error {servo_error:.3e}, {seconds:.1} s"
            ),
            DemProgress::Frame {
                frame,
                total,
                contacts,
            } => write!(f, "  impact: frame {frame}/{total}, {contacts} contacts"),
        }
    }
}

/// Builds the configured preset and relaxes it to the gate without writing
/// frames: the relaxed [`sim::System`] (for benchmarks or further driving)
/// and the gate figures. For the dynamic presets this is the settled packing
/// before the impact.
pub fn prepare(config: &DemConfig) -> Result<(sim::System, GateReport)> {
    config.validate()?;
    presets::prepare(config, &mut |_| {}).map(|(s, r, _)| (s, r))
}

/// Writes a run as a scene folder (grains.csv, contacts.csv, walls.csv,
/// scene.json) plus forces.csv (the exact forces) and dem_report.json.
pub fn write_run(dir: &Path, run: &DemRun) -> Result<()> {
    scene::write_sequence(dir, &run.frames)?;
    let mut all = scene::Forces {
        dim: run.frames.first().map(|s| s.dim).unwrap_or(2),
        rows: Vec::new(),
    };
    for (frame, forces) in run.frames.iter().zip(&run.forces) {
        all.rows
            .extend(scene::Forces::from_scene(frame, forces).rows);
    }
    scene::write_forces(&dir.join("forces.csv"), &all)?;
    let text =
        serde_json::to_string_pretty(&run.report).map_err(|e| Error::Invalid(e.to_string()))?;
    let path = dir.join("dem_report.json");
    scene::write_file_atomically(&path, (text + "\n").as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The deviatoric ratio defaults to an isotropic load and is checked.
    #[test]
    fn deviator_is_isotropic_by_default_and_validated() {
        let c = DemConfig::preset(Preset::Box, 3);
        assert_eq!(c.deviator, 1.0);
        assert!(c.validate().is_ok());
        for bad in [0.5, f64::NAN, 1e3] {
            let mut c = c.clone();
            c.deviator = bad;
            let e = c.validate().unwrap_err().to_string();
            assert!(e.contains("deviator"), "{e}");
        }
    }
}
