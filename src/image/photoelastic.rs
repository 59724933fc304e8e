//! Draws a 2D scene as a photoelastic experiment photographs it, so that
//! detection can be tested on real-like pictures with known answers: disks
//! with a dark rim (refraction at the edge), isochromatic fringes from their
//! contact forces in a circular polariscope, dim unloaded disks, uneven
//! lighting, colour (each channel has its own wavelength), blur and noise.
//!
//! Stress in a disk: the sum of Flamant point-load solutions, σ = −2 (F·e) /
//! (π ρ) e⊗e for a force F at contact point q, e = (p − q)/ρ; the isotropic
//! term that frees the boundary of traction does not change σ₁ − σ₂, which is
//! all the fringes show. Intensity: I = sin²(π N), N = (σ₁ − σ₂)/f_σ with
//! f_σ the stress of one fringe order. Deterministic by seed.

use super::PixelFrame;
use crate::error::{Error, Result};
use crate::scene::{Body, Scene};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

/// A colour image with intensities in [0, 1] per channel.
pub type RgbFloatImage = ::image::Rgb32FImage;

#[derive(Debug, Clone)]
pub struct PhotoelasticOptions {
    /// Image scale [pixels per metre].
    pub px_per_m: f64,
    /// Stress difference σ₁ − σ₂ of one fringe order in green light [Pa]
    /// (the material's fringe constant over the thickness).
    pub fringe_stress: f64,
    /// Width of the dark rim inside each disk's edge [px].
    pub rim_px: f64,
    /// Background, rim, unloaded-disk and brightest-fringe intensities.
    pub background: f32,
    pub rim: f32,
    pub unloaded: f32,
    pub fringe: f32,
    /// Lighting: intensities are multiplied by a smooth field that varies by
    /// about this fraction across the image (a gradient and a vignette).
    pub uneven_lighting: f64,
    /// Gaussian blur of the optics [px]; 0 for none.
    pub blur_px: f64,
    /// Standard deviation of additive Gaussian pixel noise.
    pub noise: f64,
    /// Samples per pixel along each axis (pixel integration).
    pub supersample: u32,
    /// Free border around the grains [px] when the frame is chosen automatically.
    pub margin_px: f64,
    pub frame: Option<PixelFrame>,
    pub seed: u64,
}

impl PhotoelasticOptions {
    pub fn new(px_per_m: f64, fringe_stress: f64) -> Self {
        PhotoelasticOptions {
            px_per_m,
            fringe_stress,
            rim_px: 3.0,
            background: 0.12,
            rim: 0.03,
            unloaded: 0.25,
            fringe: 0.95,
            uneven_lighting: 0.0,
            blur_px: 0.0,
            noise: 0.0,
            supersample: 3,
            margin_px: 20.0,
            frame: None,
            seed: 1,
        }
    }
}

/// Wavelengths of the red, green and blue channels relative to green: the
/// fringe order in a channel is N_green / ratio.
const WAVELENGTH_RATIO: [f64; 3] = [650.0 / 540.0, 1.0, 460.0 / 540.0];

struct LoadedDisk {
    centre: [f64; 2],
    radius: f64,
    /// Contact points [m] and the force on this disk there [N per unit thickness].
    loads: Vec<([f64; 2], [f64; 2])>,
}

/// Compressive contact forces for a rendered photograph [N/m]: magnitudes
/// exponentially distributed with mean `mean` (at least 0.05 `mean`), except
/// that one contact in five is nearly unloaded (< 0.05 `mean`: its disks stay
/// almost dark), as in a real packing. Each force acts on grain `a`, against
/// its outward normal. Reproducible from `seed`.
pub fn sample_contact_forces(scene: &Scene, mean: f64, seed: u64) -> Vec<[f64; 2]> {
    use rand::Rng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    scene
        .contacts
        .iter()
        .map(|c| {
            let magnitude = if rng.gen_bool(0.2) {
                rng.gen_range(0.0..0.05)
            } else {
                -rng.gen_range(0.0f64..1.0).ln().max(0.05)
            } * mean;
            [-magnitude * c.normal[0], -magnitude * c.normal[1]]
        })
        .collect()
}

