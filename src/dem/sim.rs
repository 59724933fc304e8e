//! The simulator: grains (disks or spheres), walls (planes and rigid balls),
//! a cell-grid Verlet neighbour list carrying the tangential contact history,
//! contact forces, velocity-Verlet integration with optional Cundall local and
//! viscous damping, and servo walls.
//!
//! Vectors are `[f64; 3]` with z = 0 in 2D (nothing ever produces a z
//! component there, so 2D stays exactly planar).

use super::law::Interaction;
use crate::scene::Vec3;

#[inline(always)]
fn sub(a: Vec3, b: Vec3) -> Vec3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline(always)]
fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline(always)]
fn cross(a: Vec3, b: Vec3) -> Vec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
/// Sign with sign(0) = 0.
#[inline(always)]
fn sign(x: f64) -> f64 {
    if x > 0.0 {
        1.0
    } else if x < 0.0 {
        -1.0
    } else {
        0.0
    }
}
#[inline(always)]
fn add_to(a: &mut Vec3, b: Vec3) {
    a[0] += b[0];
    a[1] += b[1];
    a[2] += b[2];
}
#[inline(always)]
fn sub_from(a: &mut Vec3, b: Vec3) {
    a[0] -= b[0];
    a[1] -= b[1];
    a[2] -= b[2];
}

/// The shape of a wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WallShape {
    /// A plane through the wall's position with this unit normal pointing into
    /// the region the grains occupy.
    Plane { normal: Vec3 },
    /// A rigid disk (2D) or sphere (3D): an impactor or intruder. It does not rotate.
    Ball { radius: f64 },
}

/// How a wall moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Motion {
    /// Moves with its (constant) velocity; zero for a fixed wall.
    Prescribed,
    /// A free rigid body of this mass (per unit thickness in 2D), under the
    /// grains' forces and gravity.
    Free { mass: f64 },
    /// A plane whose normal velocity is driven so that the normal force it
    /// carries reaches `stress` times its current area (span of the walls
    /// across it). Freezing the servo sets it to `Prescribed` with zero velocity.
    Servo { stress: f64 },
}

/// Tangential history of one contact plus its persistent id (0: not touching).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct History {
    pub xi: Vec3,
    pub id: u64,
}

#[derive(Debug, Clone)]
pub struct Wall {
    pub name: String,
    pub shape: WallShape,
    /// A point of the plane, or the ball's centre.
    pub position: Vec3,
    pub velocity: Vec3,
    pub acceleration: Vec3,
    pub motion: Motion,
    pub law: Interaction,
    /// Per grain: the history of its contact with this wall.
    pub(crate) history: Vec<History>,
    /// Total force this wall exerts on the grains (last evaluation).
    pub force: Vec3,
    /// Sum of the normal tangent stiffnesses of its contacts (servo gain).
    pub stiffness: f64,
    /// Largest servo speed [m/s].
    pub servo_speed: f64,
}

/// One contact as recorded for output.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ContactRecord {
    pub a: u32,
    /// Grain index, or wall index when `wall` is set.
    pub b: u32,
    pub wall: bool,
    pub point: Vec3,
    pub normal: Vec3,
    /// Force on `a` by `b`.
    pub force: Vec3,
    pub id: u64,
    pub mu: f64,
}

#[derive(Debug, Clone, Copy)]
struct Pair {
    i: u32,
    j: u32,
    hist: History,
    /// The grain law's [`Interaction::pair_constants`] for this pair.
    constants: [f64; 2],
}

/// Cell-grid Verlet list: all pairs closer than the sum of radii plus a skin,
/// sorted by (i, j), and per wall the grains within the skin of it; rebuilt
/// when some grain or wall has moved more than half the skin.
#[derive(Debug, Clone, Default)]
struct NeighbourList {
    pairs: Vec<Pair>,
    skin: f64,
    reference: Vec<Vec3>,
    /// Per wall: its shape and position at the build, and the grains (in
    /// increasing order) that may touch it before the next build.
    wall_reference: Vec<(WallShape, Vec3)>,
    wall_near: Vec<Vec<u32>>,
    /// The grain law the pair constants were computed with.
    law: Option<Interaction>,
    builds: u64,
    // Scratch for the counting sort and the next list.
    cell_of: Vec<u32>,
    cell_start: Vec<u32>,
    fill: Vec<u32>,
    sorted: Vec<u32>,
    spare: Vec<Pair>,
}

