//! `grainforce import labels VOLUME -o SCENE --voxel-size S …`.

use super::Args;
use grainforce::import::labels::{self, DType, FileFormat, NormalMethod, Options, WallPlane};
use grainforce::import::register::{self, MatchOptions, TransformModel};
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct LabelArgs {
    /// labels: edge length of a voxel [m].
    #[arg(long)]
    voxel_size: Option<f64>,
    /// labels: position of the centre of voxel [0][0][0], X,Y,Z [m] (default 0,0,0).
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true)]
    origin: Option<Vec<f64>>,
    /// labels: plane walls NAME:AXIS=POSITION [m], comma-separated, e.g.
    /// bottom:z=0,top:z=0.0052.
    #[arg(long, value_delimiter = ',')]
    walls: Vec<String>,
    /// labels: the label that is the container (its contacts go to wall `container`).
    #[arg(long)]
    container: Option<u32>,
    /// labels: the grey CT the labels were segmented from (same shape and format):
    /// grey-level evidence per contact and a sub-voxel gap (grey_gap, grey_gap_sd
    /// and the neck fit's grey_fit_misfit in contacts_quality.csv); dropped are
    /// necks darker than --min-grey and zones whose grey gap lies more than 3
    /// robust deviations above the median, unless the neck model misfits them.
    #[arg(long)]
    grey: Option<PathBuf>,
    /// labels: a raw volume's shape NZ,NY,NX (C order, x fastest).
    #[arg(long, value_delimiter = ',')]
    shape: Option<Vec<usize>>,
    /// labels: a raw volume's element type (u8, u16, u32, u64, i8…i64, f32, f64).
    #[arg(long, default_value = "u16")]
    dtype: String,
    /// labels: a raw volume is big-endian.
    #[arg(long)]
    big_endian: bool,
    /// labels: bytes to skip at the start of a raw volume.
    #[arg(long, default_value_t = 0)]
    header_bytes: usize,
    /// labels: grain density [kg/m³] → mass and inertia tensor columns.
    #[arg(long)]
    density: Option<f64>,
    /// labels: normal estimate: fit (local sphere fits to each grain's surface)
    /// or pca (the field's standard, least-variance direction of the interface).
    #[arg(long, default_value = "fit")]
    normals: String,
    /// labels: drop contacts whose fitted gap exceeds the median gap by more than
    /// this many voxels (near misses sharing faces; 0.5 works from 30 voxels per
    /// diameter up); `none` keeps every zone.
    #[arg(long, default_value = "none")]
    max_gap: String,
    /// labels: with --grey, drop contacts whose neck is darker than this fraction
    /// of the way from void grey to solid grey.
    #[arg(long, default_value_t = 0.9)]
    min_grey: f64,
    /// labels: with --grey, fit each grain's whole sphere to the grey and combine
    /// its gap with the neck fit's where both grains are spheres: those whose fit
    /// leaves at most LIMIT times the scan's noise (1.1 measured; off by default:
    /// docs/tomography.md, round 12b).
    #[arg(long, value_name = "LIMIT")]
    grey_whole_spheres: Option<f64>,
    /// labels: per-grain stresses to attach by position: a scene folder from
    /// `import gff`/`import imaged11`, or a CSV id,x,y,z,s_xx,…,s_yz (SI); the
    /// rigid transform between the two instruments' frames is fitted.
    #[arg(long, value_name = "GRAINS")]
    stresses: Option<PathBuf>,
    /// labels: with --stresses, the largest distance between matched centroids
    /// once transformed [m] (default 0.4 × the CT grains' median spacing).
    #[arg(long)]
    match_distance: Option<f64>,
    /// labels: with --stresses, `rigid` fits the transform between the frames;
    /// `none` takes them as the same frame.
    #[arg(long, default_value = "rigid")]
    match_transform: String,
}

