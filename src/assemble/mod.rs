//! Assembly of the GEM system: unknowns in each contact's local frame, the
//! stress rows K_st f = b_st and momentum rows K_eq f = b_eq per grain, the
//! friction cones, all non-dimensionalised.
//!
//! Only what the scene requires is modelled: a frictionless contact has one
//! unknown (its normal force), a frictional one d; a grain without contacts has
//! no rows; a grain whose only contact must balance a zero load forces that
//! contact to zero (pruned, iteratively); disconnected clusters become separate
//! systems.

mod cluster;

use crate::error::{Error, Result};
use crate::scene::{self, Body, Scene, Vec3};
use crate::solver::{LeastSquares, Triplets};

/// How a contact's force is constrained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Friction {
    /// μ = 0: normal force only (one unknown).
    Frictionless,
    /// |f_t| ≤ μ f_n.
    Coulomb(f64),
    /// No μ known: f_n ≥ 0 only, tangential force free.
    NormalOnly,
}

/// The unknowns of one contact: f = −u₀ n + u₁ t₁ (+ u₂ t₂), so u₀ = f_n ≥ 0 is
/// the compressive normal force.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactUnknowns {
    /// Index into `scene.contacts`.
    pub contact: usize,
    /// Index of u₀ in the system's unknown vector.
    pub offset: usize,
    pub friction: Friction,
    /// −n, t₁, t₂: the force direction of each unknown.
    pub directions: [Vec3; 3],
}

impl ContactUnknowns {
    pub fn count(&self, dim: usize) -> usize {
        match self.friction {
            Friction::Frictionless => 1,
            _ => dim,
        }
    }
}

/// Characteristic scales: forces are divided by `force`, lengths by `length`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Scales {
    pub force: f64,
    pub length: f64,
}

/// The rows of one wall's total force, for matching load cells.
#[derive(Debug, Clone, PartialEq)]
pub struct WallRows {
    /// Index into `scene.walls`.
    pub wall: usize,
    /// Σ of this wall's contact forces, d rows (dimensionless).
    pub rows: Triplets,
}

/// One independent problem (a connected cluster of grains).
#[derive(Debug, Clone)]
pub struct System {
    pub dim: usize,
    pub unknowns: Vec<ContactUnknowns>,
    /// Number of scalar unknowns.
    pub n: usize,
    /// Grains (indices into `scene.grains`) that have rows, in row-block order.
    pub grains: Vec<usize>,
    /// Stress rows (d(d+1)/2 per grain: xx, yy[, zz], 2xy[, 2xz, 2yz]).
    pub stress: Triplets,
    pub stress_rhs: Vec<f64>,
    /// Momentum rows (force then moment: 3 per grain in 2D, 6 in 3D).
    pub momentum: Triplets,
    pub momentum_rhs: Vec<f64>,
    pub scales: Scales,
    pub walls: Vec<WallRows>,
}

impl System {
    /// One row per contact over its unknowns (values 1): the pattern that
    /// couples each contact's block, for `EqualityLeastSquares::with_coupling`.
    pub fn contact_blocks(&self) -> Triplets {
        let mut blocks = Triplets::new(self.unknowns.len(), self.n);
        for (k, u) in self.unknowns.iter().enumerate() {
            for j in u.offset..u.offset + u.count(self.dim) {
                blocks.push(k, j, 1.0);
            }
        }
        blocks
    }

    /// The static problem (eq. 2.14) in the solvers' terms: the stress rows
    /// fitted, momentum balance imposed, Tikhonov λ.
    pub fn least_squares(&self, lambda: f64) -> LeastSquares<'_> {
        LeastSquares {
            a: &self.stress,
            b: &self.stress_rhs,
            c: &self.momentum,
            d: &self.momentum_rhs,
            lambda,
        }
    }

    /// The physical force (on grain a by b) of each modelled contact.
    pub fn forces(&self, x: &[f64]) -> Vec<(usize, Vec3)> {
        self.unknowns
            .iter()
            .map(|u| {
                let mut f = [0.0; 3];
                for j in 0..u.count(self.dim) {
                    for (k, fk) in f.iter_mut().enumerate() {
                        *fk += x[u.offset + j] * u.directions[j][k] * self.scales.force;
                    }
                }
                (u.contact, f)
            })
            .collect()
    }

    pub(crate) fn momentum_rows_per_grain(&self) -> usize {
        momentum_rows(self.dim)
    }
}

pub(crate) fn stress_rows(dim: usize) -> usize {
    dim * (dim + 1) / 2
}

