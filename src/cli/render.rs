//! `grainforce render`: a scene → the images a camera would take of it.

use grainforce::image::{
    render_sequence, save_gray, Elasticity, PlaneCondition, RenderOptions, FRAME_FILE,
};
use grainforce::scene::read_sequence;
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Scene folder (2D) to draw; a sequence gives one deformed image per frame.
    scene: PathBuf,
    /// Folder for reference.png, deformed.png (deformed-0000.png, … for a
    /// sequence) and image-frame.json.
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
    /// Image scale [pixels per metre].
    #[arg(long = "px-per-m")]
    px_per_m: f64,
    /// Young's modulus of the grains [Pa], to turn their stresses into strains.
    #[arg(long)]
    youngs: f64,
    /// Poisson's ratio of the grains.
    #[arg(long)]
    poisson: f64,
    /// Plane strain (long cylinders) instead of plane stress (thin disks).
    #[arg(long)]
    plane_strain: bool,
    /// Speckle feature size [px].
    #[arg(long, default_value_t = 6.0)]
    speckle: f64,
    /// Standard deviation of Gaussian pixel noise (intensity 0–1).
    #[arg(long, default_value_t = 0.0)]
    noise: f64,
    /// Optical blur, Gaussian σ [px].
    #[arg(long, default_value_t = 0.0)]
    blur: f64,
    /// Free border around the grains [px].
    #[arg(long, default_value_t = 20.0)]
    margin: f64,
    /// Bits per pixel of the PNG files (8 or 16).
    #[arg(long, default_value_t = 8)]
    bits: u8,
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub fn run(args: Args) -> Result<()> {
    let plane = if args.plane_strain {
        PlaneCondition::Strain
    } else {
        PlaneCondition::Stress
    };
    let elasticity = Elasticity::new(args.youngs, args.poisson, plane)?;
    let frames = read_sequence(&args.scene)?;
    let mut options = RenderOptions::new(args.px_per_m, elasticity);
    options.speckle_px = args.speckle;
    options.noise = args.noise;
    options.blur_px = args.blur;
    options.margin_px = args.margin;
    options.seed = args.seed;
    if args.bits != 8 && args.bits != 16 {
        return Err(Error::Invalid(format!(
            "--bits must be 8 or 16, not {}",
            args.bits
        )));
    }
    let rendered = render_sequence(&frames, &options)?;
    std::fs::create_dir_all(&args.output).map_err(|e| Error::io(&args.output, e))?;
    save_gray(
        &args.output.join("reference.png"),
        &rendered.reference,
        args.bits,
    )?;
    for (k, image) in rendered.deformed.iter().enumerate() {
        let name = if rendered.deformed.len() == 1 {
            "deformed.png".to_owned()
        } else {
            format!("deformed-{k:04}.png")
        };
        save_gray(&args.output.join(name), image, args.bits)?;
    }
    rendered.frame.write(&args.output.join(FRAME_FILE))?;
    status!(
        "wrote {} image(s) of {}×{} px to {} (detect with --frame {})",
        rendered.deformed.len() + 1,
        rendered.frame.width,
        rendered.frame.height,
        args.output.display(),
        args.output.join(FRAME_FILE).display()
    );
    Ok(())
}
