//! Draws a 2D scene as a photoelastic experiment photographs it, so that
//! detection can be tested on real-like pictures with known answers: disks
//! with a dark rim (refraction at the edge), isochromatic fringes from their
//! contact forces in a circular polariscope, dim unloaded disks, uneven
//! lighting, colour (each channel has its own wavelength), blur and noise.
//!
//! Stress in a disk ([`disk_stress`]): the sum of Flamant point-load
//! solutions, σ = −2 (F·e) / (π ρ) e⊗e for a force F (per unit thickness) at
//! boundary point q, e = (p − q)/ρ, plus the uniform tension Σ F_n / (2πR)
//! that frees the circular boundary of traction when the loads balance
//! (F_n the compressive normal component). The isotropic term does not change
//! σ₁ − σ₂, which is all the fringes show. Intensity: I = sin²(π N),
//! N = (σ₁ − σ₂)/f_σ with f_σ the stress of one fringe order (the fringe
//! constant over the thickness). Loads can be spread over a contact patch
//! (`patch_px`), so that a fit with point loads meets model error. Deterministic
//! by seed.

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
    /// Half-width of each contact's loaded patch [px]: the force is spread
    /// over that arc with a Hertzian (elliptic) pressure; 0 for point loads.
    pub patch_px: f64,
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
            patch_px: 0.0,
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
        && [o.rim_px, o.blur_px, o.noise, o.margin_px, o.patch_px]
            .iter()
            .all(|v| *v >= 0.0)
        && (0.0..1.0).contains(&o.uneven_lighting)
        && (1..=16).contains(&o.supersample);
    if !valid {
        return Err(Error::Invalid(
            "photoelastic rendering: scale and fringe stress must be positive, rim, blur, noise, margin and patch not negative, lighting variation below 1, 1–16 samples per axis".into(),
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
    let patch = o.patch_px / o.px_per_m;
    for (c, f) in scene.contacts.iter().zip(forces) {
        let q = [c.point[0], c.point[1]];
        spread_load(&mut disks[c.a], q, *f, patch);
        if let Body::Grain(b) = c.b {
            spread_load(&mut disks[b], q, [-f[0], -f[1]], patch);
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

/// Adds the force `f` at contact point `q` to a disk's loads: at the point
/// of its boundary nearest `q`, or spread over an arc of half-width `patch`
/// [m] with an elliptic (Hertzian) weight, in 9 parts of the same direction.
fn spread_load(disk: &mut LoadedDisk, q: [f64; 2], f: [f64; 2], patch: f64) {
    let d = [q[0] - disk.centre[0], q[1] - disk.centre[1]];
    let angle = d[1].atan2(d[0]);
    let at = |a: f64| {
        [
            disk.centre[0] + disk.radius * a.cos(),
            disk.centre[1] + disk.radius * a.sin(),
        ]
    };
    if patch <= 0.0 {
        disk.loads.push((at(angle), f));
        return;
    }
    const PARTS: usize = 9;
    let half = (patch / disk.radius).min(0.5);
    let weights: Vec<f64> = (0..PARTS)
        .map(|k| {
            let s = (k as f64 + 0.5) / PARTS as f64 * 2.0 - 1.0;
            (1.0 - s * s).sqrt()
        })
        .collect();
    let total: f64 = weights.iter().sum();
    for (k, w) in weights.iter().enumerate() {
        let s = (k as f64 + 0.5) / PARTS as f64 * 2.0 - 1.0;
        let share = w / total;
        disk.loads
            .push((at(angle + s * half), [f[0] * share, f[1] * share]));
    }
}

/// The stress [Pa, tension positive: σ_xx, σ_yy, σ_xy] at `p` in a disk of
/// radius `radius` [m] centred at `centre`, loaded at points of its boundary
/// by forces per unit thickness [N/m] (`(point, force on the disk)`): the
/// Flamant solution of each load plus the uniform tension Σ F_n / (2πR),
/// F_n = −F·n the compressive normal part (n the outward normal at the
/// load). For a balanced load set the boundary is then free of traction
/// (diametral compression by F: σ_xx = F/(πR), σ_yy = −3F/(πR) at the
/// centre, i.e. 2F/(πD) and −6F/(πD) per unit thickness). Points within
/// 10⁻³ R of a load are evaluated at that distance.
pub fn disk_stress(
    centre: [f64; 2],
    radius: f64,
    loads: &[([f64; 2], [f64; 2])],
    p: [f64; 2],
) -> [f64; 3] {
    use std::f64::consts::PI;
    let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
    let mut compression = 0.0;
    for (q, f) in loads {
        let e = [p[0] - q[0], p[1] - q[1]];
        let r = e[0].hypot(e[1]).max(1e-3 * radius);
        let e = [e[0] / r, e[1] / r];
        let radial = -2.0 * (f[0] * e[0] + f[1] * e[1]) / (PI * r);
        sxx += radial * e[0] * e[0];
        syy += radial * e[1] * e[1];
        sxy += radial * e[0] * e[1];
        let n = [q[0] - centre[0], q[1] - centre[1]];
        let len = n[0].hypot(n[1]);
        if len > 0.0 {
            compression -= (f[0] * n[0] + f[1] * n[1]) / len;
        }
    }
    let isotropic = compression / (2.0 * PI * radius);
    [sxx + isotropic, syy + isotropic, sxy]
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
        let [sxx, syy, sxy] = disk_stress(d.centre, d.radius, &d.loads, p);
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;
    use std::f64::consts::PI;

    const CENTRE: [f64; 2] = [0.3, -0.2];

    fn on_circle(radius: f64, angle: f64) -> [f64; 2] {
        [
            CENTRE[0] + radius * angle.cos(),
            CENTRE[1] + radius * angle.sin(),
        ]
    }

    /// Diametral compression by F along y: at the centre σ_xx = 2F/(πD) and
    /// σ_yy = −6F/(πD) (Frocht; per unit thickness), at any scale.
    #[test]
    fn diametral_compression_centre_stresses() {
        for (radius, force) in [(0.02, 150.0), (1e-4, 3e-3), (40.0, 7e5)] {
            let loads = [
                (on_circle(radius, PI / 2.0), [0.0, -force]),
                (on_circle(radius, -PI / 2.0), [0.0, force]),
            ];
            let s = disk_stress(CENTRE, radius, &loads, CENTRE);
            let d = 2.0 * radius;
            let scale = force / (PI * d);
            assert!((s[0] - 2.0 * scale).abs() < 1e-12 * scale, "{s:?}");
            assert!((s[1] + 6.0 * scale).abs() < 1e-12 * scale, "{s:?}");
            assert!(s[2].abs() < 1e-12 * scale, "{s:?}");
            // Along the loaded diameter σ_xx stays the uniform tension 2F/(πD).
            let p = [CENTRE[0], CENTRE[1] + 0.5 * radius];
            let s = disk_stress(CENTRE, radius, &loads, p);
            assert!((s[0] - 2.0 * scale).abs() < 1e-12 * scale, "{s:?}");
        }
    }

    /// Any balanced set of loads (normal and tangential parts, here 6 random
    /// ones) leaves the circular boundary free of traction between the loads;
    /// with the isotropic term at Σ F_n/(πR) instead of /(2πR) it would not be.
    #[test]
    fn balanced_loads_leave_the_boundary_traction_free() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for trial in 0..20 {
            let radius = 10f64.powf(rng.gen_range(-4.0..1.0));
            let mut angles: Vec<f64> = (0..6).map(|_| rng.gen_range(0.0..2.0 * PI)).collect();
            let mut forces: Vec<[f64; 2]> = (0..4)
                .map(|_| [rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)])
                .collect();
            // The last two loads balance the first four (least-norm solution
            // of the three equilibrium equations).
            let arm = |a: f64| [radius * a.cos(), radius * a.sin()];
            let (mut fx, mut fy, mut m) = (0.0, 0.0, 0.0);
            for (a, f) in angles.iter().zip(&forces) {
                let r = arm(*a);
                fx += f[0];
                fy += f[1];
                m += r[0] * f[1] - r[1] * f[0];
            }
            let (r5, r6) = (arm(angles[4]), arm(angles[5]));
            let k = nalgebra::Matrix3x4::new(
                1.0, 0.0, 1.0, 0.0, //
                0.0, 1.0, 0.0, 1.0, //
                -r5[1], r5[0], -r6[1], r6[0],
            );
            let rhs = nalgebra::Vector3::new(-fx, -fy, -m);
            let g = k.transpose() * (k * k.transpose()).try_inverse().unwrap() * rhs;
            forces.push([g[0], g[1]]);
            forces.push([g[2], g[3]]);
            let loads: Vec<_> = angles
                .iter()
                .zip(&forces)
                .map(|(a, f)| (on_circle(radius, *a), *f))
                .collect();
            let scale: f64 = forces.iter().map(|f| f[0].hypot(f[1])).sum::<f64>() / radius;
            angles.sort_by(f64::total_cmp);
            let mut checked = 0;
            for k in 0..360 {
                let t = k as f64 * PI / 180.0;
                let gap = angles
                    .iter()
                    .map(|a| ((t - a).rem_euclid(2.0 * PI)).min((a - t).rem_euclid(2.0 * PI)))
                    .fold(f64::INFINITY, f64::min);
                if gap < 0.05 {
                    continue;
                }
                let s = disk_stress(CENTRE, radius, &loads, on_circle(radius, t));
                let n = [t.cos(), t.sin()];
                let traction = [s[0] * n[0] + s[2] * n[1], s[2] * n[0] + s[1] * n[1]];
                assert!(
                    traction[0].hypot(traction[1]) < 1e-9 * scale,
                    "trial {trial}, angle {k}°: traction {traction:?} (scale {scale})"
                );
                checked += 1;
            }
            assert!(checked > 100);
        }
    }

    /// The isotropic term is Σ F_n / (2πR): one radial compressive load
    /// (unbalanced, so only this term is checked) adds F/(2πR) to both normal
    /// stresses; a tangential load adds nothing.
    #[test]
    fn isotropic_term_counts_compressive_normal_parts() {
        let radius = 0.05;
        let q = on_circle(radius, 0.3);
        let inward = [-(0.3f64).cos(), -(0.3f64).sin()];
        let tangent = [-(0.3f64).sin(), (0.3f64).cos()];
        let p = on_circle(0.5 * radius, 2.0);
        let flamant = |f: [f64; 2]| {
            let e = [p[0] - q[0], p[1] - q[1]];
            let r = e[0].hypot(e[1]);
            let e = [e[0] / r, e[1] / r];
            let radial = -2.0 * (f[0] * e[0] + f[1] * e[1]) / (PI * r);
            [
                radial * e[0] * e[0],
                radial * e[1] * e[1],
                radial * e[0] * e[1],
            ]
        };
        let force = 12.0;
        let f = [force * inward[0], force * inward[1]];
        let s = disk_stress(CENTRE, radius, &[(q, f)], p);
        let expected = force / (2.0 * PI * radius);
        let plain = flamant(f);
        for k in 0..2 {
            assert!((s[k] - plain[k] - expected).abs() < 1e-9 * expected);
        }
        let f = [force * tangent[0], force * tangent[1]];
        let s = disk_stress(CENTRE, radius, &[(q, f)], p);
        let plain = flamant(f);
        for k in 0..3 {
            assert!((s[k] - plain[k]).abs() < 1e-9 * expected);
        }
    }

    /// A contact patch spreads the load: far from the contact the fringes are
    /// those of the point load, near it the stress is much lower.
    #[test]
    fn a_contact_patch_softens_only_the_near_field() {
        let radius = 0.02;
        let mut point = LoadedDisk {
            centre: CENTRE,
            radius,
            loads: Vec::new(),
        };
        let mut patch = LoadedDisk {
            centre: CENTRE,
            radius,
            loads: Vec::new(),
        };
        for (angle, f) in [(PI / 2.0, [0.0, -100.0]), (-PI / 2.0, [0.0, 100.0])] {
            spread_load(&mut point, on_circle(radius, angle), f, 0.0);
            spread_load(&mut patch, on_circle(radius, angle), f, 0.1 * radius);
        }
        assert_eq!(patch.loads.len(), 18);
        let difference = |d: &LoadedDisk, p| {
            let s = disk_stress(d.centre, d.radius, &d.loads, p);
            ((s[0] - s[1]).powi(2) + 4.0 * s[2] * s[2]).sqrt()
        };
        let far = on_circle(0.3 * radius, 0.4);
        let (a, b) = (difference(&point, far), difference(&patch, far));
        assert!((a - b).abs() < 0.01 * a, "{a} vs {b}");
        let near = on_circle(0.98 * radius, PI / 2.0);
        let (a, b) = (difference(&point, near), difference(&patch, near));
        assert!(b < 0.5 * a, "{a} vs {b}");
    }
}
