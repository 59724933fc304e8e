//! `grainforce photoelastic`: contact forces fitted to a photoelastic
//! photograph's fringes, all disks at once, under balance and friction.

use grainforce::image::fringe_fit::{
    fit_fringes, fit_fringes_per_disk, fitted_image, wall_scale, Balance, FringeFitSettings,
};
use grainforce::image::{load_channel, Channel, FloatImage, PixelFrame, FRAME_FILE};
use grainforce::scene::{read_scene, write_file_atomically, write_forces, Forces};
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The photograph (dark-field circular polariscope).
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
    /// Friction coefficient where a contact and the scene give none.
    #[arg(long, default_value_t = 0.5)]
    mu: f64,
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
    /// Write the photograph and the fitted fringes side by side (PNG).
    #[arg(long)]
    overlay: Option<PathBuf>,
    /// Write the fit report (per-disk residuals, balance, settings) as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    let scene = read_scene(&args.scene)?;
    let image = load_channel(&args.image, args.channel)?;
    let frame = match args.scale {
        Some(s) => PixelFrame::at_origin(s, image.width(), image.height()),
        None => {
            let path = args.scene.join(FRAME_FILE);
            if !path.exists() {
                return Err(Error::Invalid(format!(
                    "no --scale given and no {FRAME_FILE} in {}",
                    args.scene.display()
                )));
            }
            PixelFrame::read(&path)?
        }
    };
    if (frame.width, frame.height) != image.dimensions() {
        return Err(Error::data(
            &args.image,
            None,
            None,
            format!(
                "the image is {}×{} px but the scene's pixel frame is {}×{}",
                image.width(),
                image.height(),
                frame.width,
                frame.height
            ),
        ));
    }
    let thickness = args.thickness.or(scene.settings.thickness);
    if let Some(t) = thickness.filter(|t| !(t.is_finite() && *t > 0.0)) {
        return Err(Error::Invalid(format!(
            "--thickness: must be positive, not {t}"
        )));
    }
    let walls_measured = scene.walls.iter().any(|w| w.measured_force.is_some());
    let fringe_stress = match (args.fsigma, thickness) {
        (Some(f), _) if !(f.is_finite() && f > 0.0) => {
            return Err(Error::Invalid(format!(
                "--fsigma: must be positive, not {f}"
            )))
        }
        (Some(f), Some(t)) => f / t,
        (Some(_), None) => {
            return Err(Error::Invalid(
                "--fsigma needs the disks' thickness: give --thickness or set it in scene.json"
                    .into(),
            ))
        }
        // Forces scale with f_σ: fit at 1 Pa, then scale to the walls.
        (None, _) if walls_measured => 1.0,
        (None, _) => {
            return Err(Error::Invalid(
                "give --fsigma, or walls.csv with the walls' measured forces to fit it".into(),
            ))
        }
    };
    let mut settings = FringeFitSettings::new(fringe_stress);
    settings.mu = args.mu;
    settings.blur_px = args.blur;
    settings.edge_px = args.edge;
    settings.max_iterations = args.iterations;
    if let Some(w) = args.balance_weight {
        settings.balance = Balance::Penalty(w);
    }
    let mut fit = if args.per_disk {
        fit_fringes_per_disk(&image, &frame, &scene, &settings)?
    } else {
        fit_fringes(&image, &frame, &scene, &settings)?
    };
    let mut fsigma_fitted = None;
    if args.fsigma.is_none() {
        let k = wall_scale(&scene, &fit.forces).ok_or_else(|| {
            Error::Invalid(
                "cannot fit f_σ: no measured wall has a contact with compressive fitted force"
                    .into(),
            )
        })?;
        for f in &mut fit.forces {
            f[0] *= k;
            f[1] *= k;
        }
        settings.fringe_stress *= k;
        fit.report.fringe_stress = settings.fringe_stress;
        fsigma_fitted = Some(settings.fringe_stress * thickness.unwrap_or(1.0));
    }
    let forces: Vec<_> = fit.forces.iter().map(|f| [f[0], f[1], 0.0]).collect();
    write_forces(&args.output, &Forces::from_scene(&scene, &forces))?;
    status!("wrote {}", args.output.display());
    if let Some(path) = &args.report {
        let mut value = serde_json::to_value(&fit.report).expect("the report serialises");
        if let Some(f) = fsigma_fitted {
            value["fsigma_fitted_to_walls"] = serde_json::json!(f);
            value["fsigma_thickness_assumed"] = serde_json::json!(thickness.is_none());
        }
        let text = serde_json::to_string_pretty(&value).expect("json");
        write_file_atomically(path, (text + "\n").as_bytes())?;
        status!("wrote {}", path.display());
    }
    if let Some(path) = &args.overlay {
        let fitted = fitted_image(&image, &frame, &scene, &settings, &fit.forces)?;
        let (w, h) = image.dimensions();
        let both = FloatImage::from_fn(2 * w, h, |x, y| {
            if x < w {
                *image.get_pixel(x, y)
            } else {
                *fitted.get_pixel(x - w, y)
            }
        });
        grainforce::image::save_gray(path, &both, 8)?;
        status!("wrote {}", path.display());
    }
    let r = &fit.report;
    status!(
        "{} disks, {} contacts: fringe residual {:.4} → {:.4} in {} steps, imbalance median {:.2e}, {} disk(s) flagged, {:.2} s",
        scene.grains.len(),
        scene.contacts.len(),
        r.objective_start,
        r.objective,
        r.iterations,
        r.median_imbalance,
        r.flagged.len(),
        r.seconds
    );
    Ok(())
}