pub struct System {
    pub dim: usize,
    pub x: Vec<Vec3>,
    pub v: Vec<Vec3>,
    pub w: Vec<Vec3>,
    /// Contact force and torque about the centroid (last evaluation).
    pub f: Vec<Vec3>,
    pub t: Vec<Vec3>,
    /// Acceleration and angular acceleration the integrator uses.
    pub a: Vec<Vec3>,
    pub alpha: Vec<Vec3>,
    pub radius: Vec<f64>,
    pub mass: Vec<f64>,
    pub inertia: Vec<f64>,
    pub walls: Vec<Wall>,
    pub grain_law: Interaction,
    pub gravity: Vec3,
    pub dt: f64,
    /// Cundall local non-viscous damping coefficient (0: off).
    pub local_damping: f64,
    /// Viscous drag rate [1/s] on grain velocities (0: off).
    pub viscous_damping: f64,
    /// Servo gain: fraction of the force error corrected per step.
    pub servo_gain: f64,
    nlist: NeighbourList,
    next_id: u64,
    pub time: f64,
    pub steps: u64,
    /// Record contacts at the next force evaluation.
    pub(crate) record: bool,
    pub(crate) records: Vec<ContactRecord>,
    /// Sum of |f| over contacts and their number (last evaluation).
    pub contact_force_sum: f64,
    pub contact_count: usize,
    /// Largest overlap relative to the smaller radius (last evaluation).
    pub max_overlap: f64,
}

