//! `grainforce import FORMAT INPUT… -o SCENE_DIR`: other tools' output as a scene.

use grainforce::import::{gff, imaged11, lammps, liggghts, pegs, yade, ImportedScene};
use grainforce::{Error, Result};
use std::path::{Path, PathBuf};

mod labels;

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Format {
    /// LAMMPS: ATOMS.dump (dump custom) PAIRS.dump (dump local of compute pair/local).
    Lammps,
    /// LIGGGHTS: ATOMS.dump (dump custom) PAIRS.dump (dump local of compute pair/gran/local).
    Liggghts,
    /// YADE: bodies.csv interactions.csv from the export recipe (see the README).
    Yade,
    /// 3D X-ray diffraction: GRAINS.gff (FitAllB/ImageD11) CONTACTS.csv (tomography).
    Gff,
    /// PeGS/PeGS2 (photoelastic): PARTICLE.mat (`*_contacts.mat` or `*_solved.mat`)
    /// [CENTERS.txt] (particleDetect's x,y,r,edge, for the unrounded radii).
    Pegs,
    /// Tomography: a label VOLUME (.npy, .tif/.tiff multi-page, or raw with --shape)
    /// → grains, contacts, normals (docs/tomography.md).
    Labels,
    /// ImageD11 grain map: GRAINS.map (.ubi) [CONTACTS.csv] with --cell and --stiffness.
    Imaged11,
}

#[derive(clap::Args)]
#[command(after_help = "Examples:
  grainforce import lammps atoms.dump pairs.dump -o scene --gravity 0,-9.81,0
  grainforce import liggghts atoms.dump pairs.dump -o scene --keywords pos,id,force
  grainforce import yade bodies.csv interactions.csv -o scene --gravity 0,0,-9.81
  grainforce import gff grains.gff contacts.csv -o scene --stress-unit MPa --length-unit mm
  grainforce import gff strains.gff contacts.csv -o scene --stiffness quartz --errors strains_errors.gff
  grainforce import pegs Step09-0001_solved.mat Step09-0001_centers.txt -o scene --image Step09-0001.jpg --thickness 0.00635
  grainforce import labels labels.npy -o scene --voxel-size 6.5e-6 --walls bottom:z=0,top:z=0.0052
  grainforce import labels labels.tif -o scene --voxel-size 6.5e-6 --grey ct.tif --density 2650
  grainforce import imaged11 grains.map contacts.csv -o scene --cell 4.9134,4.9134,5.4052,90,90,120 --stiffness quartz --grain-volume 1.4e-10")]
