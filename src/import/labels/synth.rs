//! Test volumes with known contacts: a sphere packing (e.g. from the DEM)
//! voxelised, optionally turned into clumps (non-spherical grains), and
//! optionally passed through a simulated segmentation; plus the scoring of a
//! label import against the true contacts. Tests and the measurements in
//! `docs/tomography.md` use it.
//!
//! The simulated segmentation: grey = each voxel's solid fraction (4³
//! sub-samples near surfaces), Gaussian blur, Gaussian noise, threshold at
//! half the solid grey, then a marker-controlled watershed on the Euclidean
//! distance transform of the thresholded solid (6-connected priority flood).
//! The markers are balls at the true sphere centres — an oracle for the
//! marker step (real pipelines take h-maxima of the distance map), so over-
//! and under-segmentation are not simulated; everything else (necks bridged
//! by blur, near misses merged, boundaries moved by noise) is.

use super::LabelScene;
use crate::scene::{self, Body, Scene, Vec3};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// A grain: a union of spheres (centre, radius) [m], cut by half-spaces
/// (unit normal n, offset d: the grain keeps the points with n·x ≤ d).
#[derive(Debug, Clone, PartialEq)]
pub struct SynthGrain {
    pub spheres: Vec<(Vec3, f64)>,
    pub cuts: Vec<(Vec3, f64)>,
}

/// A true contact between grains `a` and `b` (indices; labels are index + 1),
/// normal from a to b.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueContact {
    pub a: usize,
    pub b: usize,
    pub point: Vec3,
    pub normal: Vec3,
}

/// A voxel grid: voxel `[z][y][x]` centred at `origin + voxel·(x, y, z)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub origin: Vec3,
    pub voxel: f64,
    /// `[nz, ny, nx]`.
    pub shape: [usize; 3],
}

impl Grid {
    /// The grid covering the grains with `margin` voxels around them.
    pub fn around(grains: &[SynthGrain], voxel: f64, margin: f64) -> Grid {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for g in grains {
            for (c, r) in &g.spheres {
                for k in 0..3 {
                    lo[k] = lo[k].min(c[k] - r);
                    hi[k] = hi[k].max(c[k] + r);
                }
            }
        }
        let origin = lo.map(|x| x - margin * voxel);
        let n = |k: usize| ((hi[k] - lo[k]) / voxel + 2.0 * margin).ceil() as usize + 1;
        Grid {
            origin,
            voxel,
            shape: [n(2), n(1), n(0)],
        }
    }

    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn centre(&self, x: usize, y: usize, z: usize) -> Vec3 {
        [
            self.origin[0] + self.voxel * x as f64,
            self.origin[1] + self.voxel * y as f64,
            self.origin[2] + self.voxel * z as f64,
        ]
    }

    /// Index range along axis k (0 = x) covering [lo, hi] metres.
    fn range(&self, k: usize, lo: f64, hi: f64) -> std::ops::Range<usize> {
        let n = self.shape[2 - k];
        let a = ((lo - self.origin[k]) / self.voxel).floor().max(0.0) as usize;
        let b = (((hi - self.origin[k]) / self.voxel).ceil() + 1.0).max(0.0) as usize;
        a.min(n)..b.min(n)
    }
}

/// The grains and grain–grain contacts of a sphere scene (its `radius`
/// column); wall contacts are left out.
pub fn spheres_of(scene: &Scene) -> (Vec<SynthGrain>, Vec<TrueContact>) {
    let grains = scene
        .grains
        .iter()
        .map(|g| SynthGrain {
            spheres: vec![(g.position, g.equivalent_radius(3))],
            cuts: Vec::new(),
        })
        .collect();
    let contacts = scene
        .contacts
        .iter()
        .filter_map(|c| match c.b {
            Body::Grain(b) => Some(TrueContact {
                a: c.a,
                b,
                point: c.point,
                normal: c.normal,
            }),
            Body::Wall(_) => None,
        })
        .collect();
    (grains, contacts)
}

/// Every contact point of a scene with the grain it belongs to (a
/// grain–grain contact's point twice, once per grain): the `contact_points`
/// of [`clumps_of`].
pub fn contact_points(scene: &Scene) -> Vec<(usize, Vec3)> {
    scene
        .contacts
        .iter()
        .flat_map(|c| {
            let mut v = vec![(c.a, c.point)];
            if let Body::Grain(b) = c.b {
                v.push((b, c.point));
            }
            v
        })
        .collect()
}

