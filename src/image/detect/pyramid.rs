//! Big disks: the candidate search in the image shrunk by an integer factor,
//! and refinement at full resolution in windows around each disk.

use super::filters::{edge_smoothing_for_noise, gaussian_blur};
use super::options::{DetectOptions, Disk};
use super::refine::{refine, Plane};
use super::voting::{distance_peaks, peaks, vote};
use super::{check_smoothing, Candidate};
use crate::error::Result;
use crate::image::FloatImage;
use rayon::prelude::*;

/// Radius [px] at which the candidate search runs: big disks are searched
/// in an image shrunk to about this size, and only refined at full resolution.
pub(crate) const COARSE_RADIUS: f64 = 50.0;

/// By how much the image is shrunk for the candidate search: 1 (not at all)
/// unless the smallest disks are at least twice [`COARSE_RADIUS`], or the
/// picture is big (see [`big_picture_factor`]).
pub(crate) fn pyramid_factor(o: &DetectOptions, pixels: f64, mask: bool) -> usize {
    let factor = (o.radius_min / COARSE_RADIUS).floor().max(1.0) as usize;
    if factor == 1 {
        big_picture_factor(o, pixels, mask)
    } else {
        factor
    }
}

/// By how much a big picture's candidate search and rim mask are shrunk
/// when its disks are under twice
/// [`COARSE_RADIUS`]: by 2 when it has more than [`BIG_PICTURE_PIXELS`] and
/// its disks stay at least [`BIG_PICTURE_COARSE_RADIUS`] once shrunk; 1
/// otherwise, and for a mask (`mask`: its search has a gate of its own).
pub(crate) fn big_picture_factor(o: &DetectOptions, pixels: f64, mask: bool) -> usize {
    let big = !mask && pixels > BIG_PICTURE_PIXELS;
    if big && o.radius_min >= 2.0 * BIG_PICTURE_COARSE_RADIUS {
        2
    } else {
        1
    }
}

/// Pictures bigger than this [pixels] are big: a 21-megapixel photograph of
/// disks under ~96 px, searched shrunk to radii of 32–64 px, is still
/// 5 megapixels, where voting, refining every candidate and searching the
/// rim mask took 6 of its 7.7 s of CPU (`wc-slope-a`; docs/image.md, "Big
/// photographs"). The issue's time targets: 2 s under 4 megapixels, 5 s at
/// 21.
pub(crate) const BIG_PICTURE_PIXELS: f64 = 4.0e6;

/// The smallest radius [px] a big picture is searched at: about the
/// radius the monochrome dark field `wc-slope-a` is searched at in its own
/// 1-megapixel photograph (15–29 px), where its disks are found.
pub(crate) const BIG_PICTURE_COARSE_RADIUS: f64 = 16.0;

/// Candidates for big disks (a 21-megapixel photograph): the voting and the
/// background split run on the image shrunk by `factor` (block means), where
/// their buffers and time fall by factor²; the refinement and judging that
/// follow are the full-resolution ones. Returns the candidates in full
/// resolution pixels and the edge smoothing.
pub(crate) fn coarse_candidates(
    image: &FloatImage,
    o: &DetectOptions,
    signs: &[f64],
    factor: usize,
    noise: f64,
) -> Result<(Vec<Candidate>, f64)> {
    let mut laps = super::profile::Laps::start();
    let f = factor as f64;
    let (w, h) = (image.width() as usize, image.height() as usize);
    let pixels = image.as_raw();
    let coarse = downsample(w, h, factor, |k| pixels[k]);
    let sigma = o.smoothing();
    // The same smoothing as at full resolution, in the shrunk image's pixels.
    let smooth = gaussian_blur(&coarse, sigma / f);
    drop(coarse);
    laps.lap("coarse: shrink and smooth");
    let edge_sigma = o
        .edge_smoothing_px
        .unwrap_or_else(|| edge_smoothing_for_noise(noise, &smooth, sigma));
    check_smoothing(sigma, edge_sigma)?;
    let coarse_options = shrunk_options(o, f);
    laps.lap("coarse: edge smoothing from noise");
    let accumulator = vote(&smooth, &coarse_options, signs);
    laps.lap("coarse: vote");
    let mut candidates = peaks(&accumulator, &coarse_options);
    drop(accumulator);
    for &s in signs {
        candidates.extend(distance_peaks(&smooth, s, &coarse_options));
    }
    laps.lap("coarse: peaks and distance peaks");
    let full = |v: f64| f * v + 0.5 * (f - 1.0);
    let candidates = candidates
        .into_iter()
        .map(|(x, y, r)| (full(x), full(y), f * r))
        .collect();
    Ok((candidates, edge_sigma))
}