/// Renders `scene` with the given force per contact (the force on grain `a`
/// by `b`, scene axes, as in forces.csv). Returns the colour image and its frame.
pub fn render_photoelastic(
    scene: &Scene,
    forces: &[[f64; 2]],
    options: &PhotoelasticOptions,
) -> Result<(RgbFloatImage, PixelFrame)> {
    let o = options;
    if scene.dim != 2 || scene.grains.is_empty() {
        return Err(Error::Invalid(
            "a photoelastic image needs a 2D scene with grains".into(),
        ));
    }
    if forces.len() != scene.contacts.len() {
        return Err(Error::Invalid(format!(
            "{} forces given for {} contacts",
            forces.len(),
            scene.contacts.len()
        )));
    }
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let valid = positive(o.px_per_m)
        && positive(o.fringe_stress)
        && [o.rim_px, o.blur_px, o.noise, o.margin_px]
            .iter()
            .all(|v| *v >= 0.0)
        && (0.0..1.0).contains(&o.uneven_lighting)
        && (1..=16).contains(&o.supersample);
    if !valid {
        return Err(Error::Invalid(
            "photoelastic rendering: scale and fringe stress must be positive, rim, blur, noise and margin not negative, lighting variation below 1, 1–16 samples per axis".into(),
        ));
    }
    let mut disks: Vec<LoadedDisk> = scene
        .grains
        .iter()
        .map(|g| LoadedDisk {
            centre: [g.position[0], g.position[1]],
            radius: g.equivalent_radius(2),
            loads: Vec::new(),
        })
        .collect();
    for (c, f) in scene.contacts.iter().zip(forces) {
        let q = [c.point[0], c.point[1]];
        disks[c.a].loads.push((q, *f));
        if let Body::Grain(b) = c.b {
            disks[b].loads.push((q, [-f[0], -f[1]]));
        }
    }
    let frame = match o.frame {
        Some(f) => f,
        None => {
            let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            for d in &disks {
                for k in 0..2 {
                    lo[k] = lo[k].min(d.centre[k] - d.radius);
                    hi[k] = hi[k].max(d.centre[k] + d.radius);
                }
            }
            PixelFrame::around(lo, hi, o.px_per_m, o.margin_px)?
        }
    };
    let (w, h) = (frame.width as usize, frame.height as usize);
    // Disks near each pixel row band, so a pixel tests only a few.
    let band = 16usize;
    let bands: Vec<Vec<usize>> = (0..h.div_ceil(band))
        .map(|k| {
            let (top, bottom) = ((k * band) as f64 - 1.0, ((k + 1) * band) as f64 + 1.0);
            (0..disks.len())
                .filter(|&i| {
                    let c = frame.to_pixel(disks[i].centre);
                    let r = disks[i].radius * frame.px_per_m;
                    c[1] + r >= top && c[1] - r <= bottom
                })
                .collect()
        })
        .collect();
    let ss = o.supersample as usize;
    let mut data = vec![0f32; 3 * w * h];
    data.par_chunks_mut(3 * w)
        .enumerate()
        .for_each(|(row, out)| {
            let nearby = &bands[row / band];
            for col in 0..w {
                let mut sum = [0.0f64; 3];
                for a in 0..ss {
                    for b in 0..ss {
                        let x = col as f64 + (b as f64 + 0.5) / ss as f64 - 0.5;
                        let y = row as f64 + (a as f64 + 0.5) / ss as f64 - 0.5;
                        let v = sample(&disks, nearby, &frame, o, [x, y]);
                        for k in 0..3 {
                            sum[k] += v[k];
                        }
                    }
                }
                let light = lighting(
                    o.uneven_lighting,
                    col as f64 / w as f64,
                    row as f64 / h as f64,
                );
                for k in 0..3 {
                    out[3 * col + k] = (light * sum[k] / (ss * ss) as f64) as f32;
                }
            }
        });
    let mut image = RgbFloatImage::from_raw(frame.width, frame.height, data).expect("sized");
    if o.blur_px > 0.0 {
        image = imageproc::filter::gaussian_blur_f32(&image, o.blur_px as f32);
    }
    if o.noise > 0.0 {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(o.seed);
        let normal = Normal::new(0.0, o.noise).expect("finite σ");
        for v in image.iter_mut() {
            *v += normal.sample(&mut rng) as f32;
        }
    }
    for v in image.iter_mut() {
        *v = v.clamp(0.0, 1.0);
    }
    Ok((image, frame))
}

/// Illumination at relative image position (u, v) ∈ [0, 1]²: brighter on one
/// side, darker in the corners, with a total spread of about `amount`.
fn lighting(amount: f64, u: f64, v: f64) -> f64 {
    let (du, dv) = (u - 0.5, v - 0.5);
    1.0 + amount * (0.6 * du + 0.3 * dv - 0.8 * (du * du + dv * dv))
}

fn sample(
    disks: &[LoadedDisk],
    nearby: &[usize],
    frame: &PixelFrame,
    o: &PhotoelasticOptions,
    px: [f64; 2],
) -> [f64; 3] {
    let p = frame.to_scene(px);
    let rim = o.rim_px / frame.px_per_m;
    for &i in nearby {
        let d = &disks[i];
        let rho = (p[0] - d.centre[0]).hypot(p[1] - d.centre[1]);
        if rho > d.radius {
            continue;
        }
        if rho > d.radius - rim {
            return [o.rim as f64; 3];
        }
        let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
        for (q, f) in &d.loads {
            let e = [p[0] - q[0], p[1] - q[1]];
            let r = e[0].hypot(e[1]).max(1e-3 * d.radius);
            let e = [e[0] / r, e[1] / r];
            let radial = -2.0 * (f[0] * e[0] + f[1] * e[1]) / (std::f64::consts::PI * r);
            sxx += radial * e[0] * e[0];
            syy += radial * e[1] * e[1];
            sxy += radial * e[0] * e[1];
        }
        let difference = ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt();
        let order = difference / o.fringe_stress;
        let mut out = [0.0; 3];
        for k in 0..3 {
            let s = (std::f64::consts::PI * order / WAVELENGTH_RATIO[k]).sin();
            out[k] = o.unloaded as f64 + (o.fringe - o.unloaded) as f64 * s * s;
        }
        return out;
    }
    [o.background as f64; 3]
}

/// Writes a colour image as an 8-bit RGB JPEG at the given quality (1–100),
/// as a camera would.
pub fn save_jpeg(path: &std::path::Path, image: &RgbFloatImage, quality: u8) -> Result<()> {
    use ::image::ImageEncoder;
    let bytes: Vec<u8> = image
        .as_raw()
        .iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    ::image::codecs::jpeg::JpegEncoder::new_with_quality(
        std::io::BufWriter::new(file),
        quality.clamp(1, 100),
    )
    .write_image(
        &bytes,
        image.width(),
        image.height(),
        ::image::ExtendedColorType::Rgb8,
    )
    .map_err(|e| Error::data(path, None, None, format!("cannot write JPEG: {e}")))
}
