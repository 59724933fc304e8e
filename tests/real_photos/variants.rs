//! Real photographs changed in memory as another camera or light would have
//! taken them: upscaled (a bigger sensor: disks of radius 100–200 px), under
//! red light, under orange backlight. Shared by `tests/image_real_photos.rs`
//! and `examples/real_photo_variants.rs`.

use image::{imageops, RgbImage};

/// The photograph resized by `factor` (bilinear, as a camera's resampling):
/// a point (x, y) of the original (0-based pixel centres) is at
/// ((x + 0.5) f − 0.5, (y + 0.5) f − 0.5).
pub fn upscaled(photo: &RgbImage, factor: f64) -> RgbImage {
    let w = (photo.width() as f64 * factor).round() as u32;
    let h = (photo.height() as f64 * factor).round() as u32;
    imageops::resize(photo, w, h, imageops::FilterType::Triangle)
}

/// Where a 0-based pixel coordinate of the original lands after [`upscaled`].
pub fn scaled_coordinate(v: f64, original: u32, resized: u32) -> f64 {
    let f = resized as f64 / original as f64;
    (v + 0.5) * f - 0.5
}

/// The photograph as under monochromatic light of the given colour (RGB
/// gains in [0, 1]): every channel shows the red channel's structure (the
/// fringes a polariscope gives in one wavelength), scaled by the light's
/// colour, with the sensor's noise (Gaussian, `noise` of full scale, from a
/// fixed seed) on top. Red light: gains (1, 0.04, 0.02), green and blue a few
/// per cent; orange backlight: (1, 0.55, 0.08).
pub fn lit(photo: &RgbImage, gains: [f32; 3], noise: f32, seed: u64) -> RgbImage {
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut uniform = move || {
        // xorshift64*: deterministic, no dependency.
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f32 / (1u64 << 53) as f32
    };
    let mut gauss = move || {
        let (u, v) = (uniform().max(1e-12), uniform());
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    };
    let mut out = RgbImage::new(photo.width(), photo.height());
    for (o, p) in out.pixels_mut().zip(photo.pixels()) {
        let v = p[0] as f32 / 255.0;
        for c in 0..3 {
            let x = v * gains[c] + noise * gauss();
            o[c] = (255.0 * x).round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

/// Red light (the DSLR photograph's): green and blue a few per cent.
pub const RED_LIGHT: [f32; 3] = [1.0, 0.04, 0.02];
/// Orange backlight (the video frame's).
pub const ORANGE_LIGHT: [f32; 3] = [1.0, 0.55, 0.08];
