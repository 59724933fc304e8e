//! `grainforce strain`: grain stresses by image correlation, into a scene.

use grainforce::image::dic::{DicOptions, Prepared};
use grainforce::image::io::check_same_size;
use grainforce::image::strain::measure_prepared;
use grainforce::image::{
    load_gray, Elasticity, PixelFrame, PlaneCondition, StrainOptions, FRAME_FILE,
};
use grainforce::scene::{read_sequence, write_sequence};
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Image of the unloaded grains.
    reference: PathBuf,
    /// Images of the loaded grains, one per frame of the scene.
    #[arg(required = true)]
    deformed: Vec<PathBuf>,
    /// Scene folder (as `detect` wrote it); its grains.csv gets the stresses.
    #[arg(long)]
    scene: PathBuf,
    /// Young's modulus of the grains [Pa].
    #[arg(long)]
    youngs: f64,
    /// Poisson's ratio of the grains.
    #[arg(long)]
    poisson: f64,
    /// Thin disks, free faces (the default).
    #[arg(long, conflicts_with = "plane_strain")]
    plane_stress: bool,
    /// Long cylinders between rigid end plates.
    #[arg(long)]
    plane_strain: bool,
    /// Subset side [px], odd.
    #[arg(long, default_value_t = 15)]
    subset: usize,
    /// Spacing of the subsets [px].
    #[arg(long, default_value_t = 2)]
    step: usize,
    /// Largest rigid motion of a grain between the reference and a deformed image [px].
    #[arg(long, default_value_t = 10)]
    search: usize,
    /// Pixels per metre (default: from the scene's image-frame.json).
    #[arg(long)]
    scale: Option<f64>,
}

pub fn run(args: Args) -> Result<()> {
    let plane = if args.plane_strain {
        PlaneCondition::Strain
    } else {
        PlaneCondition::Stress
    };
    let options = StrainOptions {
        elasticity: Elasticity::new(args.youngs, args.poisson, plane)?,
        dic: DicOptions {
            subset: args.subset,
            step: args.step,
            search_px: args.search,
            ..DicOptions::default()
        },
    };
    options.dic.validate()?;
    let mut frames = read_sequence(&args.scene)?;
    if frames.len() != args.deformed.len() {
        return Err(Error::Invalid(format!(
            "{} deformed images for a scene of {} frame(s); give one image per frame",
            args.deformed.len(),
            frames.len()
        )));
    }
    let reference = load_gray(&args.reference)?;
    let frame_path = args.scene.join(FRAME_FILE);
    let frame = match (args.scale, frame_path.exists()) {
        (Some(s), _) => PixelFrame::at_origin(s, reference.width(), reference.height()),
        (None, true) => PixelFrame::read(&frame_path)?,
        (None, false) => {
            return Err(Error::Invalid(format!(
                "no --scale given and no {} in the scene folder",
                FRAME_FILE
            )))
        }
    };
    if (frame.width, frame.height) != reference.dimensions() {
        return Err(Error::data(
            &args.reference,
            None,
            None,
            format!(
                "the image is {}×{} px but the scene's pixel frame is {}×{}",
                reference.width(),
                reference.height(),
                frame.width,
                frame.height
            ),
        ));
    }
    let prepared_reference = Prepared::new(&reference);
    let total: usize = frames.iter().map(|f| f.grains.len()).sum();
    let bar = if super::quiet() {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(total as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} grains ({eta} left)")
            .expect("valid template"),
    );
    for (scene, path) in frames.iter_mut().zip(&args.deformed) {
        let image = load_gray(path)?;
        check_same_size(&reference, &args.reference, &image, path)?;
        let deformed = Prepared::new(&image);
        let report = measure_prepared(
            &prepared_reference,
            &deformed,
            scene,
            &frame,
            &options,
            &|| bar.inc(1),
        )
        .map_err(|e| match e {
            Error::Invalid(m) => Error::Invalid(format!("{}: {m}", path.display())),
            other => other,
        })?;
        let zncc = report
            .grains
            .iter()
            .map(|g| g.dic.mean_zncc)
            .fold(1.0, f64::min);
        bar.println(format!(
            "{}: {} grains, lowest mean ZNCC {zncc:.4}",
            path.display(),
            report.grains.len()
        ));
    }
    bar.finish_and_clear();
    write_sequence(&args.scene, &frames)?;
    status!(
        "wrote stresses into {}",
        args.scene.join("grains.csv").display()
    );
    Ok(())
}
