//! Draws a 2D scene as a camera would see it: speckle-patterned disks on a dark
//! background, each disk deformed by the homogeneous strain its stress implies
//! (isotropic elasticity), plus the matching undeformed reference image.
//!
//! The speckle is a smooth random texture fixed to the material: a pixel at x
//! shows the texture at X = F⁻¹(x − c) in the disk's reference frame, with
//! F = I + ε. Pixels integrate the scene over their area (supersampling), so
//! edges are antialiased and sub-pixel centres are honest. Deterministic by seed.

use super::elastic::Elasticity;
use super::{FloatImage, PixelFrame};
use crate::error::{Error, Result};
use crate::scene::{sym, Scene};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use rayon::prelude::*;

#[derive(Debug, Clone)]
pub struct RenderOptions {
    /// Image scale [pixels per metre].
    pub px_per_m: f64,
    /// Material law that turns each grain's stress into its strain.
    pub elasticity: Elasticity,
    /// Speckle feature size [px] (the texture's correlation length).
    pub speckle_px: f64,
    /// Background intensity in [0, 1].
    pub background: f32,
    /// Mean intensity of the disks and the half-range of their speckle.
    pub disk_mean: f32,
    pub speckle_amplitude: f32,
    /// Gaussian blur of the optics [px]; 0 for none.
    pub blur_px: f64,
    /// Standard deviation of additive Gaussian pixel noise, in intensity units.
    pub noise: f64,
    /// Samples per pixel along each axis (pixel integration).
    pub supersample: u32,
    /// Free border around the grains [px] when the frame is chosen automatically.
    pub margin_px: f64,
    /// A fixed frame (size and placement); chosen from the grains when `None`.
    pub frame: Option<PixelFrame>,
    pub seed: u64,
}

impl RenderOptions {
    pub fn new(px_per_m: f64, elasticity: Elasticity) -> Self {
        RenderOptions {
            px_per_m,
            elasticity,
            speckle_px: 6.0,
            background: 0.1,
            disk_mean: 0.6,
            speckle_amplitude: 0.3,
            blur_px: 0.0,
            noise: 0.0,
            supersample: 3,
            margin_px: 20.0,
            frame: None,
            seed: 1,
        }
    }
}

/// The undeformed reference image and the deformed (loaded) image of one scene,
/// and where they sit in the scene.
#[derive(Debug, Clone)]
pub struct RenderedPair {
    pub reference: FloatImage,
    pub deformed: FloatImage,
    pub frame: PixelFrame,
}

/// The reference image (the first frame, unloaded) and one deformed image per frame.
#[derive(Debug, Clone)]
pub struct RenderedSequence {
    pub reference: FloatImage,
    pub deformed: Vec<FloatImage>,
    pub frame: PixelFrame,
}

/// Renders one scene: reference (undeformed disks at the scene's centres) and
/// deformed image (each disk strained by its stress).
pub fn render_scene(scene: &Scene, options: &RenderOptions) -> Result<RenderedPair> {
    let mut seq = render_sequence(std::slice::from_ref(scene), options)?;
    Ok(RenderedPair {
        reference: seq.reference,
        deformed: seq.deformed.remove(0),
        frame: seq.frame,
    })
}

/// Renders the frames of a sequence in one common pixel frame. The reference
/// is the first frame without strain; a grain keeps its speckle (keyed by its
/// id) in every frame.
pub fn render_sequence(frames: &[Scene], options: &RenderOptions) -> Result<RenderedSequence> {
    validate(options)?;
    let Some(first) = frames.first() else {
        return Err(Error::Invalid("no frames to render".into()));
    };
    for scene in frames {
        if scene.dim != 2 {
            return Err(Error::Invalid(
                "only 2D scenes (disks and cylinders) can be rendered".into(),
            ));
        }
        if scene.grains.is_empty() {
            return Err(Error::Invalid("the scene has no grains to render".into()));
        }
    }
    let frame = match options.frame {
        Some(f) => f,
        None => auto_frame(frames, options)?,
    };
    let texture = Texture::new(options.seed);
    let reference = draw(
        &grains_in_pixels(first, &frame, options, false)?,
        &frame,
        &texture,
        options,
        0,
    );
    let deformed = frames
        .iter()
        .enumerate()
        .map(|(k, scene)| {
            let grains = grains_in_pixels(scene, &frame, options, true)?;
            Ok(draw(&grains, &frame, &texture, options, k as u64 + 1))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(RenderedSequence {
        reference,
        deformed,
        frame,
    })
}

fn validate(o: &RenderOptions) -> Result<()> {
    let positive = |v: f64, what: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(Error::Invalid(format!("{what} must be positive, not {v}")))
        }
    };
    positive(o.px_per_m, "the image scale (pixels per metre)")?;
    positive(o.speckle_px, "the speckle size")?;
    if !(o.blur_px >= 0.0 && o.noise >= 0.0 && o.margin_px >= 0.0) {
        return Err(Error::Invalid(
            "blur, noise and margin must not be negative".into(),
        ));
    }
    if o.supersample == 0 || o.supersample > 16 {
        return Err(Error::Invalid(format!(
            "supersampling must be 1 to 16 samples per axis, not {}",
            o.supersample
        )));
    }
    Ok(())
}

