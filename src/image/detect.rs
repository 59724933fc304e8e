//! Finding disks in an image.
//!
//! 1. Smooth (Gaussian) and take Sobel gradients (imageproc).
//! 2. Gradient-direction Hough voting: each edge pixel votes, weighted by its
//!    gradient magnitude, for centres along its gradient over the radius range
//!    (an accumulator padded so that centres of disks cut by the border count).
//! 3. Local maxima of the smoothed accumulator are candidate centres.
//! 4. Each candidate is refined: its radius from the mean radial intensity
//!    derivative, then the edge located to sub-pixel precision along rays from
//!    the centre and a circle fitted to those edge points by robust geometric
//!    least squares (twice, the second time around the first fit).
//! 5. A candidate is kept when enough of its visible rays agree with the fitted
//!    circle (which rejects texture and noise) and the disk is brighter (or
//!    darker) than its surroundings; duplicates are merged.

use super::FloatImage;
use crate::error::{Error, Result};
use rayon::prelude::*;

/// Whether the disks are brighter or darker than what surrounds them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Polarity {
    Bright,
    Dark,
    Either,
}

#[derive(Debug, Clone)]
pub struct DetectOptions {
    /// Radius range [px] of the disks to find.
    pub radius_min: f64,
    pub radius_max: f64,
    pub polarity: Polarity,
    /// Gaussian smoothing before the voting gradients [px]; `None` picks it
    /// from the radius (texture and noise must not outvote the boundary).
    pub smoothing_px: Option<f64>,
    /// Gaussian smoothing of the image the edges are located in [px]; `None`
    /// picks it from the noise: 1 px on clean images (so the narrow gaps at
    /// contacts keep their edges), more on noisy ones.
    pub edge_smoothing_px: Option<f64>,
    /// Fraction of a disk's visible rays whose edge must lie on the fitted circle.
    pub min_support: f64,
    /// Candidates with less support, down to this, are kept only when the
    /// final model fit confirms an edge as sharp and as strong as the
    /// confident disks' (small disks with many contacts show little rim).
    pub min_support_confirmed: f64,
    /// Fraction of the circumference that must lie inside the image.
    pub min_visible: f64,
    /// Candidate centres: accumulator maxima above this fraction of the largest.
    pub vote_threshold: f64,
    /// Smallest intensity step across the edge: two grey levels of an 8-bit
    /// image. Fainter "disks" are echoes of edges in another colour channel
    /// (JPEG's subsampled chroma) or quantisation, not disks.
    pub min_contrast: f64,
    /// Several size classes ([min, max] px each), e.g. a bidisperse packing:
    /// each is searched on its own, so sizes between them are not found.
    /// Empty: the one range `radius_min..radius_max`.
    pub classes: Vec<[f64; 2]>,
    /// Also look for disks outlined by a dark rim, whatever their interior
    /// (dim photoelastic disks darker than the background); bright polarity only.
    pub find_by_rims: bool,
}

impl DetectOptions {
    pub fn new(radius_min: f64, radius_max: f64) -> Self {
        DetectOptions {
            radius_min,
            radius_max,
            polarity: Polarity::Bright,
            smoothing_px: None,
            edge_smoothing_px: None,
            min_support: 0.45,
            min_support_confirmed: 0.3,
            min_visible: 0.3,
            vote_threshold: 0.04,
            min_contrast: 2.0 / 255.0,
            classes: Vec::new(),
            find_by_rims: true,
        }
    }

    /// Options for several radius classes; `radius_min..radius_max` spans them.
    pub fn with_classes(classes: &[[f64; 2]]) -> Result<Self> {
        let bad = |why: &str| {
            let list: Vec<String> = classes
                .iter()
                .map(|c| format!("{}..{}", c[0], c[1]))
                .collect();
            Error::Invalid(format!("radius classes {}: {why}", list.join(",")))
        };
        if classes.is_empty() {
            return Err(bad("none given"));
        }
        let mut sorted = classes.to_vec();
        sorted.sort_by(|a, b| a[0].total_cmp(&b[0]));
        for c in &sorted {
            if !(c[0].is_finite() && c[1].is_finite() && c[0] >= 2.0 && c[1] >= c[0]) {
                return Err(bad("each must satisfy 2 ≤ MIN ≤ MAX pixels"));
            }
        }
        if sorted.windows(2).any(|p| p[1][0] <= p[0][1]) {
            return Err(bad("classes must not overlap"));
        }
        let mut o = DetectOptions::new(sorted[0][0], sorted[sorted.len() - 1][1]);
        if sorted.len() > 1 {
            o.classes = sorted;
        }
        Ok(o)
    }

    /// The smoothing actually used.
    pub fn smoothing(&self) -> f64 {
        self.smoothing_px
            .unwrap_or_else(|| (self.radius_min / 5.0).clamp(1.5, 5.0))
    }
}

/// A disk found in an image, in pixel coordinates (see the module docs of
/// [`crate::image`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Disk {
    pub x: f64,
    pub y: f64,
    pub r: f64,
    /// Fraction of the visible rays whose edge lies on the fitted circle.
    pub support: f64,
    /// Fraction of the circumference inside the image.
    pub visible: f64,
    /// Intensity step across the edge (positive: as the polarity asked).
    pub contrast: f64,
    /// RMS distance of the inlying edge points from the circle [px].
    pub rms: f64,
}

impl Disk {
    /// Whether part of the disk lies outside the image.
    pub fn cut_by_border(&self) -> bool {
        self.visible < 0.999
    }
}

