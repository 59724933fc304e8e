//! Reading and writing grayscale images, with errors that name the file.

use super::FloatImage;
use crate::error::{Error, Result};
use ::image::{DynamicImage, ImageBuffer, ImageError, ImageFormat, Luma};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Which part of a colour image becomes the intensity that is analysed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Channel {
    Red,
    /// Photoelastic analyses measure the fringe intensity in green (PeGS
    /// does), and a camera's Bayer sensor has twice as many green sites, so
    /// green is its sharpest, least noisy channel: the photoelastic signal
    /// (G²) of contacts is read in it.
    Green,
    Blue,
    /// Luma, as the `image` crate weighs it (Rec. 709: 0.2126 R + 0.7152 G + 0.0722 B).
    Luma,
    /// Read from the image (`detect`'s default): a colour image becomes its
    /// colour distance from the background colour (see [`read_for_detection`]),
    /// a gray image is read as it is.
    #[default]
    Auto,
}

impl Channel {
    pub fn parse(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "red" | "r" => Ok(Channel::Red),
            "green" | "g" => Ok(Channel::Green),
            "blue" | "b" => Ok(Channel::Blue),
            "luma" | "gray" | "grey" => Ok(Channel::Luma),
            "auto" => Ok(Channel::Auto),
            _ => Err(Error::Invalid(format!(
                "channel `{s}`: expected auto, red, green, blue or luma"
            ))),
        }
    }
}

/// Reads an image (PNG, TIFF, BMP or JPEG; 8- or 16-bit, gray or colour) as
/// intensities in [0, 1]. Colour images are converted to luma.
pub fn load_gray(path: &Path) -> Result<FloatImage> {
    load_channel(path, Channel::Luma)
}

/// Reads an image as intensities in [0, 1]; a colour image is reduced to one
/// channel (gray images are read as they are, whatever the channel).
pub fn load_channel(path: &Path, channel: Channel) -> Result<FloatImage> {
    let reader = ::image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let decoded = reader.decode().map_err(|e| image_error(path, e))?;
    let image = match (decoded, channel) {
        (DynamicImage::ImageLuma8(g), _) => to_float(&g, 255.0),
        (DynamicImage::ImageLuma16(g), _) => to_float(&g, 65535.0),
        (other, Channel::Luma) => other.to_luma32f(),
        (DynamicImage::ImageRgb8(c), _) => pick(c.as_raw(), c.dimensions(), channel, 255.0),
        (DynamicImage::ImageRgb16(c), _) => pick(c.as_raw(), c.dimensions(), channel, 65535.0),
        (other, _) => {
            let c = other.to_rgb32f();
            pick(c.as_raw(), c.dimensions(), channel, 1.0)
        }
    };
    if image.width() == 0 || image.height() == 0 {
        return Err(Error::data(path, None, None, "the image is empty"));
    }
    Ok(image)
}

/// What `detect` analyses in an image, and why: the picture the disks are
/// searched in, the picture their photoelastic signal (G²) is read in, and
/// what was read from the image to choose them.
pub struct DetectionImage {
    pub search: FloatImage,
    pub signal: FloatImage,
    pub choice: ChannelChoice,
    /// How far the background's own pixels are from the background colour
    /// in `search` (the 90th percentile over its histogram bin: noise, light
    /// falling off); 0 when no background was estimated.
    pub background_level: f64,
}

/// How the searched picture was made (reported in the run summary and in
/// `image-frame.json`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ChannelChoice {
    /// `colour-distance`, `gray`, or the channel asked for (`red`, …).
    pub channel: String,
    /// The background colour (RGB in [0, 1]; one value for gray images), when
    /// it was estimated: the most common of the image's darkest or brightest
    /// colours.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub background: Option<Vec<f64>>,
    /// Fraction of the image within that colour's bin.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub background_fraction: Option<f64>,
    /// `bright` or `dark`: the disks in the searched picture.
    pub polarity: String,
    /// The channel the photoelastic signal (G²) is read in, when chosen from
    /// the image: green (PeGS's), unless the light leaves it nearly empty
    /// (red light), then the channel with the widest spread.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub signal: Option<String>,
    /// The picture that was searched too and set aside, with the disks each
    /// found, when `auto` chose a single channel over the colour distance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instead_of: Option<String>,
}