fn auto_frame(frames: &[Scene], o: &RenderOptions) -> Result<PixelFrame> {
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for scene in frames {
        for g in &scene.grains {
            let r = g.equivalent_radius(2);
            for k in 0..2 {
                lo[k] = lo[k].min(g.position[k] - r);
                hi[k] = hi[k].max(g.position[k] + r);
            }
        }
    }
    PixelFrame::around(lo, hi, o.px_per_m, o.margin_px)
}

/// A disk as drawn: centre and radius in pixels, the inverse deformation
/// gradient (pixel axes) and its texture placement.
struct PixelGrain {
    centre: [f64; 2],
    radius: f64,
    /// Bounding radius of the deformed disk.
    reach: f64,
    inverse: [[f64; 2]; 2],
    texture_offset: [f64; 2],
    texture_rotation: (f64, f64),
}

fn grains_in_pixels(
    scene: &Scene,
    frame: &PixelFrame,
    o: &RenderOptions,
    deformed: bool,
) -> Result<Vec<PixelGrain>> {
    let s = frame.px_per_m;
    scene
        .grains
        .iter()
        .map(|g| {
            let radius = g.equivalent_radius(2) * s;
            if !(radius.is_finite() && radius > 0.0) {
                return Err(Error::Invalid(format!(
                    "grain {} has no positive radius to draw",
                    g.id
                )));
            }
            let c = frame.to_pixel([g.position[0], g.position[1]]);
            let strain = if deformed {
                let st = [g.stress[sym::XX], g.stress[sym::YY], g.stress[sym::XY]];
                o.elasticity.strain_from_stress(st)
            } else {
                [0.0; 3]
            };
            let largest = strain.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if largest > 0.2 {
                return Err(Error::Invalid(format!(
                    "grain {}: its stress implies a strain of {largest:.3}, too large for small-strain elasticity (check E)",
                    g.id
                )));
            }
            // Pixel y points down, so the shear component changes sign.
            let f = [[1.0 + strain[0], -strain[2]], [-strain[2], 1.0 + strain[1]]];
            let det = f[0][0] * f[1][1] - f[0][1] * f[1][0];
            let inverse = [
                [f[1][1] / det, -f[0][1] / det],
                [-f[1][0] / det, f[0][0] / det],
            ];
            let key = fnv1a(g.id.as_bytes()) ^ o.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let h1 = splitmix(key);
            let h2 = splitmix(h1);
            let h3 = splitmix(h2);
            let angle = unit(h3) * std::f64::consts::TAU;
            Ok(PixelGrain {
                centre: c,
                radius,
                reach: radius * (1.0 + 2.0 * largest) + 1.0,
                inverse,
                texture_offset: [unit(h1) * 4096.0, unit(h2) * 4096.0],
                texture_rotation: (angle.cos(), angle.sin()),
            })
        })
        .collect()
}

/// Draws grains into a new image: area-integrated intensities, then optical
/// blur, then noise (seeded per image so reference and deformed noise differ).
fn draw(
    grains: &[PixelGrain],
    frame: &PixelFrame,
    texture: &Texture,
    o: &RenderOptions,
    image_index: u64,
) -> FloatImage {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let grid = Grid::new(grains, w, h);
    let ss = o.supersample as usize;
    let mut data = vec![0f32; w * h];
    data.par_chunks_mut(w).enumerate().for_each(|(row, out)| {
        for (col, value) in out.iter_mut().enumerate() {
            let candidates = grid.at(col as f64, row as f64);
            let mut sum = 0.0;
            for a in 0..ss {
                for b in 0..ss {
                    let x = col as f64 + (b as f64 + 0.5) / ss as f64 - 0.5;
                    let y = row as f64 + (a as f64 + 0.5) / ss as f64 - 0.5;
                    sum += sample(grains, candidates, texture, o, x, y);
                }
            }
            *value = (sum / (ss * ss) as f64) as f32;
        }
    });
    let mut image = FloatImage::from_raw(frame.width, frame.height, data).expect("sized");
    if o.blur_px > 0.0 {
        image = imageproc::filter::gaussian_blur_f32(&image, o.blur_px as f32);
    }
    if o.noise > 0.0 {
        let mut rng =
            rand_chacha::ChaCha8Rng::seed_from_u64(splitmix(o.seed ^ (image_index << 32)));
        let normal = Normal::new(0.0, o.noise).expect("finite σ");
        for v in image.iter_mut() {
            *v += normal.sample(&mut rng) as f32;
        }
    }
    for v in image.iter_mut() {
        *v = v.clamp(0.0, 1.0);
    }
    image
}