pub(crate) fn momentum_rows(dim: usize) -> usize {
    if dim == 2 {
        3
    } else {
        6
    }
}

#[derive(Debug, Clone, Default)]
pub struct AssembleOptions {
    /// Friction coefficient for contacts without their own `mu` (overrides scene.json).
    pub mu: Option<f64>,
    /// Friction coefficient for grain–wall contacts without their own `mu`
    /// (overrides `mu` and scene.json there): lubricated or rough walls.
    pub wall_mu: Option<f64>,
    /// Gravity (overrides scene.json).
    pub gravity: Option<Vec3>,
    /// Grains whose equations are kept (local inference); `None` = all.
    pub active: Option<Vec<bool>>,
    /// Fix to zero the force of a contact that is its grain's only one while
    /// that grain has no load to balance (valid when momentum is a hard constraint).
    pub prune_single_contacts: bool,
    /// Keep all grains in one system rather than one per connected cluster.
    pub single_system: bool,
}

/// The assembled problem of a scene.
#[derive(Debug, Clone)]
pub struct Assembly {
    pub dim: usize,
    pub systems: Vec<System>,
    pub scales: Scales,
    /// Contacts whose force is zero by pruning (index into scene.contacts).
    pub zero_contacts: Vec<usize>,
    /// Active grains left without any modelled contact.
    pub rattlers: Vec<usize>,
    /// Rattlers whose data say they carry load (non-zero stress or momentum target).
    pub loaded_rattlers: Vec<usize>,
    /// Number of contacts modelled by each friction kind: frictionless, Coulomb, normal-only.
    pub friction_counts: [usize; 3],
}

fn friction_of(scene: &Scene, c: &scene::Contact, opts: &AssembleOptions) -> Friction {
    let wall_mu = opts.wall_mu.filter(|_| matches!(c.b, Body::Wall(_)));
    match c.mu.or(wall_mu).or(opts.mu).or(scene.settings.mu) {
        Some(mu) => {
            if mu == 0.0 {
                Friction::Frictionless
            } else {
                Friction::Coulomb(mu)
            }
        }
        None => Friction::NormalOnly,
    }
}