/// Non-spherical grains from a sphere packing, with the same contacts: each
/// grain is cut flat on the side farthest from its contacts (the plane
/// max(`clearance`, 0.3 R) beyond its farthest-reaching contact point, at
/// least 0.2 R from the centre; no cut when it would remove less than a cap
/// of 0.2 R),
/// and gets a satellite sphere (radius `ratio`·R, centre 0.55 R out) in the
/// direction farthest from its contacts and the cut, shrunk until it clears
/// every other body and every contact point of the grain by `clearance`. The
/// true contacts are unchanged while the grains are no longer spheres and
/// their centroids are off their contact geometry. `contact_points` are all
/// contact points of the packing (walls included) with the grain they
/// belong to.
pub fn clumps_of(
    grains: &[SynthGrain],
    contact_points: &[(usize, Vec3)],
    ratio: f64,
    clearance: f64,
) -> Vec<SynthGrain> {
    let mut out = grains.to_vec();
    // Fibonacci directions.
    let dirs: Vec<Vec3> = (0..256)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / 256.0;
            let phi = i as f64 * std::f64::consts::PI * (3.0 - 5f64.sqrt());
            let r = (1.0 - z * z).sqrt();
            [r * phi.cos(), r * phi.sin(), z]
        })
        .collect();
    for i in 0..grains.len() {
        let (c, r) = grains[i].spheres[0];
        let mine: Vec<Vec3> = contact_points
            .iter()
            .filter(|(g, _)| *g == i)
            .filter_map(|(_, p)| unit(scene::sub(*p, c)))
            .collect();
        let best = dirs
            .iter()
            .max_by(|u, v| {
                let m = |d: &Vec3| {
                    mine.iter()
                        .map(|n| scene::dot(*n, *d))
                        .fold(-1.0_f64, f64::max)
                };
                m(v).total_cmp(&m(u))
            })
            .copied()
            .expect("directions");
        let reach = mine
            .iter()
            .map(|n| scene::dot(*n, best) * r)
            .fold(-r, f64::max);
        let offset = (reach + clearance.max(0.3 * r)).max(0.2 * r);
        if offset < 0.8 * r {
            out[i].cuts.push((best, scene::dot(best, c) + offset));
        }
        // The satellite opposite-ish: the direction farthest from the
        // contacts and from the cut.
        let mut avoid = mine.clone();
        avoid.push(best);
        let best = dirs
            .iter()
            .max_by(|u, v| {
                let m = |d: &Vec3| {
                    avoid
                        .iter()
                        .map(|n| scene::dot(*n, *d))
                        .fold(-1.0_f64, f64::max)
                };
                m(v).total_cmp(&m(u))
            })
            .copied()
            .expect("directions");
        let mut scale = 1.0;
        while scale > 0.55 {
            let rs = ratio * r * scale;
            let centre = [
                c[0] + 0.55 * r * best[0],
                c[1] + 0.55 * r * best[1],
                c[2] + 0.55 * r * best[2],
            ];
            let clear_of_bodies = out.iter().enumerate().all(|(j, g)| {
                j == i
                    || g.spheres
                        .iter()
                        .all(|(cj, rj)| scene::norm(scene::sub(*cj, centre)) >= rs + rj + clearance)
            });
            let clear_of_contacts = contact_points
                .iter()
                .filter(|(g, _)| *g == i)
                .all(|(_, p)| scene::norm(scene::sub(*p, centre)) >= rs + clearance);
            if clear_of_bodies && clear_of_contacts {
                out[i].spheres.push((centre, rs));
                break;
            }
            scale -= 0.05;
        }
    }
    out
}

fn unit(v: Vec3) -> Option<Vec3> {
    let l = scene::norm(v);
    (l > 0.0).then(|| v.map(|x| x / l))
}

/// How deep a point is inside a grain (> 0 inside), in metres.
fn depth(g: &SynthGrain, p: Vec3) -> f64 {
    let spheres = g
        .spheres
        .iter()
        .map(|(c, r)| r - scene::norm(scene::sub(p, *c)))
        .fold(f64::NEG_INFINITY, f64::max);
    g.cuts
        .iter()
        .map(|(n, d)| d - scene::dot(*n, p))
        .fold(spheres, f64::min)
}

