//! Image filters of the search: Gaussian smoothing and the noise estimate.

use crate::image::FloatImage;
use rayon::prelude::*;

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
pub(crate) fn edge_smoothing_for_noise(noise: f64, smooth: &FloatImage, vote_sigma: f64) -> f64 {
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
pub(crate) fn gaussian_blur_map<T: Copy + Default + Send>(
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

pub(crate) fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 2;
    *v.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}

/// How much of the light the median disk passes a circle must pass to be a
/// disk where the backlight is brighter than the disks (a bright field). A
/// photoelastic disk is transparent: loaded or not, tinted or not, its
/// interior passes a good part of the light (the darkest real disks of
/// docs/image.md pass 0.36 of their packing's median); a circle fitted to an
/// opaque object beside the packing (a clamp, a bolt, a piston's shadow)
/// passes almost none (0.036–0.05 on `jl-video181`'s clamp).
pub(crate) const OPAQUE_FRACTION: f64 = 0.15;

/// An opaque circle touching this many transparent disks is a grain of the
/// packing (two: it can carry a force across), not an object beside it
/// (`jl-video181`'s clamp circles touch 0, 0 and 1).
pub(crate) const OPAQUE_NEIGHBOURS: usize = 2;

/// The disks without the circles on opaque objects beside the packing: in a
/// bright field (the background's level above the disks' median), a circle
/// whose interior (its inner 0.8 R, the median of `signal`) is darker than
/// [`OPAQUE_FRACTION`] of the disks' median interior blocks the backlight
/// and is no photoelastic disk, unless it sits in the packing (touches
/// [`OPAQUE_NEIGHBOURS`] transparent disks or more: an opaque grain, an
/// intruder, carries force like the others). In a dark field nothing is
/// dropped: there unloaded disks are as dark as an opaque object. Returns
/// the kept disks (in their order) and the number dropped.
pub(crate) fn without_opaque(
    signal: &FloatImage,
    disks: Vec<super::Disk>,
    background: f64,
) -> (Vec<super::Disk>, usize) {
    let plane = super::Plane::whole(signal);
    let interiors: Vec<Option<f64>> = disks
        .par_iter()
        .map(|d| super::refine::interior_median(&plane, [d.x, d.y], 0.8 * d.r))
        .collect();
    let mut known: Vec<f64> = interiors.iter().flatten().copied().collect();
    if known.is_empty() {
        return (disks, 0);
    }
    let typical = median(&mut known);
    if !(background > typical && typical > 0.0) {
        return (disks, 0);
    }
    let opaque: Vec<bool> = interiors
        .iter()
        .map(|m| m.is_some_and(|m| m < OPAQUE_FRACTION * typical))
        .collect();
    // Outlines within a fifth of the smaller radius: touching, as the
    // contacts' widest search counts it.
    let touches = |a: &super::Disk, b: &super::Disk| {
        (a.x - b.x).hypot(a.y - b.y) - a.r - b.r <= 0.2 * a.r.min(b.r)
    };
    let in_packing = |k: usize| {
        (disks.iter().zip(&opaque))
            .filter(|&(d, &o)| !o && touches(d, &disks[k]))
            .count()
            >= OPAQUE_NEIGHBOURS
    };
    let keep: Vec<bool> = (0..disks.len())
        .map(|k| !opaque[k] || in_packing(k))
        .collect();
    let before = disks.len();
    let kept: Vec<super::Disk> = disks
        .into_iter()
        .zip(keep)
        .filter(|&(_, k)| k)
        .map(|(d, _)| d)
        .collect();
    let dropped = before - kept.len();
    (kept, dropped)
}