pub struct Args {
    /// Source format.
    #[arg(value_enum)]
    format: Format,
    /// Input files, as the format needs them (two for most formats; pegs and
    /// imaged11: one or two; labels: one).
    #[arg(required = true, num_args = 1..=2)]
    inputs: Vec<PathBuf>,
    /// Scene folder to write (forces.csv too when the source has forces).
    #[arg(short, long)]
    output: PathBuf,
    /// Gravity of the run, e.g. 0,-9.81,0 (written to scene.json).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    gravity: Option<Vec<f64>>,
    /// lammps/liggghts: input script whose `fix … gravity` gives the gravity when
    /// --gravity is not given; default: the one `in.*` file beside ATOMS.dump, if any.
    #[arg(long)]
    input_script: Option<PathBuf>,
    /// Force the dimension (2 or 3); default: 2 when all z are equal.
    #[arg(long)]
    dim: Option<usize>,
    /// lammps: which dump-local columns hold what,
    /// i=COL,j=COL,fx=COL,fy=COL,fz=COL[,tx=COL,ty=COL,tz=COL] (t = tangential part, pair/local p1..p3).
    /// Default: after an optional `index`, the columns are i j fx fy fz [p1 p2 p3].
    #[arg(long)]
    columns: Option<String>,
    /// liggghts: the compute pair/gran/local keywords in column order, e.g. pos,id,force.
    #[arg(long, value_delimiter = ',')]
    keywords: Option<Vec<String>>,
    /// liggghts: number of history values when the `history` keyword is used.
    #[arg(long, default_value_t = 0)]
    history: usize,
    /// gff: stress unit of the file (Pa, kPa, MPa, GPa or Pa per unit as a number).
    #[arg(long, default_value = "MPa")]
    stress_unit: String,
    /// gff: length unit of x y z and grainvolume (m, mm, um or metres per unit).
    #[arg(long, default_value = "mm")]
    length_unit: String,
    /// gff: tomography grain table (CSV, SI: id,volume[,x,y,z]) overriding gff volumes.
    #[arg(long)]
    tomography_grains: Option<PathBuf>,
    /// gff: stress from the strain columns by this crystal's stiffness (GPa):
    /// quartz, zirconium, cubic:C11,C12,C44, hexagonal:C11,C12,C13,C33,C44,
    /// trigonal:C11,C12,C13,C14,C33,C44, or a file with the 6×6 Voigt matrix.
    #[arg(long)]
    stiffness: Option<String>,
    /// gff: FitAllB's standard-error file (…_errors.gff) → sd_s_* columns.
    #[arg(long)]
    errors: Option<PathBuf>,
    /// pegs: pixels per metre; default: r/rm from the file (PeGS's metersperpixel),
    /// else lengths stay in pixels.
    #[arg(long, value_name = "PX_PER_M")]
    scale: Option<f64>,
    /// pegs: the photograph PeGS analysed; its height places y (up) as `detect` does,
    /// and image-frame.json is written for `strain` and overlays.
    #[arg(long)]
    image: Option<PathBuf>,
    /// pegs: disk thickness [m]; PeGS's forces [N] become forces per unit thickness
    /// (N/m, as 2D scenes hold them) and scene.json gets the thickness.
    #[arg(long)]
    thickness: Option<f64>,
    #[command(flatten)]
    labels: labels::LabelArgs,
    /// imaged11: the unstrained cell a,b,c,alpha,beta,gamma (Å, degrees).
    #[arg(long, value_delimiter = ',')]
    cell: Option<Vec<f64>>,
    /// imaged11: the volume given to every grain [m³] (a map has none).
    #[arg(long)]
    grain_volume: Option<f64>,
    /// imaged11: the group (phase) of an HDF5 grain file with several.
    #[arg(long)]
    phase: Option<String>,
}

fn unit(text: &str, table: &[(&str, f64)], what: &str) -> Result<f64> {
    if let Some((_, v)) = table.iter().find(|(n, _)| n.eq_ignore_ascii_case(text)) {
        return Ok(*v);
    }
    match text.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(Error::Invalid(format!("unknown {what} unit `{text}`"))),
    }
}

/// Gravity from the run's input script: the one given, else the single `in.*`
/// file beside the atoms dump.
fn script_gravity(atoms: &Path, given: Option<&Path>) -> Result<Option<[f64; 3]>> {
    let script = match given {
        Some(p) => Some(p.to_owned()),
        None => {
            let dir = match atoms.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_owned(),
                _ => PathBuf::from("."),
            };
            let mut found: Vec<PathBuf> = std::fs::read_dir(&dir)
                .map(|entries| {
                    entries
                        .filter_map(|e| e.ok().map(|e| e.path()))
                        .filter(|p| {
                            p.is_file()
                                && p.file_name()
                                    .and_then(|n| n.to_str())
                                    .is_some_and(|n| n.starts_with("in."))
                        })
                        .collect()
                })
                .unwrap_or_default();
            if found.len() == 1 {
                found.pop()
            } else {
                None
            }
        }
    };
    let Some(script) = script else {
        return Ok(None);
    };
    let (g, notes) = lammps::gravity_from_script(&script)?;
    for n in notes {
        eprintln!("note: {n}");
    }
    if let Some(g) = g {
        eprintln!(
            "note: gravity {},{},{} from `fix gravity` in {}",
            g[0],
            g[1],
            g[2],
            script.display()
        );
    }
    Ok(g)
}