/// Labels of the clean voxelisation (a voxel belongs to the grain its centre
/// is deepest in; label = grain index + 1) and each voxel's solid fraction.
pub fn voxelise(grains: &[SynthGrain], grid: &Grid) -> (Vec<u32>, Vec<f32>) {
    let [nz, ny, nx] = grid.shape;
    let mut labels = vec![0u32; grid.len()];
    let mut best = vec![f32::NEG_INFINITY; grid.len()];
    let mut fraction = vec![0f32; grid.len()];
    let half = 0.5 * 3f64.sqrt() * grid.voxel;
    for (i, g) in grains.iter().enumerate() {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for (c, r) in &g.spheres {
            for k in 0..3 {
                lo[k] = lo[k].min(c[k] - r - grid.voxel);
                hi[k] = hi[k].max(c[k] + r + grid.voxel);
            }
        }
        for z in grid.range(2, lo[2], hi[2]) {
            for y in grid.range(1, lo[1], hi[1]) {
                for x in grid.range(0, lo[0], hi[0]) {
                    let p = grid.centre(x, y, z);
                    let d = depth(g, p);
                    if d < -half {
                        continue;
                    }
                    let v = (z * ny + y) * nx + x;
                    if d > 0.0 && d as f32 > best[v] {
                        best[v] = d as f32;
                        labels[v] = i as u32 + 1;
                    }
                    let f = if d > half {
                        1.0
                    } else {
                        // 4³ sub-samples.
                        let mut inside = 0;
                        for a in 0..4 {
                            for b in 0..4 {
                                for c in 0..4 {
                                    let o = |k: usize| (k as f64 - 1.5) / 4.0 * grid.voxel;
                                    let q = [p[0] + o(a), p[1] + o(b), p[2] + o(c)];
                                    if depth(g, q) > 0.0 {
                                        inside += 1;
                                    }
                                }
                            }
                        }
                        inside as f32 / 64.0
                    };
                    fraction[v] = (fraction[v] + f).min(1.0);
                }
            }
        }
    }
    debug_assert!(nz * ny * nx == labels.len());
    (labels, fraction)
}

/// Gaussian blur (σ in voxels, separable, edges clamped).
pub fn blur(volume: &mut [f32], shape: [usize; 3], sigma: f64) {
    if sigma <= 0.0 {
        return;
    }
    let half = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-half..=half)
        .map(|i| (-(i as f64).powi(2) / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let [nz, ny, nx] = shape;
    let strides = [1, nx, nx * ny];
    let lens = [nx, ny, nz];
    let mut line = Vec::new();
    for axis in 0..3 {
        let (len, stride) = (lens[axis], strides[axis]);
        let others: Vec<usize> = (0..volume.len())
            .filter(|&v| (v / stride) % len == 0)
            .collect();
        for start in others {
            line.clear();
            line.extend((0..len).map(|i| volume[start + i * stride]));
            for i in 0..len {
                let mut s = 0.0;
                for (k, w) in kernel.iter().enumerate() {
                    let j = (i as isize + k as isize - half).clamp(0, len as isize - 1) as usize;
                    s += w * line[j];
                }
                volume[start + i * stride] = s;
            }
        }
    }
}

/// Squared Euclidean distance (voxels²) of each foreground voxel to the
/// nearest background voxel (Felzenszwalb–Huttenlocher, separable); the
/// volume's outside counts as background.
pub fn distance_transform(solid: &[bool], shape: [usize; 3]) -> Vec<f32> {
    let [nz, ny, nx] = shape;
    let big = ((nx + ny + nz) * (nx + ny + nz)) as f64;
    let mut d: Vec<f64> = solid.iter().map(|&s| if s { big } else { 0.0 }).collect();
    let strides = [1, nx, nx * ny];
    let lens = [nx, ny, nz];
    for axis in 0..3 {
        let (len, stride) = (lens[axis], strides[axis]);
        // Background just outside both ends.
        let n = len + 2;
        let mut f = vec![0.0; n];
        let mut out = vec![0.0; n];
        let mut v = vec![0usize; n];
        let mut z = vec![0.0; n + 1];
        for start in (0..d.len()).filter(|&i| (i / stride) % len == 0) {
            f[0] = 0.0;
            f[n - 1] = 0.0;
            for i in 0..len {
                f[i + 1] = d[start + i * stride];
            }
            lower_envelope(&f, &mut out, &mut v, &mut z);
            for i in 0..len {
                d[start + i * stride] = out[i + 1];
            }
        }
    }
    d.into_iter().map(|x| x as f32).collect()
}

/// 1D squared-distance transform of sampled function f.
fn lower_envelope(f: &[f64], out: &mut [f64], v: &mut [usize], z: &mut [f64]) {
    let n = f.len();
    let mut k = 0;
    v[0] = 0;
    z[0] = f64::NEG_INFINITY;
    z[1] = f64::INFINITY;
    for q in 1..n {
        loop {
            let p = v[k];
            let s = ((f[q] + (q * q) as f64) - (f[p] + (p * p) as f64)) / (2.0 * (q - p) as f64);
            if s <= z[k] && k > 0 {
                k -= 1;
            } else if s <= z[k] {
                v[0] = q;
                z[0] = f64::NEG_INFINITY;
                z[1] = f64::INFINITY;
                break;
            } else {
                k += 1;
                v[k] = q;
                z[k] = s;
                z[k + 1] = f64::INFINITY;
                break;
            }
        }
    }
    k = 0;
    for q in 0..n {
        while z[k + 1] < q as f64 {
            k += 1;
        }
        let p = v[k];
        out[q] = (q as f64 - p as f64).powi(2) + f[p];
    }
}

/// The simulated segmentation of a grey volume (solid ≈ 1, void ≈ 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segmentation {
    /// Gaussian blur σ [voxels] (the scanner's point spread).
    pub blur: f64,
    /// Standard deviation of the added noise, in units of the solid–void contrast.
    pub noise: f64,
    pub seed: u64,
}

