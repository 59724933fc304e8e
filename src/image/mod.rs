//! Measurements from photographs: find disks ([`detect`]), their contacts
//! ([`contacts`]) and identities over a sequence ([`track`]), their strains by
//! digital image correlation ([`dic`], [`strain`]), and the reverse — draw a
//! scene as a camera would see it ([`render`]) so that the whole chain can be
//! tested against known answers.
//!
//! Pixel coordinates: `x_px` grows to the right along a row, `y_px` grows
//! downward, and the centre of pixel (column j, row i) is at (j, i); the image
//! covers [−0.5, W − 0.5] × [−0.5, H − 0.5]. Scene coordinates have y upward;
//! [`PixelFrame`] converts between the two.

pub mod contacts;
pub mod detect;
pub mod dic;
pub mod elastic;
mod font;
pub mod fringe_fit;
mod fringe_kernel;
pub mod fringe_run;
pub mod io;
pub mod overlay;
pub mod photoelastic;
pub mod render;
pub mod strain;
pub mod synthetic;
pub mod track;

use crate::error::{Error, Result};
use crate::scene::{Body, Contact, Grain, Scene};
use std::path::Path;

/// A grayscale image with intensities in [0, 1] (8- and 16-bit inputs are scaled).
pub type FloatImage = ::image::ImageBuffer<::image::Luma<f32>, Vec<f32>>;

pub use contacts::{
    find_contacts, find_image_contacts, ContactBody, ContactEvidence, ContactOptions, ImageContact,
    PixelContact, Rim, WallLine,
};
pub use detect::{detect_disks, DetectOptions, Disk, Polarity};
pub use elastic::{Elasticity, PlaneCondition};
pub use io::{
    load_channel, load_gray, load_gray_sequence, read_for_detection, save_gray, Channel,
    ChannelChoice, DetectionImage,
};
pub use render::{render_scene, render_sequence, RenderOptions, RenderedPair, RenderedSequence};
pub use strain::{measure_stresses, StrainOptions, StrainReport};
pub use track::{track_sequence, TrackOptions, Tracker};

/// Where an image sits in the scene: its scale and the scene coordinates of its
/// bottom-left corner. Scene x = origin_x + (x_px + 0.5)/S and
/// scene y = origin_y + (H − 0.5 − y_px)/S, with S pixels per metre.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PixelFrame {
    pub px_per_m: f64,
    /// Scene coordinates [m] of the image's bottom-left corner (outer edge).
    pub origin: [f64; 2],
    pub width: u32,
    pub height: u32,
}

/// Largest image side the renderers agree to draw.
pub const MAX_IMAGE_SIDE: f64 = 30_000.0;

impl PixelFrame {
    /// The frame that shows the box `lo`..`hi` [m] with a free border of
    /// `margin_px` pixels; an error (not an out-of-memory crash) when the
    /// image would be over [`MAX_IMAGE_SIDE`] pixels on a side.
    pub fn around(lo: [f64; 2], hi: [f64; 2], px_per_m: f64, margin_px: f64) -> Result<Self> {
        let s = px_per_m;
        let width = ((hi[0] - lo[0]) * s + 2.0 * margin_px).ceil();
        let height = ((hi[1] - lo[1]) * s + 2.0 * margin_px).ceil();
        if !(width.is_finite() && height.is_finite())
            || width > MAX_IMAGE_SIDE
            || height > MAX_IMAGE_SIDE
        {
            return Err(Error::Invalid(format!(
                "the image would be {width}×{height} px; lower the scale ({s} px/m)"
            )));
        }
        Ok(PixelFrame {
            px_per_m: s,
            origin: [lo[0] - margin_px / s, lo[1] - margin_px / s],
            width: width.max(1.0) as u32,
            height: height.max(1.0) as u32,
        })
    }

    /// The frame `detect` uses when nothing else is known: origin at the
    /// bottom-left corner of the image.
    pub fn at_origin(px_per_m: f64, width: u32, height: u32) -> Self {
        PixelFrame {
            px_per_m,
            origin: [0.0, 0.0],
            width,
            height,
        }
    }