pub fn assemble(scene: &Scene, opts: &AssembleOptions) -> Result<Assembly> {
    scene.validate()?;
    let dim = scene.dim;
    let ng = scene.grains.len();
    let active = match &opts.active {
        Some(mask) if mask.len() != ng => {
            return Err(Error::Invalid("grain mask does not match the scene".into()))
        }
        Some(mask) => mask.clone(),
        None => vec![true; ng],
    };
    for (field, mu) in [("mu", opts.mu), ("wall_mu", opts.wall_mu)] {
        if let Some(mu) = mu.filter(|mu| !(*mu >= 0.0 && mu.is_finite())) {
            return Err(Error::Invalid(format!(
                "`{field}` must be a finite non-negative number, got {mu}"
            )));
        }
    }
    let gravity = opts.gravity.unwrap_or_else(|| scene.gravity());
    let targets: Vec<(Vec3, Vec3)> = scene
        .grains
        .iter()
        .map(|g| scene.momentum_target_with(g, gravity))
        .collect();
    let touches_active =
        |c: &scene::Contact| active[c.a] || matches!(c.b, Body::Grain(b) if active[b]);

    // Contacts modelled, with pruning of single contacts on unloaded grains.
    let mut modelled: Vec<bool> = scene.contacts.iter().map(touches_active).collect();
    let mut count = vec![0usize; ng];
    let bodies = |c: &scene::Contact| -> [Option<usize>; 2] {
        [
            Some(c.a),
            match c.b {
                Body::Grain(b) => Some(b),
                Body::Wall(_) => None,
            },
        ]
    };
    for (c, m) in scene.contacts.iter().zip(&modelled) {
        if *m {
            for p in bodies(c).into_iter().flatten() {
                count[p] += 1;
            }
        }
    }
    let mut zero_contacts = Vec::new();
    if opts.prune_single_contacts {
        let unloaded: Vec<bool> = targets
            .iter()
            .map(|(f, m)| f.iter().chain(m.iter()).all(|&x| x == 0.0))
            .collect();
        let mut contacts_of: Vec<Vec<usize>> = vec![Vec::new(); ng];
        for (i, c) in scene.contacts.iter().enumerate() {
            if modelled[i] {
                for p in bodies(c).into_iter().flatten() {
                    contacts_of[p].push(i);
                }
            }
        }
        let mut stack: Vec<usize> = (0..ng)
            .filter(|&p| active[p] && unloaded[p] && count[p] == 1)
            .collect();
        while let Some(p) = stack.pop() {
            if count[p] != 1 {
                continue;
            }
            let Some(&c) = contacts_of[p].iter().find(|&&c| modelled[c]) else {
                continue;
            };
            modelled[c] = false;
            zero_contacts.push(c);
            for q in bodies(&scene.contacts[c]).into_iter().flatten() {
                count[q] -= 1;
                if q != p && active[q] && unloaded[q] && count[q] == 1 {
                    stack.push(q);
                }
            }
        }
        zero_contacts.sort_unstable();
    }

    let rattlers: Vec<usize> = (0..ng).filter(|&p| active[p] && count[p] == 0).collect();
    let loaded_rattlers: Vec<usize> = rattlers
        .iter()
        .copied()
        .filter(|&p| {
            let (f, m) = targets[p];
            scene.grains[p].stress.iter().any(|&s| s != 0.0)
                || f.iter().chain(m.iter()).any(|&x| x != 0.0)
        })
        .collect();

    // Scales: lengths from the grains' size, forces from the loads they report.
    let radii: Vec<f64> = (0..ng)
        .filter(|&p| active[p] && count[p] > 0)
        .map(|p| scene.grains[p].equivalent_radius(dim))
        .collect();
    let length = median(radii).unwrap_or(1.0);
    let comps = scene::sym::components(dim);
    let mut load_sq = 0.0;
    let mut load_n = 0usize;
    for p in (0..ng).filter(|&p| active[p] && count[p] > 0) {
        let g = &scene.grains[p];
        for &k in comps {
            load_sq += (g.volume * g.stress[k] / length).powi(2);
        }
        let (f, m) = targets[p];
        for k in 0..3 {
            load_sq += f[k].powi(2) + (m[k] / length).powi(2);
        }
        load_n += 1;
    }
    let force = if load_sq > 0.0 && load_sq.is_finite() {
        (load_sq / load_n as f64).sqrt()
    } else {
        1.0
    };
    let scales = Scales { force, length };

    // Clusters of active grains joined by modelled grain–grain contacts.
    let mut uf = cluster::UnionFind::new(ng);
    for (i, c) in scene.contacts.iter().enumerate() {
        if let (true, Body::Grain(b)) = (modelled[i], c.b) {
            if active[c.a] && active[b] {
                uf.union(c.a, b);
            }
        }
    }
    let mut cluster_of_root = std::collections::HashMap::new();
    let mut cluster_grains: Vec<Vec<usize>> = Vec::new();
    for p in (0..ng).filter(|&p| active[p] && count[p] > 0) {
        let root = if opts.single_system { 0 } else { uf.find(p) };
        let k = *cluster_of_root.entry(root).or_insert_with(|| {
            cluster_grains.push(Vec::new());
            cluster_grains.len() - 1
        });
        cluster_grains[k].push(p);
    }
    let mut cluster_contacts: Vec<Vec<usize>> = vec![Vec::new(); cluster_grains.len()];
    for (i, c) in scene.contacts.iter().enumerate() {
        if !modelled[i] {
            continue;
        }
        let owner = if active[c.a] {
            c.a
        } else if let Body::Grain(b) = c.b {
            b
        } else {
            continue;
        };
        let root = if opts.single_system {
            0
        } else {
            uf.find(owner)
        };
        cluster_contacts[cluster_of_root[&root]].push(i);
    }

    let mut friction_counts = [0usize; 3];
    let mut systems = Vec::with_capacity(cluster_grains.len());
    for (grains, contacts) in cluster_grains.into_iter().zip(cluster_contacts) {
        let system = build_system(scene, opts, &targets, &active, grains, contacts, scales)?;
        for u in &system.unknowns {
            friction_counts[match u.friction {
                Friction::Frictionless => 0,
                Friction::Coulomb(_) => 1,
                Friction::NormalOnly => 2,
            }] += 1;
        }
        systems.push(system);
    }
    Ok(Assembly {
        dim,
        systems,
        scales,
        zero_contacts,
        rattlers,
        loaded_rattlers,
        friction_counts,
    })
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let m = v[v.len() / 2];
    (m > 0.0 && m.is_finite()).then_some(m)
}