impl ChannelChoice {
    pub fn describe(&self) -> String {
        let searched = match &self.background {
            Some(b) => format!(
                "{} from the background colour ({}; {:.0} % of the image), disks {}",
                self.channel.replace('-', " "),
                b.iter()
                    .map(|v| format!("{:.0}", 255.0 * v))
                    .collect::<Vec<_>>()
                    .join(", "),
                100.0 * self.background_fraction.unwrap_or(0.0),
                self.polarity
            ),
            None => format!("{} channel, disks {}", self.channel, self.polarity),
        };
        let searched = match &self.signal {
            Some(c) if c != "green" => format!("{searched}; G² read in {c}"),
            _ => searched,
        };
        match &self.instead_of {
            Some(other) => format!("{searched}, chosen over {other}"),
            None => searched,
        }
    }
}

/// Reads an image for `detect`. With [`Channel::Auto`] a colour image is
/// searched in its colour distance from the background colour: the most
/// common of its darkest or brightest colours (a 16-level-per-channel
/// histogram's fullest such bin, its mean; [`background_bins`]), whatever its
/// colour (a white or painted backdrop, a dark field, coloured light), and
/// however much of the picture the disks cover. Every part of a disk that differs from the
/// background, a fringe of any order or colour, a dark rim, a dim interior,
/// is then bright, so a disk is one bright region whose outline is the edge
/// to the background, and fringes inside it barely show. The photoelastic
/// signal is read in green (PeGS's choice). A gray image, or an explicit
/// channel, is searched as it is, disks as `polarity` says.
pub fn read_for_detection(path: &Path, channel: Channel, polarity: &str) -> Result<DetectionImage> {
    let (read, _, signal) = read_search_picture(path, channel, polarity)?;
    Ok(DetectionImage {
        signal: signal.unwrap_or_else(|| read.search.clone()),
        search: read.search,
        choice: read.choice,
        background_level: read.background_level,
    })
}

/// [`DetectionImage`] without its signal picture where that is the searched
/// one (a gray image, or a channel asked for): returned as `None`, so that a
/// big picture is not held twice.
pub(crate) struct SearchPicture {
    pub search: FloatImage,
    pub choice: ChannelChoice,
    pub background_level: f64,
}

/// [`read_for_detection`]: the searched picture, the colour distance from
/// the rival background when the histogram has one ([`background_bins`]),
/// and the signal picture when it is another.
pub(crate) fn read_search_picture(
    path: &Path,
    channel: Channel,
    polarity: &str,
) -> Result<(SearchPicture, Option<SearchPicture>, Option<FloatImage>)> {
    let reader = ::image::ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let decoded = reader.decode().map_err(|e| image_error(path, e))?;
    if decoded.width() == 0 || decoded.height() == 0 {
        return Err(Error::data(path, None, None, "the image is empty"));
    }
    let colour = decoded.color().has_color();
    if channel != Channel::Auto || !colour {
        let single = match (&decoded, channel) {
            (DynamicImage::ImageLuma8(g), _) => to_float(g, 255.0),
            (DynamicImage::ImageLuma16(g), _) => to_float(g, 65535.0),
            (other, Channel::Luma | Channel::Auto) => other.to_luma32f(),
            (other, _) => {
                let c = other.to_rgb32f();
                pick(c.as_raw(), c.dimensions(), channel, 1.0)
            }
        };
        let name = if colour {
            format!("{channel:?}").to_ascii_lowercase()
        } else {
            "gray".to_owned()
        };
        let picture = SearchPicture {
            search: single,
            choice: ChannelChoice {
                channel: name,
                background: None,
                background_fraction: None,
                polarity: polarity.to_owned(),
                signal: None,
                instead_of: None,
            },
            background_level: 0.0,
        };
        return Ok((picture, None, None));
    }
    let (w, h) = (decoded.width(), decoded.height());
    // 8-bit RGB (cameras' JPEGs) is read in place; anything else as floats.
    let (found, rival, (signal, signal_channel)) = match decoded {
        DynamicImage::ImageRgb8(c) => colour_distance(c.as_raw(), (w, h), 255.0),
        other => colour_distance(other.to_rgb32f().as_raw(), (w, h), 1.0),
    };
    let signal_name = format!("{signal_channel:?}").to_ascii_lowercase();
    let picture = |d: ColourDistance| SearchPicture {
        search: d.search,
        choice: ChannelChoice {
            channel: "colour-distance".to_owned(),
            background: Some(d.background.iter().map(|&v| v as f64).collect()),
            background_fraction: Some(d.fraction),
            polarity: "bright".to_owned(),
            signal: Some(signal_name.clone()),
            instead_of: None,
        },
        background_level: d.background_level,
    };
    Ok((picture(found), rival.map(picture), Some(signal)))
}