impl Default for Segmentation {
    fn default() -> Self {
        Segmentation {
            blur: 1.0,
            noise: 0.1,
            seed: 1,
        }
    }
}

/// Blurs and noises the solid fraction into a grey image, thresholds it and
/// splits the solid by a marker watershed; returns (labels, grey).
pub fn segment(
    grains: &[SynthGrain],
    grid: &Grid,
    fraction: &[f32],
    settings: &Segmentation,
) -> (Vec<u32>, Vec<f32>) {
    let mut grey = fraction.to_vec();
    blur(&mut grey, grid.shape, settings.blur);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(settings.seed);
    if settings.noise > 0.0 {
        let normal = Normal::new(0.0, settings.noise).expect("finite noise");
        for g in grey.iter_mut() {
            *g += normal.sample(&mut rng) as f32;
        }
    }
    let solid: Vec<bool> = grey.iter().map(|&g| g >= 0.5).collect();
    let dist = distance_transform(&solid, grid.shape);
    let [nz, ny, nx] = grid.shape;
    let mut labels = vec![0u32; grid.len()];
    let mut heap = std::collections::BinaryHeap::new();
    let mut counter = 0u64;
    // Markers: balls of a third of each sphere's radius at its centre.
    for (i, g) in grains.iter().enumerate() {
        for (c, r) in &g.spheres {
            let rm = r / 3.0;
            for z in grid.range(2, c[2] - rm, c[2] + rm) {
                for y in grid.range(1, c[1] - rm, c[1] + rm) {
                    for x in grid.range(0, c[0] - rm, c[0] + rm) {
                        let v = (z * ny + y) * nx + x;
                        if solid[v] && scene::norm(scene::sub(grid.centre(x, y, z), *c)) <= rm {
                            labels[v] = i as u32 + 1;
                            heap.push((ordered(dist[v]), std::cmp::Reverse(counter), v));
                            counter += 1;
                        }
                    }
                }
            }
        }
    }
    // Flood from the markers, deepest first.
    while let Some((_, _, v)) = heap.pop() {
        let (x, y, z) = (v % nx, (v / nx) % ny, v / (nx * ny));
        let l = labels[v];
        let mut visit = |w: usize| {
            if solid[w] && labels[w] == 0 {
                labels[w] = l;
                heap.push((ordered(dist[w]), std::cmp::Reverse(counter), w));
                counter += 1;
            }
        };
        if x > 0 {
            visit(v - 1);
        }
        if x + 1 < nx {
            visit(v + 1);
        }
        if y > 0 {
            visit(v - nx);
        }
        if y + 1 < ny {
            visit(v + nx);
        }
        if z > 0 {
            visit(v - nx * ny);
        }
        if z + 1 < nz {
            visit(v + nx * ny);
        }
    }
    (labels, grey)
}