fn build_system(
    scene: &Scene,
    opts: &AssembleOptions,
    targets: &[(Vec3, Vec3)],
    active: &[bool],
    grains: Vec<usize>,
    contacts: Vec<usize>,
    scales: Scales,
) -> Result<System> {
    let dim = scene.dim;
    let (ns, nm) = (stress_rows(dim), momentum_rows(dim));
    let mut block_of = std::collections::HashMap::with_capacity(grains.len());
    for (k, &p) in grains.iter().enumerate() {
        block_of.insert(p, k);
    }
    let mut unknowns = Vec::with_capacity(contacts.len());
    let mut n = 0;
    for &ci in &contacts {
        let c = &scene.contacts[ci];
        let friction = friction_of(scene, c, opts);
        let (t1, t2) = scene::tangents(dim, c.normal);
        let u = ContactUnknowns {
            contact: ci,
            offset: n,
            friction,
            directions: [[-c.normal[0], -c.normal[1], -c.normal[2]], t1, t2],
        };
        n += u.count(dim);
        unknowns.push(u);
    }
    let rows = grains.len();
    let mut stress = Triplets::new(rows * ns, n);
    let mut momentum = Triplets::new(rows * nm, n);
    let (fs, ls) = (scales.force, scales.length);
    for u in &unknowns {
        let c = &scene.contacts[u.contact];
        let mut sides = vec![(c.a, 1.0)];
        if let Body::Grain(b) = c.b {
            sides.push((b, -1.0));
        }
        for (p, sign) in sides {
            if !active[p] {
                continue;
            }
            let Some(&block) = block_of.get(&p) else {
                continue;
            };
            let g = &scene.grains[p];
            let r = scene::sub(c.point, g.position);
            let r = [r[0] / ls, r[1] / ls, r[2] / ls];
            for j in 0..u.count(dim) {
                let e = u.directions[j];
                let col = u.offset + j;
                let e = [sign * e[0], sign * e[1], sign * e[2]];
                // Stress rows: xx, yy[, zz] then 2·xy[, 2·xz, 2·yz].
                let s0 = block * ns;
                for k in 0..dim {
                    stress.push(s0 + k, col, r[k] * e[k]);
                }
                let offdiag: &[(usize, usize)] = if dim == 2 {
                    &[(0, 1)]
                } else {
                    &[(0, 1), (0, 2), (1, 2)]
                };
                for (m, &(i, l)) in offdiag.iter().enumerate() {
                    stress.push(s0 + dim + m, col, r[i] * e[l] + r[l] * e[i]);
                }
                // Momentum rows: force, then moment r × e.
                let m0 = block * nm;
                for k in 0..dim {
                    momentum.push(m0 + k, col, e[k]);
                }
                let moment = scene::cross(r, e);
                if dim == 2 {
                    momentum.push(m0 + 2, col, moment[2]);
                } else {
                    for k in 0..3 {
                        momentum.push(m0 + 3 + k, col, moment[k]);
                    }
                }
            }
        }
    }
    let mut stress_rhs = vec![0.0; rows * ns];
    let mut momentum_rhs = vec![0.0; rows * nm];
    for (block, &p) in grains.iter().enumerate() {
        let g = &scene.grains[p];
        let v = g.volume / (fs * ls);
        let s = &g.stress;
        use scene::sym::*;
        let values: Vec<f64> = if dim == 2 {
            vec![v * s[XX], v * s[YY], 2.0 * v * s[XY]]
        } else {
            vec![
                v * s[XX],
                v * s[YY],
                v * s[ZZ],
                2.0 * v * s[XY],
                2.0 * v * s[XZ],
                2.0 * v * s[YZ],
            ]
        };
        stress_rhs[block * ns..(block + 1) * ns].copy_from_slice(&values);
        let (f, m) = targets[p];
        for k in 0..dim {
            momentum_rhs[block * nm + k] = f[k] / fs;
        }
        if dim == 2 {
            momentum_rhs[block * nm + 2] = m[2] / (fs * ls);
        } else {
            for k in 0..3 {
                momentum_rhs[block * nm + 3 + k] = m[k] / (fs * ls);
            }
        }
    }
    let mut walls: Vec<WallRows> = Vec::new();
    for u in &unknowns {
        let c = &scene.contacts[u.contact];
        if let Body::Wall(w) = c.b {
            let k = match walls.iter().position(|x| x.wall == w) {
                Some(k) => k,
                None => {
                    walls.push(WallRows {
                        wall: w,
                        rows: Triplets::new(dim, n),
                    });
                    walls.len() - 1
                }
            };
            for j in 0..u.count(dim) {
                for d in 0..dim {
                    walls[k].rows.push(d, u.offset + j, u.directions[j][d]);
                }
            }
        }
    }
    Ok(System {
        dim,
        unknowns,
        n,
        grains,
        stress,
        stress_rhs,
        momentum,
        momentum_rhs,
        scales,
        walls,
    })
}