/// A colour distance picture ([`colour_distance`]) from one background.
struct ColourDistance {
    search: FloatImage,
    /// The background colour, each channel in [0, 1].
    background: [f32; 3],
    /// The fraction of pixels in the background's histogram bin.
    fraction: f64,
    /// The background's own level in `search` (see [`own_level`]).
    background_level: f64,
}

/// The colour distance of every pixel from the background colour (scaled so
/// that the 99th percentile of the distances is 1), the same from the rival
/// background when the histogram has one ([`background_bins`]), and the
/// picture the photoelastic signal is read in with its channel
/// ([`signal_channel`]).
#[allow(clippy::type_complexity)]
fn colour_distance<T: Copy + Into<f32> + Sync>(
    raw: &[T],
    (width, height): (u32, u32),
    full_scale: f32,
) -> (
    ColourDistance,
    Option<ColourDistance>,
    (FloatImage, Channel),
) {
    // Every pixel of a small image, every 7th (a prime stride) of a big one.
    let pixels = raw.len() / 3;
    let stride = if pixels > 4_000_000 { 7 } else { 1 };
    // Each channel binned on its own scale (its 99th percentile): light of
    // one colour leaves the others a few levels, where the backdrop and the
    // disks would share bins. Where that finds no bright field, the
    // channels are binned on the full scale, as before (dark fields).
    let own = channel_tops(raw, stride.max(3), full_scale);
    let by_own = histogram_background(raw, stride, own);
    let full = [full_scale; 3];
    let mut by_full = None;
    let dark = |b: &BinMean| {
        b.mean
            .iter()
            .all(|&v| (v as f32) < BRIGHT_FIELD * full_scale)
    };
    // A candidate (the fuller end's bin, or the rival where there is one)
    // binned on the channels' own scales while it is a bright field's,
    // else on the full scale.
    let mut choose = |pick: &dyn Fn(&HistogramBackground) -> &BinMean| {
        if !dark(pick(&by_own)) {
            return (own, by_own.seen, pick(&by_own).clone());
        }
        let h = by_full.get_or_insert_with(|| histogram_background(raw, stride, full));
        (full, h.seen, pick(h).clone())
    };
    let first = choose(&|h| &h.bin);
    let rival = choose(&|h| h.rival.as_ref().unwrap_or(&h.bin));
    let from = |(scales, seen, bin): &([f32; 3], usize, BinMean)| {
        distance_from(raw, (width, height), full_scale, stride, scales, bin, *seen)
    };
    let distance = from(&first);
    let same = rival.0 == first.0 && rival.2.bin == first.2.bin;
    let rival = (!same).then(|| from(&rival));
    let channel = signal_channel(channel_spreads(raw, stride));
    let signal = pick(raw, (width, height), channel, full_scale);
    (distance, rival, (signal, channel))
}

/// [`colour_distance`] from the background of histogram bin `bin` (binned on
/// `scales`, `seen` pixels counted).
#[allow(clippy::too_many_arguments)]
fn distance_from<T: Copy + Into<f32> + Sync>(
    raw: &[T],
    (width, height): (u32, u32),
    full_scale: f32,
    stride: usize,
    scales: &[f32; 3],
    bin: &BinMean,
    seen: usize,
) -> ColourDistance {
    let in_background = |p: &[T]| bin_of(p, scales) == bin.bin;
    let background = bin.mean.map(|v| v as f32 / full_scale);
    let gain = white_balance(background);
    let distance: Vec<f32> = raw
        .par_chunks_exact(3)
        .map(|p| {
            let d =
                [0, 1, 2].map(|c| (Into::<f32>::into(p[c]) / full_scale - background[c]) * gain[c]);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        })
        .collect();
    let scale = distance_scale(distance.iter().step_by(stride.max(3)).copied().collect());
    // The background bin's own distances (noise, shading), sampled, from
    // the bin's median colour (see [`own_level`]).
    let in_bin: Vec<&[T]> = (raw.chunks_exact(3).step_by(stride.max(3)))
        .filter(|p| in_background(p))
        .collect();
    let centre = [0, 1, 2].map(|c| {
        let mut v: Vec<f32> = in_bin.iter().map(|p| p[c].into()).collect();
        percentile(&mut v, 50).unwrap_or(bin.mean[c] as f32) / full_scale
    });
    let mut own: Vec<f32> = (in_bin.iter())
        .map(|p| {
            let d = [0, 1, 2].map(|c| (Into::<f32>::into(p[c]) / full_scale - centre[c]) * gain[c]);
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() * scale
        })
        .collect();
    let background_level = own_level(&mut own);
    let search = FloatImage::from_raw(
        width,
        height,
        distance
            .into_par_iter()
            .map(|d| (d * scale).min(1.5))
            .collect(),
    )
    .expect("same dimensions");
    ColourDistance {
        search,
        background,
        fraction: bin.count as f64 / seen.max(1) as f64,
        background_level,
    }
}

