//! Scalable synthetic packings with exact forces, for benchmarks up to 10⁶ grains
//! (a DEM relaxation is far too slow there).
//!
//! What the generator does:
//! 1. Grains on a lattice (2D triangular, 3D simple cubic) of spacing 2R₀, each
//!    centre jittered uniformly by ±`jitter`·R₀ per axis, radii uniform in
//!    [R₀/`size_ratio`, R₀]. Contacts join lattice neighbours; the contact point
//!    splits the branch vector in the ratio of the radii and the normal lies
//!    along it. Grains on the boundary touch four (six) ideal walls, the contact
//!    point on the grain's surface along the wall normal.
//! 2. 2D: bonds are removed at random (never below 3 contacts per grain) until
//!    the mean coordination reaches `coordination`, as in real frictional
//!    packings (z ≈ 4); the full triangular lattice (z = 6) would have as many
//!    unknowns as equations.
//! 3. Exact forces: a compressive guess (normal forces 1 ± 0.3, tangential up to
//!    `shear`·f_n) is projected onto momentum balance K_eq x = 0 (least change,
//!    via a sparse Cholesky factorisation of K_eq K_eqᵀ with refinement); normal
//!    forces that came out below 0.2 are raised and the projection repeated
//!    (alternating projections). Where the exact field needs more friction than
//!    μ, that contact gets μ = 1.25 |f_t|/f_n of its own (counted in
//!    [`Packing::raised_mu`]).
//! 4. Stresses follow from V σ = Σ sym(r ⊗ f), computed here from the geometry
//!    (independently of the assembler); wall loads are the sums of the exact
//!    wall forces.
//!
//! Limits: grains need not touch exactly (gaps of up to R₀(1 − 1/size_ratio)
//! between surfaces) and walls are not straight lines through every contact;
//! only the contact geometry enters GEM, so this does not matter for timing or
//! accuracy, but the pictures are not physical packings. The force network
//! has no real force chains (it is the least change from a uniform pressure).

use crate::assemble::{self, AssembleOptions, Friction};
use crate::error::{Error, Result};
use crate::scene::{self, Body, Contact, Grain, Scene, Vec3};
use crate::solver::sparse_ls::{Ordering, SpdFactor};
use crate::solver::Triplets;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Parameters of a synthetic packing.
#[derive(Debug, Clone, PartialEq)]
pub struct PackingSpec {
    pub dim: usize,
    /// Approximate number of grains (the lattice is the nearest square/cube).
    pub grains: usize,
    /// Largest over smallest radius (≥ 1).
    pub size_ratio: f64,
    /// Centre jitter as a fraction of R₀ (< 0.2 keeps contacts sensible).
    pub jitter: f64,
    /// Target mean coordination in 2D (3D keeps the cubic lattice, z = 6).
    pub coordination: f64,
    /// Friction coefficient between grains (walls are frictionless).
    pub mu: f64,
    /// Tangential part of the guess relative to the normal force.
    pub shear: f64,
    /// Share of the frictional contacts put exactly at the Coulomb limit
    /// (their μ becomes |f_t|/f_n of the truth), as in a sheared packing
    /// where many contacts slide; 0 leaves μ at `mu` (raised where the truth
    /// needs it).
    pub sliding: f64,
    /// R₀ [m].
    pub radius: f64,
    /// Force scale [N] (N/m in 2D).
    pub force: f64,
    pub seed: u64,
}

impl PackingSpec {
    pub fn new(dim: usize, grains: usize) -> Self {
        PackingSpec {
            dim,
            grains,
            size_ratio: 1.25,
            jitter: 0.1,
            coordination: 4.2,
            mu: 0.5,
            shear: 0.2,
            sliding: 0.0,
            radius: 1e-3,
            force: 10.0,
            seed: 1,
        }
    }
}

/// A synthetic scene with its exact forces (scene contact order).
#[derive(Debug, Clone)]
pub struct Packing {
    pub scene: Scene,
    pub truth: Vec<Vec3>,
    /// Contacts whose μ had to be raised above `spec.mu` to admit the exact forces.
    pub raised_mu: usize,
    /// Contacts put exactly at the Coulomb limit (`spec.sliding`).
    pub sliding: usize,
    /// Largest |K_eq f| of the truth relative to the mean contact force.
    pub equilibrium_residual: f64,
}

