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
//! 6. A model fit to the raw pixels of each disk's edge ring places it to a
//!    fraction of a pixel; disks outlined by a dark rim whatever their
//!    interior (dim photoelastic disks) are added.
//!
//! Big disks (radius ≥ 100 px), and disks of radius ≥ 32 px in a picture of
//! over 4 megapixels, are searched (steps 1–3) in the image shrunk by an
//! integer factor and refined at full resolution.
//!
//! Files: `options` what to look for and what is found; `voting` steps 1–3;
//! `pyramid` the search in the shrunk image; `refine` step 4–5 along rays,
//! `circle_fit` the circle through the edge points; `polish` the model fit;
//! `rims` the dim disks; `filters` smoothing and the noise estimate; this
//! file runs them in order and merges what they find.

mod circle_fit;
mod filters;
mod options;
mod polish;
pub(crate) mod profile;
mod pyramid;
mod refine;
mod rims;
mod voting;

pub(crate) use circle_fit::solve3;
pub(crate) use filters::without_opaque;
pub use filters::{gaussian_blur, noise_level};
pub use options::{DetectOptions, Disk, Polarity};
pub(crate) use refine::Plane;

use super::FloatImage;
use crate::error::{Error, Result};
use filters::{edge_smoothing_for_noise, median};
use polish::{polish, ModelFit};
pub(crate) use pyramid::small_disk_factor;
use pyramid::{coarse_candidates, downsample, pyramid_factor, upsample, COARSE_RADIUS};
use rayon::prelude::*;
use refine::{refine, refine_outermost};
use rims::{add_rim_enclosed, add_rim_enclosed_coarse};
use voting::{distance_peaks, peaks, vote, whole_disk_votes};

/// Finds every disk whose radius lies in the given range. Returns them sorted
/// by row, then column. An image without disks gives an empty list (the caller
/// decides whether that is an error).
pub fn detect_disks(image: &FloatImage, options: &DetectOptions) -> Result<Vec<Disk>> {
    search(image, options, false)
}

/// [`detect_disks`] in a binary mask (1 on 0: the regions dark rims
/// enclose). Its voting peaks are refined only when the strongest reaches
/// [`MASK_VOTES`]; the distance peaks always are.
pub(crate) fn detect_disks_in_mask(
    mask: &FloatImage,
    options: &DetectOptions,
) -> Result<Vec<Disk>> {
    search(mask, options, true)
}

/// The votes a binary mask's strongest peak needs (a share of
/// [`whole_disk_votes`], a disk of the smallest radius, which gets about
/// half the votes of a disk 10 % bigger: its smoothed edge lies just inside
/// the range) for its voting peaks to be refined: a
/// mask without one region shaped like a disk is specks, whose thousands of
/// weak peaks (the threshold is relative to the strongest) cost more than
/// the rest of the search. Measured: the rendered 21-MP hopper's mask 1.23;
/// the monochrome dark field `wc-slope-a`, where no disk shows a dark rim,
/// 0.30 (0.18 at 21 MP: 4700 candidates, half its CPU time, no disk).
/// Judged per candidate instead (0.05–0.2 of a whole disk, or a filled
/// interior) it lost hopper disks: regions merged with a neighbour's, or
/// rings flooded inside, vote weakly at their centre.
const MASK_VOTES: f32 = 0.5;