    pub fn to_scene(&self, px: [f64; 2]) -> [f64; 2] {
        [
            self.origin[0] + (px[0] + 0.5) / self.px_per_m,
            self.origin[1] + (self.height as f64 - 0.5 - px[1]) / self.px_per_m,
        ]
    }

    pub fn to_pixel(&self, p: [f64; 2]) -> [f64; 2] {
        [
            (p[0] - self.origin[0]) * self.px_per_m - 0.5,
            self.height as f64 - 0.5 - (p[1] - self.origin[1]) * self.px_per_m,
        ]
    }

    /// A direction (e.g. a normal) from pixel to scene axes: y flips.
    pub fn direction_to_scene(&self, d: [f64; 2]) -> [f64; 2] {
        [d[0], -d[1]]
    }

    pub fn validate(&self) -> Result<()> {
        if !(self.px_per_m.is_finite() && self.px_per_m > 0.0) {
            return Err(Error::Invalid(format!(
                "the image scale must be a positive number of pixels per metre, not {}",
                self.px_per_m
            )));
        }
        Ok(())
    }

    /// Reads `image-frame.json` as written by `detect` and `render`.
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let frame: PixelFrame = serde_json::from_str(&text)
            .map_err(|e| Error::data(path, Some(e.line()), None, e.to_string()))?;
        frame
            .validate()
            .map_err(|e| Error::data(path, None, Some("px_per_m"), e.to_string()))?;
        Ok(frame)
    }

    pub fn write(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self).expect("a frame always serialises");
        crate::scene::write_file_atomically(path, (text + "\n").as_bytes())
    }
}

/// The name of the file, beside a scene's CSV files, that records the pixel frame.
pub const FRAME_FILE: &str = "image-frame.json";

/// Builds a 2D scene from disks found in one image: grains with the given ids
/// (area π r², `radius` column, zero stress), and contacts with grains or walls.
/// Contact ids are their order, from 0.
pub fn scene_from_detection(
    disks: &[Disk],
    ids: &[String],
    contacts: &[PixelContact],
    walls: &[WallLine],
    frame: &PixelFrame,
) -> Result<Scene> {
    if ids.len() != disks.len() {
        return Err(Error::Invalid(format!(
            "{} ids given for {} disks",
            ids.len(),
            disks.len()
        )));
    }
    frame.validate()?;
    let s = frame.px_per_m;
    let mut scene = Scene::new(2);
    for (disk, id) in disks.iter().zip(ids) {
        let p = frame.to_scene([disk.x, disk.y]);
        let r = disk.r / s;
        let mut grain = Grain::new(
            id.clone(),
            [p[0], p[1], 0.0],
            std::f64::consts::PI * r * r,
            [0.0; 6],
        );
        grain.radius = Some(r);
        scene.grains.push(grain);
    }
    for (k, c) in contacts.iter().enumerate() {
        let b = match c.b {
            ContactBody::Disk(j) => Body::Grain(j),
            ContactBody::Wall(w) => {
                let name = &walls
                    .get(w)
                    .ok_or_else(|| {
                        Error::Invalid(format!("contact {k} names wall {w}, not given"))
                    })?
                    .name;
                Body::Wall(scene.wall_or_insert(name))
            }
        };
        let p = frame.to_scene(c.point);
        let n = frame.direction_to_scene(c.normal);
        scene.contacts.push(Contact {
            id: k.to_string(),
            a: c.a,
            b,
            point: [p[0], p[1], 0.0],
            normal: [n[0], n[1], 0.0],
            mu: None,
        });
    }
    Ok(scene)
}

/// Where the walls of a detection come from.
#[derive(Debug, Clone, Default)]
pub enum WallSource {
    #[default]
    None,
    /// Lines the user gives, in pixels.
    Lines(Vec<WallLine>),
    /// The four image borders (`left`, `right`, `top`, `bottom`).
    ImageEdges,
    /// Four walls along the bounding box of the first frame's disks
    /// (`left`, `right`, `top`, `bottom`; each at the second outermost disk
    /// edge of its side: [`contacts::packing_box_walls`]): what holds a packing whose walls
    /// the picture does not show. Without any wall a balanced field of
    /// compressive forces has no load and is zero (docs/photoelastic.md).
    PackingBox,
}

