//! `grainforce detect`: photographs → scene folder.

use grainforce::image::{
    detect_images, overlay, Channel, ContactBody, DetectOptions, DetectSettings, Detection,
    PixelFrame, Polarity, WallLine, WallSource, FRAME_FILE,
};
use grainforce::scene::write_sequence;
use grainforce::{Error, Result};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// Images (grayscale or colour PNG, TIFF, BMP or JPEG; 8- or 16-bit), one per frame.
    #[arg(required = true)]
    images: Vec<PathBuf>,
    /// Scene folder to write (grains.csv, contacts.csv, scene.json, image-frame.json).
    #[arg(short = 'o', long = "output")]
    output: PathBuf,
    /// Radius range of the disks, in pixels: MIN..MAX, or several classes
    /// separated by commas (MIN..MAX,MIN..MAX, e.g. 45..55,70..80 for a
    /// bidisperse packing: sizes between the classes are not searched).
    #[arg(long, value_parser = parse_ranges)]
    radius: RadiusClasses,
    /// Pixels per metre. Without it, lengths stay in pixels (1 px = 1 m).
    #[arg(long, conflicts_with = "frame")]
    scale: Option<f64>,
    /// Pixel frame (image-frame.json, as `render` writes it): scale and the
    /// scene position of the image, so detected positions match the scene's.
    #[arg(long)]
    frame: Option<PathBuf>,
    /// Out-of-plane thickness of the disks [m] (recorded in scene.json).
    #[arg(long)]
    thickness: Option<f64>,
    /// Walls: `box` (the default) along the bounding box of the disks found,
    /// each at the second outermost disk edge of its side, what holds a
    /// packing whose walls the picture does not show (the disks on the box's
    /// sides touch it; without any wall a balanced field of
    /// compressive forces carries no load and `photoelastic` fits zero);
    /// `none` for no walls (a packing free on every side); `edges` for the
    /// image borders; or NAME=x0,y0,x1,y1 lines in pixels. The choice is
    /// printed and recorded in image-frame.json (`walls`).
    #[arg(long, num_args = 1..)]
    walls: Vec<String>,
    /// A fixed contact rule: the largest gap [px] between fitted circles that
    /// counts as a contact. Without it, contacts are judged from the image:
    /// each disk's dark rim is measured, the edges must meet within a
    /// tolerance that grows with the radius, no background may show between
    /// the rims, and the photoelastic signal (G²) near the contact adds
    /// confidence (see contacts-evidence.csv).
    #[arg(long)]
    gap: Option<f64>,
    /// Write doubtful contacts into contacts.csv too (they are always listed,
    /// flagged, in contacts-evidence.csv).
    #[arg(long, conflicts_with = "gap")]
    keep_doubtful: bool,
    /// Refine each circle's outline until it settles instead of in two
    /// narrow passes, so that a circle caught on a fringe edge beside a dim
    /// stretch of outline creeps out to it. Off by default: on the rendered
    /// 58-disk photograph it fixes the two worst circles (4 px off → 0.2 px)
    /// and, with `photoelastic --wall-mu 0 --candidates 0.2`, takes the
    /// fringe fit from relerr 0.083 to 0.019; but it moves some real
    /// photographs' centres further from PeGS's (docs/photoelastic.md).
    #[arg(long)]
    settle_edges: bool,
    /// In the colour (or gray) distance from the background, refine each
    /// disk once more along each ray's outermost edge and keep that circle
    /// where it encloses the first and is better supported, so a circle
    /// found inside a loaded disk along its fringes reaches the outline.
    /// On by default (`--outermost-outline=false` turns it off): on
    /// rendered 58-disk photographs it takes the worst circle from 12 px
    /// off to 2 px (docs/image.md, rounds 15 and 16).
    #[arg(long, num_args = 0..=1, require_equals = true, default_value_t = true,
        default_missing_value = "true", action = clap::ArgAction::Set)]
    outermost_outline: bool,
    /// The disks are darker than their surroundings.
    #[arg(long, conflicts_with = "either_polarity")]
    dark_disks: bool,
    /// Find both bright and dark disks.
    #[arg(long)]
    either_polarity: bool,
    /// What of a colour image the disks are searched in: auto (the default)
    /// reads the background colour from the image (the most common of its
    /// darkest or brightest colours) and searches the colour distance from
    /// it, in which disks are bright whatever their fringes, rims or the
    /// light's colour; or one channel: red, green, blue or luma (then the
    /// polarity options apply). The choice is printed and recorded in
    /// image-frame.json. Gray images are searched as they are and, with
    /// bright disks, in their distance from the background level too (the
    /// one with the better supported outlines is kept).
    #[arg(long, default_value = "auto", value_parser = parse_channel)]
    channel: Channel,
    /// Gaussian smoothing before voting [px] (default: from the radius).
    #[arg(long)]
    smoothing: Option<f64>,
    /// Overlay picture (PNG) of the detection; with several images one per
    /// frame, numbered (overlay-0000.png, …).
    #[arg(long)]
    overlay: Option<PathBuf>,
}