/// Finds every disk whose radius lies in the given range. Returns them sorted
/// by row, then column. An image without disks gives an empty list (the caller
/// decides whether that is an error).
pub fn detect_disks(image: &FloatImage, options: &DetectOptions) -> Result<Vec<Disk>> {
    if options.classes.len() > 1 {
        let mut found = Vec::new();
        for c in &options.classes {
            let mut one = options.clone();
            (one.radius_min, one.radius_max, one.classes) = (c[0], c[1], Vec::new());
            found.extend(detect_disks(image, &one)?);
        }
        return Ok(without_overlaps(found));
    }
    let o = options;
    if !(o.radius_min.is_finite() && o.radius_max.is_finite())
        || o.radius_min < 2.0
        || o.radius_max < o.radius_min
    {
        return Err(Error::Invalid(format!(
            "the radius range must satisfy 2 ≤ MIN ≤ MAX pixels, not {}..{}",
            o.radius_min, o.radius_max
        )));
    }
    let sigma = o.smoothing();
    let (w, h) = image.dimensions();
    if w < 8 || h < 8 {
        return Err(Error::Invalid(format!(
            "the image is only {w}×{h} px; too small to find disks in"
        )));
    }
    let signs: &[f64] = match o.polarity {
        Polarity::Bright => &[1.0],
        Polarity::Dark => &[-1.0],
        Polarity::Either => &[1.0, -1.0],
    };
    let factor = pyramid_factor(o);
    let pyramid = factor > 1 && w as usize >= 8 * factor && h as usize >= 8 * factor;
    // The noise is measured once (on big images it costs a pass and a buffer).
    let mut noise = None;
    let mut noise_of = |image: &FloatImage| *noise.get_or_insert_with(|| noise_level(image));
    let (candidates, edge_sigma) = if pyramid {
        coarse_candidates(image, o, signs, factor, noise_of(image))?
    } else {
        let smooth = gaussian_blur(image, sigma);
        let edge_sigma = o
            .edge_smoothing_px
            .unwrap_or_else(|| edge_smoothing_for_noise(noise_of(image), &smooth, sigma));
        check_smoothing(sigma, edge_sigma)?;
        let accumulator = vote(&smooth, o, signs);
        let mut candidates = peaks(&accumulator, o);
        for &s in signs {
            candidates.extend(distance_peaks(&smooth, s, o));
        }
        (candidates, edge_sigma)
    };
    let edge_image = gaussian_blur(image, edge_sigma);
    let plane = Plane::whole(&edge_image);
    let refine_candidate = |&(cx, cy, hint): &Candidate| {
        let plane = &plane;
        signs
            .iter()
            .filter_map(move |&s| refine(plane, [cx, cy], hint, s, edge_sigma, o))
            .collect::<Vec<_>>()
    };
    let mut found: Vec<Disk> = if pyramid {
        refine_strongest_first(&candidates, refine_candidate, o)
    } else {
        candidates
            .par_iter()
            .flat_map_iter(refine_candidate)
            .collect()
    };
    drop(edge_image);
    // Merge duplicates: the best-supported copy of each disk wins.
    found.sort_by(|a, b| score(b).total_cmp(&score(a)));
    let mut kept: Vec<Disk> = Vec::new();
    for d in found {
        let duplicate = kept.iter().any(|k| {
            let dist = ((k.x - d.x).powi(2) + (k.y - d.y).powi(2)).sqrt();
            dist < 0.7 * k.r.max(d.r)
        });
        if !duplicate {
            kept.push(d);
        }
    }
    let fits: Vec<Option<ModelFit>> = (0..kept.len())
        .into_par_iter()
        .map(|k| polish(image, &kept, k))
        .collect();
    // What a confirmed edge looks like: the confident disks' median fit.
    let confident = |d: &Disk| d.support >= o.min_support;
    let mut steps: Vec<f64> = Vec::new();
    let mut widths: Vec<f64> = Vec::new();
    for (d, f) in kept.iter().zip(&fits) {
        if let (true, Some(f)) = (confident(d), f) {
            steps.push(f.step.abs());
            widths.push(f.width);
        }
    }
    let (typical_step, typical_width) = (median(&mut steps), median(&mut widths));
    let kept: Vec<Disk> = kept
        .iter()
        .zip(fits)
        .filter_map(|(d, f)| match f {
            Some(f) if confident(d) => Some(f.disk),
            None if confident(d) => Some(*d),
            Some(f) => (!steps.is_empty()
                && f.step.abs() >= 0.5 * typical_step
                && f.width <= 1.5 * typical_width + 0.3)
                .then_some(f.disk),
            None => None,
        })
        .collect();
    let kept = without_overlaps(kept);
    if o.find_by_rims && o.polarity == Polarity::Bright {
        if pyramid {
            return Ok(add_rim_enclosed_coarse(
                image,
                o,
                kept,
                factor,
                noise_of(image),
            ));
        }
        return Ok(add_rim_enclosed(image, o, kept));
    }
    Ok(kept)
}

/// Refines the candidates (strongest first) in batches, skipping those that
/// lie inside a disk already found with confidence. Disks overlap by at most
/// 0.15 R, so any other disk's centre is at least 0.85 of its radius away
/// from such a candidate, beyond what refining recovers from (a quarter
/// radius): the candidate can only give the same disk again or a circle the
/// overlap rule removes. On big images most candidates are such echoes (of
/// fringes inside loaded disks), and refining one at full resolution is the
/// costliest step of the search.
fn refine_strongest_first(
    candidates: &[Candidate],
    refine_candidate: impl Fn(&Candidate) -> Vec<Disk> + Sync,
    o: &DetectOptions,
) -> Vec<Disk> {
    let mut found: Vec<Disk> = Vec::new();
    let mut confident: Vec<Disk> = Vec::new();
    for batch in candidates.chunks(32 * rayon::current_num_threads()) {
        let open: Vec<&Candidate> = batch
            .iter()
            .filter(|c| !confident.iter().any(|d| (d.x - c.0).hypot(d.y - c.1) < d.r))
            .collect();
        let refined: Vec<Disk> = open
            .par_iter()
            .flat_map_iter(|c| refine_candidate(c))
            .collect();
        confident.extend(refined.iter().filter(|d| d.support >= o.min_support));
        found.extend(refined);
    }
    found
}

/// A candidate centre (x, y) [px] and the radius its votes suggest.
type Candidate = (f64, f64, f64);

fn check_smoothing(sigma: f64, edge_sigma: f64) -> Result<()> {
    if !(sigma.is_finite() && sigma > 0.0 && edge_sigma.is_finite() && edge_sigma > 0.0) {
        return Err(Error::Invalid(format!(
            "smoothing must be positive, not {sigma} and {edge_sigma} px"
        )));
    }
    Ok(())
}

/// Radius [px] at which the candidate search runs: big disks are searched
/// in an image shrunk to about this size, and only refined at full resolution.
const COARSE_RADIUS: f64 = 50.0;

/// By how much the image is shrunk for the candidate search: 1 (not at all)
/// unless the smallest disks are at least twice [`COARSE_RADIUS`].
fn pyramid_factor(o: &DetectOptions) -> usize {
    (o.radius_min / COARSE_RADIUS).floor().max(1.0) as usize
}

/// Candidates for big disks (a 21-megapixel photograph): the voting and the
/// background split run on the image shrunk by `factor` (block means), where
/// their buffers and time fall by factor²; the refinement and judging that
/// follow are the full-resolution ones. Returns the candidates in full
/// resolution pixels and the edge smoothing.
fn coarse_candidates(
    image: &FloatImage,
    o: &DetectOptions,
    signs: &[f64],
    factor: usize,
    noise: f64,
) -> Result<(Vec<Candidate>, f64)> {
    let f = factor as f64;
    let (w, h) = (image.width() as usize, image.height() as usize);
    let pixels = image.as_raw();
    let coarse = downsample(w, h, factor, |k| pixels[k]);
    let sigma = o.smoothing();
    // The same smoothing as at full resolution, in the shrunk image's pixels.
    let smooth = gaussian_blur(&coarse, sigma / f);
    drop(coarse);
    let edge_sigma = o
        .edge_smoothing_px
        .unwrap_or_else(|| edge_smoothing_for_noise(noise, &smooth, sigma));
    check_smoothing(sigma, edge_sigma)?;
    let coarse_options = shrunk_options(o, f);
    let accumulator = vote(&smooth, &coarse_options, signs);
    let mut candidates = peaks(&accumulator, &coarse_options);
    drop(accumulator);
    for &s in signs {
        candidates.extend(distance_peaks(&smooth, s, &coarse_options));
    }
    let full = |v: f64| f * v + 0.5 * (f - 1.0);
    let candidates = candidates
        .into_iter()
        .map(|(x, y, r)| (full(x), full(y), f * r))
        .collect();
    Ok((candidates, edge_sigma))
}

/// The options for the image shrunk by `f`: radii and smoothing in its pixels.
fn shrunk_options(o: &DetectOptions, f: f64) -> DetectOptions {
    let mut shrunk = o.clone();
    shrunk.radius_min = o.radius_min / f;
    shrunk.radius_max = o.radius_max / f;
    shrunk.smoothing_px = Some(o.smoothing() / f);
    shrunk.edge_smoothing_px = o.edge_smoothing_px.map(|s| s / f);
    shrunk.find_by_rims = false;
    shrunk
}