/// The options for the image shrunk by `f`: radii and smoothing in its pixels.
pub(crate) fn shrunk_options(o: &DetectOptions, f: f64) -> DetectOptions {
    let mut shrunk = o.clone();
    shrunk.radius_min = o.radius_min / f;
    shrunk.radius_max = o.radius_max / f;
    shrunk.smoothing_px = Some(o.smoothing() / f);
    shrunk.edge_smoothing_px = o.edge_smoothing_px.map(|s| s / f);
    shrunk.find_by_rims = false;
    shrunk
}

/// Bright disks found in the image shrunk by `f`, refined at full resolution
/// in a window of the full image (`pixel(x, y)`, `size` px) smoothed by σ; a
/// disk whose refinement fails or wanders off keeps its scaled circle.
pub(crate) fn refine_scaled(
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
pub(crate) fn downsample(
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

/// The smallest radius [px] the defaults search at: a picture of smaller
/// disks is searched up-sampled by an integer factor to at least this
/// radius, and the circles scaled back. The search's rules in pixels (the
/// smoothing's floor of 1.5 px, the edge windows, the 32 rays of a small
/// disk) then meet small disks at the scale where they were measured (the
/// support's tolerance stays one photograph's pixel: `sensor_pixel`): 12 px is the smallest radius the photographs
/// here are found at in their own pixels (`wc-slope-b`, radii 12–24 px,
/// 383 of 384), and at half size (radii 6–15 px) they lost 17–30 % of
/// their disks (docs/image.md, round 12).
pub(crate) const SMALL_DISK_RADIUS: f64 = 12.0;

/// An up-sampled picture holds at most this many pixels (64 MB of floats);
/// a bigger one is searched at its own size.
const UPSAMPLED_PIXELS: f64 = 16.0e6;

/// By how much a picture of `pixels` is up-sampled for the search: the
/// least integer that brings `radius_min` to [`SMALL_DISK_RADIUS`], or 1.
pub(crate) fn small_disk_factor(radius_min: f64, pixels: f64) -> usize {
    if radius_min.is_nan() || radius_min <= 0.0 || radius_min >= SMALL_DISK_RADIUS {
        return 1;
    }
    let k = (SMALL_DISK_RADIUS / radius_min).ceil();
    if pixels * k * k > UPSAMPLED_PIXELS {
        1
    } else {
        k as usize
    }
}

/// An image of `w` × `h` pixels (`value(k)` for pixel k in row-major order)
/// up-sampled by `factor` with Keys' cubic convolution (a = −½, Catmull–Rom,
/// which reproduces a linear ramp exactly, so no edge moves; edges of the
/// picture extended): pixel (J, I) is the picture's point
/// ((J + ½)/f − ½, (I + ½)/f − ½). Cubic, not bilinear: on the half-size
/// `wc-slope` photographs bilinear up-sampling kept 7–15 disks fewer
/// (measured with OpenCV's two resizes).
pub(crate) fn upsample(
    w: usize,
    h: usize,
    factor: usize,
    value: impl Fn(usize) -> f32 + Sync,
) -> FloatImage {
    // Each output offset's four source taps and weights (the same for
    // every block of `factor` pixels).
    let taps: Vec<(isize, [f32; 4])> = (0..factor)
        .map(|p| {
            let t = (p as f64 + 0.5) / factor as f64 - 0.5;
            let base = t.floor();
            let u = t - base;
            (base as isize, keys_weights(u))
        })
        .collect();
    let (uw, uh) = (w * factor, h * factor);
    let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as usize;
    // Rows first: each source row up-sampled along x.
    let rows: Vec<f32> = (0..h)
        .into_par_iter()
        .flat_map_iter(|i| {
            let taps = &taps;
            let value = &value;
            (0..uw).map(move |x| {
                let (base, weights) = taps[x % factor];
                let j0 = (x / factor) as isize + base;
                (0..4)
                    .map(|t| weights[t] * value(i * w + clamp(j0 - 1 + t as isize, w)))
                    .sum::<f32>()
            })
        })
        .collect();
    let mut out = vec![0f32; uw * uh];
    out.par_chunks_mut(uw).enumerate().for_each(|(y, line)| {
        let (base, weights) = taps[y % factor];
        let i0 = (y / factor) as isize + base;
        for (t, &wt) in weights.iter().enumerate() {
            let src = &rows[clamp(i0 - 1 + t as isize, h) * uw..][..uw];
            for (o, &v) in line.iter_mut().zip(src) {
                *o += wt * v;
            }
        }
    });
    FloatImage::from_raw(uw as u32, uh as u32, out).expect("sized")
}

/// Keys' cubic convolution weights (a = −½) of the taps at −1, 0, 1, 2
/// for a point `u` ∈ [0, 1) past tap 0.
fn keys_weights(u: f64) -> [f32; 4] {
    const A: f64 = -0.5;
    let near = |x: f64| ((A + 2.0) * x - (A + 3.0)) * x * x + 1.0;
    let far = |x: f64| ((A * x - 5.0 * A) * x + 8.0 * A) * x - 4.0 * A;
    [far(1.0 + u), near(u), near(1.0 - u), far(2.0 - u)].map(|v| v as f32)
}

/// An image around a point (to `reach` px, clipped to the image) smoothed by
/// σ, with a margin so that the smoothing inside `reach` matches the whole
/// image's.
pub(crate) struct SmoothedWindow {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The up-sampled picture keeps the pixel centres where they were: a
    /// ramp in x and y (which cubic convolution reproduces exactly away from
    /// the edges) is the same ramp at the points ((J + ½)/f − ½, …).
    #[test]
    fn upsampling_keeps_the_pixel_centres() {
        let (w, h) = (9, 7);
        let ramp = |x: f64, y: f64| 0.1 + 0.05 * x + 0.02 * y;
        let value = |k: usize| ramp((k % w) as f64, (k / w) as f64) as f32;
        for f in [2usize, 3] {
            let big = upsample(w, h, f, value);
            assert_eq!(big.dimensions(), ((w * f) as u32, (h * f) as u32));
            let back = |v: u32| (v as f64 + 0.5) / f as f64 - 0.5;
            for y in 2 * f as u32..(h as u32 - 2) * f as u32 {
                for x in 2 * f as u32..(w as u32 - 2) * f as u32 {
                    let got = big.get_pixel(x, y)[0] as f64;
                    assert!((got - ramp(back(x), back(y))).abs() < 1e-5, "{f}: {x}, {y}");
                }
            }
        }
        let flat = upsample(5, 4, 3, |_| 0.25);
        assert!(flat.pixels().all(|p| (p[0] - 0.25).abs() < 1e-6));
    }

    /// Disks under 12 px are searched up-sampled to 12 px or more, unless
    /// the up-sampled picture would be too big.
    #[test]
    fn small_disks_are_searched_up_sampled() {
        assert_eq!(small_disk_factor(12.0, 1.0e6), 1);
        assert_eq!(small_disk_factor(7.0, 1.0e6), 2);
        assert_eq!(small_disk_factor(6.0, 1.0e6), 2);
        assert_eq!(small_disk_factor(5.0, 1.0e6), 3);
        assert_eq!(small_disk_factor(7.0, 5.0e6), 1);
    }

    /// Only a big picture of disks that stay 16 px or more once shrunk is
    /// searched at half size; smaller pictures, smaller disks and rim masks
    /// are searched as before, and big disks by their own rule.
    #[test]
    fn big_pictures_are_searched_at_half_size() {
        let (half_of_21_mp, under_4_mp) = (2292.0 * 2292.0, 1999.0 * 1999.0);
        let small_disks = DetectOptions::new(34.0, 67.0);
        assert_eq!(pyramid_factor(&small_disks, half_of_21_mp, false), 2);
        assert_eq!(pyramid_factor(&small_disks, under_4_mp, false), 1);
        assert_eq!(pyramid_factor(&small_disks, half_of_21_mp, true), 1);
        let smaller = DetectOptions::new(30.0, 60.0);
        assert_eq!(pyramid_factor(&smaller, half_of_21_mp, false), 1);
        let big_disks = DetectOptions::new(110.0, 135.0);
        assert_eq!(pyramid_factor(&big_disks, 21.0e6, false), 2);
        assert_eq!(pyramid_factor(&big_disks, under_4_mp, true), 2);
    }
}
