//! `grainforce photoelastic`: contact forces fitted to a photoelastic
//! photograph's fringes, all disks at once, under balance and friction.

use grainforce::image::fringe_fit::Polariscope;
use grainforce::image::fringe_run::{self, ContactChoice, PhotoelasticConfig};
use grainforce::image::Channel;
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The photograph (circular polariscope, dark or bright field: see --polariscope).
    image: PathBuf,
    /// Scene folder with the disks and contacts (from `detect` or `import pegs`).
    #[arg(long)]
    scene: PathBuf,
    /// Where to write the fitted forces (forces.csv format, N/m per unit thickness).
    #[arg(short, long)]
    output: PathBuf,
    /// Fringe constant f_σ [N/m]; without it, fitted to the walls' load
    /// cells (walls.csv), which must then be given.
    #[arg(long)]
    fsigma: Option<f64>,
    /// Disk thickness [m] (default: the scene's scene.json).
    #[arg(long)]
    thickness: Option<f64>,
    /// Pixels per metre (default: the scene's image-frame.json).
    #[arg(long)]
    scale: Option<f64>,
    /// The channel of a colour photograph that is fitted.
    #[arg(long, default_value = "green", value_parser = |s: &str| Channel::parse(s).map_err(|e| e.to_string()))]
    channel: Channel,
    /// Friction coefficient where a contact and the scene give none (1: a
    /// polymer disk's friction, ~0.6, plus the detected contact normal's
    /// error; docs/photoelastic.md, round 11).
    #[arg(long, default_value_t = fringe_run::DEFAULT_MU)]
    mu: f64,
    /// Friction coefficient of the contacts with walls (default: --mu);
    /// 0 for smooth walls.
    #[arg(long)]
    wall_mu: Option<f64>,
    /// Balance as a weighted penalty of this weight instead of exactly.
    #[arg(long)]
    balance_weight: Option<f64>,
    /// Blur of the optics [px].
    #[arg(long, default_value_t = 1.0)]
    blur: f64,
    /// Band inside each disk's edge left out of the fit (the rim) [px].
    #[arg(long, default_value_t = 6.0)]
    edge: f64,
    /// Largest number of Levenberg–Marquardt steps.
    #[arg(long, default_value_t = 60)]
    iterations: usize,
    /// The per-disk fit (each disk alone, sides averaged) instead, for comparison.
    #[arg(long)]
    per_disk: bool,
    /// Which contacts are fitted: `all` (the fringes decide which carry
    /// force), or `evidence`: only those `detect` judged force-bearing
    /// (contacts-evidence.csv; all without the file).
    #[arg(long, value_enum, default_value_t = ContactChoice::default())]
    contacts: ContactChoice,
    /// Also fit every disk pair closer than this share of the smaller radius
    /// as a candidate contact (a contact detection may have missed: a circle
    /// found a few pixels small); the candidates' forces are listed in the
    /// report, not in forces.csv. Default: 0.2 on a scene from `detect`
    /// (its contacts-evidence.csv present), off on others; 0: off. On a
    /// scene from `detect`, disks that stop short of a wall by less than
    /// this share of their radius are wall candidates too.
    #[arg(long)]
    candidates: Option<f64>,
    /// Fit contacts the fringes do not support to zero and drop them (listed
    /// in the report): a contact must explain this many pixels' worth of
    /// residual variance. Off (0) by default: measured, it drops weak true
    /// contacts and leaves the costly false ones (docs/photoelastic.md).
    #[arg(long, default_value_t = 0.0)]
    sparsity: f64,
    /// The polariscope: `dark` field (bright fringes on dark disks), `bright`
    /// field (dark fringes on bright disks), or `auto`: both fitted through
    /// the first smoothed stage and the one closer to the photograph kept;
    /// the report and the summary say which.
    #[arg(long, value_enum, default_value_t = Polariscope::Auto)]
    polariscope: Polariscope,
    /// Fit each disk's background as a plane (light falling off across the
    /// disk) instead of a constant.
    #[arg(long)]
    lighting: bool,
    /// Where disks are still flagged (fringes unexplained) after the narrow
    /// start, fit again from a fit with balance as a penalty of this weight
    /// and keep the lower residual (reported under `second_starts`); 0: off.
    #[arg(long, default_value_t = fringe_run::DEFAULT_PENALTY_START)]
    penalty_start: f64,
    /// Where the fit leaves disks flagged under exact balance, fit again
    /// from a fit with every friction wedge at this μ (when below --mu) and
    /// keep the lower residual (reported under `second_starts`); 0: off.
    #[arg(long, default_value_t = fringe_run::DEFAULT_NARROW_START)]
    narrow_start: f64,
    /// After the fit, each disk whose fringes it leaves unexplained is
    /// fitted again from up to this many starts (per-disk, fringe
    /// gradients, tangents flipped, doubled, halved) with its and its
    /// neighbours' contacts free and every other force held, balance exact;
    /// kept where the whole residual falls (0: off).
    #[arg(long, default_value_t = fringe_run::DEFAULT_LOCAL_STARTS)]
    local_starts: usize,
    /// Write the photograph and the fitted fringes side by side (PNG).
    #[arg(long)]
    overlay: Option<PathBuf>,
    /// Write the fit report (per-disk residuals, balance, settings) as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    let config = PhotoelasticConfig {
        fsigma: args.fsigma,
        thickness: args.thickness,
        scale: args.scale,
        channel: args.channel,
        mu: args.mu,
        wall_mu: args.wall_mu,
        balance_weight: args.balance_weight,
        blur: args.blur,
        edge: args.edge,
        iterations: args.iterations,
        per_disk: args.per_disk,
        contacts: args.contacts,
        candidate_gap: args.candidates,
        sparsity: args.sparsity,
        polariscope: args.polariscope,
        lighting: args.lighting,
        penalty_start: args.penalty_start,
        narrow_start: args.narrow_start,
        local_starts: args.local_starts,
    };
    let done = fringe_run::run(&args.image, &args.scene, &config).map_err(spell_flags)?;
    done.write(
        Some(&args.output),
        args.report.as_deref(),
        args.overlay.as_deref(),
    )?;
    for path in [
        Some(&args.output),
        args.report.as_ref(),
        args.overlay.as_ref(),
    ]
    .into_iter()
    .flatten()
    {
        status!("wrote {}", path.display());
    }
    let r = &done.fit.report;
    status!(
        "{} disks, {} contacts ({} fitted), {} field: fringe residual {:.4} → {:.4} in {} steps, imbalance median {:.2e}, {} disk(s) flagged, {:.2} s",
        done.scene.grains.len(),
        done.scene.contacts.len(),
        done.scene.contacts.len() - done.left_out.len(),
        if r.bright_field { "bright" } else { "dark" },
        r.objective_start,
        r.objective,
        r.iterations,
        r.median_imbalance,
        r.flagged.len(),
        r.seconds
    );
    if !r.balance_left_out.is_empty() {
        status!(
            "balance left out for {} disk(s) whose contacts cannot carry a balanced load (a contact missed?): {}",
            r.balance_left_out.len(),
            r.balance_left_out.join(", ")
        );
    }
    for warning in done.warnings() {
        eprintln!("warning: {warning}");
    }
    Ok(())
}

/// The library's `field` names as this verb's flags.
fn spell_flags(e: Error) -> Error {
    match e {
        Error::Invalid(m) => {
            let mut m = m;
            for field in [
                "fsigma",
                "thickness",
                "scale",
                "penalty_start",
                "narrow_start",
            ] {
                m = m.replace(
                    &format!("`{field}`"),
                    &format!("--{}", field.replace('_', "-")),
                );
            }
            Error::Invalid(m)
        }
        other => other,
    }
}
