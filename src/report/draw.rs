//! Anti-aliased drawing primitives on an RGB image, by coverage from exact
//! distances (thick segments with round caps, rings, disks). Shared by charts and
//! force-chain pictures; coordinates are in pixels, y downwards, and anything
//! outside the image is clipped.

use image::{Rgb, RgbImage};

/// Blends `color` into the pixel at (x, y) with weight `alpha` ∈ [0, 1].
pub(crate) fn blend(img: &mut RgbImage, x: i64, y: i64, color: Rgb<u8>, alpha: f64) {
    if alpha <= 0.0 || x < 0 || y < 0 || x >= img.width() as i64 || y >= img.height() as i64 {
        return;
    }
    let a = alpha.min(1.0);
    let p = img.get_pixel_mut(x as u32, y as u32);
    for k in 0..3 {
        let v = p.0[k] as f64 * (1.0 - a) + color.0[k] as f64 * a;
        p.0[k] = v.round().clamp(0.0, 255.0) as u8;
    }
}

/// Pixel range [lo, hi] covering [a, b] clipped to [0, size).
fn span(a: f64, b: f64, size: u32) -> Option<(i64, i64)> {
    if !(a.is_finite() && b.is_finite()) {
        return None;
    }
    let lo = a.floor().max(0.0);
    let hi = b.ceil().min(size as f64 - 1.0);
    (lo <= hi).then_some((lo as i64, hi as i64))
}

/// A segment from p to q of the given width (round caps). Widths below one pixel
/// are drawn one pixel wide but fainter, so hairlines stay visible.
pub(crate) fn thick_line(
    img: &mut RgbImage,
    p: (f64, f64),
    q: (f64, f64),
    width: f64,
    color: Rgb<u8>,
) {
    let (half, strength) = if width >= 1.0 {
        (width / 2.0, 1.0)
    } else {
        (0.5, width.max(0.0))
    };
    let pad = half + 1.0;
    let Some((x0, x1)) = span(p.0.min(q.0) - pad, p.0.max(q.0) + pad, img.width()) else {
        return;
    };
    let Some((y0, y1)) = span(p.1.min(q.1) - pad, p.1.max(q.1) + pad, img.height()) else {
        return;
    };
    let (dx, dy) = (q.0 - p.0, q.1 - p.1);
    let len2 = dx * dx + dy * dy;
    for y in y0..=y1 {
        for x in x0..=x1 {
            // Pixel centre at +0.5.
            let (cx, cy) = (x as f64 + 0.5 - p.0, y as f64 + 0.5 - p.1);
            let t = if len2 > 0.0 {
                ((cx * dx + cy * dy) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (ex, ey) = (cx - t * dx, cy - t * dy);
            let d = (ex * ex + ey * ey).sqrt();
            let coverage = (half + 0.5 - d).clamp(0.0, 1.0);
            blend(img, x, y, color, coverage * strength);
        }
    }
}

/// A circle outline of radius r (to the middle of the stroke) and stroke width w.
pub fn ring(img: &mut RgbImage, c: (f64, f64), r: f64, width: f64, color: Rgb<u8>) {
    let half = width.max(1.0) / 2.0;
    let pad = r + half + 1.0;
    let Some((x0, x1)) = span(c.0 - pad, c.0 + pad, img.width()) else {
        return;
    };
    let Some((y0, y1)) = span(c.1 - pad, c.1 + pad, img.height()) else {
        return;
    };
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = ((x as f64 + 0.5 - c.0).powi(2) + (y as f64 + 0.5 - c.1).powi(2)).sqrt();
            blend(
                img,
                x,
                y,
                color,
                (half + 0.5 - (d - r).abs()).clamp(0.0, 1.0),
            );
        }
    }
}

/// A filled disk of radius r.
pub fn disk(img: &mut RgbImage, c: (f64, f64), r: f64, color: Rgb<u8>) {
    let pad = r + 1.0;
    let Some((x0, x1)) = span(c.0 - pad, c.0 + pad, img.width()) else {
        return;
    };
    let Some((y0, y1)) = span(c.1 - pad, c.1 + pad, img.height()) else {
        return;
    };
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = ((x as f64 + 0.5 - c.0).powi(2) + (y as f64 + 0.5 - c.1).powi(2)).sqrt();
            blend(img, x, y, color, (r + 0.5 - d).clamp(0.0, 1.0));
        }
    }
}

/// A filled axis-aligned rectangle [x0, x1) × [y0, y1) in whole pixels.
pub(crate) fn fill_rect(img: &mut RgbImage, x0: i64, y0: i64, x1: i64, y1: i64, color: Rgb<u8>) {
    for y in y0.max(0)..y1.min(img.height() as i64) {
        for x in x0.max(0)..x1.min(img.width() as i64) {
            img.put_pixel(x as u32, y as u32, color);
        }
    }
}

/// A one-pixel rectangle outline around [x0, x1) × [y0, y1).
pub(crate) fn rect_outline(img: &mut RgbImage, x0: i64, y0: i64, x1: i64, y1: i64, color: Rgb<u8>) {
    fill_rect(img, x0, y0, x1, y0 + 1, color);
    fill_rect(img, x0, y1 - 1, x1, y1, color);
    fill_rect(img, x0, y0, x0 + 1, y1, color);
    fill_rect(img, x1 - 1, y0, x1, y1, color);
}

/// Perceptual colour maps by linear interpolation between matplotlib's values
/// at ninths of the range (close approximations, not the exact tables).
pub mod colormap {
    use image::Rgb;

    const INFERNO: [[u8; 3]; 10] = [
        [0, 0, 4],
        [27, 12, 65],
        [74, 12, 107],
        [120, 28, 109],
        [165, 44, 96],
        [207, 68, 70],
        [237, 105, 37],
        [251, 155, 6],
        [247, 209, 61],
        [252, 255, 164],
    ];

    const VIRIDIS: [[u8; 3]; 10] = [
        [68, 1, 84],
        [72, 40, 120],
        [62, 74, 137],
        [49, 104, 142],
        [38, 130, 142],
        [31, 158, 137],
        [53, 183, 121],
        [110, 206, 88],
        [181, 222, 43],
        [253, 231, 37],
    ];

    fn sample(table: &[[u8; 3]; 10], t: f64) -> Rgb<u8> {
        let t = if t.is_finite() {
            t.clamp(0.0, 1.0)
        } else {
            0.0
        };
        let x = t * 9.0;
        let i = (x.floor() as usize).min(8);
        let f = x - i as f64;
        let mut c = [0u8; 3];
        for k in 0..3 {
            let v = table[i][k] as f64 * (1.0 - f) + table[i + 1][k] as f64 * f;
            c[k] = v.round() as u8;
        }
        Rgb(c)
    }

    /// inferno(t), t ∈ [0, 1] from black through purple and orange to pale yellow.
    pub(crate) fn inferno(t: f64) -> Rgb<u8> {
        sample(&INFERNO, t)
    }

    /// viridis(t), t ∈ [0, 1] from dark purple through teal to yellow.
    pub fn viridis(t: f64) -> Rgb<u8> {
        sample(&VIRIDIS, t)
    }
}