/// Sets the walls of a [`WallSource::PackingBox`] from the first frame's
/// disks, as the contacts will see them (after any growth to their outline).
fn box_walls_once(walls: &mut Vec<WallLine>, source: &WallSource, first: bool, disks: &[Disk]) {
    if first && matches!(source, WallSource::PackingBox) {
        *walls = contacts::packing_box_walls(disks);
    }
}

#[derive(Debug, Clone)]
pub struct DetectSettings {
    pub detect: DetectOptions,
    /// Largest boundary gap [px] between the fitted circles that still counts
    /// as a contact; `None` (the default): judged from the image (rims
    /// measured, tolerance scaled with the radius, evidence; see
    /// [`contacts::find_image_contacts`]).
    pub gap_px: Option<f64>,
    pub contacts: ContactOptions,
    /// Write doubtful contacts as contacts too (they are always reported).
    pub keep_doubtful: bool,
    pub walls: WallSource,
    pub px_per_m: f64,
    /// A known placement of the images in the scene (e.g. the one `render`
    /// wrote); overrides `px_per_m` and must match the images' size.
    pub frame: Option<PixelFrame>,
    /// Out-of-plane thickness [m], recorded in scene.json.
    pub thickness: Option<f64>,
    pub track: TrackOptions,
    /// The channel of a colour image that is analysed.
    pub channel: Channel,
}

impl DetectSettings {
    pub fn new(radius_min: f64, radius_max: f64, px_per_m: f64) -> Self {
        DetectSettings {
            detect: DetectOptions::new(radius_min, radius_max),
            gap_px: None,
            contacts: ContactOptions::default(),
            keep_doubtful: false,
            walls: WallSource::None,
            px_per_m,
            frame: None,
            thickness: None,
            track: TrackOptions::new(radius_min),
            channel: Channel::default(),
        }
    }
}

/// The outer part of a disk (a fraction of its radius) left out when its
/// photoelastic signal is read: the dark outline of a real disk has a strong
/// gradient of its own, loaded or not.
const COLOUR_EDGE_MARGIN: f64 = 0.1;

/// How far (a fraction of the radius) the outlines of two disks may cross
/// in a photograph: loaded photoelastic disks flatten where they press into
/// each other, and a disk seen slightly from the side shows its wall.
const COLOUR_OVERLAP: f64 = 0.35;

/// The support a disk needs in the colour distance (confident, and confirmed
/// by the model fit), below the defaults'.
const COLOUR_SUPPORT: [f64; 2] = [0.35, 0.25];

/// A disk's median colour distance over its inner 0.8 R must be at least
/// this multiple of the background's own level (its noise) and this
/// fraction of the 99th percentile. Measured: real disks 0.10–0.9 (the
/// dimmest, jlin-step83's unloaded disks, 0.10), circles fitted to a
/// piston's edges 0.01–0.02 under red light with noise (background 0.023).
const COLOUR_FILL: [f64; 2] = [2.5, 0.04];

/// How far apart (a fraction of the smaller radius) two outlines may be
/// and still count for the gap between touching disks: two rims of up to
/// a fifth of the radius each.
const TOUCHING_SEARCH: f64 = 0.4;

/// The smallest radius [px] the colour-distance search works at: bigger
/// disks are searched in the image shrunk by an integer factor to about this
/// size. The search's pixel-sized settings were made for radii of 30–90 px
/// (the photographs of `docs/image.md`), its cost grows with the pixels, and
/// centres found at this scale are as close to PeGS's in radii (the phone
/// photograph searched at half size: 0.023 / 0.055 R, 1.3 s CPU; at full
/// size 0.022 / 0.064 R, 4.5 s).
const COLOUR_SEARCH_RADIUS: f64 = 32.0;