/// The background's own level in a distance picture (its noise, light
/// falling off) from the distances of its histogram bin's pixels from the
/// bin's median (not from its mean, the background colour, which the
/// dimmest disks' pixels pull): their 90th percentile, but at most
/// [`OWN_OVER_MEDIAN`] times their median. The bin is 1/16 of full scale
/// wide, and in a dim dark field (a monochrome camera's, or any picture
/// whose response is not linear: the sweep's gamma 1.6) the dimmest disks'
/// pixels fall into the background's bin; their distances raised its 90th
/// percentile from 0.004 to 0.09 of the scale on `wc-slope-a`, and the fill
/// rule (2.5 times this level) then dropped every disk dimmer than 25 grey
/// levels (docs/image.md, round 12). The median is the background's as long
/// as its pixels are most of the bin.
fn own_level(own: &mut [f32]) -> f64 {
    let Some(p90) = percentile(own, 90) else {
        return 0.0;
    };
    let p50 = percentile(own, 50).unwrap_or(0.0);
    p90.min(OWN_OVER_MEDIAN * p50) as f64
}

/// See [`own_level`]: the 90th percentile of a Gaussian's absolute
/// deviations is 2.44 times their median (and of a colour distance, three
/// channels of it, 1.63 times), so a background of noise alone keeps its
/// 90th percentile.
const OWN_OVER_MEDIAN: f32 = 2.5;

/// The `per_cent`th percentile of `v` (reordered in place); None when `v`
/// is empty.
fn percentile(v: &mut [f32], per_cent: usize) -> Option<f32> {
    let k = (v.len() * per_cent / 100).min(v.len().checked_sub(1)?);
    Some(*v.select_nth_unstable_by(k, f32::total_cmp).1)
}

/// The scale of a distance picture: the reciprocal of a sample's 99th
/// percentile, which it brings to 1 (1 when the sample is empty or flat).
fn distance_scale(mut sample: Vec<f32>) -> f32 {
    let top = percentile(&mut sample, 99).unwrap_or(1.0);
    if top > 1e-6 {
        1.0 / top
    } else {
        1.0
    }
}

/// Histogram bins per channel for [`histogram_background`].
const LEVELS: usize = 16;

/// The bin of pixel `p`, each channel on its own `scales`.
fn bin_of<T: Copy + Into<f32>>(p: &[T], scales: &[f32; 3]) -> usize {
    let q =
        |c: usize| ((Into::<f32>::into(p[c]) / scales[c] * LEVELS as f32) as usize).min(LEVELS - 1);
    (q(0) * LEVELS + q(1)) * LEVELS + q(2)
}

/// A histogram bin: its index, its count and its pixels' mean colour (raw units).
#[derive(Clone)]
struct BinMean {
    bin: usize,
    count: usize,
    mean: [f64; 3],
}

/// The background's bin and its rival ([`background_bins`]) of a histogram
/// of every `stride`-th pixel binned on `scales`, and the pixels counted.
struct HistogramBackground {
    bin: BinMean,
    rival: Option<BinMean>,
    seen: usize,
}