/// [`add_rim_enclosed`] for big images: the rims are marked at full
/// resolution (one byte a pixel: they are too thin to survive shrinking), the
/// enclosed regions searched in the mask shrunk by `factor`, and each region
/// found refined at full resolution in a window of the mask.
fn add_rim_enclosed_coarse(
    image: &FloatImage,
    o: &DetectOptions,
    found: Vec<Disk>,
    factor: usize,
    noise: f64,
) -> Vec<Disk> {
    let f = factor as f64;
    let (w, h) = (image.width() as usize, image.height() as usize);
    let enclosed = rim_enclosed(image, noise);
    let filled = downsample(w, h, factor, |k| if enclosed[k] { 1.0 } else { 0.0 });
    let Ok(coarse) = detect_disks(&filled, &shrunk_options(o, f)) else {
        return found;
    };
    drop(filled);
    // The filled regions have sharp edges: the least smoothing places them.
    let value = |x: usize, y: usize| if enclosed[y * w + x] { 1.0 } else { 0.0 };
    let rim_disks = refine_scaled(&coarse, f, o, 1.0, value, (w, h));
    with_rim_disks(found, rim_disks, o)
}

/// Bright disks found in the image shrunk by `f`, refined at full resolution
/// in a window of the full image (`pixel(x, y)`, `size` px) smoothed by σ; a
/// disk whose refinement fails or wanders off keeps its scaled circle.
fn refine_scaled(
    found: &[Disk],
    f: f64,
    o: &DetectOptions,
    sigma: f64,
    pixel: impl Fn(usize, usize) -> f32 + Sync,
    size: (usize, usize),
) -> Vec<Disk> {
    // The farthest refine samples from the candidate centre: the radius
    // search's end plus the widest edge window, with room for the fit to move.
    let reach = 1.3 * o.radius_max + 4.0 * sigma + 8.0 + f;
    found
        .par_iter()
        .map(|d| {
            let centre = [f * d.x + 0.5 * (f - 1.0), f * d.y + 0.5 * (f - 1.0)];
            let scaled = Disk {
                x: centre[0],
                y: centre[1],
                r: f * d.r,
                rms: f * d.rms,
                ..*d
            };
            let window = SmoothedWindow::new(&pixel, size, centre, reach, sigma);
            let plane = window.plane();
            refine(&plane, centre, scaled.r, 1.0, sigma, o)
                .filter(|r| (r.x - centre[0]).hypot(r.y - centre[1]) < 0.25 * scaled.r)
                .unwrap_or(scaled)
        })
        .collect()
}

/// An image of `w` × `h` pixels (`value(k)` for pixel k in row-major order)
/// shrunk by `factor`: each pixel the mean of a factor × factor block (the
/// blocks at the right and bottom edges may be partial), so pixel (J, I) is
/// centred on the full image's (f J + (f − 1)/2, f I + (f − 1)/2).
fn downsample(
    w: usize,
    h: usize,
    factor: usize,
    value: impl Fn(usize) -> f32 + Sync,
) -> FloatImage {
    let (cw, ch) = (w.div_ceil(factor), h.div_ceil(factor));
    let mut out = vec![0f32; cw * ch];
    out.par_chunks_mut(cw).enumerate().for_each(|(ci, line)| {
        let rows = ci * factor..((ci + 1) * factor).min(h);
        let count_rows = rows.len();
        for i in rows {
            for (cj, o) in line.iter_mut().enumerate() {
                *o += (cj * factor..((cj + 1) * factor).min(w))
                    .map(|j| value(i * w + j))
                    .sum::<f32>();
            }
        }
        for (cj, o) in line.iter_mut().enumerate() {
            let count_cols = ((cj + 1) * factor).min(w) - cj * factor;
            *o /= (count_rows * count_cols) as f32;
        }
    });
    FloatImage::from_raw(cw as u32, ch as u32, out).expect("sized")
}

/// An image around a point (to `reach` px, clipped to the image) smoothed by
/// σ, with a margin so that the smoothing inside `reach` matches the whole
/// image's.
struct SmoothedWindow {
    data: Vec<f32>,
    w: usize,
    h: usize,
    origin: [f64; 2],
}

impl SmoothedWindow {
    fn new(
        pixel: &impl Fn(usize, usize) -> f32,
        (w, h): (usize, usize),
        centre: [f64; 2],
        reach: f64,
        sigma: f64,
    ) -> Self {
        let margin = reach + (3.0 * sigma).ceil() + 2.0;
        let clip = |v: f64, n: usize| (v.floor().max(0.0) as usize).min(n - 1);
        let (x0, x1) = (
            clip(centre[0] - margin, w),
            clip(centre[0] + margin + 1.0, w),
        );
        let (y0, y1) = (
            clip(centre[1] - margin, h),
            clip(centre[1] + margin + 1.0, h),
        );
        let crop = FloatImage::from_fn((x1 - x0 + 1) as u32, (y1 - y0 + 1) as u32, |x, y| {
            ::image::Luma([pixel(x0 + x as usize, y0 + y as usize)])
        });
        SmoothedWindow {
            w: crop.width() as usize,
            h: crop.height() as usize,
            data: gaussian_blur(&crop, sigma).into_raw(),
            origin: [x0 as f64, y0 as f64],
        }
    }

    fn plane(&self) -> Plane<'_> {
        Plane {
            data: &self.data,
            w: self.w,
            h: self.h,
            origin: self.origin,
        }
    }
}

/// Adds the disks outlined by a dark rim that the intensity search missed:
/// the rims (thin dark lines: the black top-hat of the lightly smoothed image,
/// above the noise) are marked, the regions they enclose filled, and the
/// filled picture searched for bright disks. A disk found both ways gives the
/// offset between the two radii (the filled one reaches the rim's outer
/// edge); new disks are brought to the intensity search's radius by its
/// median, and kept only where they cross no disk already found.
fn add_rim_enclosed(image: &FloatImage, o: &DetectOptions, found: Vec<Disk>) -> Vec<Disk> {
    let (w, h) = image.dimensions();
    let enclosed = rim_enclosed(image, noise_level(image));
    let filled = FloatImage::from_raw(
        w,
        h,
        enclosed
            .iter()
            .map(|&e| if e { 1.0 } else { 0.0 })
            .collect(),
    )
    .expect("sized");
    drop(enclosed);
    let mut search = o.clone();
    search.find_by_rims = false;
    let Ok(enclosed) = detect_disks(&filled, &search) else {
        return found;
    };
    with_rim_disks(found, enclosed, o)
}

/// Which pixels a dark rim encloses (or belong to one): the rims are the
/// pixels of the image smoothed by 1 px whose black top-hat (a 4 px disk as
/// structuring element) exceeds 0.03 and four times the noise (σ `noise` of
/// the raw pixels); the background is flooded in from the image border, and
/// whatever it cannot reach is enclosed. One byte a pixel.
fn rim_enclosed(image: &FloatImage, noise: f64) -> Vec<bool> {
    use ::image::GrayImage;
    use imageproc::morphology::{grayscale_close, Mask};
    let (w, h) = (image.width() as usize, image.height() as usize);
    let gray = GrayImage::from_raw(
        w as u32,
        h as u32,
        gaussian_blur_map(image, 1.0, |v| (v.clamp(0.0, 1.0) * 255.0).round() as u8),
    )
    .expect("sized");
    let closed = grayscale_close(&gray, &Mask::disk(4));
    // Gaussian smoothing σ = 1 px divides white noise by 2√π.
    let noise = noise / (2.0 * std::f64::consts::PI.sqrt());
    let threshold = (0.03f64).max(4.0 * noise) * 255.0;
    let rim: Vec<bool> = closed
        .as_raw()
        .iter()
        .zip(gray.as_raw())
        .map(|(&c, &g)| (c as f64 - g as f64) > threshold)
        .collect();
    drop((gray, closed));
    // Scanline flood fill of the background from the border: the stack holds
    // runs of a row, not pixels, so it stays small on big images.
    let mut reached = vec![false; w * h];
    let open = |k: usize, reached: &[bool]| !reached[k] && !rim[k];
    let mut seeds: Vec<(usize, usize)> = Vec::new();
    for x in 0..w {
        seeds.push((x, 0));
        seeds.push((x, h - 1));
    }
    for y in 0..h {
        seeds.push((0, y));
        seeds.push((w - 1, y));
    }
    while let Some((x, y)) = seeds.pop() {
        let row = y * w;
        if !open(row + x, &reached) {
            continue;
        }
        let (mut left, mut right) = (x, x);
        while left > 0 && open(row + left - 1, &reached) {
            left -= 1;
        }
        while right + 1 < w && open(row + right + 1, &reached) {
            right += 1;
        }
        reached[row + left..=row + right].fill(true);
        for ny in [y.wrapping_sub(1), y + 1] {
            if ny >= h {
                continue;
            }
            // One seed per run of open pixels next to this one.
            let mut previous_open = false;
            for nx in left..=right {
                let now_open = open(ny * w + nx, &reached);
                if now_open && !previous_open {
                    seeds.push((nx, ny));
                }
                previous_open = now_open;
            }
        }
    }
    reached.iter().map(|&r| !r).collect()
}

