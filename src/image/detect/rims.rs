//! Dim disks: the regions that dark rims enclose, found whatever the disks'
//! interior intensity.

use super::detect_disks_in_mask;
use super::filters::{gaussian_blur_map, median, noise_level};
use super::options::{DetectOptions, Disk};
use super::pyramid::{downsample, refine_scaled, shrunk_options};
use crate::image::FloatImage;

/// Radius [px] at which the filled rim mask is searched. Its regions have
/// sharp edges, so they are found at a smaller radius than the intensity
/// search's [`COARSE_RADIUS`](super::pyramid::COARSE_RADIUS) and then
/// refined at full resolution. On the 21-megapixel hopper (radii 110–135 px)
/// shrinking by 3 instead of 2 gives the same disks (centres within 3e-4 R)
/// and contacts, and the mask search's CPU time falls from 1.5 to 0.7 s;
/// shrinking by 4 (radius 27) lost a disk and 4 contacts. `tests/image_photo.rs`
/// (`big_disks_searched_in_a_shrunk_image`, radii from 100 px) shrinks by 3.
const MASK_RADIUS: f64 = 33.0;

/// By how much the rim mask is shrunk: as much as [`MASK_RADIUS`] allows,
/// and never less than the intensity search's `factor`.
fn mask_factor(o: &DetectOptions, factor: usize) -> usize {
    ((o.radius_min / MASK_RADIUS).floor() as usize).max(factor)
}

/// [`add_rim_enclosed`] for big images: the rims are marked at full
/// resolution (one byte a pixel: they are too thin to survive shrinking), the
/// enclosed regions searched in the mask shrunk (see [`mask_factor`]), and
/// each region found refined at full resolution in a window of the mask.
pub(crate) fn add_rim_enclosed_coarse(
    image: &FloatImage,
    o: &DetectOptions,
    found: Vec<Disk>,
    factor: usize,
    noise: f64,
) -> Vec<Disk> {
    let mut laps = super::profile::Laps::start();
    let factor = mask_factor(o, factor);
    let f = factor as f64;
    let (w, h) = (image.width() as usize, image.height() as usize);
    let enclosed = rim_enclosed(image, noise);
    laps.lap("rims: mark and flood (full resolution)");
    let filled = downsample(w, h, factor, |k| if enclosed[k] { 1.0 } else { 0.0 });
    let Ok(coarse) = detect_disks_in_mask(&filled, &shrunk_options(o, f)) else {
        return found;
    };
    drop(filled);
    laps.lap("rims: search the shrunk mask");
    // The filled regions have sharp edges: the least smoothing places them.
    let value = |x: usize, y: usize| if enclosed[y * w + x] { 1.0 } else { 0.0 };
    let rim_disks = refine_scaled(&coarse, f, o, 1.0, value, (w, h));
    laps.lap(&format!("rims: refine {} at full resolution", coarse.len()));
    with_rim_disks(found, rim_disks, o)
}

/// Adds the disks outlined by a dark rim that the intensity search missed:
/// the rims (thin dark lines: the black top-hat of the lightly smoothed image,
/// above the noise) are marked, the regions they enclose filled, and the
/// filled picture searched for bright disks. A disk found both ways gives the
/// offset between the two radii (the filled one reaches the rim's outer
/// edge); new disks are brought to the intensity search's radius by its
/// median, and kept only where they cross no disk already found.
pub(crate) fn add_rim_enclosed(
    image: &FloatImage,
    o: &DetectOptions,
    found: Vec<Disk>,
) -> Vec<Disk> {
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
    let Ok(enclosed) = detect_disks_in_mask(&filled, &search) else {
        return found;
    };
    with_rim_disks(found, enclosed, o)
}

/// Which pixels a dark rim encloses (or belong to one): the rims are the
/// pixels of the image smoothed by 1 px whose black top-hat (a 4 px disk as
/// structuring element) exceeds 0.03 and four times the noise (σ `noise` of
/// the raw pixels); the background is flooded in from the image border, and
/// whatever it cannot reach is enclosed. One byte a pixel.
pub(crate) fn rim_enclosed(image: &FloatImage, noise: f64) -> Vec<bool> {
    use ::image::GrayImage;
    use imageproc::morphology::{grayscale_close, Mask};
    let (w, h) = (image.width() as usize, image.height() as usize);
    let gray = GrayImage::from_raw(
        w as u32,
        h as u32,
        gaussian_blur_map(image, 1.0, |v| (v.clamp(0.0, 1.0) * 255.0).round() as u8),
    )
    .expect("sized");
    let mut laps = super::profile::Laps::start();
    let closed = grayscale_close(&gray, &Mask::disk(4));
    laps.lap("rims: black top-hat (grayscale close)");
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
pub(crate) fn with_rim_disks(
    found: Vec<Disk>,
    enclosed: Vec<Disk>,
    o: &DetectOptions,
) -> Vec<Disk> {
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