fn histogram_background<T: Copy + Into<f32>>(
    raw: &[T],
    stride: usize,
    scales: [f32; 3],
) -> HistogramBackground {
    let mut count = vec![0usize; LEVELS * LEVELS * LEVELS];
    let mut sum = vec![[0.0f64; 3]; LEVELS * LEVELS * LEVELS];
    let mut seen = 0usize;
    for p in raw.chunks_exact(3).step_by(stride) {
        let b = bin_of(p, &scales);
        count[b] += 1;
        for c in 0..3 {
            sum[b][c] += Into::<f32>::into(p[c]) as f64;
        }
        seen += 1;
    }
    // Luma on the channels' scales too.
    let luma = |p: [f64; 3]| {
        0.299 * p[0] / scales[0] as f64
            + 0.587 * p[1] / scales[1] as f64
            + 0.114 * p[2] / scales[2] as f64
    };
    let bin_luma: Vec<f64> = (0..count.len())
        .map(|b| luma(sum[b]) / count[b].max(1) as f64)
        .collect();
    let sample: Vec<f64> = raw
        .chunks_exact(3)
        .step_by(stride.max(3))
        .map(|p| luma([0, 1, 2].map(|c| Into::<f32>::into(p[c]) as f64)))
        .collect();
    let (bin, rival) = background_bins(&count, &bin_luma, sample, 1.0 / LEVELS as f64);
    let mean_of = |b: usize| BinMean {
        bin: b,
        count: count[b],
        mean: [0, 1, 2].map(|c| sum[b][c] / count[b].max(1) as f64),
    };
    HistogramBackground {
        bin: mean_of(bin),
        rival: rival.map(mean_of),
        seen,
    }
}

/// Each channel's 99th percentile over every `stride`-th pixel, at least
/// one 255th of full scale.
fn channel_tops<T: Copy + Into<f32>>(raw: &[T], stride: usize, full_scale: f32) -> [f32; 3] {
    [0, 1, 2].map(|c| {
        let mut v: Vec<f32> = raw
            .chunks_exact(3)
            .step_by(stride)
            .map(|p| p[c].into())
            .collect();
        percentile(&mut v, 99).map_or(full_scale, |top| top.max(full_scale / 255.0))
    })
}

/// Per-channel gains that make a bright background grey (von Kries white
/// balance): behind a bright field the background is the light itself, and
/// light of one colour (red, orange, green) dims the other channels, and
/// with them every difference between a disk and the background that lies
/// in those channels (`jl-static0765` under red light in
/// benches/robustness_photos.py: 139 → 104 of 152 disks). Each channel is scaled by
/// the brightest background channel over its own, at most [`MAX_GAIN`]
/// times (noise grows with the gain). A dark field (no background channel
/// of [`BRIGHT_FIELD`]) and a channel the light leaves nearly empty (under
/// [`DEAD_CHANNEL`] of the brightest: its noise, not its picture) keep a
/// gain of 1.
fn white_balance(background: [f32; 3]) -> [f32; 3] {
    let brightest = background.iter().copied().fold(0.0f32, f32::max);
    if brightest < BRIGHT_FIELD {
        return [1.0; 3];
    }
    let gain = background.map(|b| {
        if b < DEAD_CHANNEL * brightest {
            1.0
        } else {
            (brightest / b).clamp(1.0, MAX_GAIN)
        }
    });
    if gain.iter().all(|&g| g < COLOURED_LIGHT) {
        return [1.0; 3];
    }
    gain
}

/// See [`white_balance`]: a light is coloured when one channel's gain
/// reaches this; a white light's tint is left alone (the photographs of
/// docs/image.md in white light: at most 1.09, `jl-video181`'s yellowish
/// backlight; the sweep's coloured lights 3.3–8).
const COLOURED_LIGHT: f32 = 1.5;

/// See [`white_balance`]: the largest channel gain (a red light's blue is
/// 0.12 of its red in the sweep's illuminants, gain 8.3).
const MAX_GAIN: f32 = 8.0;
/// See [`white_balance`]: a background whose brightest channel is under
/// this (fraction of full scale) is a dark field, left unbalanced.
const BRIGHT_FIELD: f32 = 0.25;
/// See [`white_balance`]: a background channel under this fraction of the
/// brightest carries too little of the picture to balance (a red LED's
/// green and blue, 2–5 %, `tests/image_real_photos.rs`; amplified, their
/// noise made circles: `jlin-narrow21` +6, `jlin-iphone83` 83 → 60).
const DEAD_CHANNEL: f32 = 0.1;

