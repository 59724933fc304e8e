//! Candidate centres: phase-coded Hough voting and the distance to the
//! background.

use super::options::DetectOptions;
use super::Candidate;
use crate::image::FloatImage;
use rayon::prelude::*;

pub(crate) struct Accumulator {
    /// Magnitude of the phase-coded votes.
    pub(crate) data: Vec<f32>,
    /// Radius encoded in the votes' phase, per cell.
    pub(crate) radius: Vec<f32>,
    pub(crate) w: usize,
    pub(crate) h: usize,
    /// Accumulator cell (i, j) is the centre (j − pad, i − pad) in pixels.
    pub(crate) pad: usize,
}

/// Sobel kernels (imageproc's) as f32, scaled to an intensity change per pixel.
pub(crate) fn sobel(image: &FloatImage) -> (FloatImage, FloatImage) {
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
pub(crate) fn vote(smooth: &FloatImage, o: &DetectOptions, signs: &[f64]) -> Accumulator {
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
pub(crate) fn peaks(acc: &Accumulator, o: &DetectOptions) -> Vec<Candidate> {
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
pub(crate) fn distance_peaks(smooth: &FloatImage, sign: f64, o: &DetectOptions) -> Vec<Candidate> {
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

/// The votes at the centre of a whole disk of the smallest radius, drawn
/// with value 1 on 0 and smoothed as `o` says: a scale for the votes of a
/// binary mask's regions. The smoothed edge peaks just inside the radius,
/// where no votes are cast, so a disk 10 % bigger gets about twice these
/// (`rim_mask_gate_passes_disks_not_specks`: 2.19 at 22 px for 20..30).
pub(crate) fn whole_disk_votes(o: &DetectOptions) -> f32 {
    let sigma = o.smoothing();
    let r = o.radius_min;
    let half = (r + 4.0 * sigma).ceil() as u32 + 4;
    let size = 2 * half + 1;
    let centre = half as f64;
    let disk = FloatImage::from_fn(size, size, |x, y| {
        let inside = (x as f64 - centre).hypot(y as f64 - centre) <= r;
        ::image::Luma([if inside { 1.0 } else { 0.0 }])
    });
    let smooth = super::filters::gaussian_blur(&disk, sigma);
    let accumulator = vote(&smooth, o, &[1.0]);
    accumulator.data.iter().fold(0f32, |m, &v| m.max(v))
}