/// Adds to `found` the rim-enclosed disks `enclosed` that it lacks, brought
/// to the intensity search's radius (see [`add_rim_enclosed`]).
fn with_rim_disks(found: Vec<Disk>, enclosed: Vec<Disk>, o: &DetectOptions) -> Vec<Disk> {
    let mut offsets: Vec<f64> = Vec::new();
    let mut extra = Vec::new();
    for e in enclosed {
        match found
            .iter()
            .find(|d| (d.x - e.x).hypot(d.y - e.y) < 0.3 * d.r)
        {
            Some(d) => offsets.push(e.r - d.r),
            None => extra.push(e),
        }
    }
    let offset = median(&mut offsets);
    let mut all = found;
    for mut e in extra {
        e.r -= offset;
        let crosses =
            |k: &Disk| (k.x - e.x).hypot(k.y - e.y) < k.r + e.r - (3.0f64).max(0.15 * k.r.min(e.r));
        if e.r >= o.radius_min && e.r <= o.radius_max && !all.iter().any(crosses) {
            all.push(e);
        }
    }
    all.sort_by(|a, b| a.y.total_cmp(&b.y).then(a.x.total_cmp(&b.x)));
    all
}

/// Disks do not overlap: of two circles that cross by more than a few pixels,
/// the better supported stays (the other is fitted to fringes or to the space
/// between disks, or is a size class's echo of a disk of another). Sorted by
/// row, then column.
fn without_overlaps(mut kept: Vec<Disk>) -> Vec<Disk> {
    kept.sort_by(|a, b| score(b).total_cmp(&score(a)));
    let mut solid: Vec<Disk> = Vec::with_capacity(kept.len());
    for d in kept {
        let crosses =
            |k: &Disk| (k.x - d.x).hypot(k.y - d.y) < k.r + d.r - (3.0f64).max(0.15 * k.r.min(d.r));
        if !solid.iter().any(crosses) {
            solid.push(d);
        }
    }
    solid.sort_by(|a, b| a.y.total_cmp(&b.y).then(a.x.total_cmp(&b.x)));
    solid
}

/// Final sub-pixel fit of a disk model to the raw pixels of a ring around the
/// edge: I ≈ a + b / (1 + exp((|p − c| − r)/s)), by Levenberg–Marquardt over
/// (cx, cy, r, a, b, s). Under white noise this least-squares fit uses every
/// pixel's evidence (the ray edges use one point per ray), and texture inside
/// the disk only adds zero-mean scatter. Pixels on or near other disks are left
/// out, so contacts do not pull the fit. `None` when the fit does not settle
/// near the starting circle.
struct ModelFit {
    disk: Disk,
    /// Intensity step b across the edge and the edge's width s [px].
    step: f64,
    width: f64,
}

