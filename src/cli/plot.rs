//! `grainforce plot`: a force-chain picture of a scene and its forces, or a
//! Pareto front from a λ sweep.

use grainforce::report::{self, forcechain::ForceChainOptions, forcechain::Plane};
use grainforce::scene;
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Scene folder (not with --pareto).
    #[arg(conflicts_with = "pareto")]
    scene: Option<PathBuf>,
    /// forces.csv to draw (not with --pareto).
    #[arg(conflicts_with = "pareto")]
    forces: Option<PathBuf>,
    /// Output PNG.
    #[arg(short, long, value_name = "OUT.png")]
    output: PathBuf,
    /// Draw this Pareto-front CSV (lambda,stress_residual,momentum_residual,knee) instead.
    #[arg(long, value_name = "PARETO.csv")]
    pareto: Option<PathBuf>,
    /// Projection plane of a 3D scene.
    #[arg(long, default_value = "xy", value_parser = ["xy", "xz", "yz"])]
    plane: String,
    /// Image width in pixels.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(64..=20000))]
    width: u32,
    /// Frame of a sequence to draw (default: the first).
    #[arg(long)]
    frame: Option<i64>,
    /// Write grain ids at their centroids.
    #[arg(long)]
    ids: bool,
    /// Force drawn at full width and darkest colour (default: the largest), to
    /// compare pictures on one scale.
    #[arg(long, value_name = "F")]
    max_force: Option<f64>,
}

pub fn run(args: Args) -> Result<()> {
    if let Some(path) = &args.pareto {
        let (points, knee) = report::read_pareto_csv(path)?;
        if points.is_empty() {
            return Err(Error::Invalid(format!(
                "{} holds no points",
                path.display()
            )));
        }
        let img = report::draw_pareto(&points, knee);
        report::save_png(&args.output, &img)?;
        status!("wrote {} ({} points)", args.output.display(), points.len());
        return Ok(());
    }
    let (Some(scene_dir), Some(forces_path)) = (&args.scene, &args.forces) else {
        return Err(Error::Invalid(
            "plot needs SCENE_DIR and FORCES.csv (or --pareto PARETO.csv)".into(),
        ));
    };
    if let Some(m) = args.max_force {
        if !(m.is_finite() && m > 0.0) {
            return Err(Error::Invalid(format!(
                "--max-force {m} must be a positive number"
            )));
        }
    }
    let frames = scene::read_sequence(scene_dir)?;
    let scene = match args.frame {
        None => &frames[0],
        Some(k) => frames.iter().find(|s| s.frame == Some(k)).ok_or_else(|| {
            let numbers: Vec<i64> = frames.iter().filter_map(|s| s.frame).collect();
            let available = match (numbers.iter().min(), numbers.iter().max()) {
                (Some(lo), Some(hi)) => format!("frames {lo} to {hi}"),
                _ => "no frame numbers (a single scene)".into(),
            };
            Error::Invalid(format!(
                "--frame {k}: {} has {available}",
                scene_dir.display()
            ))
        })?,
    };
    let table = scene::read_forces(forces_path)?;
    let forces = table.for_scene(scene, forces_path)?;
    let sd = standard_deviations(&table, scene);
    let plane: Plane = args.plane.parse()?;
    let title = match scene.frame {
        Some(k) => format!("frame {k}"),
        None => String::new(),
    };
    let opts = ForceChainOptions {
        width_px: args.width,
        plane,
        show_ids: args.ids,
        max_force: args.max_force,
        title: (!title.is_empty()).then_some(title),
        units: None,
    };
    let img = report::forcechain::draw_force_chains_with_sd(scene, &forces, sd.as_deref(), &opts)?;
    report::save_png(&args.output, &img)?;
    status!(
        "wrote {} ({}x{} px, {} contacts)",
        args.output.display(),
        img.width(),
        img.height(),
        scene.contacts.len()
    );
    Ok(())
}

/// The sd columns of forces.csv in the scene's contact order, when present
/// (a contact without a value counts as exactly known).
fn standard_deviations(table: &scene::Forces, scene: &scene::Scene) -> Option<Vec<scene::Vec3>> {
    if table.rows.iter().all(|r| r.sd.is_none()) {
        return None;
    }
    let map: std::collections::HashMap<&str, scene::Vec3> = table
        .rows
        .iter()
        .filter(|r| r.frame == scene.frame || r.frame.is_none())
        .filter_map(|r| r.sd.map(|sd| (r.contact.as_str(), sd)))
        .collect();
    Some(
        scene
            .contacts
            .iter()
            .map(|c| map.get(c.id.as_str()).copied().unwrap_or([0.0; 3]))
            .collect(),
    )
}