/// The disks of a picture of distances from the background (bright disks,
/// their outlines the edge to the background): the colour distance, or a
/// gray photograph's distance from its background level.
fn colour_search(
    search: &FloatImage,
    detect: &DetectOptions,
    background_level: f64,
) -> Result<Vec<Disk>> {
    let pixels = search.width() as f64 * search.height() as f64;
    let o = colour_search_options(detect, background_level, pixels);
    detect::detect_disks_shrunk(search, &o, colour_search_factor(&o))
}

/// The settings of a [`colour_search`] (bright disks without dark rims, the
/// smoothing of the shrunk picture, looser support, a filled interior).
fn colour_search_options(
    detect: &DetectOptions,
    background_level: f64,
    pixels: f64,
) -> DetectOptions {
    // Disks are bright regions without dark rims in the colour distance.
    let mut o = detect.clone();
    o.polarity = Polarity::Bright;
    o.find_by_rims = false;
    o.overlap = o.overlap.max(COLOUR_OVERLAP);
    // Outlines in the colour distance are a few pixels wide: more
    // smoothing would blur away the outline of a disk whose inside
    // is as pale as the background.
    // Disks are searched in the image shrunk to radii of 32–64 px
    // (below), or small ones up-sampled to 12 px or more; the smoothing
    // is that picture's.
    let f = match detect::small_disk_factor(o.radius_min, pixels) {
        1 => colour_search_factor(&o) as f64,
        up => 1.0 / up as f64,
    };
    o.smoothing_px = o
        .smoothing_px
        .or(Some(f * (o.radius_min / f / 15.0).clamp(1.5, 3.0)));
    // Rays that end on a neighbour or a wall carry no outline: in a
    // dense real packing fewer of them show it.
    o.min_support = o.min_support.min(COLOUR_SUPPORT[0]);
    o.min_support_confirmed = o.min_support_confirmed.min(COLOUR_SUPPORT[1]);
    // A disk differs from the background inside, not only at its
    // outline: a circle on a wall's or a piston's edges is empty.
    o.min_fill = o
        .min_fill
        .max(COLOUR_FILL[0] * background_level)
        .max(COLOUR_FILL[1]);
    o
}

/// The options of a picture searched as it is (not in its distance from
/// the background): the outermost outline is a distance picture's rule.
fn as_is(detect: &DetectOptions) -> DetectOptions {
    let mut o = detect.clone();
    o.outermost_outline = false;
    o
}

/// The outline evidence of a search: the support (the fraction of rays that
/// agree with the circle) summed over the disks.
fn outline_evidence(disks: &[Disk]) -> f64 {
    disks.iter().map(|d| d.support).sum()
}

/// A gray photograph is searched as it is (the rim rules of a single
/// channel, made for rendered pictures) and also as a colour one is, in its
/// distance from the background level; the distance is kept when its
/// outline evidence is clearly the greater (by [`SINGLE_CHANNEL_MARGIN`]).
/// A monochrome camera's dark field shows disks without dark rims, lit
/// fringes and bright rims (`wc-slope-a` in docs/image.md), which the rim
/// rules miss.
fn gray_distance_instead(
    gray: &FloatImage,
    detect: &DetectOptions,
    as_is: &[Disk],
) -> Result<Option<(Vec<Disk>, ChannelChoice)>> {
    // Read pixel by pixel from the gray picture: a big one is searched
    // shrunk, and a whole distance picture would be its size again in memory.
    let (w, h) = (gray.width() as usize, gray.height() as usize);
    let pixels = gray.as_raw();
    let search = |distance: &io::GrayDistance| {
        let o = colour_search_options(detect, distance.own_level, (w * h) as f64);
        let value = |k: usize| distance.at(pixels[k]);
        detect::detect_disks_shrunk_from((w, h), value, &o, colour_search_factor(&o))
    };
    let (first, rival) = io::GrayDistance::of(gray);
    let mut found = search(&first)?;
    let mut distance = first;
    if let Some(rival) = rival {
        let by_rival = search(&rival)?;
        if rival_background_wins(&found, &by_rival) {
            (found, distance) = (by_rival, rival);
        }
    }
    let (level, fraction) = (distance.level, distance.fraction);
    let (ours, theirs) = (outline_evidence(&found), outline_evidence(as_is));
    if ours <= (1.0 + SINGLE_CHANNEL_MARGIN) * theirs {
        return Ok(None);
    }
    let picked = ChannelChoice {
        channel: "gray-distance".to_owned(),
        background: Some(vec![level as f64]),
        background_fraction: Some(fraction),
        polarity: "bright".to_owned(),
        signal: None,
        instead_of: Some(format!(
            "the gray picture as it is (outline support summed over the disks: \
             {theirs:.1} for {} disks; distance: {ours:.1} for {})",
            as_is.len(),
            found.len()
        )),
    };
    Ok(Some((found, picked)))
}