pub fn run(args: &Args, gravity: Option<[f64; 3]>) -> Result<()> {
    let la = &args.labels;
    if args.inputs.len() != 1 {
        return Err(Error::Invalid(format!(
            "import labels takes one VOLUME file, got {}",
            args.inputs.len()
        )));
    }
    let voxel_size = la.voxel_size.ok_or_else(|| {
        Error::Invalid("import labels needs --voxel-size (the voxel edge in metres)".into())
    })?;
    let origin = match &la.origin {
        None => [0.0; 3],
        Some(o) if o.len() == 3 => [o[0], o[1], o[2]],
        Some(o) => {
            return Err(Error::Invalid(format!(
                "--origin needs 3 numbers X,Y,Z, got {}",
                o.len()
            )))
        }
    };
    let format = match &la.shape {
        None => FileFormat::Auto,
        Some(s) if s.len() == 3 => FileFormat::Raw {
            shape: [s[0], s[1], s[2]],
            dtype: DType::parse(&la.dtype)?,
            big_endian: la.big_endian,
            header_bytes: la.header_bytes,
        },
        Some(s) => {
            return Err(Error::Invalid(format!(
                "--shape needs 3 numbers NZ,NY,NX, got {}",
                s.len()
            )))
        }
    };
    let walls = la
        .walls
        .iter()
        .map(|w| WallPlane::parse(w))
        .collect::<Result<Vec<_>>>()?;
    let normals = NormalMethod::parse(&la.normals).map_err(|_| {
        Error::Invalid(format!(
            "--normals must be fit or pca, got `{}`",
            la.normals
        ))
    })?;
    let max_gap = match la.max_gap.as_str() {
        "none" => None,
        text => match text.parse::<f64>() {
            Ok(v) if v.is_finite() => Some(v),
            _ => {
                return Err(Error::Invalid(format!(
                    "--max-gap must be a number of voxels or `none`, got `{text}`"
                )))
            }
        },
    };
    let grey_whole_spheres = match la.grey_whole_spheres {
        Some(limit) if !(limit.is_finite() && limit > 0.0) => {
            let why = "a positive multiple of the scan's noise";
            return Err(Error::Invalid(format!(
                "--grey-whole-spheres must be {why}, got {limit}"
            )));
        }
        limit => limit,
    };
    let options = Options {
        voxel_size,
        origin,
        walls,
        container: la.container,
        normals,
        density: la.density,
        max_gap,
        min_grey: la.min_grey,
        grey_whole_spheres,
        ..Options::default()
    };
    let transform = TransformModel::parse(&la.match_transform).map_err(|_| {
        Error::Invalid(format!(
            "--match-transform must be rigid or none, got `{}`",
            la.match_transform
        ))
    })?;
    // Read before the volume: a bad stress file fails fast.
    let stressed = match &la.stresses {
        Some(p) => Some(register::read_stressed_grains(p)?),
        None => None,
    };
    let grey = la.grey.as_ref().map(|g| (g.as_path(), &format));
    let mut imported = labels::import_file(&args.inputs[0], &format, grey, &options)?;
    let matched = match &stressed {
        Some(source) => Some(register::attach_stresses(
            &mut imported.scene,
            source,
            &MatchOptions {
                max_distance: la.match_distance,
                transform,
                ..MatchOptions::default()
            },
        )?),
        None => None,
    };
    if let Some(g) = gravity {
        imported.scene.settings.gravity = Some(g.to_vec());
    }
    imported.scene.settings.description = Some(match (&la.stresses, &matched) {
        (Some(p), Some(m)) => format!(
            "grainforce import labels {} (voxel {voxel_size} m): grains and contacts from a label \
             volume; stresses of {} grains from {} by position (rms distance {:.3e} m)",
            args.inputs[0].display(),
            m.matches.len(),
            p.display(),
            m.registration.rms
        ),
        _ => format!(
            "grainforce import labels {} (voxel {voxel_size} m): grains and contacts from a label \
             volume; stresses are zero until attached",
            args.inputs[0].display()
        ),
    });
    imported.write(&args.output)?;
    if let Some(m) = &matched {
        m.write(&args.output)?;
        let r = &m.registration;
        status!(
            "stresses: {} grains matched (rms distance {:.3e} m, {:.2} of the spacing; largest \
             {:.3e} m), rotation {:.2}°, translation ({:.3e}, {:.3e}, {:.3e}) m; {} label grain(s) \
             and {} stressed grain(s) unmatched (stress_match.csv, stress_match.json)",
            m.matches.len(),
            r.rms,
            r.rms / r.spacing,
            r.residuals.iter().cloned().fold(0.0, f64::max),
            r.angle_degrees(),
            r.translation[0],
            r.translation[1],
            r.translation[2],
            m.unmatched_scene.len(),
            m.unmatched_source.len()
        );
        for w in &m.warnings {
            eprintln!("warning: {w}");
        }
    }
    let s = &imported.scene;
    let dropped = imported.detected.iter().filter(|c| !c.kept).count();
    status!(
        "wrote {}: {} grains, {} contacts ({} wall), {} doubtful zone(s) dropped, {} rattler(s); \
         contacts_quality.csv has every zone",
        args.output.display(),
        s.grains.len(),
        s.contacts.len(),
        s.contacts
            .iter()
            .filter(|c| matches!(c.b, grainforce::scene::Body::Wall(_)))
            .count(),
        dropped,
        imported.rattlers.len()
    );
    for w in &imported.warnings {
        eprintln!("warning: {w}");
    }
    Ok(())
}
