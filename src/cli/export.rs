//! `grainforce export vtk SCENE_DIR [FORCES.csv] -o out.vtp|out.pvd`: files for ParaView.

use grainforce::export::vtk;
use grainforce::scene;
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Format {
    /// VTK XML PolyData (.vtp) for ParaView; a .pvd collection for sequences.
    Vtk,
}

#[derive(clap::Args)]
#[command(
    after_help = "Writes OUT.vtp (grains as points) and OUT_contacts.vtp (contacts as lines).
A sequence, or an output ending in .pvd, gives OUT_<frame>.vtp files and an OUT.pvd index.
In ParaView: File > Open the .vtp/.pvd; colour contacts by force_magnitude, and use a Tube
filter (radius by force_magnitude) for force chains, Glyph (sphere, scale by radius) for grains."
)]
pub struct Args {
    #[arg(value_enum)]
    format: Format,
    /// Scene folder.
    scene: PathBuf,
    /// Forces to include (forces.csv format); without them only geometry and stresses.
    forces: Option<PathBuf>,
    /// Output file: .vtp (one frame) or .pvd (series).
    #[arg(short, long)]
    output: PathBuf,
    /// Write the arrays as ASCII text instead of appended raw binary (larger,
    /// readable in a text editor).
    #[arg(long)]
    ascii: bool,
}

pub fn run(args: Args) -> Result<()> {
    let Format::Vtk = args.format;
    let encoding = if args.ascii {
        vtk::Encoding::Ascii
    } else {
        vtk::Encoding::Binary
    };
    let frames = scene::read_sequence(&args.scene)?;
    let forces = match &args.forces {
        Some(path) => {
            let f = scene::read_forces(path)?;
            Some(
                frames
                    .iter()
                    .map(|s| f.for_scene(s, path))
                    .collect::<Result<Vec<_>>>()?,
            )
        }
        None => None,
    };
    let ext = args
        .output
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or_default();
    if ext == "pvd" || frames.len() > 1 {
        if ext != "pvd" {
            return Err(Error::Invalid(format!(
                "{} holds {} frames: give an output ending in .pvd for the series",
                args.scene.display(),
                frames.len()
            )));
        }
        let files = vtk::write_series(&args.output, &frames, forces.as_deref(), encoding)?;
        status!(
            "wrote {} and {} frame file pairs",
            args.output.display(),
            files.len()
        );
    } else if ext == "vtp" {
        let files = vtk::write_frame(
            &args.output,
            &frames[0],
            forces.as_ref().map(|f| f[0].as_slice()),
            encoding,
        )?;
        status!(
            "wrote {} and {}",
            files.grains.display(),
            files.contacts.display()
        );
    } else {
        return Err(Error::Invalid(format!(
            "output {} should end in .vtp (one frame) or .pvd (series)",
            args.output.display()
        )));
    }
    Ok(())
}