/// Whether the search from the rival background ([`io::background_bins`]:
/// the other end of the histogram, nearly as full as the fuller end's bin
/// and farther from the median pixel) is kept instead of the fuller end's.
/// It is, unless the fuller end's search is better on both counts: clearly
/// more outline evidence (by [`SINGLE_CHANNEL_MARGIN`]) and more disks.
/// Either count alone misleads: in a packing of touching disks with bright
/// rims, circles on the rims' inner edges show whole outlines while the
/// true background shows only the gaps between disks
/// (`tests/image_detect_small.rs` `hex_dark_field`: 119.8 for 134 disks
/// against 110.1 for 165), and a search with a false circle finds more
/// disks (`jl-colorcomp2` under orange light in docs/image.md: 4 disks,
/// 1.8, against 3, 2.3). Where bright rims are the rival, its search is
/// worse on both (`tests/image_backgrounds.rs`: 24.0 for 43 disks against
/// 46.0 for 46).
fn rival_background_wins(fuller: &[Disk], rival: &[Disk]) -> bool {
    let clearly_more =
        outline_evidence(fuller) > (1.0 + SINGLE_CHANNEL_MARGIN) * outline_evidence(rival);
    !(clearly_more && fuller.len() > rival.len())
}

/// The colour distance is unsigned: a disk darker than a dark background
/// and its dark rim differ from the background by a few grey levels, and in
/// a dark-field picture whose rims are as dark as the background, dark
/// fringes at a contact merge with the outline. The signal channel searched
/// as it is (signed, with the rim rules) then shows the outlines better.
/// Both are judged by the outline evidence of what they find: the support
/// (the fraction of rays that agree with the circle) summed over the disks,
/// which grows with the number of disks and with how complete each outline
/// is. Returns the channel's disks and the choice to report when its
/// evidence is clearly the greater (by [`SINGLE_CHANNEL_MARGIN`]); otherwise
/// `None`, and the colour distance stands: on a near tie its outlines and
/// contact rule are the ones measured on real photographs (on
/// `pegs2-step09` under red light the red channel's evidence equals the
/// colour distance's, 27.7, and its contacts are 6 of 52 against 50).
fn single_channel_instead(
    channel: &FloatImage,
    options: &DetectOptions,
    by_distance: &[Disk],
    choice: &ChannelChoice,
) -> Result<Option<(Vec<Disk>, ChannelChoice)>> {
    // Shrunk as the colour distance is on big pictures: at full resolution
    // a 21-megapixel dark field took 9 s of CPU (docs/image.md, "21 megapixels").
    let single =
        detect::detect_disks_shrunk(channel, options, signal_search_factor(channel, options))?;
    let (ours, theirs) = (outline_evidence(&single), outline_evidence(by_distance));
    if ours <= (1.0 + SINGLE_CHANNEL_MARGIN) * theirs {
        return Ok(None);
    }
    let name = choice.signal.clone().unwrap_or_else(|| "green".to_owned());
    let polarity = options.polarity.name();
    let picked = ChannelChoice {
        channel: name.clone(),
        background: None,
        background_fraction: None,
        polarity: polarity.to_owned(),
        signal: None,
        instead_of: Some(format!(
            "the colour distance from the background (outline support summed over \
             the disks: {theirs:.1} for {} disks; {name}: {ours:.1} for {})",
            by_distance.len(),
            single.len()
        )),
    };
    Ok(Some((single, picked)))
}