/// One or more radius classes, [min, max] px each.
#[derive(Clone)]
struct RadiusClasses(Vec<[f64; 2]>);

fn parse_ranges(s: &str) -> std::result::Result<RadiusClasses, String> {
    s.split(',')
        .map(|r| parse_range(r.trim()).map(|(a, b)| [a, b]))
        .collect::<std::result::Result<_, _>>()
        .map(RadiusClasses)
}

fn parse_range(s: &str) -> std::result::Result<(f64, f64), String> {
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| format!("`{s}`: expected MIN..MAX, e.g. 20..35"))?;
    let parse = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|_| format!("`{v}` is not a number"))
    };
    Ok((parse(a)?, parse(b)?))
}

/// Per-contact evidence and confidence, doubtful contacts flagged.
const EVIDENCE_FILE: &str = "contacts-evidence.csv";

/// One row per candidate contact: its id in contacts.csv (empty when only
/// doubtful), the bodies, the gap between the rims' outer edges and its
/// tolerance [px], whether background shows between the rims, G² near the
/// contact on each side (over the packing's floor), the confidence and the
/// status (`contact` or `doubtful`).
fn write_evidence(path: &Path, detection: &Detection, keep_doubtful: bool) -> Result<()> {
    let sequence = detection.frames.len() > 1;
    let mut text = String::from(
        "contact,a,b,outer_gap_px,tolerance_px,background_between,g2_a,g2_b,confidence,status,force_bearing",
    );
    text += if sequence { ",frame\n" } else { "\n" };
    for (k, frame) in detection.frames.iter().enumerate() {
        let mut id = 0usize;
        for c in &frame.candidates {
            let written = keep_doubtful || !c.doubtful;
            let contact = if written {
                id += 1;
                (id - 1).to_string()
            } else {
                String::new()
            };
            let b = match c.contact.b {
                ContactBody::Disk(b) => frame.ids[b].clone(),
                ContactBody::Wall(w) => detection.walls[w].name.clone(),
            };
            let e = &c.evidence;
            let background = match e.background_between {
                Some(true) => "yes",
                Some(false) => "no",
                None => "unknown",
            };
            text += &format!(
                "{contact},{},{b},{:.2},{:.2},{background},{:.2},{:.2},{:.3},{},{}",
                frame.ids[c.contact.a],
                e.outer_gap,
                e.tolerance,
                e.g2[0],
                e.g2[1],
                e.confidence,
                if c.doubtful { "doubtful" } else { "contact" },
                if e.force_bearing { "yes" } else { "no" }
            );
            text += &if sequence {
                format!(",{k}\n")
            } else {
                "\n".into()
            };
        }
    }
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// image-frame.json: the pixel frame, what the disks were searched in (the
/// first image's choice) and where the walls came from (extra keys that
/// frame readers ignore).
fn write_frame(path: &Path, detection: &Detection, walls: &WallSource) -> Result<()> {
    let mut json = serde_json::to_value(detection.frame).expect("a frame always serialises");
    if let (Some(map), Some(first)) = (json.as_object_mut(), detection.frames.first()) {
        map.insert(
            "search".into(),
            serde_json::to_value(&first.choice).expect("a choice always serialises"),
        );
        map.insert("walls".into(), wall_word(walls).into());
    }
    let text = serde_json::to_string_pretty(&json).expect("JSON always prints");
    grainforce::scene::write_file_atomically(path, (text + "\n").as_bytes())
}

fn parse_channel(s: &str) -> std::result::Result<Channel, String> {
    Channel::parse(s).map_err(|e| e.to_string())
}

/// The walls asked for; the packing's box when none are named (a detected
/// packing needs an external load for the fringe fit: docs/photoelastic.md,
/// round 11).
fn walls(specs: &[String]) -> Result<WallSource> {
    if specs.is_empty() {
        return Ok(WallSource::PackingBox);
    }
    for (word, source) in [
        ("edges", WallSource::ImageEdges),
        ("box", WallSource::PackingBox),
        ("none", WallSource::None),
    ] {
        if specs.iter().any(|s| s == word) {
            if specs.len() > 1 {
                return Err(Error::Invalid(format!(
                    "--walls {word} cannot be combined with other walls"
                )));
            }
            return Ok(source);
        }
    }
    Ok(WallSource::Lines(
        specs
            .iter()
            .map(|s| WallLine::parse(s))
            .collect::<Result<_>>()?,
    ))
}

/// The walls written, for the run summary.
fn describe_walls(source: &WallSource, walls: &[WallLine]) -> String {
    match source {
        WallSource::PackingBox => format!(
            "{} walls along the packing's bounding box (--walls box, the default; --walls none for none)",
            walls.len()
        ),
        WallSource::None => "no walls (--walls none)".into(),
        WallSource::ImageEdges => "walls at the image borders (--walls edges)".into(),
        WallSource::Lines(l) => format!("{} walls as given", l.len()),
    }
}

/// `--walls`'s word for where the walls came from.
fn wall_word(walls: &WallSource) -> &'static str {
    match walls {
        WallSource::None => "none",
        WallSource::Lines(_) => "lines",
        WallSource::ImageEdges => "edges",
        WallSource::PackingBox => "box",
    }
}