pub fn run(args: Args) -> Result<()> {
    let gravity = match &args.gravity {
        Some(g) if !(2..=3).contains(&g.len()) => {
            return Err(Error::Invalid(format!(
                "--gravity needs 2 or 3 numbers, got {}",
                g.len()
            )))
        }
        Some(g) => {
            let mut v = [0.0; 3];
            v[..g.len()].copy_from_slice(g);
            Some(v)
        }
        None => None,
    };
    if let Format::Pegs = args.format {
        return run_pegs(&args, gravity);
    }
    if let Format::Labels = args.format {
        return labels::run(&args, gravity);
    }
    if let Format::Imaged11 = args.format {
        return run_imaged11(&args, gravity);
    }
    if args.inputs.len() != 2 {
        return Err(Error::Invalid(format!(
            "this format needs two input files, got {}",
            args.inputs.len()
        )));
    }
    let (first, second) = (&args.inputs[0], &args.inputs[1]);
    let gravity = match args.format {
        Format::Lammps | Format::Liggghts if gravity.is_none() => {
            script_gravity(first, args.input_script.as_deref())?
        }
        _ => gravity,
    };
    let imported: ImportedScene = match args.format {
        Format::Lammps => {
            let columns = match &args.columns {
                Some(s) => Some(lammps::LocalColumns::parse(s)?),
                None => None,
            };
            lammps::import(
                first,
                second,
                &lammps::Options {
                    columns,
                    dim: args.dim,
                    gravity,
                },
            )?
        }
        Format::Liggghts => liggghts::import(
            first,
            second,
            &liggghts::Options {
                keywords: args.keywords.clone(),
                history: args.history,
                dim: args.dim,
                gravity,
            },
        )?,
        Format::Yade => yade::import(
            first,
            second,
            &yade::Options {
                dim: args.dim,
                gravity,
            },
        )?,
        Format::Gff => gff::import(
            first,
            second,
            &gff::Options {
                stress_unit: unit(
                    &args.stress_unit,
                    &[("Pa", 1.0), ("kPa", 1e3), ("MPa", 1e6), ("GPa", 1e9)],
                    "stress",
                )?,
                length_unit: unit(
                    &args.length_unit,
                    &[("m", 1.0), ("mm", 1e-3), ("um", 1e-6), ("µm", 1e-6)],
                    "length",
                )?,
                tomography_grains: args.tomography_grains.clone(),
                stiffness: match &args.stiffness {
                    Some(spec) => Some(gff::Stiffness::parse(spec)?),
                    None => None,
                },
                errors: args.errors.clone(),
            },
        )?,
        Format::Pegs => unreachable!("handled by run_pegs"),
        Format::Labels => unreachable!("handled by labels::run"),
        Format::Imaged11 => unreachable!("handled by run_imaged11"),
    };
    imported.write(&args.output)?;
    report(&args, &imported)
}

/// `import imaged11`: grains (and contacts) with stresses from the UBIs.
fn run_imaged11(args: &Args, gravity: Option<[f64; 3]>) -> Result<()> {
    let cell = match &args.cell {
        Some(c) if c.len() == 6 => [c[0], c[1], c[2], c[3], c[4], c[5]],
        Some(c) => {
            return Err(Error::Invalid(format!(
                "--cell needs 6 numbers a,b,c,alpha,beta,gamma, got {}",
                c.len()
            )))
        }
        None => {
            return Err(Error::Invalid(
                "import imaged11 needs --cell a,b,c,alpha,beta,gamma (the unstrained cell)".into(),
            ))
        }
    };
    let stiffness = match &args.stiffness {
        Some(spec) => gff::Stiffness::parse(spec)?,
        None => {
            return Err(Error::Invalid(
                "import imaged11 needs --stiffness (e.g. quartz, zirconium)".into(),
            ))
        }
    };
    let options = imaged11::Options {
        cell,
        stiffness,
        grain_volume: args.grain_volume,
        phase: args.phase.clone(),
    };
    let mut imported = imaged11::import(
        &args.inputs[0],
        args.inputs.get(1).map(PathBuf::as_path),
        &options,
    )?;
    if let Some(g) = gravity {
        imported.frames[0].settings.gravity = Some(g.to_vec());
    }
    imported.write(&args.output)?;
    report(args, &imported)
}