pub fn generate(spec: &PackingSpec) -> Result<Packing> {
    if !(spec.dim == 2 || spec.dim == 3) {
        return Err(Error::Invalid(format!(
            "dimension must be 2 or 3, got {}",
            spec.dim
        )));
    }
    if spec.grains < 2 {
        return Err(Error::Invalid("a packing needs at least 2 grains".into()));
    }
    if !(spec.size_ratio >= 1.0 && spec.size_ratio.is_finite()) {
        return Err(Error::Invalid(format!(
            "size ratio must be ≥ 1, got {}",
            spec.size_ratio
        )));
    }
    if !(0.0..=1.0).contains(&spec.sliding) {
        return Err(Error::Invalid(format!(
            "the sliding share must be in [0, 1], got {}",
            spec.sliding
        )));
    }
    if !(0.0..0.25).contains(&spec.jitter) {
        return Err(Error::Invalid(format!(
            "jitter must be in [0, 0.25), got {}",
            spec.jitter
        )));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(spec.seed);
    let mut scene = if spec.dim == 2 {
        lattice_2d(spec, &mut rng)
    } else {
        lattice_3d(spec, &mut rng)
    };
    scene.settings.mu = Some(spec.mu);
    scene.settings.description = Some(format!(
        "grainforce bench synthetic packing: {}D lattice, {} grains, size ratio {}, jitter {}, seed {}",
        spec.dim,
        scene.grains.len(),
        spec.size_ratio,
        spec.jitter,
        spec.seed
    ));
    let (truth, residual) = exact_forces(&scene, spec, &mut rng)?;
    let (mut raised_mu, mut sliding) = (0, 0);
    for (c, f) in scene.contacts.iter_mut().zip(&truth) {
        if c.mu == Some(0.0) {
            continue;
        }
        let (fn_, ft) = normal_tangential(c.normal, *f);
        // Drawn only when asked for, so packings without sliding keep their
        // random sequence.
        if spec.sliding > 0.0 && rng.gen_bool(spec.sliding) && ft > 0.0 {
            c.mu = Some(ft / fn_);
            sliding += 1;
        } else if ft > spec.mu * fn_ {
            c.mu = Some(1.25 * ft / fn_);
            raised_mu += 1;
        }
    }
    set_stresses(&mut scene, &truth);
    set_wall_loads(&mut scene, &truth);
    Ok(Packing {
        scene,
        truth,
        raised_mu,
        sliding,
        equilibrium_residual: residual,
    })
}

/// Compressive normal force f_n = −n·f and the tangential magnitude.
pub(crate) fn normal_tangential(n: Vec3, f: Vec3) -> (f64, f64) {
    let fn_ = -scene::dot(f, n);
    let ft = scene::norm([f[0] + fn_ * n[0], f[1] + fn_ * n[1], f[2] + fn_ * n[2]]);
    (fn_, ft)
}

fn radius_of(spec: &PackingSpec, rng: &mut ChaCha8Rng) -> f64 {
    let lo = spec.radius / spec.size_ratio;
    if spec.size_ratio == 1.0 {
        spec.radius
    } else {
        rng.gen_range(lo..=spec.radius)
    }
}

fn jittered(spec: &PackingSpec, rng: &mut ChaCha8Rng, p: Vec3) -> Vec3 {
    let j = spec.jitter * spec.radius;
    let mut q = p;
    for v in q.iter_mut().take(spec.dim) {
        if j > 0.0 {
            *v += rng.gen_range(-j..=j);
        }
    }
    q
}

fn new_grain(spec: &PackingSpec, id: usize, position: Vec3, r: f64) -> Grain {
    let volume = if spec.dim == 2 {
        std::f64::consts::PI * r * r
    } else {
        4.0 / 3.0 * std::f64::consts::PI * r.powi(3)
    };
    let mut g = Grain::new(id.to_string(), position, volume, [0.0; 6]);
    g.radius = Some(r);
    g
}

fn bond(scene: &mut Scene, a: usize, b: usize) {
    let (ga, gb) = (&scene.grains[a], &scene.grains[b]);
    let (ra, rb) = (ga.radius.unwrap_or(1.0), gb.radius.unwrap_or(1.0));
    let d = scene::sub(gb.position, ga.position);
    let l = scene::norm(d);
    let n = [d[0] / l, d[1] / l, d[2] / l];
    let t = l * ra / (ra + rb);
    let p = ga.position;
    let id = format!("c{}", scene.contacts.len());
    scene.contacts.push(Contact {
        id,
        a,
        b: Body::Grain(b),
        point: [p[0] + t * n[0], p[1] + t * n[1], p[2] + t * n[2]],
        normal: n,
        mu: None,
    });
}

fn wall_contact(scene: &mut Scene, a: usize, wall: usize, n: Vec3) {
    let g = &scene.grains[a];
    let r = g.radius.unwrap_or(1.0);
    let p = g.position;
    let id = format!("c{}", scene.contacts.len());
    scene.contacts.push(Contact {
        id,
        a,
        b: Body::Wall(wall),
        point: [p[0] + r * n[0], p[1] + r * n[1], p[2] + r * n[2]],
        normal: n,
        mu: Some(0.0),
    });
}

fn add_walls(scene: &mut Scene, names: &[&str]) -> Vec<usize> {
    names.iter().map(|n| scene.wall_or_insert(n)).collect()
}

fn lattice_2d(spec: &PackingSpec, rng: &mut ChaCha8Rng) -> Scene {
    let r0 = spec.radius;
    let nx = ((spec.grains as f64).sqrt().round() as usize).max(2);
    let ny = spec.grains.div_ceil(nx).max(2);
    let h = r0 * 3f64.sqrt();
    let mut s = Scene::new(2);
    for j in 0..ny {
        for i in 0..nx {
            let shift = if j % 2 == 1 { r0 } else { 0.0 };
            let p = [r0 + 2.0 * r0 * i as f64 + shift, r0 + h * j as f64, 0.0];
            let p = jittered(spec, rng, p);
            let r = radius_of(spec, rng);
            s.grains.push(new_grain(spec, s.grains.len(), p, r));
        }
    }
    let idx = |i: usize, j: usize| j * nx + i;
    let mut bonds = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            if i + 1 < nx {
                bonds.push((idx(i, j), idx(i + 1, j)));
            }
            if j + 1 < ny {
                // Even rows touch (i−1, i) above; odd rows (shifted right) touch (i, i+1).
                let (lo, hi) = if j % 2 == 0 {
                    (i.checked_sub(1), Some(i))
                } else {
                    (Some(i), (i + 1 < nx).then_some(i + 1))
                };
                for k in [lo, hi].into_iter().flatten() {
                    bonds.push((idx(i, j), idx(k, j + 1)));
                }
            }
        }
    }
    let walls = add_walls(&mut s, &["bottom", "top", "left", "right"]);
    let mut wall_list: Vec<(usize, usize, Vec3)> = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let a = idx(i, j);
            if j == 0 {
                wall_list.push((a, walls[0], [0.0, -1.0, 0.0]));
            }
            if j == ny - 1 {
                wall_list.push((a, walls[1], [0.0, 1.0, 0.0]));
            }
            if i == 0 {
                wall_list.push((a, walls[2], [-1.0, 0.0, 0.0]));
            }
            if i == nx - 1 {
                wall_list.push((a, walls[3], [1.0, 0.0, 0.0]));
            }
        }
    }
    // Dilute to the target coordination, never below 3 contacts per grain and
    // keeping each grain's contact directions spread round it (largest angular
    // gap < 0.8π), or compressive forces could not balance it.
    let ng = s.grains.len();
    let angle = |from: usize, to: usize| {
        let d = scene::sub(s.grains[to].position, s.grains[from].position);
        d[1].atan2(d[0])
    };
    let mut dirs: Vec<Vec<(usize, f64)>> = vec![Vec::new(); ng];
    for (k, &(a, b)) in bonds.iter().enumerate() {
        dirs[a].push((k, angle(a, b)));
        dirs[b].push((k, angle(b, a)));
    }
    for &(a, _, n) in &wall_list {
        dirs[a].push((usize::MAX, n[1].atan2(n[0])));
    }
    let spread_without = |list: &[(usize, f64)], bond: usize| {
        let mut a: Vec<f64> = list.iter().filter(|d| d.0 != bond).map(|d| d.1).collect();
        if a.len() < 3 {
            return false;
        }
        a.sort_by(f64::total_cmp);
        let mut gap = a[0] + 2.0 * std::f64::consts::PI - a[a.len() - 1];
        for w in a.windows(2) {
            gap = gap.max(w[1] - w[0]);
        }
        gap < 0.8 * std::f64::consts::PI
    };
    let target_contacts = (spec.coordination * ng as f64 / 2.0).ceil() as usize;
    let mut total = bonds.len() + wall_list.len();
    let mut order: Vec<usize> = (0..bonds.len()).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, rng.gen_range(0..=i));
    }
    let mut keep = vec![true; bonds.len()];
    for k in order {
        if total <= target_contacts {
            break;
        }
        let (a, b) = bonds[k];
        if spread_without(&dirs[a], k) && spread_without(&dirs[b], k) {
            keep[k] = false;
            dirs[a].retain(|d| d.0 != k);
            dirs[b].retain(|d| d.0 != k);
            total -= 1;
        }
    }
    for (k, &(a, b)) in bonds.iter().enumerate() {
        if keep[k] {
            bond(&mut s, a, b);
        }
    }
    for (a, w, n) in wall_list {
        wall_contact(&mut s, a, w, n);
    }
    s
}