fn polish(image: &FloatImage, disks: &[Disk], k: usize) -> Option<ModelFit> {
    let d = disks[k];
    let (w, h) = (image.width() as i64, image.height() as i64);
    let half = 3.5;
    let neighbours: Vec<&Disk> = disks
        .iter()
        .enumerate()
        .filter(|(j, e)| *j != k && (e.x - d.x).hypot(e.y - d.y) < d.r + e.r + 2.0 * half)
        .map(|(_, e)| e)
        .collect();
    let mut pixels: Vec<(f64, f64, f64)> = Vec::new();
    let reach = d.r + half + 1.0;
    for i in ((d.y - reach).floor() as i64).max(0)..=((d.y + reach).ceil() as i64).min(h - 1) {
        for j in ((d.x - reach).floor() as i64).max(0)..=((d.x + reach).ceil() as i64).min(w - 1) {
            let (x, y) = (j as f64, i as f64);
            let rho = (x - d.x).hypot(y - d.y);
            if (rho - d.r).abs() > half {
                continue;
            }
            if neighbours
                .iter()
                .any(|e| (x - e.x).hypot(y - e.y) < e.r + half)
            {
                continue;
            }
            pixels.push((x, y, image.get_pixel(j as u32, i as u32)[0] as f64));
        }
    }
    if pixels.len() < 40 {
        return None;
    }
    // Start: the two intensity levels from the pixels inside and outside.
    let (mut inner, mut n_in, mut outer, mut n_out) = (0.0, 0, 0.0, 0);
    for &(x, y, v) in &pixels {
        if (x - d.x).hypot(y - d.y) < d.r - 1.5 {
            inner += v;
            n_in += 1;
        } else if (x - d.x).hypot(y - d.y) > d.r + 1.5 {
            outer += v;
            n_out += 1;
        }
    }
    if n_in < 10 || n_out < 10 {
        return None;
    }
    let (a0, b0) = (
        outer / n_out as f64,
        inner / n_in as f64 - outer / n_out as f64,
    );
    let mut p = nalgebra::Vector6::new(d.x, d.y, d.r, a0, b0, 0.7);
    let cost = |p: &nalgebra::Vector6<f64>| -> f64 {
        pixels
            .iter()
            .map(|&(x, y, v)| {
                let u = ((x - p[0]).hypot(y - p[1]) - p[2]) / p[5];
                let m = p[3] + p[4] / (1.0 + u.clamp(-50.0, 50.0).exp());
                (v - m) * (v - m)
            })
            .sum()
    };
    let mut current = cost(&p);
    let mut lambda = 1e-3;
    for _ in 0..20 {
        let mut jtj = nalgebra::Matrix6::<f64>::zeros();
        let mut jtr = nalgebra::Vector6::<f64>::zeros();
        for &(x, y, v) in &pixels {
            let (dx, dy) = (x - p[0], y - p[1]);
            let rho = dx.hypot(dy).max(1e-9);
            let u = (rho - p[2]) / p[5];
            let l = 1.0 / (1.0 + u.clamp(-50.0, 50.0).exp());
            let dl = -l * (1.0 - l); // dL/du
            let m = p[3] + p[4] * l;
            let g = p[4] * dl / p[5];
            let j = nalgebra::Vector6::new(-g * dx / rho, -g * dy / rho, -g, 1.0, l, -g * u);
            jtj += j * j.transpose();
            jtr += j * (v - m);
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = jtj;
            for a in 0..6 {
                damped[(a, a)] *= 1.0 + lambda;
            }
            let Some(step) = damped.lu().solve(&jtr) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = p + step;
            trial[5] = trial[5].clamp(0.2, 4.0);
            let c = cost(&trial);
            if c < current {
                let moved = (trial - p).norm();
                p = trial;
                current = c;
                lambda = (lambda * 0.3).max(1e-9);
                improved = moved > 1e-4;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let shift = (p[0] - d.x).hypot(p[1] - d.y);
    let sign_ok = p[4] * (b0.signum()) > 0.0;
    if !(shift < 2.0 && (p[2] - d.r).abs() < 2.0 && sign_ok && p.iter().all(|v| v.is_finite())) {
        return None;
    }
    Some(ModelFit {
        disk: Disk {
            x: p[0],
            y: p[1],
            r: p[2],
            ..d
        },
        step: p[4],
        width: p[5],
    })
}

/// Pixel noise σ by the median absolute response to the mask
/// [1 −2 1; −2 4 −2; 1 −2 1] (Immerkær 1996, median form: edges and texture
/// barely move it), which responds to white noise with standard deviation 6σ.
pub fn noise_level(image: &FloatImage) -> f64 {
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w < 3 || h < 3 {
        return 0.0;
    }
    let d = image.as_raw();
    let mut responses: Vec<f64> = (1..h - 1)
        .flat_map(|i| (1..w - 1).map(move |j| (i, j)))
        .step_by(3)
        .map(|(i, j)| {
            let at = |y: usize, x: usize| d[y * w + x] as f64;
            let v = at(i - 1, j - 1) - 2.0 * at(i - 1, j) + at(i - 1, j + 1) - 2.0 * at(i, j - 1)
                + 4.0 * at(i, j)
                - 2.0 * at(i, j + 1)
                + at(i + 1, j - 1)
                - 2.0 * at(i + 1, j)
                + at(i + 1, j + 1);
            v.abs()
        })
        .collect();
    1.4826 * median(&mut responses) / 6.0
}

/// Edge smoothing that brings the noise (σ of the raw pixels) in the edge
/// image down to a few percent of the image's contrast (the spread between
/// its 10th and 90th percentiles once smoothed), between 1 px and the voting
/// smoothing.
fn edge_smoothing_for_noise(noise: f64, smooth: &FloatImage, vote_sigma: f64) -> f64 {
    let mut values: Vec<f64> = smooth
        .as_raw()
        .iter()
        .step_by(7)
        .map(|&v| v as f64)
        .collect();
    if values.len() < 10 {
        return 1.0;
    }
    let n = values.len();
    let p10 = *values
        .select_nth_unstable_by(n / 10, |a, b| a.total_cmp(b))
        .1;
    let p90 = *values
        .select_nth_unstable_by(9 * n / 10, |a, b| a.total_cmp(b))
        .1;
    let contrast = (p90 - p10).max(1e-6);
    // Gaussian smoothing σ_s divides white noise by 2√π σ_s.
    let needed = noise / (0.04 * contrast * 2.0 * std::f64::consts::PI.sqrt());
    needed.clamp(1.0, vote_sigma.max(1.0))
}

/// Separable Gaussian blur (kernel to ±3σ, edges extended), rows and columns
/// in parallel: the large σ used for voting makes this the costliest filter.
pub fn gaussian_blur(image: &FloatImage, sigma: f64) -> FloatImage {
    let data = gaussian_blur_map(image, sigma, |v| v);
    FloatImage::from_raw(image.width(), image.height(), data).expect("sized")
}

/// [`gaussian_blur`], each output value passed through `map` (e.g. to bytes).
/// Bands of rows are blurred one at a time, so the only whole-image buffer is
/// the output.
fn gaussian_blur_map<T: Copy + Default + Send>(
    image: &FloatImage,
    sigma: f64,
    map: impl Fn(f32) -> T + Sync,
) -> Vec<T> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let radius = (3.0 * sigma).ceil().max(1.0) as isize;
    let mut kernel: Vec<f32> = (-radius..=radius)
        .map(|k| (-(k * k) as f64 / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let total: f32 = kernel.iter().sum();
    kernel.iter_mut().for_each(|v| *v /= total);
    let src = image.as_raw();
    let band = 64usize;
    let mut out = vec![T::default(); w * h];
    out.par_chunks_mut(band * w)
        .enumerate()
        .for_each(|(b, out_band)| {
            let first = b * band;
            let last = (first + out_band.len() / w).min(h);
            // The rows this band's column pass reads, blurred along the row.
            let top = (first as isize - radius).max(0) as usize;
            let bottom = (last as isize - 1 + radius).min(h as isize - 1) as usize;
            let mut rows = vec![0f32; (bottom - top + 1) * w];
            for (i, row_out) in (top..=bottom).zip(rows.chunks_mut(w)) {
                let line = &src[i * w..(i + 1) * w];
                for (j, o) in row_out.iter_mut().enumerate() {
                    let mut acc = 0.0;
                    for (t, k) in kernel.iter().enumerate() {
                        let x =
                            (j as isize + t as isize - radius).clamp(0, w as isize - 1) as usize;
                        acc += k * line[x];
                    }
                    *o = acc;
                }
            }
            let mut line = vec![0f32; w];
            for (i, out_line) in (first..last).zip(out_band.chunks_mut(w)) {
                line.fill(0.0);
                for (t, k) in kernel.iter().enumerate() {
                    let y = (i as isize + t as isize - radius).clamp(0, h as isize - 1) as usize;
                    let src_row = &rows[(y - top) * w..(y - top + 1) * w];
                    for (o, v) in line.iter_mut().zip(src_row) {
                        *o += k * v;
                    }
                }
                for (o, &v) in out_line.iter_mut().zip(&line) {
                    *o = map(v);
                }
            }
        });
    out
}

fn score(d: &Disk) -> f64 {
    d.support * d.visible
}

struct Accumulator {
    /// Magnitude of the phase-coded votes.
    data: Vec<f32>,
    /// Radius encoded in the votes' phase, per cell.
    radius: Vec<f32>,
    w: usize,
    h: usize,
    /// Accumulator cell (i, j) is the centre (j − pad, i − pad) in pixels.
    pad: usize,
}

/// Sobel kernels (imageproc's) as f32, scaled to an intensity change per pixel.
fn sobel(image: &FloatImage) -> (FloatImage, FloatImage) {
    use imageproc::kernel::{Kernel, SOBEL_HORIZONTAL_3X3, SOBEL_VERTICAL_3X3};
    let scaled = |k: Kernel<'static, i32>| -> Vec<f32> {
        (0..3)
            .flat_map(|y| (0..3).map(move |x| (x, y)))
            .map(|(x, y)| k.get(x, y) as f32 / 8.0)
            .collect()
    };
    let (kx, ky) = (scaled(SOBEL_HORIZONTAL_3X3), scaled(SOBEL_VERTICAL_3X3));
    let gx: FloatImage = imageproc::filter::filter_clamped(image, Kernel::new(&kx, 3, 3));
    let gy: FloatImage = imageproc::filter::filter_clamped(image, Kernel::new(&ky, 3, 3));
    (gx, gy)
}

/// Phase-coded Hough voting (Atherton & Kerbyson 1999): a vote at distance t
/// carries the phase 2π(t − r_min)/(r_max − r_min). Votes of one circle add
/// coherently at its centre; the streaks that rays of neighbouring disks lay
/// across it have mixed phases and largely cancel, which keeps the centres of
/// touching disks apart. The phase of the peak also gives the radius.
fn vote(smooth: &FloatImage, o: &DetectOptions, signs: &[f64]) -> Accumulator {
    let (gx, gy) = sobel(smooth);
    let (w, h) = (smooth.width() as usize, smooth.height() as usize);
    let (gx, gy) = (gx.into_raw(), gy.into_raw());
    let magnitude = |p: usize| (gx[p] * gx[p] + gy[p] * gy[p]).sqrt();
    // Ignore the weakest gradients: they carry noise, not edges, and cost time.
    let mut sorted: Vec<f32> = (0..w * h).map(magnitude).collect();
    let k = ((sorted.len() as f64 * 0.995) as usize).min(sorted.len() - 1);
    let high = *sorted.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1;
    drop(sorted);
    let floor = 0.1 * high;
    // Thin the edges (non-maximum suppression across them, as Canny does), so
    // each boundary point votes once and the votes' phases stay coherent.
    // Each row's voters: column, gradient magnitude and direction.
    let voters: Vec<Vec<(u32, f32, f32, f32)>> = (0..h)
        .into_par_iter()
        .map(|i| {
            let mut row = Vec::new();
            for j in 0..w {
                let p = i * w + j;
                let m = magnitude(p);
                if m <= floor {
                    continue;
                }
                let (dx, dy) = (gx[p] / m, gy[p] / m);
                let (sx, sy) = (dx.round() as isize, dy.round() as isize);
                let at = |y: isize, x: isize| {
                    if x < 0 || y < 0 || x >= w as isize || y >= h as isize {
                        0.0
                    } else {
                        magnitude(y as usize * w + x as usize)
                    }
                };
                let (i, j) = (i as isize, j as isize);
                if m >= at(i + sy, j + sx) && m >= at(i - sy, j - sx) {
                    row.push((j as u32, m, dx, dy));
                }
            }
            row
        })
        .collect();
    drop((gx, gy));
    let pad = o.radius_max.ceil() as usize + 2;
    let (aw, ah) = (w + 2 * pad, h + 2 * pad);
    let (r0, r1) = (o.radius_min, o.radius_max);
    let steps = ((r1 - r0) / 0.5).ceil() as usize + 1;
    let span = (steps - 1).max(1) as f64;
    let phases: Vec<(f64, f32, f32)> = (0..steps)
        .map(|k| {
            let t = r0 + (r1 - r0) * k as f64 / span;
            let phase = std::f64::consts::TAU * k as f64 / steps as f64;
            (t, phase.cos() as f32, phase.sin() as f32)
        })
        .collect();
    // The accumulator is cut into bands of rows, each filled by one task from
    // the rows of voters that can reach it: one accumulator in memory (not
    // one per thread), and each cell's sum in the same order on any machine.
    let band_rows = ah.div_ceil(4 * rayon::current_num_threads()).max(8);
    let mut re = vec![0f32; aw * ah];
    let mut im = vec![0f32; aw * ah];
    re.par_chunks_mut(band_rows * aw)
        .zip(im.par_chunks_mut(band_rows * aw))
        .enumerate()
        .for_each(|(b, (re, im))| {
            let (top, bottom) = (b * band_rows, b * band_rows + re.len() / aw);
            let reach = r1 + 1.0;
            let first = (top as f64 - pad as f64 - reach).floor().max(0.0) as usize;
            let last = ((bottom as f64 - pad as f64 + reach).ceil().max(0.0) as usize).min(h);
            for (i, row) in voters.iter().enumerate().take(last).skip(first) {
                for &(j, m, dx, dy) in row {
                    let (j, dx, dy) = (j as usize, dx as f64, dy as f64);
                    for &s in signs {
                        for &(t, c, sn) in &phases {
                            let y = (i as f64 + s * t * dy + pad as f64).round();
                            if y < top as f64 || y >= bottom as f64 {
                                continue;
                            }
                            let x = (j as f64 + s * t * dx + pad as f64).round();
                            if x >= 0.0 && (x as usize) < aw {
                                let cell = (y as usize - top) * aw + x as usize;
                                re[cell] += m * c;
                                im[cell] += m * sn;
                            }
                        }
                    }
                }
            }
        });
    drop(voters);
    let blur = |v: Vec<f32>| {
        let image = FloatImage::from_raw(aw as u32, ah as u32, v).expect("sized");
        imageproc::filter::gaussian_blur_f32(&image, 1.0).into_raw()
    };
    let (re, im) = (blur(re), blur(im));
    let data: Vec<f32> = re
        .iter()
        .zip(&im)
        .map(|(a, b)| (a * a + b * b).sqrt())
        .collect();
    let radius: Vec<f32> = re
        .iter()
        .zip(&im)
        .map(|(a, b)| {
            let phase = (b.atan2(*a) as f64).rem_euclid(std::f64::consts::TAU);
            (r0 + (r1 - r0) * phase / std::f64::consts::TAU * steps as f64
                / (steps - 1).max(1) as f64) as f32
        })
        .collect();
    Accumulator {
        data,
        radius,
        w: aw,
        h: ah,
        pad,
    }
}

/// Local maxima of the accumulator above the threshold, strongest first, as
/// centres in pixel coordinates with the radius their phase suggests.
fn peaks(acc: &Accumulator, o: &DetectOptions) -> Vec<Candidate> {
    let max = acc.data.iter().fold(0f32, |m, &v| m.max(v));
    if max <= 0.0 {
        return Vec::new();
    }
    let threshold = (o.vote_threshold * max as f64) as f32;
    let q = ((o.radius_min / 4.0).round() as isize).max(2);
    let (w, h) = (acc.w as isize, acc.h as isize);
    let mut found: Vec<(f32, usize, usize)> = (0..acc.h)
        .into_par_iter()
        .flat_map_iter(|i| {
            let mut row = Vec::new();
            for j in 0..acc.w {
                let v = acc.data[i * acc.w + j];
                if v < threshold {
                    continue;
                }
                let mut is_max = true;
                'window: for di in -q..=q {
                    for dj in -q..=q {
                        let (y, x) = (i as isize + di, j as isize + dj);
                        if (di, dj) == (0, 0) || x < 0 || y < 0 || x >= w || y >= h {
                            continue;
                        }
                        let u = acc.data[y as usize * acc.w + x as usize];
                        // Ties go to the first in raster order.
                        if u > v || (u == v && (di, dj) < (0, 0)) {
                            is_max = false;
                            break 'window;
                        }
                    }
                }
                if is_max {
                    row.push((v, i, j));
                }
            }
            row
        })
        .collect();
    found.sort_by(|a, b| b.0.total_cmp(&a.0));
    let pad = acc.pad as f64;
    found
        .into_iter()
        .map(|(_, i, j)| {
            (
                j as f64 - pad,
                i as f64 - pad,
                acc.radius[i * acc.w + j] as f64,
            )
        })
        .collect()
}

/// Second source of candidates: the smoothed image split at its Otsu level
/// into disks and background, then the local maxima of the distance to the
/// background, which sit at the centres of disks however many neighbours
/// touch them (their voting peaks can be weak).
fn distance_peaks(smooth: &FloatImage, sign: f64, o: &DetectOptions) -> Vec<Candidate> {
    let (lo, hi) = smooth
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return Vec::new();
    }
    let bytes = ::image::GrayImage::from_fn(smooth.width(), smooth.height(), |x, y| {
        let v = (smooth.get_pixel(x, y)[0] - lo) / (hi - lo);
        ::image::Luma([(v * 255.0).round() as u8])
    });
    let level = imageproc::contrast::otsu_level(&bytes);
    // Background pixels are the "foreground" the distance transform measures to.
    let background = ::image::GrayImage::from_fn(smooth.width(), smooth.height(), |x, y| {
        let v = bytes.get_pixel(x, y)[0];
        let is_disk = if sign > 0.0 { v > level } else { v <= level };
        ::image::Luma([if is_disk { 0 } else { 255 }])
    });
    let distance = imageproc::distance_transform::euclidean_squared_distance_transform(&background);
    let (w, h) = (smooth.width() as i64, smooth.height() as i64);
    let q = ((o.radius_min / 3.0).round() as i64).max(2);
    let (dmin, dmax) = ((0.5 * o.radius_min).powi(2), (1.3 * o.radius_max).powi(2));
    let mut found = Vec::new();
    for i in 0..h {
        for j in 0..w {
            let v = distance.get_pixel(j as u32, i as u32)[0];
            if v < dmin || v > dmax {
                continue;
            }
            let mut is_max = true;
            'window: for di in -q..=q {
                for dj in -q..=q {
                    let (y, x) = (i + di, j + dj);
                    if (di, dj) == (0, 0) || x < 0 || y < 0 || x >= w || y >= h {
                        continue;
                    }
                    let u = distance.get_pixel(x as u32, y as u32)[0];
                    if u > v || (u == v && (di, dj) < (0, 0)) {
                        is_max = false;
                        break 'window;
                    }
                }
            }
            if is_max {
                found.push((j as f64, i as f64, v.sqrt()));
            }
        }
    }
    found
}