fn search(image: &FloatImage, options: &DetectOptions, mask: bool) -> Result<Vec<Disk>> {
    if options.classes.len() > 1 {
        let mut found = Vec::new();
        for c in &options.classes {
            let mut one = options.clone();
            (one.radius_min, one.radius_max, one.classes) = (c[0], c[1], Vec::new());
            found.extend(search(image, &one, mask)?);
        }
        return Ok(without_overlaps(found, options.overlap));
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
    let mut laps = profile::Laps::start();
    let pixels = w as f64 * h as f64;
    let factor = pyramid_factor(o, pixels, mask);
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
        if mask {
            let strongest = accumulator.data.iter().fold(0f32, |m, &v| m.max(v));
            let whole = whole_disk_votes(o);
            if strongest < MASK_VOTES * whole {
                candidates.clear();
            }
        }
        for &s in signs {
            candidates.extend(distance_peaks(&smooth, s, o));
        }
        (candidates, edge_sigma)
    };
    laps.lap("search: candidates");
    let edge_image = gaussian_blur(image, edge_sigma);
    laps.lap("search: edge smoothing (full resolution)");
    let plane = Plane::whole(&edge_image);
    // A big picture's candidates come from its half-size copy, up to a
    // pixel of it off: a disk judged short of confident is refined again
    // from its own circle, so that its judgement does not hang on the start.
    let restart = pyramid && o.radius_min < 2.0 * COARSE_RADIUS;
    let refine_candidate = |&(cx, cy, hint): &Candidate| {
        let plane = &plane;
        signs
            .iter()
            .filter_map(move |&s| {
                let disk = refine(plane, [cx, cy], hint, s, edge_sigma, o)?;
                if !restart || disk.support >= o.min_support {
                    return Some(disk);
                }
                let again = refine(plane, [disk.x, disk.y], disk.r, s, edge_sigma, o);
                Some(again.filter(|a| a.support > disk.support).unwrap_or(disk))
            })
            .collect::<Vec<_>>()
    };
    let found: Vec<Disk> = if pyramid {
        refine_strongest_first(&candidates, refine_candidate, o)
    } else {
        candidates
            .par_iter()
            .flat_map_iter(refine_candidate)
            .collect()
    };
    laps.lap(&format!("search: refine {} candidates", candidates.len()));
    let mut kept = without_copies(found);
    if o.outermost_outline && o.polarity == Polarity::Bright {
        let outermost: Vec<Disk> = kept
            .par_iter()
            .map(|d| {
                refine_outermost(&plane, d, 1.0, edge_sigma, o)
                    .filter(|e| score(e) > score(d) && encloses(e, d, o))
                    .unwrap_or(*d)
            })
            .collect();
        kept = without_copies(outermost);
        laps.lap("search: outermost outlines");
    }
    drop(edge_image);
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
    let kept = without_overlaps(kept, o.overlap);
    laps.lap("search: model fit (polish)");
    if o.find_by_rims && o.polarity == Polarity::Bright {
        let with_rims = if pyramid {
            add_rim_enclosed_coarse(image, o, kept, factor, noise_of(image))
        } else {
            add_rim_enclosed(image, o, kept)
        };
        laps.lap("search: rim-enclosed disks");
        return Ok(with_rims);
    }
    Ok(kept)
}

/// Finds the disks as [`detect_disks`] does, the whole search (candidates,
/// edges, fits, judgement) in the image shrunk by `factor` (block means),
/// and the circles scaled back. Every pixel-sized setting (smoothing, edge
/// windows, the model fit's ring, support tolerances) then meets the disks at
/// the scale it was made for, so a photograph taken with more pixels finds
/// what it would with fewer, in a fraction of the time; positions keep the
/// same precision in radii. Smoothing given in `o` is in full-resolution
/// pixels.
pub fn detect_disks_shrunk(
    image: &FloatImage,
    o: &DetectOptions,
    factor: usize,
) -> Result<Vec<Disk>> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let shrunk = factor > 1 && w >= 8 * factor && h >= 8 * factor;
    if !shrunk && small_disk_factor(o.radius_min, (w * h) as f64) == 1 {
        return detect_disks(image, o);
    }
    let pixels = image.as_raw();
    detect_disks_shrunk_from((w, h), |k| pixels[k], o, factor)
}

/// [`detect_disks_shrunk`] in a picture given pixel by pixel (`value(k)`
/// for pixel k in row-major order, `w` × `h`), so that a picture derived
/// from another (a gray picture's distance from its background) needs no
/// full-size buffer of its own; made whole only when it is not shrunk.
pub(crate) fn detect_disks_shrunk_from(
    (w, h): (usize, usize),
    value: impl Fn(usize) -> f32 + Sync,
    o: &DetectOptions,
    factor: usize,
) -> Result<Vec<Disk>> {
    if factor <= 1 || w < 8 * factor || h < 8 * factor {
        let image = FloatImage::from_fn(w as u32, h as u32, |x, y| {
            ::image::Luma([value(y as usize * w + x as usize)])
        });
        let up = small_disk_factor(o.radius_min, (w * h) as f64);
        if up > 1 {
            return detect_small_disks(&image, o, up);
        }
        return detect_disks(&image, o);
    }
    let f = factor as f64;
    let small = downsample(w, h, factor, value);
    let mut so = o.clone();
    (so.radius_min, so.radius_max) = (o.radius_min / f, o.radius_max / f);
    so.classes = o.classes.iter().map(|c| [c[0] / f, c[1] / f]).collect();
    so.smoothing_px = o.smoothing_px.map(|s| s / f);
    so.edge_smoothing_px = o.edge_smoothing_px.map(|s| s / f);
    let found = detect_disks(&small, &so)?;
    // Block (J, I) is centred on the full image's (f J + (f − 1)/2, …).
    let full = |v: f64| f * v + 0.5 * (f - 1.0);
    Ok(found
        .into_iter()
        .map(|d| Disk {
            x: full(d.x),
            y: full(d.y),
            r: f * d.r,
            rms: f * d.rms,
            ..d
        })
        .collect())
}