/// A background darker than this (every channel, fraction of full scale)
/// is a dark field, where a disk or its rim can be darker than the
/// background and the colour distance loses them; only there is the signal
/// channel searched as well (a second search costs as much as the first
/// and more: 4.6 s of CPU on a 3.7-megapixel phone photograph).
const DARK_FIELD: f64 = 0.25;

/// How much more outline evidence (a fraction) the signal channel must show
/// to be searched instead of the colour distance: a disk's in twenty.
const SINGLE_CHANNEL_MARGIN: f64 = 0.05;

/// The background's level in the picture the photoelastic signal is read
/// in (the signal channel of a colour photograph, a gray one as it is);
/// `None` when the background was not read from the image.
fn background_signal(choice: &ChannelChoice) -> Option<f64> {
    let background = choice.background.as_ref()?;
    let channel = match choice.signal.as_deref() {
        _ if background.len() == 1 => 0,
        Some("red") => 0,
        Some("blue") => 2,
        _ => 1,
    };
    background.get(channel).copied()
}

/// By how much the colour distance (and, at the defaults, the signal
/// channel of a dark field and a gray picture) is shrunk for the search.
fn colour_search_factor(o: &DetectOptions) -> usize {
    (o.radius_min / COLOUR_SEARCH_RADIUS).floor().max(1.0) as usize
}

/// By how much a dark field's signal channel or a gray picture is shrunk
/// for the search at the defaults: as the colour distance on big pictures
/// (over [`SHRUNK_SIGNAL_PIXELS`]), not at all on smaller ones, where the
/// full-resolution search is affordable and found more (`jl-colorcomp2`,
/// 0.4 MP, radii 113–143 px: shrunk by 3 its green search lost a disk to
/// the colour distance's false one).
fn signal_search_factor(image: &FloatImage, o: &DetectOptions) -> usize {
    let pixels = image.width() as f64 * image.height() as f64;
    if pixels > SHRUNK_SIGNAL_PIXELS {
        colour_search_factor(o)
    } else {
        1
    }
}

/// Pictures bigger than this [pixels] have their signal-channel search
/// shrunk (the time targets: 2 s under 4 MP, 5 s at 21 MP).
const SHRUNK_SIGNAL_PIXELS: f64 = 4.0e6;

/// What one image gave.
#[derive(Debug, Clone)]
pub struct DetectedFrame {
    /// The disks; judged from the image, their circles reach the outer edge
    /// of their rims.
    pub disks: Vec<Disk>,
    /// Each disk's rim, where one shows (empty with a fixed `gap_px`).
    pub rims: Vec<Option<Rim>>,
    /// Every candidate contact with its evidence and confidence, doubtful ones
    /// included (empty with a fixed `gap_px`).
    pub candidates: Vec<ImageContact>,
    /// Grain ids, stable over the sequence.
    pub ids: Vec<String>,
    pub contacts: Vec<PixelContact>,
    pub scene: Scene,
    /// What the disks were searched in (read from the image by default).
    pub choice: ChannelChoice,
}

#[derive(Debug, Clone)]
pub struct Detection {
    pub frames: Vec<DetectedFrame>,
    pub walls: Vec<WallLine>,
    pub frame: PixelFrame,
}