/// The background's histogram bin: the fullest bin whose colour is among the
/// image's darkest or brightest (its mean luma within one bin of the 5th
/// percentile's or of the 95th's; of the fullest dark and the fullest bright
/// one, the fuller), or the fullest of all when none is; and a rival, the
/// other end's fullest bin, when it is at least [`NEAR_FULLEST`] as full and
/// farther from the median pixel. Behind a polariscope the background is the
/// light without a disk: extinguished in a dark field, the brightest part of
/// a bright one; disks are in between. A
/// dense packing of unloaded disks of one colour fills more of the picture
/// than the background does (two photographs of docs/image.md: the disks'
/// teal 5–8 % of the pixels, the backdrop's white 4 %). `bin_luma` is each
/// bin's mean luma, `sample` the luma of a sample of pixels, `one_bin` a
/// bin's width, all in one unit.
pub(crate) fn background_bins(
    count: &[usize],
    bin_luma: &[f64],
    mut sample: Vec<f64>,
    one_bin: f64,
) -> (usize, Option<usize>) {
    let fullest = |keep: &dyn Fn(usize) -> bool| {
        (0..count.len())
            .filter(|&b| count[b] > 0 && keep(b))
            .max_by_key(|&b| count[b])
    };
    let all = || fullest(&|_| true).unwrap_or(0);
    if sample.len() < 2 {
        return (all(), None);
    }
    let n = sample.len();
    let dark = *sample
        .select_nth_unstable_by(n / 20, |a, b| a.total_cmp(b))
        .1;
    let bright = *sample
        .select_nth_unstable_by(n * 19 / 20, |a, b| a.total_cmp(b))
        .1;
    let is_dark = |b: usize| bin_luma[b] <= dark + one_bin;
    let is_bright = |b: usize| !is_dark(b) && bin_luma[b] >= bright - one_bin;
    let (Some(darkest), brightest) = (fullest(&is_dark), fullest(&is_bright)) else {
        return (fullest(&is_bright).unwrap_or_else(all), None);
    };
    let Some(brightest) = brightest else {
        return (darkest, None);
    };
    // Which end of the histogram is the background: the fuller one's bin,
    // but the other end's competes when it is nearly as full and farther
    // from the median pixel (disks lie between the extremes). In a packing
    // of touching disks with bright rims the rims' bin can be the fuller by
    // a little (`tests/image_detect_small.rs`: 11 241 against the dark
    // triangles' 9 853), and in a dark field with bright rims the rims' bin
    // is the farther (`tests/image_backgrounds.rs`); the searches judge
    // (`rival_background_wins` in `src/image/mod.rs`). None of the 14
    // photographs of docs/image.md with a reference has a rival.
    let median = *sample
        .select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b))
        .1;
    let (fuller, other) = if count[darkest] >= count[brightest] {
        (darkest, brightest)
    } else {
        (brightest, darkest)
    };
    let from_median = |b: usize| (bin_luma[b] - median).abs();
    let rival = count[other] as f64 >= NEAR_FULLEST * count[fuller] as f64
        && from_median(other) > from_median(fuller);
    (fuller, rival.then_some(other))
}

/// See [`background_bins`]: the other end's bin competes to be the
/// background when it holds at least this share of the fuller end's.
const NEAR_FULLEST: f64 = 0.5;

/// A gray picture's distance from its background level (the fullest of
/// sixteen levels among its darkest or brightest, [`background_bins`]),
/// scaled as [`colour_distance`] scales it; with the background level, the
/// fraction of pixels in its bin and the background's own level in the
/// distance (90th percentile over the bin).
pub fn gray_distance(gray: &FloatImage) -> (FloatImage, f32, f64, f64) {
    let (levels, _) = GrayDistance::of(gray);
    let values = gray.as_raw();
    let distance = values.par_iter().map(|&v| levels.at(v)).collect();
    let (w, h) = gray.dimensions();
    (
        FloatImage::from_raw(w, h, distance).expect("same dimensions"),
        levels.level,
        levels.fraction,
        levels.own_level,
    )
}

/// How [`gray_distance`] maps a gray picture's pixels, so that the distance
/// can be read pixel by pixel (e.g. shrunk) without a picture of its own.
pub(crate) struct GrayDistance {
    /// The background level.
    pub level: f32,
    scale: f32,
    /// The fraction of pixels in the background's bin.
    pub fraction: f64,
    /// The background's own level in the distance.
    pub own_level: f64,
}

/// Gray levels binned by [`GrayDistance::of`].
const GRAY_LEVELS: usize = 16;