/// Small disks, searched both up-sampled by `factor` and in the picture's
/// own pixels, and the two merged: each disk of the own-pixel search that
/// is no copy of an up-sampled one is added, and of circles that cross the
/// better supported stays. Up-sampled, the search's pixel-sized rules meet
/// disks under 12 px at the scale they were made for (random packings of
/// radii 6–12 px in a dark field: 0.942 of the disks in their own pixels,
/// 0.969 up-sampled); in its own pixels it keeps disks of a dense packing
/// whose merged outlines the up-sampled search loses (a hexagonal packing
/// of radii 9–10.5 px in a dark field: 0.901 against 0.839; both 0.907,
/// the random packing 0.982; docs/image.md, round 13). The own-pixel search
/// costs a quarter of the up-sampled one or less.
fn detect_small_disks(image: &FloatImage, o: &DetectOptions, factor: usize) -> Result<Vec<Disk>> {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let pixels = image.as_raw();
    let (up, own) = rayon::join(
        || detect_disks_upsampled((w, h), |k| pixels[k], o, factor),
        || detect_disks(image, o),
    );
    let mut found = up?;
    for d in own? {
        if !found.iter().any(|k| same_disk(k, &d)) {
            found.push(d);
        }
    }
    Ok(without_overlaps(found, o.overlap))
}

/// Finds the disks as [`detect_disks`] does in the picture up-sampled by
/// `factor` (see [`small_disk_factor`]), every setting given in pixels
/// and the support's tolerance (one photograph's pixel) scaled with it, and
/// the circles scaled back.
fn detect_disks_upsampled(
    (w, h): (usize, usize),
    value: impl Fn(usize) -> f32 + Sync,
    o: &DetectOptions,
    factor: usize,
) -> Result<Vec<Disk>> {
    let f = factor as f64;
    let big = upsample(w, h, factor, value);
    let mut uo = o.clone();
    (uo.radius_min, uo.radius_max) = (o.radius_min * f, o.radius_max * f);
    uo.classes = o.classes.iter().map(|c| [c[0] * f, c[1] * f]).collect();
    uo.smoothing_px = o.smoothing_px.map(|s| s * f);
    uo.edge_smoothing_px = o.edge_smoothing_px.map(|s| s * f);
    uo.sensor_pixel = o.sensor_pixel * f;
    let found = detect_disks(&big, &uo)?;
    // Pixel (J, I) of the up-sampled picture is the point ((J + ½)/f − ½, …).
    let back = |v: f64| (v + 0.5) / f - 0.5;
    Ok(found
        .into_iter()
        .map(|d| Disk {
            x: back(d.x),
            y: back(d.y),
            r: d.r / f,
            rms: d.rms / f,
            ..d
        })
        .collect())
}

/// Refines the candidates (strongest first) in batches, skipping those that
/// lie inside a disk already found with confidence. Outlines cross by at
/// most 0.35 R, so the centres of two disks are at least 1.65 R apart and any
/// other disk's centre is at least 0.65 R away from such a candidate, beyond what refining recovers from (a quarter
/// radius): the candidate can only give the same disk again or a circle the
/// overlap rule removes. Most candidates are such echoes (of fringes inside
/// loaded disks), and refining is the costliest step of the search. The
/// batches have a fixed size, so the result does not depend on the number of
/// threads.
pub(crate) fn refine_strongest_first(
    candidates: &[Candidate],
    refine_candidate: impl Fn(&Candidate) -> Vec<Disk> + Sync,
    o: &DetectOptions,
) -> Vec<Disk> {
    let mut found: Vec<Disk> = Vec::new();
    let mut confident: Vec<Disk> = Vec::new();
    let mut refined_count = 0;
    for batch in candidates.chunks(REFINE_BATCH) {
        let open: Vec<&Candidate> = batch
            .iter()
            .filter(|c| !confident.iter().any(|d| (d.x - c.0).hypot(d.y - c.1) < d.r))
            .collect();
        refined_count += open.len();
        let refined: Vec<Disk> = open
            .par_iter()
            .flat_map_iter(|c| refine_candidate(c))
            .collect();
        confident.extend(refined.iter().filter(|d| d.support >= o.min_support));
        found.extend(refined);
    }
    profile::Laps::start().lap(&format!("(refined {refined_count} of them)"));
    found
}

/// Candidates refined at once by [`refine_strongest_first`].
const REFINE_BATCH: usize = 64;

/// A candidate centre (x, y) [px] and the radius its votes suggest.
pub(crate) type Candidate = (f64, f64, f64);

pub(crate) fn check_smoothing(sigma: f64, edge_sigma: f64) -> Result<()> {
    if !(sigma.is_finite() && sigma > 0.0 && edge_sigma.is_finite() && edge_sigma > 0.0) {
        return Err(Error::Invalid(format!(
            "smoothing must be positive, not {sigma} and {edge_sigma} px"
        )));
    }
    Ok(())
}