fn lattice_3d(spec: &PackingSpec, rng: &mut ChaCha8Rng) -> Scene {
    let r0 = spec.radius;
    let n = ((spec.grains as f64).cbrt().round() as usize).max(2);
    let mut s = Scene::new(3);
    let idx = |i: usize, j: usize, k: usize| (k * n + j) * n + i;
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let p = [
                    r0 + 2.0 * r0 * i as f64,
                    r0 + 2.0 * r0 * j as f64,
                    r0 + 2.0 * r0 * k as f64,
                ];
                let p = jittered(spec, rng, p);
                let r = radius_of(spec, rng);
                s.grains.push(new_grain(spec, s.grains.len(), p, r));
            }
        }
    }
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                if i + 1 < n {
                    bond(&mut s, idx(i, j, k), idx(i + 1, j, k));
                }
                if j + 1 < n {
                    bond(&mut s, idx(i, j, k), idx(i, j + 1, k));
                }
                if k + 1 < n {
                    bond(&mut s, idx(i, j, k), idx(i, j, k + 1));
                }
            }
        }
    }
    let names = ["x-", "x+", "y-", "y+", "z-", "z+"];
    let walls = add_walls(&mut s, &names);
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let a = idx(i, j, k);
                let ijk = [i, j, k];
                for axis in 0..3 {
                    let mut e = [0.0; 3];
                    if ijk[axis] == 0 {
                        e[axis] = -1.0;
                        wall_contact(&mut s, a, walls[2 * axis], e);
                    }
                    if ijk[axis] == n - 1 {
                        e[axis] = 1.0;
                        wall_contact(&mut s, a, walls[2 * axis + 1], e);
                    }
                }
            }
        }
    }
    s
}