impl GrayDistance {
    /// The distance from the background level, and from the rival
    /// background's when the histogram has one ([`background_bins`]).
    pub fn of(gray: &FloatImage) -> (Self, Option<Self>) {
        let values = gray.as_raw();
        let stride = if values.len() > 4_000_000 { 7 } else { 1 };
        let mut count = [0usize; GRAY_LEVELS];
        let mut sum = [0.0f64; GRAY_LEVELS];
        for &v in values.iter().step_by(stride) {
            count[gray_bin(v)] += 1;
            sum[gray_bin(v)] += v as f64;
        }
        let bin_luma: Vec<f64> = (0..GRAY_LEVELS)
            .map(|b| sum[b] / count[b].max(1) as f64)
            .collect();
        let sample: Vec<f64> = values
            .iter()
            .step_by(stride.max(3))
            .map(|&v| v as f64)
            .collect();
        let (b, rival) = background_bins(&count, &bin_luma, sample, 1.0 / GRAY_LEVELS as f64);
        let seen: usize = count.iter().sum();
        let from = |b: usize| {
            Self::from_bin(
                values,
                stride,
                b,
                bin_luma[b] as f32,
                count[b] as f64 / seen.max(1) as f64,
            )
        };
        (from(b), rival.map(from))
    }

    /// The distance from the level of bin `b` (mean `level`, holding
    /// `fraction` of the pixels) of `values`, sampled every `stride`-th.
    fn from_bin(values: &[f32], stride: usize, b: usize, level: f32, fraction: f64) -> Self {
        // The bin's own distances are taken from its median: see [`own_level`].
        let mut in_bin: Vec<f32> = (values.iter().step_by(stride.max(3)))
            .filter(|&&v| gray_bin(v) == b)
            .copied()
            .collect();
        let centre = percentile(&mut in_bin, 50).unwrap_or(level);
        let scale = distance_scale(
            values
                .iter()
                .step_by(stride.max(3))
                .map(|&v| (v - level).abs())
                .collect(),
        );
        let mut own: Vec<f32> = values
            .iter()
            .step_by(stride.max(3))
            .filter(|&&v| gray_bin(v) == b)
            .map(|&v| (v - centre).abs() * scale)
            .collect();
        let own_level = own_level(&mut own);
        GrayDistance {
            level,
            scale,
            fraction,
            own_level,
        }
    }

    /// The distance of a pixel of value `v`.
    pub fn at(&self, v: f32) -> f32 {
        ((v - self.level).abs() * self.scale).min(1.5)
    }
}

/// The bin of gray value `v` in [`GrayDistance::of`]'s histogram.
fn gray_bin(v: f32) -> usize {
    ((v.clamp(0.0, 1.0) * GRAY_LEVELS as f32) as usize).min(GRAY_LEVELS - 1)
}

/// The spread of each channel (1st to 99th percentile of a sample of every
/// `stride`-th pixel): how much of the picture the light puts in it.
fn channel_spreads<T: Copy + Into<f32>>(raw: &[T], stride: usize) -> [f32; 3] {
    let spread = |c: usize| -> f32 {
        let mut v: Vec<f32> = raw
            .chunks_exact(3)
            .step_by(stride.max(3))
            .map(|p| p[c].into())
            .collect();
        if v.len() < 2 {
            return 0.0;
        }
        let n = v.len();
        let lo = *v.select_nth_unstable_by(n / 100, |a, b| a.total_cmp(b)).1;
        let hi = *v
            .select_nth_unstable_by(n * 99 / 100, |a, b| a.total_cmp(b))
            .1;
        hi - lo
    };
    [spread(0), spread(1), spread(2)]
}

/// The channel the photoelastic signal is read in: green, as PeGS reads it,
/// unless the light leaves green nearly empty (red or orange light: its
/// spread under a quarter of the widest channel's), then the channel with the
/// widest spread.
fn signal_channel(spreads: [f32; 3]) -> Channel {
    let widest = (0..3)
        .max_by(|&a, &b| spreads[a].total_cmp(&spreads[b]))
        .expect("3");
    if spreads[1] >= 0.25 * spreads[widest] {
        Channel::Green
    } else {
        [Channel::Red, Channel::Green, Channel::Blue][widest]
    }
}