/// A borrowed image plane with bilinear sampling: the whole image, or a
/// window of it whose first pixel is the image's pixel `origin`.
pub(crate) struct Plane<'a> {
    pub data: &'a [f32],
    pub w: usize,
    pub h: usize,
    pub origin: [f64; 2],
}

impl Plane<'_> {
    pub fn whole(image: &FloatImage) -> Plane<'_> {
        Plane {
            data: image.as_raw(),
            w: image.width() as usize,
            h: image.height() as usize,
            origin: [0.0, 0.0],
        }
    }

    /// Bilinear interpolation at image coordinates; `None` outside the pixel
    /// centres' hull.
    pub fn sample(&self, x: f64, y: f64) -> Option<f64> {
        let (x, y) = (x - self.origin[0], y - self.origin[1]);
        if !(x >= 0.0 && y >= 0.0 && x <= (self.w - 1) as f64 && y <= (self.h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (
            (x.floor() as usize).min(self.w - 2),
            (y.floor() as usize).min(self.h - 2),
        );
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let at = |i: usize, j: usize| self.data[i * self.w + j] as f64;
        let top = at(y0, x0) * (1.0 - fx) + at(y0, x0 + 1) * fx;
        let bottom = at(y0 + 1, x0) * (1.0 - fx) + at(y0 + 1, x0 + 1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }
}

/// One ray's edge: its point and whether the image gradient there points
/// along the ray (as it does on a disk's boundary, and rarely on texture).
struct Edge {
    x: f64,
    y: f64,
    strength: f64,
    aligned: bool,
}

const STEP: f64 = 0.25;
/// Largest angle between the gradient and the ray at a boundary point: tan 25°.
const ALIGNMENT: f64 = 0.466;

/// Refines a candidate centre into a disk, or rejects it.
fn refine(
    img: &Plane,
    centre: [f64; 2],
    hint: f64,
    sign: f64,
    sigma: f64,
    o: &DetectOptions,
) -> Option<Disk> {
    let r0 = radial_peak(img, centre, hint, sign, o)?;
    let (mut c, mut r) = (centre, r0);
    // Wide search windows first (the candidate may be a few pixels off), then
    // narrower ones: the medium window judges support (wide enough that
    // texture and noise cannot look like a circle), the narrow ones place the
    // edge (close enough that texture inside the disk is not mistaken for it).
    let narrow = (1.5 * sigma).max(1.25);
    let windows = [0.25 * r0 + 2.0 * sigma, 2.0 * sigma + 2.0, narrow, narrow];
    let mut judged = None;
    for (pass, &half_window) in windows.iter().enumerate() {
        let (edges, rays, visible_rays) = ray_edges(img, c, r, sign, half_window, sigma);
        if visible_rays == 0 || (visible_rays as f64) < o.min_visible * rays as f64 {
            return None;
        }
        let fit = robust_circle_fit(&edges, c, r)?;
        if pass == 1 {
            judged = Some((edges, fit, rays, visible_rays));
        }
        c = [fit[0], fit[1]];
        r = fit[2];
    }
    let (edges, fit, rays, visible_rays) = judged?;
    // Support is judged with a fixed tolerance so noise cannot widen it.
    let tolerance = 1.0 + 0.02 * fit[2];
    let residuals: Vec<f64> = edges
        .iter()
        .filter(|e| e.aligned)
        .map(|e| ((e.x - fit[0]).powi(2) + (e.y - fit[1]).powi(2)).sqrt() - fit[2])
        .filter(|res| res.abs() <= tolerance)
        .collect();
    let support = residuals.len() as f64 / visible_rays as f64;
    let visible = visible_rays as f64 / rays as f64;
    if support < o.min_support_confirmed.min(o.min_support)
        || r < o.radius_min - 1.0
        || r > o.radius_max + 1.0
    {
        return None;
    }
    // The step across the edge, measured outside the smoothing's reach.
    let contrast = edge_contrast(img, c, r, sign, sigma);
    if contrast <= o.min_contrast.max(0.0) {
        return None;
    }
    let rms = (residuals.iter().map(|v| v * v).sum::<f64>() / residuals.len() as f64).sqrt();
    // The smoothed edge of a disk peaks σ²/(2r) inside the true one.
    let r = r + sigma * sigma / (2.0 * r);
    Some(Disk {
        x: c[0],
        y: c[1],
        r,
        support,
        visible,
        contrast,
        rms,
    })
}

/// The radius at which the mean outward intensity drop (signed by polarity)
/// peaks, near the radius the votes suggest (over the whole range when the
/// suggestion sits near either end, where its phase is ambiguous).
fn radial_peak(img: &Plane, c: [f64; 2], hint: f64, sign: f64, o: &DetectOptions) -> Option<f64> {
    let band = (0.25 * (o.radius_max - o.radius_min)).max(3.0);
    let (mut lo, mut hi) = (o.radius_min - 2.0, o.radius_max + 2.0);
    if hint - band > o.radius_min && hint + band < o.radius_max {
        (lo, hi) = (hint - band, hint + band);
    }
    let lo = lo.max(1.0);
    let n = ((hi - lo) / 0.5).ceil() as usize + 1;
    let rays = ((std::f64::consts::TAU * hi / 3.0).ceil() as usize).clamp(24, 720);
    let mut sum = vec![0.0; n];
    let mut count = vec![0usize; n];
    for k in 0..rays {
        let a = std::f64::consts::TAU * k as f64 / rays as f64;
        let (ca, sa) = (a.cos(), a.sin());
        for (b, (s, m)) in sum.iter_mut().zip(count.iter_mut()).enumerate() {
            let rho = lo + 0.5 * b as f64;
            let inner = img.sample(c[0] + (rho - 0.5) * ca, c[1] + (rho - 0.5) * sa);
            let outer = img.sample(c[0] + (rho + 0.5) * ca, c[1] + (rho + 0.5) * sa);
            if let (Some(i), Some(u)) = (inner, outer) {
                *s += sign * (i - u);
                *m += 1;
            }
        }
    }
    let need = (rays / 5).max(4);
    let profile: Vec<f64> = sum
        .iter()
        .zip(&count)
        .map(|(&s, &m)| {
            if m >= need {
                s / m as f64
            } else {
                f64::NEG_INFINITY
            }
        })
        .collect();
    let (best, &value) = profile
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    if value.is_nan() || value <= 0.0 {
        return None;
    }
    let offset = if best > 0 && best + 1 < n {
        parabola_vertex(profile[best - 1], value, profile[best + 1])
    } else {
        0.0
    };
    Some(lo + 0.5 * (best as f64 + offset))
}

/// Vertex offset (in steps) of the least-squares parabola through the samples
/// within `reach` of `best` (three samples at least), kept within the span.
fn parabola_fit(v: &[f64], best: usize, reach: usize) -> f64 {
    let lo = best.saturating_sub(reach);
    let hi = (best + reach).min(v.len() - 1);
    if hi - lo < 2 {
        return 0.0;
    }
    // Normal equations for v ≈ a + b t + c t², t relative to best.
    let mut m = [[0.0; 3]; 3];
    let mut rhs = [0.0; 3];
    for (k, &y) in v.iter().enumerate().take(hi + 1).skip(lo) {
        let t = k as f64 - best as f64;
        let basis = [1.0, t, t * t];
        for a in 0..3 {
            rhs[a] += basis[a] * y;
            for b in 0..3 {
                m[a][b] += basis[a] * basis[b];
            }
        }
    }
    match solve3(m, rhs) {
        Some([_, b, c]) if c < 0.0 => {
            (-b / (2.0 * c)).clamp(lo as f64 - best as f64, hi as f64 - best as f64)
        }
        _ => 0.0,
    }
}

/// Vertex offset (in steps, within ±½) of the parabola through three samples.
fn parabola_vertex(a: f64, b: f64, c: f64) -> f64 {
    let denominator = a - 2.0 * b + c;
    if !(a.is_finite() && c.is_finite()) || denominator >= 0.0 {
        return 0.0;
    }
    (0.5 * (a - c) / denominator).clamp(-0.5, 0.5)
}

/// Sub-pixel edge along each ray from the centre, searched within ±half_window
/// of the radius. Returns the edges, the number of rays and the number of rays
/// whose search window lies inside the image.
fn ray_edges(
    img: &Plane,
    c: [f64; 2],
    r: f64,
    sign: f64,
    half_window: f64,
    sigma: f64,
) -> (Vec<Edge>, usize, usize) {
    let rays = ((std::f64::consts::TAU * r / 1.5).ceil() as usize).clamp(32, 1440);
    // Samples every STEP px; the derivative spans ±0.5 px (two samples each side).
    let lead = (0.5 / STEP) as usize;
    let n = (2.0 * half_window / STEP).ceil() as usize + 1 + 2 * lead;
    let start = r - half_window - 0.5;
    let mut edges = Vec::with_capacity(rays);
    let mut visible = 0;
    let mut samples = vec![0.0; n];
    for k in 0..rays {
        let a = std::f64::consts::TAU * k as f64 / rays as f64;
        let (ca, sa) = (a.cos(), a.sin());
        let mut inside = start > 0.0;
        for (m, s) in samples.iter_mut().enumerate() {
            let rho = start + STEP * m as f64;
            match img.sample(c[0] + rho * ca, c[1] + rho * sa) {
                Some(v) => *s = v,
                None => {
                    inside = false;
                    break;
                }
            }
        }
        if !inside {
            continue;
        }
        visible += 1;
        let derivative: Vec<f64> = (lead..n - lead)
            .map(|m| sign * (samples[m - lead] - samples[m + lead]))
            .collect();
        let (best, &value) = derivative
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .expect("non-empty window");
        if best == 0 || best + 1 == derivative.len() || value <= 0.0 {
            continue;
        }
        // The peak of a smoothed edge is about σ wide: fit the parabola over it.
        let reach = ((sigma / STEP).round() as usize).max(1);
        let offset = parabola_fit(&derivative, best, reach);
        let rho = start + STEP * (best as f64 + lead as f64 + offset);
        let (x, y) = (c[0] + rho * ca, c[1] + rho * sa);
        // Tangential derivative over the same 1 px span as the radial one.
        let aligned = match (
            img.sample(x - 0.5 * sa, y + 0.5 * ca),
            img.sample(x + 0.5 * sa, y - 0.5 * ca),
        ) {
            (Some(p), Some(q)) => (p - q).abs() <= ALIGNMENT * value,
            _ => false,
        };
        edges.push(Edge {
            x,
            y,
            strength: value,
            aligned,
        });
    }
    (edges, rays, visible)
}

/// Geometric circle fit with iterative trimming of outliers (edges of
/// neighbours, contacts, texture). Returns (cx, cy, r) and the inlier count.
fn robust_circle_fit(edges: &[Edge], c: [f64; 2], r: f64) -> Option<[f64; 3]> {
    if edges.len() < 8 {
        return None;
    }
    let mut strengths: Vec<f64> = edges.iter().map(|e| e.strength).collect();
    let median_strength = median(&mut strengths);
    let usable = |e: &Edge| e.aligned && e.strength >= 0.25 * median_strength;
    let mut use_edge: Vec<bool> = edges.iter().map(usable).collect();
    let mut p = [c[0], c[1], r];
    for round in 0..4 {
        p = circle_gauss_newton(edges, &use_edge, p)?;
        let mut res: Vec<f64> = edges
            .iter()
            .map(|e| (((e.x - p[0]).powi(2) + (e.y - p[1]).powi(2)).sqrt() - p[2]).abs())
            .collect();
        let mut used: Vec<f64> = res
            .iter()
            .zip(&use_edge)
            .filter(|(_, &u)| u)
            .map(|(&v, _)| v)
            .collect();
        let mad = median(&mut used);
        let cutoff = if round == 0 {
            (4.0 * 1.4826 * mad).max(1.5)
        } else {
            (3.0 * 1.4826 * mad).max(0.5)
        };
        let mut inliers = 0;
        for (k, e) in edges.iter().enumerate() {
            use_edge[k] = res[k] <= cutoff && usable(e);
            inliers += use_edge[k] as usize;
        }
        res.clear();
        if inliers < 8 {
            return None;
        }
    }
    Some(p)
}

/// Minimises Σ (|pₖ − c| − r)² over the used edge points.
fn circle_gauss_newton(edges: &[Edge], use_edge: &[bool], start: [f64; 3]) -> Option<[f64; 3]> {
    let mut p = start;
    for _ in 0..20 {
        let mut jtj = [[0.0; 3]; 3];
        let mut jtr = [0.0; 3];
        for (e, _) in edges.iter().zip(use_edge).filter(|(_, &u)| u) {
            let (dx, dy) = (e.x - p[0], e.y - p[1]);
            let d = (dx * dx + dy * dy).sqrt().max(1e-9);
            let res = d - p[2];
            let j = [-dx / d, -dy / d, -1.0];
            for a in 0..3 {
                jtr[a] += j[a] * res;
                for b in 0..3 {
                    jtj[a][b] += j[a] * j[b];
                }
            }
        }
        let step = solve3(jtj, jtr)?;
        for k in 0..3 {
            p[k] -= step[k];
        }
        if step.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
            break;
        }
    }
    (p.iter().all(|v| v.is_finite()) && p[2] > 0.0).then_some(p)
}

/// Solves a 3×3 system by Cramer's rule; `None` when singular.
pub(crate) fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if d.abs().partial_cmp(&(1e-12 * scale.powi(3))) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let mut x = [0.0; 3];
    for k in 0..3 {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        x[k] = det(m) / d;
    }
    Some(x)
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 2;
    *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

/// The intensity inside minus outside the circle, sampled beyond the
/// smoothing's reach and signed by the polarity: its 80th percentile over the
/// visible rays, since in a dense packing many rays end on a neighbour.
fn edge_contrast(img: &Plane, c: [f64; 2], r: f64, sign: f64, sigma: f64) -> f64 {
    let gap = 2.0 * sigma + 1.0;
    let rays = 64;
    let mut steps = Vec::with_capacity(rays);
    for k in 0..rays {
        let a = std::f64::consts::TAU * k as f64 / rays as f64;
        let (ca, sa) = (a.cos(), a.sin());
        let inner = img.sample(
            c[0] + (r - gap).max(0.0) * ca,
            c[1] + (r - gap).max(0.0) * sa,
        );
        let outer = img.sample(c[0] + (r + gap) * ca, c[1] + (r + gap) * sa);
        if let (Some(i), Some(u)) = (inner, outer) {
            steps.push(sign * (i - u));
        }
    }
    if steps.is_empty() {
        return 0.0;
    }
    let k = (steps.len() * 4 / 5).min(steps.len() - 1);
    *steps.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}