/// Intensity of the scene at a point: the texture of the disk covering it
/// (the one whose boundary is farthest, where disks overlap), else background.
fn sample(
    grains: &[PixelGrain],
    candidates: &[u32],
    texture: &Texture,
    o: &RenderOptions,
    x: f64,
    y: f64,
) -> f64 {
    let mut best: Option<(f64, usize, [f64; 2])> = None;
    for &k in candidates {
        let g = &grains[k as usize];
        let d = [x - g.centre[0], y - g.centre[1]];
        if d[0].abs() > g.reach || d[1].abs() > g.reach {
            continue;
        }
        let m = &g.inverse;
        let material = [
            m[0][0] * d[0] + m[0][1] * d[1],
            m[1][0] * d[0] + m[1][1] * d[1],
        ];
        let rho = (material[0] * material[0] + material[1] * material[1]).sqrt() / g.radius;
        if rho <= 1.0 && best.is_none_or(|(b, _, _)| rho < b) {
            best = Some((rho, k as usize, material));
        }
    }
    match best {
        None => o.background as f64,
        Some((_, k, material)) => {
            let g = &grains[k];
            let (c, s) = g.texture_rotation;
            let u = (c * material[0] - s * material[1]) / o.speckle_px + g.texture_offset[0];
            let v = (s * material[0] + c * material[1]) / o.speckle_px + g.texture_offset[1];
            let n = texture.noise(u, v) + 0.5 * texture.noise(2.0 * u + 0.37, 2.0 * v + 0.71);
            o.disk_mean as f64 + o.speckle_amplitude as f64 * (4.0 * n).tanh()
        }
    }
}

/// Uniform grid of grain indices, so each pixel tests only nearby disks.
struct Grid {
    cell: f64,
    columns: usize,
    rows: usize,
    cells: Vec<Vec<u32>>,
}

impl Grid {
    fn new(grains: &[PixelGrain], w: usize, h: usize) -> Self {
        let largest = grains.iter().fold(1.0f64, |m, g| m.max(g.reach));
        let cell = (2.0 * largest).max(8.0);
        let columns = (w as f64 / cell).ceil() as usize + 1;
        let rows = (h as f64 / cell).ceil() as usize + 1;
        let mut cells = vec![Vec::new(); columns * rows];
        for (k, g) in grains.iter().enumerate() {
            let clamp_col = |v: f64| ((v / cell).floor().max(0.0) as usize).min(columns - 1);
            let clamp_row = |v: f64| ((v / cell).floor().max(0.0) as usize).min(rows - 1);
            // Pixels (and their sub-samples) reach half a pixel beyond their centre.
            let (c0, c1) = (
                clamp_col(g.centre[0] - g.reach - 1.0),
                clamp_col(g.centre[0] + g.reach + 1.0),
            );
            let (r0, r1) = (
                clamp_row(g.centre[1] - g.reach - 1.0),
                clamp_row(g.centre[1] + g.reach + 1.0),
            );
            if g.centre[0] + g.reach < -1.0 || g.centre[1] + g.reach < -1.0 {
                continue;
            }
            for r in r0..=r1 {
                for c in c0..=c1 {
                    cells[r * columns + c].push(k as u32);
                }
            }
        }
        Grid {
            cell,
            columns,
            rows,
            cells,
        }
    }

    fn at(&self, x: f64, y: f64) -> &[u32] {
        let c = ((x / self.cell).floor().max(0.0) as usize).min(self.columns - 1);
        let r = ((y / self.cell).floor().max(0.0) as usize).min(self.rows - 1);
        &self.cells[r * self.columns + c]
    }
}

/// Gradient (Perlin) noise: smooth (C² fade), zero at lattice points, roughly
/// in [−0.7, 0.7], feature size one lattice cell.
struct Texture {
    gradients: [[f64; 2]; 256],
    seed: u64,
}

impl Texture {
    fn new(seed: u64) -> Self {
        let mut gradients = [[0.0; 2]; 256];
        for (k, g) in gradients.iter_mut().enumerate() {
            let a = (k as f64 + 0.5) / 256.0 * std::f64::consts::TAU;
            *g = [a.cos(), a.sin()];
        }
        Texture { gradients, seed }
    }

    fn corner(&self, ix: i64, iy: i64, dx: f64, dy: f64) -> f64 {
        let h = splitmix((ix as u64).wrapping_mul(0x8CB9_2BA7_2F3D_8DD7) ^ (iy as u64) ^ self.seed);
        let g = self.gradients[(h & 255) as usize];
        g[0] * dx + g[1] * dy
    }

    fn noise(&self, x: f64, y: f64) -> f64 {
        let (fx, fy) = (x.floor(), y.floor());
        let (ix, iy) = (fx as i64, fy as i64);
        let (dx, dy) = (x - fx, y - fy);
        let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
        let (u, v) = (fade(dx), fade(dy));
        let n00 = self.corner(ix, iy, dx, dy);
        let n10 = self.corner(ix + 1, iy, dx - 1.0, dy);
        let n01 = self.corner(ix, iy + 1, dx, dy - 1.0);
        let n11 = self.corner(ix + 1, iy + 1, dx - 1.0, dy - 1.0);
        let a = n00 + u * (n10 - n00);
        let b = n01 + u * (n11 - n01);
        a + v * (b - a)
    }
}

fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// A stable hash (FNV-1a), so a grain's speckle depends only on its id and the seed.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3)
    })
}