fn overlay_path(base: &Path, frame: usize, count: usize) -> PathBuf {
    if count == 1 {
        return base.to_owned();
    }
    let stem = base
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "overlay".into());
    base.with_file_name(format!("{stem}-{frame:04}.png"))
}

pub fn run(args: Args) -> Result<()> {
    let frame = args.frame.as_deref().map(PixelFrame::read).transpose()?;
    let px_per_m = match (args.scale, frame) {
        (Some(s), _) => s,
        (None, Some(f)) => f.px_per_m,
        (None, None) => {
            eprintln!("note: no --scale given; lengths are written in pixels (1 px = 1 m)");
            1.0
        }
    };
    let classes = DetectOptions::with_classes(&args.radius.0)?;
    let mut settings = DetectSettings::new(classes.radius_min, classes.radius_max, px_per_m);
    settings.detect = classes;
    settings.frame = frame;
    settings.gap_px = args.gap;
    settings.keep_doubtful = args.keep_doubtful;
    settings.thickness = args.thickness;
    settings.channel = args.channel;
    settings.walls = walls(&args.walls)?;
    settings.detect.smoothing_px = args.smoothing;
    settings.detect.settle_edges = args.settle_edges;
    settings.detect.outermost_outline = args.outermost_outline;
    settings.detect.polarity = if args.dark_disks {
        Polarity::Dark
    } else if args.either_polarity {
        Polarity::Either
    } else {
        Polarity::Bright
    };
    let count = args.images.len();
    let mut walls_for_overlay = match &settings.walls {
        WallSource::Lines(l) => l.clone(),
        _ => Vec::new(),
    };
    let detection = detect_images(&args.images, &settings, &mut |k, path, image, found| {
        let doubtful = found.candidates.iter().filter(|c| c.doubtful).count();
        let bearing = found
            .candidates
            .iter()
            .filter(|c| c.evidence.force_bearing && (settings.keep_doubtful || !c.doubtful))
            .count();
        status!(
            "{}: searched the {}",
            path.display(),
            found.choice.describe()
        );
        status!(
            "{}: {} disks, {} contacts ({bearing} carrying force){}",
            path.display(),
            found.disks.len(),
            found.contacts.len(),
            if doubtful > 0 {
                format!(" ({doubtful} doubtful, flagged in {EVIDENCE_FILE})")
            } else {
                String::new()
            }
        );
        if k == 0 && matches!(settings.walls, WallSource::PackingBox) {
            // The same box the detection drew from the first frame's disks.
            walls_for_overlay = grainforce::image::contacts::packing_box_walls(&found.disks);
        }
        if let Some(base) = &args.overlay {
            let mut picture = overlay::draw_overlay(
                image,
                &found.disks,
                &found.ids,
                &found.contacts,
                &walls_for_overlay,
            );
            if !settings.keep_doubtful {
                let doubtful: Vec<_> = found
                    .candidates
                    .iter()
                    .filter(|c| c.doubtful)
                    .map(|c| c.contact)
                    .collect();
                overlay::mark_doubtful(&mut picture, &found.disks, &doubtful);
            }
            overlay::save_overlay(&overlay_path(base, k, count), &picture)?;
        }
        Ok(())
    })?;
    let scenes: Vec<_> = detection.frames.iter().map(|f| f.scene.clone()).collect();
    write_sequence(&args.output, &scenes)?;
    write_frame(&args.output.join(FRAME_FILE), &detection, &settings.walls)?;
    if settings.gap_px.is_none() {
        write_evidence(
            &args.output.join(EVIDENCE_FILE),
            &detection,
            settings.keep_doubtful,
        )?;
    }
    status!(
        "wrote {} ({} frame{}); {}",
        args.output.display(),
        scenes.len(),
        if scenes.len() == 1 { "" } else { "s" },
        describe_walls(&settings.walls, &detection.walls)
    );
    Ok(())
}