impl System {
    /// Grains at `x` with radii and density (mass per unit thickness in 2D),
    /// all at rest; `skin` is the Verlet-list margin.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        dim: usize,
        x: Vec<Vec3>,
        radius: Vec<f64>,
        density: f64,
        grain_law: Interaction,
        gravity: Vec3,
        dt: f64,
        skin: f64,
    ) -> System {
        let n = x.len();
        let (mass, inertia): (Vec<f64>, Vec<f64>) = radius
            .iter()
            .map(|&r| {
                if dim == 2 {
                    let m = density * std::f64::consts::PI * r * r;
                    (m, 0.5 * m * r * r)
                } else {
                    let m = density * 4.0 / 3.0 * std::f64::consts::PI * r * r * r;
                    (m, 0.4 * m * r * r)
                }
            })
            .unzip();
        System {
            dim,
            x,
            v: vec![[0.0; 3]; n],
            w: vec![[0.0; 3]; n],
            f: vec![[0.0; 3]; n],
            t: vec![[0.0; 3]; n],
            a: vec![[0.0; 3]; n],
            alpha: vec![[0.0; 3]; n],
            radius,
            mass,
            inertia,
            walls: Vec::new(),
            grain_law,
            gravity,
            dt,
            local_damping: 0.0,
            viscous_damping: 0.0,
            servo_gain: 0.01,
            nlist: NeighbourList {
                skin,
                ..Default::default()
            },
            next_id: 1,
            time: 0.0,
            steps: 0,
            record: false,
            records: Vec::new(),
            contact_force_sum: 0.0,
            contact_count: 0,
            max_overlap: 0.0,
        }
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Adds a wall; returns its index.
    #[allow(clippy::too_many_arguments)]
    pub fn add_wall(
        &mut self,
        name: &str,
        shape: WallShape,
        position: Vec3,
        velocity: Vec3,
        motion: Motion,
        law: Interaction,
        servo_speed: f64,
    ) -> usize {
        self.walls.push(Wall {
            name: name.to_owned(),
            shape,
            position,
            velocity,
            acceleration: [0.0; 3],
            motion,
            law,
            history: vec![History::default(); self.len()],
            force: [0.0; 3],
            stiffness: 0.0,
            servo_speed,
        });
        self.walls.len() - 1
    }

    pub fn wall_index(&self, name: &str) -> Option<usize> {
        self.walls.iter().position(|w| w.name == name)
    }

    pub fn neighbour_builds(&self) -> u64 {
        self.nlist.builds
    }

    fn needs_rebuild(&self) -> bool {
        if self.nlist.reference.len() != self.len()
            || self.nlist.wall_reference.len() != self.walls.len()
        {
            return true;
        }
        let limit = 0.25 * self.nlist.skin * self.nlist.skin;
        let moved = |x: &Vec3, r: &Vec3| {
            let d = sub(*x, *r);
            dot(d, d) > limit
        };
        self.walls
            .iter()
            .zip(&self.nlist.wall_reference)
            .any(|(wall, (shape, at))| wall.shape != *shape || moved(&wall.position, at))
            || self
                .x
                .iter()
                .zip(&self.nlist.reference)
                .any(|(x, r)| moved(x, r))
    }

    /// Per wall, the grains that can touch it while neither they nor the wall
    /// move more than half the skin: gap below the skin (with a sliver of
    /// margin against round-off in the gap).
    fn near_walls(&mut self) {
        let skin = self.nlist.skin * (1.0 + 1e-9) + 1e-300;
        self.nlist.wall_near.resize(self.walls.len(), Vec::new());
        self.nlist.wall_reference.clear();
        for (wall, near) in self.walls.iter().zip(self.nlist.wall_near.iter_mut()) {
            near.clear();
            for (i, (x, &ri)) in self.x.iter().zip(&self.radius).enumerate() {
                let gap = match wall.shape {
                    WallShape::Plane { normal } => dot(sub(*x, wall.position), normal) - ri,
                    WallShape::Ball { radius } => {
                        let d = sub(wall.position, *x);
                        dot(d, d).sqrt() - ri - radius
                    }
                };
                // A NaN gap keeps the grain a candidate.
                if gap < skin || gap.is_nan() {
                    near.push(i as u32);
                }
            }
            self.nlist.wall_reference.push((wall.shape, wall.position));
        }
    }

    /// Rebuilds the pair list with a cell grid (O(N)), keeping the history of
    /// pairs present in both lists.
    // Out of line: it is rare, and inlined it crowds the force loop.
    #[inline(never)]
    fn rebuild(&mut self) {
        let n = self.len();
        let dim = self.dim;
        let rmax = self.radius.iter().cloned().fold(0.0, f64::max);
        let reach = 2.0 * rmax + self.nlist.skin;
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for x in &self.x {
            for k in 0..dim {
                lo[k] = lo[k].min(x[k]);
                hi[k] = hi[k].max(x[k]);
            }
        }
        let mut cells = [1usize; 3];
        let mut size = [1.0f64; 3];
        for k in 0..dim {
            let extent = (hi[k] - lo[k]).max(reach);
            cells[k] = ((extent / reach).floor() as usize).clamp(1, 1 << 20);
            size[k] = extent / cells[k] as f64;
            // Guard: a degenerate extent must still give cells ≥ reach.
            if size[k] < reach {
                size[k] = reach;
            }
        }
        let total = cells[0] * cells[1] * cells[2];
        let cell_index = |x: &Vec3| -> [usize; 3] {
            let mut c = [0usize; 3];
            for k in 0..dim {
                c[k] = (((x[k] - lo[k]) / size[k]) as usize).min(cells[k] - 1);
            }
            c
        };
        let nl = &mut self.nlist;
        nl.cell_of.clear();
        nl.cell_start.clear();
        nl.cell_start.resize(total + 1, 0);
        for x in &self.x {
            let c = cell_index(x);
            let id = (c[2] * cells[1] + c[1]) * cells[0] + c[0];
            nl.cell_of.push(id as u32);
            nl.cell_start[id + 1] += 1;
        }
        for c in 0..total {
            nl.cell_start[c + 1] += nl.cell_start[c];
        }
        nl.sorted.clear();
        nl.sorted.resize(n, 0);
        nl.fill.clear();
        nl.fill.extend_from_slice(&nl.cell_start[..total]);
        for i in 0..n {
            let c = nl.cell_of[i] as usize;
            nl.sorted[nl.fill[c] as usize] = i as u32;
            nl.fill[c] += 1;
        }
        let skin = nl.skin;
        let mut pairs = std::mem::take(&mut nl.spare);
        pairs.clear();
        let law = self.grain_law;
        let (radius, mass) = (&self.radius, &self.mass);
        let mut near: Vec<u32> = Vec::with_capacity(64);
        let zr: std::ops::RangeInclusive<isize> = if dim == 3 { -1..=1 } else { 0..=0 };
        for i in 0..n {
            let xi = self.x[i];
            let ri = self.radius[i];
            let c = cell_index(&xi);
            near.clear();
            for dz in zr.clone() {
                let cz = c[2] as isize + dz;
                if cz < 0 || cz >= cells[2] as isize {
                    continue;
                }
                for dy in -1..=1isize {
                    let cy = c[1] as isize + dy;
                    if cy < 0 || cy >= cells[1] as isize {
                        continue;
                    }
                    for dx in -1..=1isize {
                        let cx = c[0] as isize + dx;
                        if cx < 0 || cx >= cells[0] as isize {
                            continue;
                        }
                        let id = ((cz as usize * cells[1] + cy as usize) * cells[0]) + cx as usize;
                        let (s, e) = (nl.cell_start[id] as usize, nl.cell_start[id + 1] as usize);
                        for &j in &nl.sorted[s..e] {
                            if (j as usize) <= i {
                                continue;
                            }
                            let d = sub(self.x[j as usize], xi);
                            let reach = ri + self.radius[j as usize] + skin;
                            if dot(d, d) < reach * reach {
                                near.push(j);
                            }
                        }
                    }
                }
            }
            near.sort_unstable();
            pairs.extend(near.iter().map(|&j| {
                let (ri, rj) = (radius[i], radius[j as usize]);
                let (mi, mj) = (mass[i], mass[j as usize]);
                Pair {
                    i: i as u32,
                    j,
                    hist: History::default(),
                    constants: law.pair_constants(ri * rj / (ri + rj), mi * mj / (mi + mj)),
                }
            }));
        }
        // Carry over histories: both lists are sorted by (i, j).
        let old = &nl.pairs;
        let mut k = 0;
        for p in pairs.iter_mut() {
            while k < old.len() && (old[k].i, old[k].j) < (p.i, p.j) {
                k += 1;
            }
            if k < old.len() && (old[k].i, old[k].j) == (p.i, p.j) {
                p.hist = old[k].hist;
            }
        }
        // A pair that leaves the list while touching would lose its history;
        // the skin criterion guarantees it cannot be touching.
        nl.spare = std::mem::replace(&mut nl.pairs, pairs);
        nl.law = Some(law);
        nl.reference.clone_from(&self.x);
        nl.builds += 1;
        self.near_walls();
    }

    /// Recomputes the pair constants after the grain law was changed.
    fn update_pair_constants(&mut self) {
        let law = self.grain_law;
        let (radius, mass) = (&self.radius, &self.mass);
        for p in self.nlist.pairs.iter_mut() {
            let (i, j) = (p.i as usize, p.j as usize);
            let (ri, rj) = (radius[i], radius[j]);
            let (mi, mj) = (mass[i], mass[j]);
            p.constants = law.pair_constants(ri * rj / (ri + rj), mi * mj / (mi + mj));
        }
        self.nlist.law = Some(law);
    }

    /// Evaluates all contact forces at the current positions with the current
    /// velocities. `advance` adds this step's tangential increment to the
    /// histories (false: evaluate the state without moving the springs).
    pub fn compute_forces(&mut self, advance: bool) {
        if self.needs_rebuild() {
            self.rebuild();
        } else if self.nlist.law != Some(self.grain_law) {
            self.update_pair_constants();
        }
        let dt = if advance { self.dt } else { 0.0 };
        self.f.fill([0.0; 3]);
        self.t.fill([0.0; 3]);
        let record = self.record;
        self.records.clear();
        let mut force_sum = 0.0;
        let mut count = 0usize;
        let mut max_overlap = 0.0f64;
        let law = self.grain_law;
        let x = &self.x;
        let v = &self.v;
        let w = &self.w;
        let radius = &self.radius;
        let mass = &self.mass;
        let f = &mut self.f;
        let t = &mut self.t;
        let next_id = &mut self.next_id;
        let records = &mut self.records;
        for pair in self.nlist.pairs.iter_mut() {
            let (i, j) = (pair.i as usize, pair.j as usize);
            let d = sub(x[j], x[i]);
            let dist2 = dot(d, d);
            let (ri, rj) = (radius[i], radius[j]);
            let reach = ri + rj;
            if dist2 >= reach * reach {
                if pair.hist.id != 0 {
                    pair.hist = History::default();
                }
                continue;
            }
            let dist = dist2.sqrt();
            let n = [d[0] / dist, d[1] / dist, d[2] / dist];
            let delta = reach - dist;
            let arm_i = ri - 0.5 * delta;
            let arm_j = rj - 0.5 * delta;
            let (vi, vj, wi, wj) = (v[i], v[j], w[i], w[j]);
            // The contact point is at arm_i n from i and −arm_j n from j:
            // ω_i × r_i − ω_j × r_j = (arm_i ω_i + arm_j ω_j) × n.
            let spin = cross(
                [
                    arm_i * wi[0] + arm_j * wj[0],
                    arm_i * wi[1] + arm_j * wj[1],
                    arm_i * wi[2] + arm_j * wj[2],
                ],
                n,
            );
            let rel = [
                vi[0] - vj[0] + spin[0],
                vi[1] - vj[1] + spin[1],
                vi[2] - vj[2] + spin[2],
            ];
            let vn = dot(rel, n);
            let vt = [rel[0] - vn * n[0], rel[1] - vn * n[1], rel[2] - vn * n[2]];
            if pair.hist.id == 0 {
                pair.hist.id = *next_id;
                *next_id += 1;
            }
            let cf = law.force_with(delta, pair.constants, vn, vt, n, &mut pair.hist.xi, dt);
            let fa = [
                -cf.normal * n[0] + cf.tangential[0],
                -cf.normal * n[1] + cf.tangential[1],
                -cf.normal * n[2] + cf.tangential[2],
            ];
            add_to(&mut f[i], fa);
            sub_from(&mut f[j], fa);
            // Only the tangential force has a moment about the centres
            // (r ∥ n): r_i × f = arm_i n × f_t, −r_j × f = arm_j n × f_t.
            let moment = cross(n, cf.tangential);
            add_to(
                &mut t[i],
                [arm_i * moment[0], arm_i * moment[1], arm_i * moment[2]],
            );
            add_to(
                &mut t[j],
                [arm_j * moment[0], arm_j * moment[1], arm_j * moment[2]],
            );
            force_sum += dot(fa, fa).sqrt();
            count += 1;
            // Divides only for a candidate maximum.
            let smaller = ri.min(rj);
            if delta > max_overlap * smaller {
                max_overlap = max_overlap.max(delta / smaller);
            }
            if record {
                records.push(ContactRecord {
                    a: i as u32,
                    b: j as u32,
                    wall: false,
                    point: [
                        x[i][0] + arm_i * n[0],
                        x[i][1] + arm_i * n[1],
                        x[i][2] + arm_i * n[2],
                    ],
                    normal: n,
                    force: fa,
                    id: pair.hist.id,
                    mu: law.mu,
                });
            }
        }
        for (wi, (wall, near)) in self.walls.iter_mut().zip(&self.nlist.wall_near).enumerate() {
            wall.force = [0.0; 3];
            wall.stiffness = 0.0;
            let wall_mass = match wall.motion {
                Motion::Free { mass } => Some(mass),
                _ => None,
            };
            // Grains off this list cannot touch the wall and have no history with it.
            for &i in near {
                let i = i as usize;
                let ri = radius[i];
                let (delta, n, rstar) = match wall.shape {
                    WallShape::Plane { normal } => {
                        let h = dot(sub(x[i], wall.position), normal);
                        (ri - h, [-normal[0], -normal[1], -normal[2]], ri)
                    }
                    WallShape::Ball { radius: rb } => {
                        let d = sub(wall.position, x[i]);
                        let reach = ri + rb;
                        let dist2 = dot(d, d);
                        if dist2 >= reach * reach {
                            if wall.history[i].id != 0 {
                                wall.history[i] = History::default();
                            }
                            continue;
                        }
                        let dist = dist2.sqrt();
                        (
                            reach - dist,
                            [d[0] / dist, d[1] / dist, d[2] / dist],
                            ri * rb / reach,
                        )
                    }
                };
                let hist = &mut wall.history[i];
                if delta <= 0.0 {
                    if hist.id != 0 {
                        *hist = History::default();
                    }
                    continue;
                }
                let r_i = [ri * n[0], ri * n[1], ri * n[2]];
                let ci = cross(w[i], r_i);
                let rel = [
                    v[i][0] + ci[0] - wall.velocity[0],
                    v[i][1] + ci[1] - wall.velocity[1],
                    v[i][2] + ci[2] - wall.velocity[2],
                ];
                let vn = dot(rel, n);
                let vt = [rel[0] - vn * n[0], rel[1] - vn * n[1], rel[2] - vn * n[2]];
                let mstar = match wall_mass {
                    Some(mb) => mass[i] * mb / (mass[i] + mb),
                    None => mass[i],
                };
                if hist.id == 0 {
                    hist.id = *next_id;
                    *next_id += 1;
                }
                let cf = wall
                    .law
                    .force(delta, rstar, mstar, vn, vt, n, &mut hist.xi, dt);
                let fa = [
                    -cf.normal * n[0] + cf.tangential[0],
                    -cf.normal * n[1] + cf.tangential[1],
                    -cf.normal * n[2] + cf.tangential[2],
                ];
                add_to(&mut f[i], fa);
                add_to(&mut t[i], cross(r_i, fa));
                add_to(&mut wall.force, fa);
                wall.stiffness += cf.stiffness;
                force_sum += dot(fa, fa).sqrt();
                count += 1;
                max_overlap = max_overlap.max(delta / ri);
                if record {
                    records.push(ContactRecord {
                        a: i as u32,
                        b: wi as u32,
                        wall: true,
                        point: [x[i][0] + r_i[0], x[i][1] + r_i[1], x[i][2] + r_i[2]],
                        normal: n,
                        force: fa,
                        id: hist.id,
                        mu: wall.law.mu,
                    });
                }
            }
        }
        self.contact_force_sum = force_sum;
        self.contact_count = count;
        self.max_overlap = max_overlap;
    }

    /// Accelerations from the last forces: a = f/m + g, α = t/I, with the
    /// configured numerical damping folded in when on.
    fn update_accelerations(&mut self) {
        let g = self.gravity;
        let local = self.local_damping;
        let visc = self.viscous_damping;
        for i in 0..self.len() {
            let m = self.mass[i];
            let mut total = [
                self.f[i][0] + m * g[0],
                self.f[i][1] + m * g[1],
                self.f[i][2] + m * g[2],
            ];
            let mut torque = self.t[i];
            if local > 0.0 {
                // Cundall: oppose the motion with a fraction of the unbalanced load.
                for k in 0..3 {
                    total[k] -= local * total[k].abs() * sign(self.v[i][k]);
                    torque[k] -= local * torque[k].abs() * sign(self.w[i][k]);
                }
            }
            if visc > 0.0 {
                for k in 0..3 {
                    total[k] -= visc * m * self.v[i][k];
                    torque[k] -= visc * self.inertia[i] * self.w[i][k];
                }
            }
            let inv_i = 1.0 / self.inertia[i];
            for k in 0..3 {
                self.a[i][k] = total[k] / m;
                self.alpha[i][k] = torque[k] * inv_i;
            }
        }
        for wall in &mut self.walls {
            if let Motion::Free { mass } = wall.motion {
                for k in 0..3 {
                    // The grains push the wall with −force.
                    wall.acceleration[k] = -wall.force[k] / mass + g[k];
                }
            }
        }
    }

    /// Evaluates forces at the present state (histories not advanced) and sets
    /// the accelerations from them; used before the first step and to sample
    /// a state without moving it.
    pub fn evaluate(&mut self) {
        self.compute_forces(false);
        self.update_accelerations();
    }

    /// One velocity-Verlet step.
    pub fn step(&mut self) {
        let dt = self.dt;
        let h = 0.5 * dt;
        for (((x, v), w), (a, alpha)) in self
            .x
            .iter_mut()
            .zip(self.v.iter_mut())
            .zip(self.w.iter_mut())
            .zip(self.a.iter().zip(&self.alpha))
        {
            for k in 0..3 {
                v[k] += h * a[k];
                w[k] += h * alpha[k];
                x[k] += dt * v[k];
            }
        }
        self.servo_velocities();
        for wall in &mut self.walls {
            if let Motion::Free { .. } = wall.motion {
                for k in 0..3 {
                    wall.velocity[k] += h * wall.acceleration[k];
                }
            }
            for k in 0..3 {
                wall.position[k] += dt * wall.velocity[k];
            }
        }
        self.compute_forces(true);
        self.update_accelerations();
        for ((v, w), (a, alpha)) in self
            .v
            .iter_mut()
            .zip(self.w.iter_mut())
            .zip(self.a.iter().zip(&self.alpha))
        {
            for k in 0..3 {
                v[k] += h * a[k];
                w[k] += h * alpha[k];
            }
        }
        for wall in &mut self.walls {
            if let Motion::Free { .. } = wall.motion {
                for k in 0..3 {
                    wall.velocity[k] += h * wall.acceleration[k];
                }
            }
        }
        self.time += dt;
        self.steps += 1;
    }

    /// Area of a plane wall: the product of the spans between the pairs of
    /// opposite axis-aligned planes across it (the grains' extent where there
    /// is no such pair). 2D areas are lengths (per unit thickness).
    pub fn wall_area(&self, index: usize) -> f64 {
        let WallShape::Plane { normal } = self.walls[index].shape else {
            return 0.0;
        };
        let mut area = 1.0;
        for axis in 0..self.dim {
            if normal[axis].abs() > 0.5 {
                continue;
            }
            let mut lo = None;
            let mut hi = None;
            for wall in &self.walls {
                if let WallShape::Plane { normal: m } = wall.shape {
                    if m[axis] > 0.999 {
                        lo = Some(wall.position[axis]);
                    } else if m[axis] < -0.999 {
                        hi = Some(wall.position[axis]);
                    }
                }
            }
            let span = match (lo, hi) {
                (Some(l), Some(h)) => h - l,
                _ => {
                    let (mut l, mut h) = (f64::INFINITY, f64::NEG_INFINITY);
                    for (x, r) in self.x.iter().zip(&self.radius) {
                        l = l.min(x[axis] - r);
                        h = h.max(x[axis] + r);
                    }
                    h - l
                }
            };
            area *= span;
        }
        area
    }

    /// Normal load a plane wall carries (≥ 0 when it compresses the grains).
    pub fn wall_normal_force(&self, index: usize) -> f64 {
        match self.walls[index].shape {
            WallShape::Plane { normal } => dot(self.walls[index].force, normal),
            WallShape::Ball { .. } => 0.0,
        }
    }

    /// Relative error of each servo wall's load (0 when there are none).
    pub fn servo_error(&self) -> f64 {
        let mut worst: f64 = 0.0;
        for (k, wall) in self.walls.iter().enumerate() {
            if let Motion::Servo { stress } = wall.motion {
                let target = stress * self.wall_area(k);
                worst = worst.max((self.wall_normal_force(k) - target).abs() / target);
            }
        }
        worst
    }

    fn servo_velocities(&mut self) {
        let dt = self.dt;
        for k in 0..self.walls.len() {
            let Motion::Servo { stress } = self.walls[k].motion else {
                continue;
            };
            let WallShape::Plane { normal } = self.walls[k].shape else {
                continue;
            };
            let target = stress * self.wall_area(k);
            let load = self.wall_normal_force(k);
            let vmax = self.walls[k].servo_speed;
            let stiffness = self.walls[k].stiffness;
            // Far below the target the packing is loose and the contact
            // stiffness says nothing about how far the wall must travel:
            // approach at full speed, then let the stiffness-scaled law settle it.
            let speed = if stiffness > 0.0 && load > 0.5 * target {
                (self.servo_gain * (target - load) / (stiffness * dt)).clamp(-vmax, vmax)
            } else {
                vmax
            };
            self.walls[k].velocity = [speed * normal[0], speed * normal[1], speed * normal[2]];
        }
    }

    /// Stops every servo wall where it is; returns what to give [`System::resume_servos`].
    pub fn freeze_servos(&mut self) -> Vec<(usize, Motion)> {
        let mut frozen = Vec::new();
        for (k, wall) in self.walls.iter_mut().enumerate() {
            if let Motion::Servo { .. } = wall.motion {
                frozen.push((k, wall.motion));
                wall.motion = Motion::Prescribed;
                wall.velocity = [0.0; 3];
            }
        }
        frozen
    }

    /// Restarts the servos stopped by [`System::freeze_servos`].
    pub fn resume_servos(&mut self, frozen: &[(usize, Motion)]) {
        for &(k, motion) in frozen {
            self.walls[k].motion = motion;
        }
    }

    /// Largest relative error of the load of the given (frozen or active) servo walls.
    pub fn load_error(&self, servos: &[(usize, Motion)]) -> f64 {
        let mut worst: f64 = 0.0;
        for &(k, motion) in servos {
            if let Motion::Servo { stress } = motion {
                let target = stress * self.wall_area(k);
                worst = worst.max((self.wall_normal_force(k) - target).abs() / target);
            }
        }
        worst
    }

    /// Out-of-balance measures: (mean |Σf + m g| over grains / mean |f| over
    /// contacts, mean |Σ r×f| / (mean |f| · mean radius)), from the last
    /// evaluation. Grains without contacts count with zero net force only
    /// when there is no gravity.
    pub fn unbalanced(&self) -> (f64, f64) {
        if self.contact_count == 0 {
            return (f64::INFINITY, f64::INFINITY);
        }
        let mean_contact = self.contact_force_sum / self.contact_count as f64;
        let n = self.len() as f64;
        let mut force = 0.0;
        let mut moment = 0.0;
        for i in 0..self.len() {
            let m = self.mass[i];
            let net = [
                self.f[i][0] + m * self.gravity[0],
                self.f[i][1] + m * self.gravity[1],
                self.f[i][2] + m * self.gravity[2],
            ];
            force += dot(net, net).sqrt();
            moment += dot(self.t[i], self.t[i]).sqrt();
        }
        let mean_radius = self.radius.iter().sum::<f64>() / n;
        (
            force / n / mean_contact,
            moment / n / (mean_contact * mean_radius),
        )
    }

    /// Kinetic energy of the grains and free walls.
    pub fn kinetic_energy(&self) -> f64 {
        let mut e = 0.0;
        for i in 0..self.len() {
            e += 0.5 * self.mass[i] * dot(self.v[i], self.v[i])
                + 0.5 * self.inertia[i] * dot(self.w[i], self.w[i]);
        }
        for wall in &self.walls {
            if let Motion::Free { mass } = wall.motion {
                e += 0.5 * mass * dot(wall.velocity, wall.velocity);
            }
        }
        e
    }

    /// Elastic energy stored in the contacts plus gravitational potential (−m g·x).
    pub fn potential_energy(&self) -> f64 {
        let mut e = 0.0;
        for p in &self.nlist.pairs {
            if p.hist.id == 0 {
                continue;
            }
            let (i, j) = (p.i as usize, p.j as usize);
            let d = sub(self.x[j], self.x[i]);
            let delta = self.radius[i] + self.radius[j] - dot(d, d).sqrt();
            if delta > 0.0 {
                let rstar = self.radius[i] * self.radius[j] / (self.radius[i] + self.radius[j]);
                e += self.grain_law.energy(delta, rstar, p.hist.xi);
            }
        }
        for wall in &self.walls {
            for i in 0..self.len() {
                let hist = wall.history[i];
                if hist.id == 0 {
                    continue;
                }
                let ri = self.radius[i];
                let (delta, rstar) = match wall.shape {
                    WallShape::Plane { normal } => {
                        (ri - dot(sub(self.x[i], wall.position), normal), ri)
                    }
                    WallShape::Ball { radius } => {
                        let d = sub(wall.position, self.x[i]);
                        (ri + radius - dot(d, d).sqrt(), ri * radius / (ri + radius))
                    }
                };
                if delta > 0.0 {
                    e += wall.law.energy(delta, rstar, hist.xi);
                }
            }
            if let Motion::Free { mass } = wall.motion {
                e -= mass * dot(self.gravity, wall.position);
            }
        }
        for i in 0..self.len() {
            e -= self.mass[i] * dot(self.gravity, self.x[i]);
        }
        e
    }

    /// Elastic energy of the contacts only.
    pub fn elastic_energy(&self) -> f64 {
        let mut e = self.potential_energy();
        for i in 0..self.len() {
            e += self.mass[i] * dot(self.gravity, self.x[i]);
        }
        for wall in &self.walls {
            if let Motion::Free { mass } = wall.motion {
                e += mass * dot(self.gravity, wall.position);
            }
        }
        e
    }

    /// Total linear momentum of grains and free walls.
    pub fn momentum(&self) -> Vec3 {
        let mut p = [0.0; 3];
        for i in 0..self.len() {
            for k in 0..3 {
                p[k] += self.mass[i] * self.v[i][k];
            }
        }
        for wall in &self.walls {
            if let Motion::Free { mass } = wall.motion {
                for k in 0..3 {
                    p[k] += mass * wall.velocity[k];
                }
            }
        }
        p
    }

    /// Total angular momentum about the origin (grains only).
    pub fn angular_momentum(&self) -> Vec3 {
        let mut l = [0.0; 3];
        for i in 0..self.len() {
            let c = cross(self.x[i], self.v[i]);
            for k in 0..3 {
                l[k] += self.mass[i] * c[k] + self.inertia[i] * self.w[i][k];
            }
        }
        l
    }
}