fn ordered(x: f32) -> u32 {
    // Non-negative floats order like their bits.
    x.max(0.0).to_bits()
}

/// Contact detection and normal accuracy against the truth.
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    pub true_contacts: usize,
    /// Zones kept (grain–grain).
    pub detected: usize,
    /// True contacts with a kept zone.
    pub found: usize,
    /// Kept zones that are a true contact (the largest zone of a true pair).
    pub correct: usize,
    /// Angle between the written normal and the truth, degrees, per found contact.
    pub angles: Vec<f64>,
    /// The same for the standard (PCA) normal.
    pub pca_angles: Vec<f64>,
    /// Distance of the written contact point from the truth [m].
    pub point_errors: Vec<f64>,
}

impl Score {
    pub fn recall(&self) -> f64 {
        self.found as f64 / self.true_contacts.max(1) as f64
    }

    pub fn precision(&self) -> f64 {
        self.correct as f64 / self.detected.max(1) as f64
    }
}

/// Quantile q (0…1) of the values (nearest rank; NaN when empty).
pub fn quantile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    v[i]
}

/// The true contacts as pairs of labels (index + 1), the lower first: the
/// key of a detected grain–grain contact (`a`, `Other::Grain(b)`).
pub fn true_pairs(truth: &[TrueContact]) -> std::collections::HashSet<(u32, u32)> {
    truth
        .iter()
        .map(|t| (t.a.min(t.b) as u32 + 1, t.a.max(t.b) as u32 + 1))
        .collect()
}

/// How far apart two grains' main spheres are, surface to surface [m]
/// (negative where they overlap): a DEM pair's true separation.
pub fn apart(a: &SynthGrain, b: &SynthGrain) -> f64 {
    let ((ca, ra), (cb, rb)) = (a.spheres[0], b.spheres[0]);
    scene::norm(scene::sub(ca, cb)) - ra - rb
}

/// The precision an unbiased Gaussian estimate of the gap with standard
/// deviation `sd` [voxels] would reach with the rule "keep a zone whose
/// estimate is at most z·sd above the contacts' level" (`z`: 2.33 loses 1 %
/// of the contacts, 3 loses 0.13 %): expected kept contacts over expected
/// kept zones, given the true contacts' number and the near misses' true
/// separations [voxels]. What the rule could reach at that spread.
pub fn precision_limit(contacts: usize, near_misses: &[f64], sd: f64, z: f64) -> f64 {
    let kept_contacts = contacts as f64 * super::neck::cdf(z);
    let kept_misses: f64 = near_misses
        .iter()
        .map(|g| super::neck::cdf(z - g / sd))
        .sum();
    kept_contacts / (kept_contacts + kept_misses)
}

/// Scores the grain–grain contacts of an import (all zones when `all`,
/// else the kept ones) against the truth. Labels are grain index + 1.
pub fn score(imported: &LabelScene, truth: &[TrueContact], all: bool) -> Score {
    use std::collections::HashMap;
    let mut zones: HashMap<(usize, usize), Vec<&super::DetectedContact>> = HashMap::new();
    let mut detected = 0;
    for c in &imported.detected {
        if !(all || c.kept) {
            continue;
        }
        if let super::Other::Grain(b) = c.b {
            detected += 1;
            let (a, b) = (c.a as usize - 1, b as usize - 1);
            zones.entry((a.min(b), a.max(b))).or_default().push(c);
        }
    }
    let mut s = Score {
        true_contacts: truth.len(),
        detected,
        found: 0,
        correct: 0,
        angles: Vec::new(),
        pca_angles: Vec::new(),
        point_errors: Vec::new(),
    };
    for t in truth {
        let key = (t.a.min(t.b), t.a.max(t.b));
        let Some(z) = zones.get(&key) else { continue };
        let c = z.iter().max_by_key(|c| c.faces).expect("non-empty");
        s.found += 1;
        s.correct += 1;
        // The imported normal points from the lower label to the higher.
        let sign = if c.a as usize - 1 == t.a { 1.0 } else { -1.0 };
        let angle = |n: Vec3| {
            (sign * scene::dot(n, t.normal))
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        };
        s.angles.push(angle(c.normal));
        s.pca_angles.push(angle(c.pca_normal));
        s.point_errors
            .push(scene::norm(scene::sub(c.point, t.point)));
    }
    s
}