/// Exact forces by alternating projection; returns them and the relative
/// momentum residual.
fn exact_forces(
    scene: &Scene,
    spec: &PackingSpec,
    rng: &mut ChaCha8Rng,
) -> Result<(Vec<Vec3>, f64)> {
    let opts = AssembleOptions {
        single_system: true,
        ..AssembleOptions::default()
    };
    let assembly = assemble::assemble(scene, &opts)?;
    let Some(system) = assembly.systems.first() else {
        return Err(Error::Invalid("the packing has no contacts".into()));
    };
    let dim = scene.dim;
    let mut x = vec![0.0; system.n];
    for u in &system.unknowns {
        let fn_ = 1.0 + 0.3 * rng.gen_range(-1.0..=1.0);
        x[u.offset] = fn_;
        if u.count(dim) > 1 {
            for j in 1..dim {
                x[u.offset + j] = spec.shear * fn_ * rng.gen_range(-1.0..=1.0) / (dim - 1) as f64;
            }
        }
    }
    // With AMD's fill in 3D this was the largest memory user of the
    // 10⁵-sphere benchmark (18.5 GB, 290 s).
    let projector = Projector::new(&system.momentum, Ordering::for_dim(system.dim))?;
    let floor = 0.2;
    let mut done = false;
    for _ in 0..60 {
        projector.project(&mut x)?;
        let mut raised = false;
        for u in &system.unknowns {
            if x[u.offset] < floor {
                x[u.offset] = floor;
                raised = true;
            }
        }
        if !raised {
            done = true;
            break;
        }
    }
    if !done {
        // One last projection so the truth is in exact equilibrium; normals may
        // then dip slightly below the floor but must stay compressive.
        projector.project(&mut x)?;
    }
    if let Some(u) = system.unknowns.iter().find(|u| x[u.offset] <= 0.0) {
        return Err(Error::Solver(format!(
            "could not make an admissible exact force field (contact {} is tensile)",
            scene.contacts[u.contact].id
        )));
    }
    let residual = system
        .momentum
        .mul(&x)
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let mean = x.iter().map(|v| v.abs()).sum::<f64>() / x.len().max(1) as f64;
    let scale = spec.force / system.scales.force;
    let mut truth = vec![[0.0; 3]; scene.contacts.len()];
    for (c, f) in system.forces(&x) {
        truth[c] = [f[0] * scale, f[1] * scale, f[2] * scale];
    }
    debug_assert!(system
        .unknowns
        .iter()
        .all(|u| u.friction != Friction::NormalOnly));
    Ok((truth, residual / mean))
}

