//! `grainforce dem`: synthetic ground-truth scenes by the discrete element method.

use grainforce::dem::{self, ContactLaw, DemConfig, Preset, SizeDistribution};
use std::path::PathBuf;

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum PresetArg {
    /// Oedometric test: fixed frictionless side and bottom walls, servo top wall,
    /// no gravity (2D: 58 disks, radii 2.5–4 mm, μ = 0.5, k_n = k_t = 67.5 kN/mm,
    /// 30 kPa; 3D: 77 quartz-like spheres ~0.6 mm, density 2650, 70 N).
    Oedometer,
    /// N grains compressed isotropically by servo walls (default 1000).
    Box,
    /// Six Ø 44.45 mm polyurethane disks in a corner struck by a heavy impactor
    /// at (−1.141, −0.66) m/s; 5000 frames/s over 0.028 s (2D, gravity).
    Impact,
    /// A settled bed of 400 bidisperse disks (Ø 2.54 / 3.175 cm, μ = 0.6) hit by a
    /// Ø 20 cm steel intruder at 2.4 m/s; 4500 frames/s over 0.03 s (2D, gravity).
    BedImpact,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum LawArg {
    /// Linear spring–dashpot (k_n, k_t).
    Linear,
    /// Hertz–Mindlin (E, ν): f_n ∝ δ^{3/2}, k_t ∝ √(R* δ).
    Hertz,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum SizesArg {
    /// Radii uniform in [--radius-min, --radius-max].
    Uniform,
    /// Half the grains (by number) of each radius --radius-min, --radius-max.
    Bidisperse,
    /// p(R) ∝ 1/R² on [--radius-min, --radius-max].
    InverseSquare,
}

const DETAILS: &str = "\
Runs a DEM preset and writes a scene folder with the exact contact forces.

Writes grains.csv (centroid, volume, stress from V σ = Σ sym(r ⊗ f) with r
from the centroid, tension positive, radius, mass, inertia), contacts.csv
(point on the line of centres, normal from a to b, per-contact mu),
walls.csv (force of each wall on the grains), scene.json, forces.csv (the
DEM's contact forces, force on `a` by `b`) and dem_report.json (what the
quasi-static gate reached, residuals, time step). Quasi-static presets relax
until the unbalanced-force ratio (mean net force on grains / mean contact
force), the moment ratio and the kinetic/elastic energy ratio are all below
--gate. Dynamic presets write a `frame` column with kinematic accelerations
(gravity included: Σ f = m (a − g)) and angular accelerations.
In 2D everything is per unit thickness; contact laws act on a disk of
--thickness and are divided by it.";

#[derive(clap::Args)]
#[command(after_help = DETAILS)]
pub struct Args {
    /// Which scene to prepare.
    #[arg(value_enum)]
    preset: PresetArg,
    /// Output scene folder (created if needed).
    #[arg(short, long)]
    output: PathBuf,
    /// Number of grains (default: the preset's).
    #[arg(long)]
    grains: Option<usize>,
    /// Random seed (same seed, same scene).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Dimension: 2 (disks) or 3 (spheres).
    #[arg(long, default_value_t = 2)]
    dim: usize,
    /// Quasi-static gate on the out-of-balance ratios (use ~1e-10 for inference tests).
    #[arg(long, allow_hyphen_values = true)]
    gate: Option<f64>,
    /// Contact law (default: linear for oedometer/box, Hertz for the impacts).
    #[arg(long, value_enum)]
    law: Option<LawArg>,
    /// 2D out-of-plane thickness [m] (recorded in scene.json).
    #[arg(long, allow_hyphen_values = true)]
    thickness: Option<f64>,
    /// Dynamic presets: steps between frames (default: from the frame rate).
    #[arg(long)]
    frames_every: Option<u64>,
    /// Dynamic presets: simulated time after the impact [s].
    #[arg(long, allow_hyphen_values = true)]
    duration: Option<f64>,
    /// Grain–grain friction coefficient.
    #[arg(long, allow_hyphen_values = true)]
    mu: Option<f64>,
    /// Wall friction coefficient (0: frictionless).
    #[arg(long, allow_hyphen_values = true)]
    wall_mu: Option<f64>,
    /// Target stress of the servo walls [Pa].
    #[arg(long, allow_hyphen_values = true)]
    pressure: Option<f64>,
    /// Box preset: the top and bottom walls load to this multiple of the
    /// pressure (triaxial; friction mobilised near the packing's strength).
    #[arg(long, allow_hyphen_values = true)]
    deviator: Option<f64>,
    /// Coefficient of restitution of grain–grain contacts.
    #[arg(long, allow_hyphen_values = true)]
    restitution: Option<f64>,
    /// Size distribution (with --radius-min and --radius-max).
    #[arg(long, value_enum)]
    sizes: Option<SizesArg>,
    /// Smallest grain radius [m].
    #[arg(long, allow_hyphen_values = true)]
    radius_min: Option<f64>,
    /// Largest grain radius [m].
    #[arg(long, allow_hyphen_values = true)]
    radius_max: Option<f64>,
    /// Time step as a fraction of √(m_min/k_max).
    #[arg(long, allow_hyphen_values = true)]
    safety: Option<f64>,
    /// Step limit for the relaxation.
    #[arg(long)]
    max_steps: Option<u64>,
    /// Print progress.
    #[arg(long, short)]
    verbose: bool,
}

pub fn run(args: Args) -> grainforce::Result<()> {
    let preset = match args.preset {
        PresetArg::Oedometer => Preset::Oedometer,
        PresetArg::Box => Preset::Box,
        PresetArg::Impact => Preset::Impact,
        PresetArg::BedImpact => Preset::BedImpact,
    };
    if args.dim != 2 && args.dim != 3 {
        return Err(grainforce::Error::Invalid(format!(
            "--dim must be 2 or 3 (got {})",
            args.dim
        )));
    }
    let mut c = DemConfig::preset(preset, args.dim).seed(args.seed);
    if let Some(n) = args.grains {
        c.grains = n;
    }
    if let Some(g) = args.gate {
        c.gate = g;
    }
    if let Some(l) = args.law {
        c.law = match l {
            LawArg::Linear => ContactLaw::Linear,
            LawArg::Hertz => ContactLaw::Hertz,
        };
    }
    if let Some(t) = args.thickness {
        c.thickness = t;
    }
    if let Some(k) = args.frames_every {
        if k == 0 {
            return Err(grainforce::Error::Invalid(
                "--frames-every must be at least 1".into(),
            ));
        }
        c.frames_every = Some(k);
    }
    if let Some(d) = args.duration {
        c.duration = d;
    }
    if let Some(m) = args.mu {
        c.grain.mu = m;
    }
    if let Some(m) = args.wall_mu {
        c.wall.mu = m;
    }
    if let Some(d) = args.deviator {
        c.deviator = d;
    }
    if let Some(p) = args.pressure {
        c.pressure = p;
    }
    if let Some(e) = args.restitution {
        c.grain.restitution = e;
    }
    if let Some(s) = args.safety {
        c.safety = s;
    }
    if let Some(s) = args.max_steps {
        c.max_steps = s;
    }
    if args.sizes.is_some() || args.radius_min.is_some() || args.radius_max.is_some() {
        let lo = args.radius_min.unwrap_or(c.sizes.min_radius());
        let hi = args.radius_max.unwrap_or(c.sizes.max_radius());
        c.sizes = match args.sizes.unwrap_or(SizesArg::Uniform) {
            SizesArg::Uniform => SizeDistribution::Uniform { min: lo, max: hi },
            SizesArg::Bidisperse => SizeDistribution::Bidisperse {
                small: lo,
                large: hi,
                fraction_small: 0.5,
            },
            SizesArg::InverseSquare => SizeDistribution::InverseSquare { min: lo, max: hi },
        };
    }
    let verbose = args.verbose;
    let run = dem::simulate_with_progress(&c, &mut |p| {
        if verbose {
            eprintln!("{p}");
        }
    })?;
    dem::write_run(&args.output, &run)?;
    let r = &run.report;
    status!(
        "{}: {} grains, {} contacts{}, {} steps of {:.3e} s, unbalanced ratio {:.2e}, moment ratio {:.2e}, \
         kinetic/elastic {:.2e} (gate {:.1e}: {}), max residual {:.2e}, {:.1} s",
        args.output.display(),
        r.grains,
        r.contacts,
        if run.frames.len() > 1 {
            format!(" (last of {} frames)", run.frames.len())
        } else {
            String::new()
        },
        r.steps,
        r.time_step,
        r.unbalanced_ratio,
        r.moment_ratio,
        r.kinetic_ratio,
        r.gate,
        if r.passed { "reached" } else { "NOT reached" },
        r.max_momentum_residual,
        r.seconds
    );
    if !r.passed {
        eprintln!(
            "warning: the quasi-static gate was not reached within {} steps; see dem_report.json",
            c.max_steps
        );
    }
    Ok(())
}