/// One channel (or the luma) of interleaved RGB samples, scaled to [0, 1],
/// without an intermediate float copy of all three channels.
fn pick<T: Copy + Into<f32> + Sync>(
    raw: &[T],
    (width, height): (u32, u32),
    channel: Channel,
    full_scale: f32,
) -> FloatImage {
    let data = raw
        .par_chunks_exact(3)
        .map(|p| {
            let [r, g, b]: [f32; 3] = [p[0].into(), p[1].into(), p[2].into()];
            let v = match channel {
                Channel::Red => r,
                Channel::Green => g,
                Channel::Blue => b,
                Channel::Luma | Channel::Auto => 0.2126 * r + 0.7152 * g + 0.0722 * b,
            };
            v / full_scale
        })
        .collect();
    FloatImage::from_raw(width, height, data).expect("same dimensions")
}

fn to_float<T: ::image::Primitive + Into<f32>>(
    g: &ImageBuffer<Luma<T>, Vec<T>>,
    full_scale: f32,
) -> FloatImage {
    let data = g.as_raw().iter().map(|&v| v.into() / full_scale).collect();
    FloatImage::from_raw(g.width(), g.height(), data).expect("same dimensions")
}

fn image_error(path: &Path, e: ImageError) -> Error {
    match e {
        ImageError::IoError(io) => Error::io(path, io),
        ImageError::Unsupported(u) => Error::data(
            path,
            None,
            None,
            format!("unsupported image format ({u}); use PNG, TIFF, BMP or JPEG"),
        ),
        other => Error::data(path, None, None, format!("cannot decode image: {other}")),
    }
}

/// Reads several images that must all have the same size (a sequence of frames).
pub fn load_gray_sequence(paths: &[PathBuf]) -> Result<Vec<FloatImage>> {
    let mut images: Vec<FloatImage> = Vec::with_capacity(paths.len());
    for path in paths {
        let image = load_gray(path)?;
        if let Some(first) = images.first() {
            check_same_size(first, &paths[0], &image, path)?;
        }
        images.push(image);
    }
    Ok(images)
}

/// An error naming both files when two images of a sequence differ in size.
pub fn check_same_size(
    first: &FloatImage,
    first_path: &Path,
    image: &FloatImage,
    path: &Path,
) -> Result<()> {
    if image.dimensions() != first.dimensions() {
        return Err(Error::data(
            path,
            None,
            None,
            format!(
                "the image is {}×{} px but {} is {}×{} px; all images of a sequence must have the same size",
                image.width(),
                image.height(),
                first_path.display(),
                first.width(),
                first.height()
            ),
        ));
    }
    Ok(())
}

/// Writes intensities in [0, 1] (clamped) as an 8- or 16-bit grayscale image;
/// the format follows the extension (PNG, TIFF or BMP).
pub fn save_gray(path: &Path, image: &FloatImage, bits: u8) -> Result<()> {
    let image: DynamicImage = match bits {
        8 => {
            let data = image.as_raw().iter().map(|&v| quantise(v, 255.0) as u8);
            ImageBuffer::<Luma<u8>, Vec<u8>>::from_raw(
                image.width(),
                image.height(),
                data.collect(),
            )
            .expect("same dimensions")
            .into()
        }
        16 => {
            let data = image.as_raw().iter().map(|&v| quantise(v, 65535.0) as u16);
            ImageBuffer::<Luma<u16>, Vec<u16>>::from_raw(
                image.width(),
                image.height(),
                data.collect(),
            )
            .expect("same dimensions")
            .into()
        }
        _ => {
            return Err(Error::Invalid(format!(
                "images are written with 8 or 16 bits per pixel, not {bits}"
            )))
        }
    };
    save_atomically(path, &image)
}

/// Encodes in memory in the format the extension names, then writes to a
/// temporary file that is renamed into place: a killed run leaves the old
/// file or none.
pub(crate) fn save_atomically(path: &Path, image: &DynamicImage) -> Result<()> {
    let format = ImageFormat::from_path(path)
        .map_err(|e| Error::data(path, None, None, format!("cannot write image: {e}")))?;
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write_to(&mut bytes, format).map_err(|e| match e {
        ImageError::IoError(io) => Error::io(path, io),
        other => Error::data(path, None, None, format!("cannot write image: {other}")),
    })?;
    crate::scene::write_file_atomically(path, bytes.get_ref())
}

fn quantise(v: f32, full_scale: f32) -> f32 {
    (v.clamp(0.0, 1.0) * full_scale).round()
}