const MAX_PROJECTION_SWEEPS: usize = 30;

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// Least-change projection onto K x = 0 via a Cholesky factorisation of K Kᵀ
/// (+ a tiny shift for safety) and two refinement sweeps.
struct Projector<'a> {
    k: &'a Triplets,
    llt: SpdFactor,
}

impl<'a> Projector<'a> {
    fn new(k: &'a Triplets, ordering: Ordering) -> Result<Self> {
        use faer::sparse::{SparseColMat, Triplet};
        // Entries of each column of K.
        let mut by_col: Vec<Vec<(usize, f64)>> = vec![Vec::new(); k.ncols];
        for i in 0..k.nnz() {
            by_col[k.cols[i]].push((k.rows[i], k.vals[i]));
        }
        let mut diag = vec![0.0; k.nrows];
        let mut entries = Vec::new();
        for col in &by_col {
            for &(r1, v1) in col {
                diag[r1] += v1 * v1;
                for &(r2, v2) in col {
                    if r1 < r2 {
                        entries.push(Triplet::new(r1, r2, v1 * v2));
                    }
                }
            }
        }
        drop(by_col);
        let max_diag = diag.iter().fold(0.0f64, |m, &v| m.max(v));
        for (r, d) in diag.iter().enumerate() {
            entries.push(Triplet::new(r, r, d + 1e-13 * max_diag));
        }
        // Duplicates summed, rows sorted: the upper triangle in CSC.
        let kkt = SparseColMat::<usize, f64>::try_new_from_triplets(k.nrows, k.nrows, &entries)
            .map_err(|e| Error::Solver(format!("K Kᵀ assembly: {e:?}")))?;
        drop(entries);
        let llt = SpdFactor::new(
            k.nrows,
            kkt.symbolic().col_ptr(),
            kkt.symbolic().row_idx(),
            kkt.val(),
            ordering,
            0.0,
        )
        .map_err(|e| {
            Error::Solver(format!(
                "K Kᵀ is not positive definite ({e}): the lattice has a mechanism"
            ))
        })?;
        Ok(Projector { k, llt })
    }

    /// Sweeps until K x stops shrinking: on nearly redundant rows (an almost
    /// perfect lattice, K Kᵀ conditioned like 1/jitter²) each sweep only
    /// contracts by ~shift/σ², and a truth left out of balance there would
    /// make exact data inconsistent.
    fn project(&self, x: &mut [f64]) -> Result<()> {
        let mut y = self.k.mul(x);
        let mut residual = max_abs(&y);
        for _ in 0..MAX_PROJECTION_SWEEPS {
            self.llt.solve_in_place(&mut y, 1)?;
            let correction = self.k.mul_transpose(&y);
            for (xi, ci) in x.iter_mut().zip(correction) {
                *xi -= ci;
            }
            y = self.k.mul(x);
            let next = max_abs(&y);
            if next.is_nan() || next >= 0.5 * residual {
                break;
            }
            residual = next;
        }
        Ok(())
    }
}

/// V σ = Σ sym(r ⊗ f) (tension positive) for every grain.
pub fn set_stresses(scene: &mut Scene, forces: &[Vec3]) {
    scene.set_stresses_from(forces);
}

/// Each wall's measured load = the sum of its exact contact forces.
pub fn set_wall_loads(scene: &mut Scene, forces: &[Vec3]) {
    let known: Vec<Option<Vec3>> = forces.iter().copied().map(Some).collect();
    let totals = scene::wall_totals(scene, &known);
    for (w, t) in scene.walls.iter_mut().zip(totals) {
        w.measured_force = Some(t);
    }
}