/// Detects disks in each image of a sequence (one image: a single scene),
/// tracks their ids, finds contacts and builds one scene per image. Images are
/// read one at a time; `on_frame` sees each (e.g. to draw an overlay). Errors
/// name the file: unreadable, of another size than the first, or without disks.
pub fn detect_images(
    paths: &[std::path::PathBuf],
    settings: &DetectSettings,
    on_frame: &mut dyn FnMut(usize, &Path, &FloatImage, &DetectedFrame) -> Result<()>,
) -> Result<Detection> {
    if paths.is_empty() {
        return Err(Error::Invalid("no images given".into()));
    }
    if settings.gap_px.is_some_and(|g| !g.is_finite()) {
        return Err(Error::Invalid(
            "the contact gap must be a number of pixels".into(),
        ));
    }
    if let Some(t) = settings.thickness {
        if !(t.is_finite() && t > 0.0) {
            return Err(Error::Invalid(format!(
                "the thickness must be positive, not {t}"
            )));
        }
    }
    let mut tracker = track::Tracker::new(settings.track.clone())?;
    let mut frames = Vec::with_capacity(paths.len());
    let mut first: Option<FloatImage> = None;
    let mut pixel_frame = None;
    let mut walls = Vec::new();
    for (k, path) in paths.iter().enumerate() {
        let mut laps = detect::profile::Laps::start();
        let polarity = settings.detect.polarity.name();
        // `signal` is `None` where it is the searched picture itself.
        let (picture, rival, signal) = io::read_search_picture(path, settings.channel, polarity)?;
        let io::SearchPicture {
            search,
            choice,
            background_level,
        } = picture;
        laps.lap("read: decode and channel choice");
        let mut choice = choice;
        let mut by_colour = choice.background.is_some();
        match &first {
            Some(f) => io::check_same_size(f, &paths[0], &search, path)?,
            None => {
                let frame = match settings.frame {
                    Some(f) if (f.width, f.height) != search.dimensions() => {
                        return Err(Error::data(
                            path,
                            None,
                            None,
                            format!(
                                "the image is {}×{} px but its pixel frame says {}×{}",
                                search.width(),
                                search.height(),
                                f.width,
                                f.height
                            ),
                        ))
                    }
                    Some(f) => f,
                    None => {
                        PixelFrame::at_origin(settings.px_per_m, search.width(), search.height())
                    }
                };
                frame.validate()?;
                pixel_frame = Some(frame);
                walls = match &settings.walls {
                    WallSource::None => Vec::new(),
                    WallSource::Lines(lines) => lines.clone(),
                    WallSource::ImageEdges => contacts::edge_walls(search.width(), search.height()),
                    // Set once the first frame's disks are known.
                    WallSource::PackingBox => Vec::new(),
                };
                // Only its size is needed for the checks that follow.
                first = Some(FloatImage::new(search.width(), search.height()));
            }
        }
        let frame = pixel_frame.expect("set with the first image");
        let (disks, image) = if by_colour {
            let image = signal.unwrap_or_else(|| search.clone());
            let by_distance = colour_search(&search, &settings.detect, background_level)?;
            // Not needed again: freed before a second search fills its own buffers.
            drop(search);
            laps.lap("colour-distance search");
            let by_distance = match rival {
                Some(rival) => {
                    let by_rival =
                        colour_search(&rival.search, &settings.detect, rival.background_level)?;
                    if laps.running() {
                        laps.lap(&format!(
                            "rival background: {:.1} for {} disks (fuller end's {:.1} for {})",
                            outline_evidence(&by_rival),
                            by_rival.len(),
                            outline_evidence(&by_distance),
                            by_distance.len()
                        ));
                    }
                    if rival_background_wins(&by_distance, &by_rival) {
                        choice = rival.choice;
                        by_rival
                    } else {
                        by_distance
                    }
                }
                None => by_distance,
            };
            let dark_field = choice
                .background
                .as_ref()
                .is_some_and(|b| b.iter().all(|&v| v < DARK_FIELD));
            let instead = if dark_field {
                single_channel_instead(&image, &as_is(&settings.detect), &by_distance, &choice)?
            } else {
                None
            };
            laps.lap("signal-channel search");
            let disks = match instead {
                Some((single, picked)) => {
                    by_colour = false;
                    choice = picked;
                    single
                }
                None => by_distance,
            };
            (disks, image)
        } else {
            // At the defaults a big gray picture is searched shrunk as the
            // colour distance is (its rim rules were made for radii of
            // 30–90 px); at full resolution a 21-megapixel gray dark field
            // took 28 of its 32 s of CPU here.
            let disks = if settings.channel == Channel::Auto {
                let factor = signal_search_factor(&search, &settings.detect);
                detect::detect_disks_shrunk(&search, &as_is(&settings.detect), factor)?
            } else {
                detect_disks(&search, &as_is(&settings.detect))?
            };
            let gray_auto = settings.channel == Channel::Auto
                && choice.channel == "gray"
                && settings.detect.polarity == Polarity::Bright;
            let instead = if gray_auto {
                gray_distance_instead(&search, &settings.detect, &disks)?
            } else {
                None
            };
            laps.lap("gray search");
            let disks = match instead {
                Some((found, picked)) => {
                    by_colour = true;
                    choice = picked;
                    found
                }
                None => disks,
            };
            // The searched picture is the signal one here (one copy in memory).
            (disks, signal.unwrap_or(search))
        };
        // A circle on an opaque object (a clamp beside the packing) is no
        // photoelastic disk: it blocks the backlight the disks pass.
        let disks = match background_signal(&choice).filter(|_| by_colour) {
            Some(level) => {
                let (kept, dropped) = detect::without_opaque(&image, disks, level);
                if dropped > 0 {
                    laps.lap(&format!("dropped {dropped} opaque circles"));
                }
                kept
            }
            None => disks,
        };
        if disks.is_empty() {
            return Err(Error::data(
                path,
                None,
                None,
                format!(
                    "no disks of radius {}..{} px found in the {}; check --radius, or choose \
                     the channel (--channel red|green|blue|luma) and the disks' polarity \
                     (--dark-disks, --either-polarity)",
                    settings.detect.radius_min,
                    settings.detect.radius_max,
                    choice.describe()
                ),
            ));
        }
        let (disks, rims, candidates, contacts) = match settings.gap_px {
            Some(gap) => {
                box_walls_once(&mut walls, &settings.walls, k == 0, &disks);
                let contacts = find_contacts(&disks, &walls, gap);
                (disks, Vec::new(), Vec::new(), contacts)
            }
            None if by_colour => {
                // The circles are the outlines against the background: the
                // whole disk where its rim differs from the background, the
                // interior where the rim is as dark as the background (then
                // touching disks' outlines stop short by two rims, and each
                // circle grows by one). The photoelastic signal is read in green.
                let mut options = settings.contacts.clone();
                let rim = 0.5 * contacts::touching_gap(&disks, TOUCHING_SEARCH);
                let disks: Vec<Disk> = disks
                    .into_iter()
                    .map(|d| Disk { r: d.r + rim, ..d })
                    .collect();
                let rims = vec![None; disks.len()];
                options.edge_margin = options.edge_margin.max(COLOUR_EDGE_MARGIN);
                // The disks were found in the image shrunk by this factor:
                // the outlines are placed to its pixels, not the photograph's.
                options.base_px *= colour_search_factor(&settings.detect) as f64;
                box_walls_once(&mut walls, &settings.walls, k == 0, &disks);
                let candidates = find_image_contacts(&image, &disks, &rims, &walls, &options);
                let contacts = candidates
                    .iter()
                    .filter(|c| settings.keep_doubtful || !c.doubtful)
                    .map(|c| c.contact)
                    .collect();
                (disks, rims, candidates, contacts)
            }
            None => {
                let rims = contacts::measure_rims(&image, &disks);
                let outer = contacts::outer_disks(&disks, &rims);
                box_walls_once(&mut walls, &settings.walls, k == 0, &outer);
                let candidates =
                    find_image_contacts(&image, &outer, &rims, &walls, &settings.contacts);
                let contacts = candidates
                    .iter()
                    .filter(|c| settings.keep_doubtful || !c.doubtful)
                    .map(|c| c.contact)
                    .collect();
                (outer, rims, candidates, contacts)
            }
        };
        laps.lap("contacts");
        let ids: Vec<String> = tracker.assign(&disks).iter().map(u64::to_string).collect();
        let mut scene = scene_from_detection(&disks, &ids, &contacts, &walls, &frame)?;
        scene.settings.thickness = settings.thickness;
        scene.settings.description = Some(format!(
            "disks detected by grainforce in {}",
            path.file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default()
        ));
        if paths.len() > 1 {
            scene.frame = Some(k as i64);
        }
        let detected = DetectedFrame {
            disks,
            rims,
            candidates,
            ids,
            contacts,
            scene,
            choice,
        };
        on_frame(k, path, &image, &detected)?;
        laps.lap("scene and on_frame (overlay)");
        frames.push(detected);
    }
    Ok(Detection {
        frames,
        walls,
        frame: pixel_frame.expect("at least one image"),
    })
}