/// `import pegs`: the scene, PeGS's forces as forces.csv, and image-frame.json
/// when the photograph is given.
fn run_pegs(args: &Args, gravity: Option<[f64; 3]>) -> Result<()> {
    // The format from the bytes, not the name: some "photo.jpg" are TIFFs.
    let image_size = match &args.image {
        Some(p) => {
            let cannot = |e: &dyn std::fmt::Display| {
                Error::data(p, None, None, format!("cannot read the image size: {e}"))
            };
            let reader = image::ImageReader::open(p)
                .map_err(|e| Error::io(p, e))?
                .with_guessed_format()
                .map_err(|e| cannot(&e))?;
            Some(reader.into_dimensions().map_err(|e| cannot(&e))?)
        }
        None => None,
    };
    let options = pegs::Options {
        centres: args.inputs.get(1).cloned(),
        px_per_m: args.scale,
        image_height: image_size.map(|s| s.1),
        thickness: args.thickness,
        gravity,
    };
    let (imported, conversion) = pegs::import(&args.inputs[0], &options)?;
    match conversion.scale_source {
        pegs::ScaleSource::File => eprintln!(
            "note: {} px/m from the file's r/rm (PeGS's metersperpixel)",
            conversion.px_per_m
        ),
        pegs::ScaleSource::Pixels => {
            eprintln!("note: no --scale and no rm in the file; lengths are written in pixels (1 px = 1 m)")
        }
        pegs::ScaleSource::Given => {}
    }
    if !conversion.height_given {
        eprintln!(
            "note: no --image; y is measured up from the lowest disk edge (row {}), not from the \
             photograph's bottom edge",
            conversion.image_height
        );
    }
    if args.thickness.is_none() && imported.forces.is_some() {
        eprintln!(
            "note: no --thickness; PeGS's forces [N] are written as forces per metre of thickness"
        );
    }
    // The scene is checked whole before anything is written.
    imported.write(&args.output)?;
    if let Some((width, height)) = image_size {
        grainforce::image::PixelFrame {
            px_per_m: conversion.px_per_m,
            origin: [0.0, 0.0],
            width,
            height,
        }
        .write(&args.output.join(grainforce::image::FRAME_FILE))?;
    }
    report(args, &imported)
}

fn report(args: &Args, imported: &ImportedScene) -> Result<()> {
    let grains: usize = imported.frames.iter().map(|f| f.grains.len()).sum();
    let contacts: usize = imported.frames.iter().map(|f| f.contacts.len()).sum();
    status!(
        "wrote {}: {} frame(s), {} grains, {} contacts ({}D){}",
        args.output.display(),
        imported.frames.len(),
        grains,
        contacts,
        imported.frames[0].dim,
        if imported.forces.is_some() && matches!(args.format, Format::Pegs) {
            ", PeGS's forces in forces.csv (the reference for `score`)"
        } else if imported.forces.is_some() {
            ", true forces in forces.csv"
        } else {
            ""
        }
    );
    for w in &imported.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(u) = imported.gravity_like_load() {
        eprintln!(
            "warning: {}",
            grainforce::import::gravity_like_warning(u, imported.frames[0].dim)
        );
    }
    if let Some(r) = imported.momentum_residual() {
        if r > 1e-3 {
            let cause = if imported.frames[0].settings.gravity.is_some() {
                "the source lacks some contacts (e.g. walls) or has other loads"
            } else {
                "give the run's --gravity, or the source lacks some contacts (e.g. walls)"
            };
            eprintln!(
                "warning: the contact forces do not balance m (a - g) on some grains (largest \
                 residual {r:.3} of the mean contact force): {cause}"
            );
        }
    }
    Ok(())
}