/// Disks do not overlap: of two circles that cross by more than a few pixels,
/// the better supported stays (the other is fitted to fringes or to the space
/// between disks, or is a size class's echo of a disk of another). Sorted by
/// row, then column.
pub(crate) fn without_overlaps(mut kept: Vec<Disk>, overlap: f64) -> Vec<Disk> {
    kept.sort_by(|a, b| score(b).total_cmp(&score(a)));
    let mut solid: Vec<Disk> = Vec::with_capacity(kept.len());
    for d in kept {
        let crosses = |k: &Disk| {
            (k.x - d.x).hypot(k.y - d.y) < k.r + d.r - (3.0f64).max(overlap * k.r.min(d.r))
        };
        if !solid.iter().any(crosses) {
            solid.push(d);
        }
    }
    solid.sort_by(|a, b| a.y.total_cmp(&b.y).then(a.x.total_cmp(&b.x)));
    solid
}

/// Duplicates merged: the best-supported copy of each disk wins.
fn without_copies(mut found: Vec<Disk>) -> Vec<Disk> {
    found.sort_by(|a, b| score(b).total_cmp(&score(a)));
    let mut kept: Vec<Disk> = Vec::new();
    for d in found {
        if !kept.iter().any(|k| same_disk(k, &d)) {
            kept.push(d);
        }
    }
    kept
}

/// Whether circle `outer` contains circle `inner` and is larger by more
/// than the support's tolerance: a disk's outline encloses whatever inside
/// it was taken for one (a reading that moves sideways is another disk's),
/// and a reading within the tolerance is the same outline, which stays as
/// first found (moved by a pixel or two, `jlin-fixed48`'s and
/// `jlin-step83`'s circles cost their fringe fits; docs/image.md, round 15).
fn encloses(outer: &Disk, inner: &Disk, o: &DetectOptions) -> bool {
    let tolerance = o.sensor_pixel + 0.02 * outer.r;
    (outer.x - inner.x).hypot(outer.y - inner.y) + inner.r <= outer.r + tolerance
        && outer.r > inner.r + tolerance
}

/// Whether two circles are copies of one disk (centres within 0.7 of the
/// larger radius).
fn same_disk(a: &Disk, b: &Disk) -> bool {
    (a.x - b.x).hypot(a.y - b.y) < 0.7 * a.r.max(b.r)
}

pub(crate) fn score(d: &Disk) -> f64 {
    d.support * d.visible
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask(size: u32, filled: impl Fn(u32, u32) -> bool) -> FloatImage {
        FloatImage::from_fn(size, size, |x, y| {
            ::image::Luma([if filled(x, y) { 1.0 } else { 0.0 }])
        })
    }

    fn strongest_share(image: &FloatImage, o: &DetectOptions) -> f32 {
        let accumulator = vote(&gaussian_blur(image, o.smoothing()), o, &[1.0]);
        let strongest = accumulator.data.iter().fold(0f32, |m, &v| m.max(v));
        strongest / whole_disk_votes(o)
    }

    /// The rim mask's gate: a region shaped like a disk (whole, or a ring
    /// flooded inside) passes it and is found; a mask of specks (as on a
    /// monochrome dark field) does not.
    #[test]
    fn rim_mask_gate_passes_disks_not_specks() {
        let o = DetectOptions::new(20.0, 30.0);
        let whole = mask(160, |x, y| (x as f64 - 80.0).hypot(y as f64 - 75.0) <= 25.0);
        assert!(strongest_share(&whole, &o) >= MASK_VOTES);
        let found = detect_disks_in_mask(&whole, &o).unwrap();
        assert_eq!(found.len(), 1, "{found:?}");
        assert!((found[0].x - 80.0).hypot(found[0].y - 75.0) < 1.0);
        let ring = mask(160, |x, y| {
            let d = (x as f64 - 80.0).hypot(y as f64 - 75.0);
            (20.0..=25.0).contains(&d)
        });
        assert!(strongest_share(&ring, &o) >= MASK_VOTES);
        // Specks of 2–5 px at random (fixed seed), 10 % of the pixels.
        let mut state: u64 = 39;
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 33) as u32
        };
        let blobs: Vec<(u32, u32, u32)> = (0..170)
            .map(|_| (next() % 160, next() % 160, 2 + next() % 4))
            .collect();
        let specks = mask(160, |x, y| {
            blobs
                .iter()
                .any(|&(bx, by, s)| x >= bx && x < bx + s && y >= by && y < by + s)
        });
        let share = strongest_share(&specks, &o);
        assert!(share < MASK_VOTES, "specks vote {share} of a whole disk");
    }
}
