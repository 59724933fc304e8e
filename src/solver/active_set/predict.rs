//! A cheap guess of the active set before the first factorisation.
//!
//! At the unconstrained optimum x₀ the gradient of the objective is balanced
//! by the momentum multipliers, so the correction δ the cones ask for solves
//!
//! ```text
//!     minimise ½ δᵀ(AᵀA + λ²I)δ   subject to   C δ = 0,   x₀ + δ ∈ K
//! ```
//!
//! — no right-hand side is left. C δ = 0 is relaxed to an augmented
//! Lagrangian: a penalty ρ‖T C δ‖² (T normalises each row of C in the metric
//! of diag(AᵀA + λ²), so ρ has no units) whose centre is shifted by the
//! multipliers every few sweeps. Block Gauss–Seidel over the contacts solves
//! each contact's 2×2 problem over its wedge exactly, colour by colour
//! (contacts of one colour share no row, so each colour is relaxed in
//! parallel and the sweep is still Gauss–Seidel). The correction is local
//! (each grain's stress pins its own contacts), so some tens of sweeps, each
//! O(nnz), settle which piece of its cone each contact lands on. Only that
//! guess is used: the Newton iteration that follows still solves the exact
//! problem, so a wrong guess costs solves, never accuracy. In 3D each
//! contact's local problem is a 3×3 quadratic over its circular cone: the
//! unconstrained minimum when inside, else the best ray of the boundary (a
//! one-dimensional search over the sliding direction) or the apex.
//!
//! After the active set's first solve the same sweeps run around its answer
//! x₁: there the cones balance the gradient with their forces v (exact now,
//! from the solve's multipliers), so the correction's objective gains the
//! linear term vᵀδ.

use super::{Contact, Piece};
use crate::solver::{LeastSquares, Triplets};
use rayon::prelude::*;
use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};

/// Penalty weight ρ of the relaxed momentum rows, relative to the stress rows.
/// 2D, 3·10⁴ grains, stress noise (changes after the first solve, 100
/// sweeps, multipliers every 5): 3 → 97, 10 → 23, 30 → 121.
const PENALTY: f64 = 10.0;
/// Sweeps between updates of the multipliers (method of multipliers): without
/// them the penalty's bias left 330 changes after 300 sweeps; every 2, 3, 5,
/// 10 sweeps: 21, 20, 23, 36 changes (2 settled after 78 sweeps, 3 after 87).
const SWEEPS_PER_UPDATE: usize = 3;
/// Gauss–Seidel sweeps at most (2D 10⁵, changes after the first solve: 50
/// sweeps 133, 100 → 47, 150 → 33, 250 → 32; a sweep costs ~10 ms there).
const MAX_SWEEPS: usize = 100;
/// Multiplier updates in a row without any contact changing piece before
/// the guess is taken as settled.
const SETTLED_UPDATES: usize = 2;
/// Contacts of one colour handed to a thread at a time.
const CHUNK: usize = 1024;

/// A contact's unknowns (normal first, then its 0–2 tangential ones; `count`
/// of them) and μ; K slots (2 in 2D, 3 in 3D).
struct Local<const K: usize> {
    unknowns: [usize; K],
    count: usize,
    mu: f64,
}

/// Each contact's rows of [A; C], packed: row index (C rows after A's) and
/// the entries of its normal and tangential unknowns.
struct Stencils<const K: usize> {
    offset: Vec<usize>,
    row: Vec<u32>,
    val: Vec<[f64; K]>,
}

impl<const K: usize> Stencils<K> {
    fn of(a: &Triplets, c: &Triplets, contacts: &[Contact]) -> Option<Stencils<K>> {
        if a.nrows + c.nrows > u32::MAX as usize {
            return None;
        }
        // Which contact and slot (0 normal, 1 tangent) each unknown is.
        let mut owner = vec![None; a.ncols];
        for (k, ct) in contacts.iter().enumerate() {
            owner[ct.normal] = Some((k, 0));
            for (slot, &t) in ct.tangents.iter().enumerate().take(K - 1) {
                owner[t] = Some((k, 1 + slot));
            }
        }
        let mut entries: Vec<Vec<(u32, [f64; K])>> = vec![Vec::new(); contacts.len()];
        let a_entries = (0..a.nnz()).map(|q| (a.rows[q], a.cols[q], a.vals[q]));
        let c_entries = (0..c.nnz()).map(|q| (a.nrows + c.rows[q], c.cols[q], c.vals[q]));
        for (r, j, v) in a_entries.chain(c_entries) {
            let Some((k, slot)) = owner[j] else { continue };
            let list = &mut entries[k];
            let r = r as u32;
            match list.iter_mut().find(|(row, _)| *row == r) {
                Some((_, vals)) => vals[slot] += v,
                None => {
                    let mut vals = [0.0; K];
                    vals[slot] = v;
                    list.push((r, vals));
                }
            }
        }
        let mut stencils = Stencils {
            offset: vec![0],
            row: Vec::new(),
            val: Vec::new(),
        };
        for list in entries {
            for (r, v) in list {
                stencils.row.push(r);
                stencils.val.push(v);
            }
            stencils.offset.push(stencils.row.len());
        }
        Some(stencils)
    }

    /// The same stencils with the contacts in `order`.
    fn permuted(&self, order: &[usize]) -> Stencils<K> {
        let mut out = Stencils {
            offset: Vec::with_capacity(order.len() + 1),
            row: Vec::with_capacity(self.row.len()),
            val: Vec::with_capacity(self.val.len()),
        };
        out.offset.push(0);
        for &k in order {
            let range = self.offset[k]..self.offset[k + 1];
            out.row.extend_from_slice(&self.row[range.clone()]);
            out.val.extend_from_slice(&self.val[range]);
            out.offset.push(out.row.len());
        }
        out
    }

    /// Greedy colouring: contacts of one colour share no row, so a sweep may
    /// relax each colour's contacts in parallel and still be Gauss–Seidel.
    /// Returns the contacts ordered by colour and the groups to sweep in
    /// turn: each colour's range there and how many of its contacts go to a
    /// thread at a time. Contacts past 64 colours (a grain with scores of
    /// contacts) form a last group relaxed on one thread.
    fn colours(&self, rows: usize) -> (Vec<usize>, Vec<(Range<usize>, usize)>) {
        const SERIAL: u8 = 64;
        let count = self.offset.len() - 1;
        let mut taken = vec![0u64; rows];
        let mut colour = vec![0u8; count];
        for (k, c) in colour.iter_mut().enumerate() {
            let used = (self.offset[k]..self.offset[k + 1])
                .fold(0u64, |m, p| m | taken[self.row[p] as usize]);
            let free = (!used).trailing_zeros();
            *c = if free < 64 { free as u8 } else { SERIAL };
            if free < 64 {
                for p in self.offset[k]..self.offset[k + 1] {
                    taken[self.row[p] as usize] |= 1 << free;
                }
            }
        }
        let mut order: Vec<usize> = (0..count).collect();
        order.sort_by_key(|&k| colour[k]);
        let mut groups = Vec::new();
        let mut start = 0;
        for end in 1..=count {
            if end == count || colour[order[end]] != colour[order[start]] {
                let chunk = if colour[order[start]] == SERIAL {
                    end - start
                } else {
                    CHUNK
                };
                groups.push((start..end, chunk));
                start = end;
            }
        }
        (order, groups)
    }

    fn of_contact(&self, k: usize) -> impl Iterator<Item = (usize, [f64; K])> + '_ {
        (self.offset[k]..self.offset[k + 1]).map(move |p| (self.row[p] as usize, self.val[p]))
    }
}

/// The pieces the relaxed correction lands on. `start` is the unconstrained
/// optimum, or an active-set iterate with `cone_forces` v (per contact,
/// normal then tangential): the correction's objective then gains vᵀδ, the
/// gradient the cones balance there. `diag` is diag(AᵀA + λ²I), `rho` each
/// contact's ρ of the Newton iteration (for the 3D springs). `None` when
/// the stencils do not fit (more than 2³² rows).
pub(super) fn pieces(
    problem: &LeastSquares,
    contacts: &[Contact],
    start: &[f64],
    cone_forces: Option<&[(f64, [f64; 2])]>,
    diag: &[f64],
    rho: &[f64],
) -> Option<Vec<Piece>> {
    if contacts.iter().any(|ct| ct.tangents.len() > 1) {
        pieces_in::<3>(problem, contacts, start, cone_forces, diag, rho)
    } else {
        pieces_in::<2>(problem, contacts, start, cone_forces, diag, rho)
    }
}

fn pieces_in<const K: usize>(
    problem: &LeastSquares,
    contacts: &[Contact],
    start: &[f64],
    cone_forces: Option<&[(f64, [f64; 2])]>,
    diag: &[f64],
    rho: &[f64],
) -> Option<Vec<Piece>> {
    let LeastSquares { a, c, lambda, .. } = *problem;
    let mut pieces: Vec<Piece> = contacts
        .iter()
        .map(|ct| {
            let (xn, xt) = ct.split(start);
            ct.project(xn, xt).0
        })
        .collect();
    let scale = start.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return Some(pieces);
    }
    let stencils = Stencils::<K>::of(a, c, contacts)?;
    // Sweeps run colour by colour, each colour's contacts in parallel; the
    // contacts are stored in that order.
    let (order, groups) = stencils.colours(a.nrows + c.nrows);
    let mut stencils = stencils.permuted(&order);
    // A flat copy: the sweeps visit every contact a hundred times, and
    // chasing each contact's own tangent list through the heap dominated
    // their cost (3.7 s against 1.1 s at 2D 10⁵ on a scene read from CSV).
    let locals: Vec<Local<K>> = (order.iter())
        .map(|&k| {
            let ct = &contacts[k];
            let mut unknowns = [ct.normal; K];
            for (slot, &t) in ct.tangents.iter().enumerate().take(K - 1) {
                unknowns[1 + slot] = t;
            }
            Local {
                unknowns,
                count: 1 + ct.tangents.len().min(K - 1),
                mu: ct.mu,
            }
        })
        .collect();
    let lambda2 = lambda * lambda;
    // Row weights: 1 on A, ρT² on C, each C row of unit norm in the metric
    // diag(AᵀA + λ²)⁻¹ so that ρ has no units.
    let mut weight = vec![1.0; a.nrows + c.nrows];
    let c_weight = &mut weight[a.nrows..];
    c_weight.iter_mut().for_each(|w| *w = 0.0);
    for q in 0..c.nnz() {
        let h = diag[c.cols[q]];
        if h > 0.0 {
            c_weight[c.rows[q]] += c.vals[q] * c.vals[q] / h;
        }
    }
    for w in c_weight.iter_mut() {
        *w = if *w > 0.0 { PENALTY / *w } else { 0.0 };
    }
    // The weights go into the stencils (√w per row), so a sweep reads one
    // row state per entry.
    for (r, v) in stencils.row.iter().zip(&mut stencils.val) {
        let root = weight[*r as usize].sqrt();
        v.iter_mut().for_each(|e| *e *= root);
    }
    // Each contact's block of M = AᵀA + λ²I + ρCᵀT²C.
    let blocks: Vec<[[f64; K]; K]> = (0..locals.len())
        .map(|k| {
            let mut h = [[0.0; K]; K];
            for (i, row) in h.iter_mut().enumerate() {
                row[i] = lambda2;
            }
            for (_, v) in stencils.of_contact(k) {
                for i in 0..K {
                    for j in 0..K {
                        h[i][j] += v[i] * v[j];
                    }
                }
            }
            h
        })
        .collect();

    // The correction's gradient at δ = 0 (the cone forces at the start),
    // per contact in colour order.
    let gradient_at_start: Vec<[f64; K]> = (order.iter())
        .map(|&k| {
            let mut g = [0.0; K];
            if let Some(&(normal, tangential)) = cone_forces.and_then(|v| v.get(k)) {
                g[0] = normal;
                g[1..].copy_from_slice(&tangential[..K - 1]);
            }
            g
        })
        .collect();

    // δ per contact and, per row of [A; C] (scaled by √w), the residual
    // plus the multiplier's shift of the penalty's centre, and the residual
    // alone: [√w (r + s), √w r]. Contacts of one colour write disjoint rows;
    // atomics (plain loads and stores on x86) let them share the vector.
    let sweep = Sweep {
        gradient_at_start: &gradient_at_start,
        locals: &locals,
        blocks: &blocks,
        stencils: &stencils,
        start,
        lambda2,
        rows: (0..a.nrows + c.nrows)
            .map(|_| [AtomicU64::new(0), AtomicU64::new(0)])
            .collect(),
    };
    let mut delta = vec![[0.0; K]; locals.len()];
    let mut guess: Vec<Piece> = order.iter().map(|&k| pieces[k]).collect();
    let mut settled = 0;
    let mut flips_since_update = 0;
    for count in 1..=MAX_SWEEPS {
        for (range, chunk) in &groups {
            flips_since_update += (delta[range.clone()].par_chunks_mut(*chunk))
                .zip(guess[range.clone()].par_chunks_mut(*chunk))
                .enumerate()
                .map(|(index, (delta, guess))| {
                    let first = range.start + index * chunk;
                    let mut flips = 0;
                    for (i, (d, p)) in delta.iter_mut().zip(guess.iter_mut()).enumerate() {
                        flips += usize::from(sweep.relax(first + i, d, p));
                    }
                    flips
                })
                .sum::<usize>();
        }
        if count % SWEEPS_PER_UPDATE == 0 {
            for row in &sweep.rows[a.nrows..] {
                let [with_shift, residual] = load(row);
                row[0].store((with_shift + residual).to_bits(), Relaxed);
            }
            settled = if flips_since_update == 0 {
                settled + 1
            } else {
                0
            };
            flips_since_update = 0;
            if settled >= SETTLED_UPDATES {
                break;
            }
        }
    }
    // A 3D sliding contact's Newton step carries a spring across its sliding
    // direction, stiffened by the cone's force v (κ = μα/τ of the projection
    // of x − ρv). The relaxed gradient is that force's guess. Without it the
    // first solve had no springs and the second added them all (10⁵ spheres:
    // ~50 000). With them, 3D 10⁴ spheres, 30 % sliding, stress noise: 5
    // solves (2 factorised) instead of 6 (3 factorised).
    if K == 3 {
        (guess.par_iter_mut().enumerate()).for_each(|(i, piece)| {
            if !matches!(piece, Piece::Boundary { .. }) {
                return;
            }
            let k = order[i];
            let (force, grad) = (sweep.current(i, &delta[i]), sweep.gradient(i, &delta[i]));
            let (_, sliding) = contacts[k].natural(
                (force[0], [force[1], force[2]]),
                (grad[0], [grad[1], grad[2]]),
                rho[k],
            );
            // A non-finite force keeps the guess's piece without a spring.
            if matches!(sliding, Piece::Boundary { kappa, dir } if kappa.is_finite() && dir.iter().all(|d| d.is_finite())) {
                *piece = sliding;
            }
        });
    }
    for (&k, piece) in order.iter().zip(guess) {
        pieces[k] = piece;
    }
    Some(pieces)
}

/// What a sweep reads (contacts in colour order) and the row states it
/// updates.
struct Sweep<'a, const K: usize> {
    gradient_at_start: &'a [[f64; K]],
    locals: &'a [Local<K>],
    blocks: &'a [[[f64; K]; K]],
    stencils: &'a Stencils<K>,
    start: &'a [f64],
    lambda2: f64,
    rows: Vec<[AtomicU64; 2]>,
}

fn load(row: &[AtomicU64; 2]) -> [f64; 2] {
    [
        f64::from_bits(row[0].load(Relaxed)),
        f64::from_bits(row[1].load(Relaxed)),
    ]
}

impl<const K: usize> Sweep<'_, K> {
    /// The relaxed objective's gradient over contact k's unknowns: the force
    /// its cone would exert (the multipliers' guess).
    fn gradient(&self, k: usize, delta: &[f64; K]) -> [f64; K] {
        let mut grad = [0.0; K];
        for i in 0..K {
            grad[i] = self.lambda2 * delta[i] + self.gradient_at_start[k][i];
        }
        for (r, v) in self.stencils.of_contact(k) {
            let with_shift = f64::from_bits(self.rows[r][0].load(Relaxed));
            for i in 0..K {
                grad[i] += v[i] * with_shift;
            }
        }
        grad
    }

    /// Contact k's force: the start plus its correction.
    fn current(&self, k: usize, delta: &[f64; K]) -> [f64; K] {
        let ct = &self.locals[k];
        let mut current = [0.0; K];
        for i in 0..ct.count {
            current[i] = self.start[ct.unknowns[i]] + delta[i];
        }
        current
    }

    /// Moves contact k (its correction `delta`) to the minimum of its local
    /// problem and updates its rows; returns whether its piece changed.
    fn relax(&self, k: usize, delta: &mut [f64; K], piece: &mut Piece) -> bool {
        let ct = &self.locals[k];
        let grad = self.gradient(k, delta);
        let current = self.current(k, delta);
        let block = &self.blocks[k];
        // h = g − H x: the same quadratic with its origin at the apex.
        let mut h = [0.0; 3];
        let mut hm = [[0.0; 3]; 3];
        for i in 0..ct.count {
            h[i] = grad[i];
            for j in 0..ct.count {
                h[i] -= block[i][j] * current[j];
                hm[i][j] = block[i][j];
            }
        }
        let found = match ct.count {
            1 => local_nonnegative(hm[0][0], h[0]).map(|(p, z)| (p, [z, 0.0, 0.0])),
            2 => local_wedge(ct.mu, &[hm[0][0], hm[0][1], hm[1][1]], &[h[0], h[1]])
                .map(|(p, z)| (p, [z[0], z[1], 0.0])),
            _ => local_cone(ct.mu, &hm, &h),
        };
        let Some((next_piece, next)) = found else {
            return false;
        };
        let flipped = *piece != next_piece;
        *piece = next_piece;
        let mut step = [0.0; K];
        for i in 0..ct.count {
            step[i] = next[i] - current[i];
        }
        if step != [0.0; K] {
            for i in 0..K {
                delta[i] += step[i];
            }
            for (r, v) in self.stencils.of_contact(k) {
                let change: f64 = (0..K).map(|i| v[i] * step[i]).sum();
                let [with_shift, residual] = load(&self.rows[r]);
                self.rows[r][0].store((with_shift + change).to_bits(), Relaxed);
                self.rows[r][1].store((residual + change).to_bits(), Relaxed);
            }
        }
        flipped
    }
}

/// Minimises ½ h_nn z² + h z over z ≥ 0.
fn local_nonnegative(hnn: f64, h: f64) -> Option<(Piece, f64)> {
    if hnn <= 0.0 {
        return None;
    }
    let z = -h / hnn;
    Some(if z > 0.0 {
        (Piece::Interior, z)
    } else {
        (Piece::Apex, 0.0)
    })
}

/// Minimises ½ zᵀHz + hᵀz (H = [h_nn, h_nt, h_tt]) over the wedge
/// |z_t| ≤ μ z_n: the unconstrained minimum when admissible, else the best
/// of the faces and the apex.
fn local_wedge(mu: f64, block: &[f64; 3], h: &[f64; 2]) -> Option<(Piece, [f64; 2])> {
    let [hnn, hnt, htt] = *block;
    let det = hnn * htt - hnt * hnt;
    if !(hnn > 0.0 && htt > 0.0 && det > 1e-12 * hnn * htt) {
        return None;
    }
    let [hn, ht] = *h;
    let zn = -(htt * hn - hnt * ht) / det;
    let zt = -(hnn * ht - hnt * hn) / det;
    if zt.abs() <= mu * zn {
        return Some((Piece::Interior, [zn, zt]));
    }
    // Faces z = s (1, ±μ), s ≥ 0; the apex is s = 0 on either.
    let mut best = (Piece::Apex, [0.0; 2], 0.0);
    for sign in [1.0, -1.0] {
        let e = [1.0, sign * mu];
        let curvature = hnn * e[0] * e[0] + 2.0 * hnt * e[0] * e[1] + htt * e[1] * e[1];
        let slope = hn * e[0] + ht * e[1];
        let s = (-slope / curvature).max(0.0);
        let q = 0.5 * curvature * s * s + slope * s;
        if s > 0.0 && q < best.2 {
            let piece = Piece::Boundary {
                dir: [sign, 0.0],
                kappa: 1.0,
            };
            best = (piece, [s * e[0], s * e[1]], q);
        }
    }
    Some((best.0, best.1))
}

/// Angles of the first scan of the cone's boundary (a fixed table: no
/// trigonometry per contact), and safeguarded Newton steps refining the best
/// one. Newton on the ray value's stationarity settles in a few steps where
/// golden-section search took 18 evaluations, each with a sine and cosine
/// (with the scan's, ~60 % of the guess's time at 10⁴ spheres; the guess
/// now takes ~0.7 of its time, `qs` end to end 0.96–0.975).
const CONE_SCAN: usize = 24;
const CONE_NEWTON: usize = 30;
/// Golden sections where Newton has no bracket (rare): the angle to
/// 2π/24 · 0.618⁴⁰ ≈ 1e-9.
const CONE_GOLDEN: usize = 40;
/// The ray's angle is settled to this (radians): far below what the pieces
/// the guess hands on need.
const CONE_ANGLE_TOL: f64 = 1e-10;

/// (θ, cos θ, sin θ) of the scanned angles θ = 2πi / CONE_SCAN.
fn scan_angles() -> &'static [(f64, f64, f64); CONE_SCAN] {
    static TABLE: std::sync::OnceLock<[(f64, f64, f64); CONE_SCAN]> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        std::array::from_fn(|i| {
            let theta = i as f64 * std::f64::consts::TAU / CONE_SCAN as f64;
            (theta, theta.cos(), theta.sin())
        })
    })
}

/// The quadratic ½ zᵀMz + hᵀz along the boundary rays z = s e(θ),
/// e(θ) = (1, μ cos θ, μ sin θ), s ≥ 0: slope p(θ) = hᵀe, curvature
/// k(θ) = eᵀMe, best s = −p/k and value −p²/(2k) when p < 0 < k.
struct BoundaryRays<'a> {
    mu: f64,
    m: &'a [[f64; 3]; 3],
    h: &'a [f64; 3],
}

impl BoundaryRays<'_> {
    fn direction(&self, cos: f64, sin: f64) -> [f64; 3] {
        [1.0, self.mu * cos, self.mu * sin]
    }

    /// (value, s, e) of the best point on the ray; (0, 0, e) when the ray
    /// does not go downhill.
    fn best(&self, cos: f64, sin: f64) -> (f64, f64, [f64; 3]) {
        let e = self.direction(cos, sin);
        let (mut curvature, mut slope) = (0.0, 0.0);
        for i in 0..3 {
            slope += self.h[i] * e[i];
            for j in 0..3 {
                curvature += e[i] * self.m[i][j] * e[j];
            }
        }
        if curvature.is_nan() || curvature <= 0.0 || slope >= 0.0 {
            return (0.0, 0.0, e);
        }
        let s = -slope / curvature;
        (0.5 * slope * s, s, e)
    }

    /// g(θ) = 2p′k − pk′ and g′(θ). The value's derivative is −p g/(2k²),
    /// so where the ray goes downhill (p < 0) it has g's sign.
    fn stationarity(&self, cos: f64, sin: f64) -> (f64, f64) {
        let (mu, m, h) = (self.mu, self.m, self.h);
        let e = self.direction(cos, sin);
        // e′ = (0, −μ sin, μ cos), e″ = (0, −μ cos, −μ sin).
        let d1 = [0.0, -mu * sin, mu * cos];
        let d2 = [0.0, -mu * cos, -mu * sin];
        let dot = |a: &[f64; 3], b: &[f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        let mul = |v: &[f64; 3]| -> [f64; 3] { std::array::from_fn(|i| dot(&m[i], v)) };
        let (me, md1) = (mul(&e), mul(&d1));
        let (p, p1, p2) = (dot(h, &e), dot(h, &d1), dot(h, &d2));
        let k = dot(&e, &me);
        let k1 = 2.0 * dot(&d1, &me);
        let k2 = 2.0 * (dot(&d2, &me) + dot(&d1, &md1));
        (2.0 * p1 * k - p * k1, 2.0 * p2 * k + p1 * k1 - p * k2)
    }

    /// The angle in [lo, hi] where g changes sign (g(lo) < 0 < g(hi)), by
    /// Newton steps kept inside the bracket (bisection when a step leaves it).
    fn settle(&self, mut lo: f64, mut hi: f64, start: f64) -> f64 {
        let mut theta = start;
        for _ in 0..CONE_NEWTON {
            let (g, dg) = self.stationarity(theta.cos(), theta.sin());
            if g < 0.0 {
                lo = theta;
            } else {
                hi = theta;
            }
            let newton = theta - g / dg;
            let next = if dg > 0.0 && newton > lo && newton < hi {
                newton
            } else {
                0.5 * (lo + hi)
            };
            let moved = (next - theta).abs();
            theta = next;
            if moved <= CONE_ANGLE_TOL || hi - lo <= CONE_ANGLE_TOL {
                break;
            }
        }
        theta
    }

    /// The angle of the least value in [lo, hi] by golden sections
    /// (unimodal near the best scanned angle).
    fn golden(&self, mut lo: f64, mut hi: f64) -> f64 {
        let value = |t: f64| self.best(t.cos(), t.sin()).0;
        let ratio = 0.5 * (5f64.sqrt() - 1.0);
        let mut t1 = hi - ratio * (hi - lo);
        let mut t2 = lo + ratio * (hi - lo);
        let (mut q1, mut q2) = (value(t1), value(t2));
        for _ in 0..CONE_GOLDEN {
            if q1 < q2 {
                hi = t2;
                (t2, q2) = (t1, q1);
                t1 = hi - ratio * (hi - lo);
                q1 = value(t1);
            } else {
                lo = t1;
                (t1, q1) = (t2, q2);
                t2 = lo + ratio * (hi - lo);
                q2 = value(t2);
            }
        }
        if q1 < q2 {
            t1
        } else {
            t2
        }
    }
}

/// Minimises ½ zᵀHz + hᵀz over the circular cone ‖z_t‖ ≤ μ z_n (3×3 H):
/// the unconstrained minimum when inside, else the best point on a ray
/// s (1, μ cos θ, μ sin θ), s ≥ 0, of the boundary (for a ray the best s and
/// the value are closed-form; θ by a scan and safeguarded Newton steps), or
/// the apex when no ray goes downhill.
fn local_cone(mu: f64, m: &[[f64; 3]; 3], h: &[f64; 3]) -> Option<(Piece, [f64; 3])> {
    if let Some(z) = solve3(m, h) {
        let z = [-z[0], -z[1], -z[2]];
        if z[1] * z[1] + z[2] * z[2] <= (mu * z[0]).powi(2) && z[0] >= 0.0 {
            return Some((Piece::Interior, z));
        }
    } else {
        return None;
    }
    let rays = BoundaryRays { mu, m, h };
    let table = scan_angles();
    let (mut best_at, mut best) = (0, f64::INFINITY);
    for (i, &(_, cos, sin)) in table.iter().enumerate() {
        let (q, _, _) = rays.best(cos, sin);
        if q < best {
            (best_at, best) = (i, q);
        }
    }
    if best >= 0.0 {
        return Some((Piece::Apex, [0.0; 3]));
    }
    let step = std::f64::consts::TAU / CONE_SCAN as f64;
    let scanned = table[best_at].0;
    let (lo, hi) = (scanned - step, scanned + step);
    // The minimum lies within a scan step of the best scanned angle. Where
    // both neighbours go downhill with the value's slope pointing inwards,
    // Newton settles it; otherwise (a narrow downhill fan) golden sections.
    let (_, lo_cos, lo_sin) = table[(best_at + CONE_SCAN - 1) % CONE_SCAN];
    let (_, hi_cos, hi_sin) = table[(best_at + 1) % CONE_SCAN];
    let bracketed = rays.best(lo_cos, lo_sin).0 < 0.0
        && rays.best(hi_cos, hi_sin).0 < 0.0
        && rays.stationarity(lo_cos, lo_sin).0 < 0.0
        && rays.stationarity(hi_cos, hi_sin).0 > 0.0;
    let refined = if bracketed {
        rays.settle(lo, hi, scanned)
    } else {
        rays.golden(lo, hi)
    };
    let theta = if rays.best(refined.cos(), refined.sin()).0 <= best {
        refined
    } else {
        scanned
    };
    let (cos, sin) = (theta.cos(), theta.sin());
    let (_, s, e) = rays.best(cos, sin);
    Some((
        Piece::Boundary {
            dir: [cos, sin],
            kappa: 1.0,
        },
        [s * e[0], s * e[1], s * e[2]],
    ))
}

/// x with M x = h for a symmetric positive definite 3×3 M (Cramer's rule),
/// `None` when M is (nearly) singular.
fn solve3(m: &[[f64; 3]; 3], h: &[f64; 3]) -> Option<[f64; 3]> {
    let det3 = |a: &[[f64; 3]; 3]| {
        a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1])
            - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
            + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
    };
    let det = det3(m);
    let scale = m[0][0] * m[1][1] * m[2][2];
    if !(m[0][0] > 0.0 && m[1][1] > 0.0 && m[2][2] > 0.0 && det > 1e-12 * scale) {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut a = *m;
        for i in 0..3 {
            a[i][k] = h[i];
        }
        *xk = det3(&a) / det;
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Contacts of one colour share no row; 70 contacts on one row (a grain
    /// with 70 contacts) overflow the 64 colours into a last group that is
    /// relaxed on one thread.
    #[test]
    fn colours_share_no_row_and_overflow_into_a_serial_group() {
        // Contacts 0..70 all touch row 0 and their own row 1 + k; contacts
        // 70..170 form a chain, contact k touching rows k and k + 1.
        let mut stencils = Stencils {
            offset: vec![0],
            row: Vec::new(),
            val: Vec::new(),
        };
        let mut add = |rows: &[u32]| {
            for &r in rows {
                stencils.row.push(r);
                stencils.val.push([1.0, 0.0]);
            }
            stencils.offset.push(stencils.row.len());
        };
        for k in 0..70 {
            add(&[0, 1 + k]);
        }
        for k in 0..100 {
            add(&[200 + k, 201 + k]);
        }
        let (order, groups) = stencils.colours(400);
        assert_eq!(order.len(), 170);
        let mut seen = [false; 170];
        for &k in &order {
            assert!(!seen[k]);
            seen[k] = true;
        }
        let (last, chunk) = groups.last().unwrap().clone();
        assert_eq!(
            (last.len(), chunk),
            (6, 6),
            "70 − 64 contacts relaxed serially"
        );
        for (range, _) in &groups[..groups.len() - 1] {
            let mut rows: Vec<u32> = (range.clone())
                .flat_map(|i| stencils.of_contact(order[i]).map(|(r, _)| r as u32))
                .collect();
            let total = rows.len();
            rows.sort_unstable();
            rows.dedup();
            assert_eq!(rows.len(), total, "a colour with a shared row");
        }
    }
}

#[cfg(test)]
mod cone_tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn value(m: &[[f64; 3]; 3], h: &[f64; 3], z: &[f64; 3]) -> f64 {
        let mut q = 0.0;
        for i in 0..3 {
            q += h[i] * z[i];
            for j in 0..3 {
                q += 0.5 * z[i] * m[i][j] * z[j];
            }
        }
        q
    }

    /// L Lᵀ + shift·I for a random 3×3 L: symmetric positive definite.
    fn random_quadratic(rng: &mut ChaCha8Rng, shift: f64) -> [[f64; 3]; 3] {
        let l: [[f64; 3]; 3] =
            std::array::from_fn(|_| std::array::from_fn(|_| rng.gen_range(-1.0..1.0)));
        std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                (0..3).map(|k| l[i][k] * l[j][k]).sum::<f64>() + if i == j { shift } else { 0.0 }
            })
        })
    }

    /// The local cone minimum is no worse than any of many admissible points
    /// and itself admissible; its piece matches where it lies.
    #[test]
    fn local_cone_minimum_beats_sampled_admissible_points() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..300 {
            let mu = rng.gen_range(0.1..1.0);
            let m = random_quadratic(&mut rng, 0.1);
            let h: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
            let (piece, z) = local_cone(mu, &m, &h).unwrap();
            let tau = z[1].hypot(z[2]);
            assert!(tau <= mu * z[0] * (1.0 + 1e-9) + 1e-12, "{z:?}");
            match piece {
                Piece::Interior => assert!(tau < mu * z[0]),
                Piece::Apex => assert_eq!(z, [0.0; 3]),
                Piece::Boundary { .. } => assert!((tau - mu * z[0]).abs() < 1e-9),
            }
            let best = value(&m, &h, &z);
            for _ in 0..2000 {
                let s = rng.gen_range(0.0..3.0f64);
                let r = rng.gen_range(0.0..=1.0f64) * mu * s;
                let t = rng.gen_range(0.0..std::f64::consts::TAU);
                let y = [s, r * t.cos(), r * t.sin()];
                assert!(value(&m, &h, &y) >= best - 1e-7, "{y:?} beats {z:?}");
            }
        }
    }

    /// The least value over the boundary rays by a dense scan of θ.
    fn scanned_minimum(mu: f64, m: &[[f64; 3]; 3], h: &[f64; 3]) -> f64 {
        let rays = BoundaryRays { mu, m, h };
        (0..200_000)
            .map(|i| {
                let t = i as f64 * std::f64::consts::TAU / 200_000.0;
                rays.best(t.cos(), t.sin()).0
            })
            .fold(0.0, f64::min)
    }

    fn check(mu: f64, m: &[[f64; 3]; 3], h: &[f64; 3]) {
        let Some((Piece::Boundary { dir, .. }, z)) = local_cone(mu, m, h) else {
            return;
        };
        let (found, dense) = (value(m, h, &z), scanned_minimum(mu, m, h));
        // The dense scan is 3e-5 rad from the best angle at worst: the value
        // found must be at least as good, up to round-off.
        assert!(
            found <= dense + 1e-12 * dense.abs(),
            "{found} against {dense}"
        );
        assert!((dir[0].hypot(dir[1]) - 1.0).abs() < 1e-12);
        assert!((z[1].hypot(z[2]) - mu * z[0]).abs() <= 1e-12 * z[0]);
    }

    /// Newton on the angle reaches the best boundary ray (no worse than a
    /// scan of 2·10⁵ angles) on random convex quadratics, μ from 0.01 to 10.
    #[test]
    fn settled_angle_beats_a_dense_scan() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut boundary = 0;
        for _ in 0..400 {
            let mu = 10f64.powf(rng.gen_range(-2.0..1.0));
            let m = random_quadratic(&mut rng, 0.05);
            let h: [f64; 3] = std::array::from_fn(|_| rng.gen_range(-1.0..1.0));
            boundary += usize::from(matches!(
                local_cone(mu, &m, &h),
                Some((Piece::Boundary { .. }, _))
            ));
            check(mu, &m, &h);
        }
        assert!(boundary > 100, "only {boundary} cases on the boundary");
    }

    /// A narrow fan of downhill rays (only within 0.1 rad of θ = 0.3, less
    /// than a scan step): no Newton bracket, golden sections settle it.
    #[test]
    fn narrow_downhill_fan_is_settled_without_a_bracket() {
        let (mu, theta) = (0.5, 0.3f64);
        let m = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        // h·e = a + μ b cos(θ − 0.3) < 0 only where cos(θ − 0.3) > 0.995.
        let (a, b) = (0.995 * mu, -1.0);
        let h = [a, b * theta.cos(), b * theta.sin()];
        let rays = BoundaryRays { mu, m: &m, h: &h };
        let table = scan_angles();
        let downhill = table
            .iter()
            .filter(|&&(_, c, s)| rays.best(c, s).0 < 0.0)
            .count();
        assert!(downhill <= 1, "{downhill} scanned rays go downhill");
        let (piece, z) = local_cone(mu, &m, &h).unwrap();
        let Piece::Boundary { dir, .. } = piece else {
            panic!("{piece:?}");
        };
        // A search on values resolves a minimum to about √ε.
        assert!((dir[1].atan2(dir[0]) - theta).abs() < 1e-7, "{dir:?}");
        check(mu, &m, &h);
        assert!(z[0] > 0.0);
    }
}

#[cfg(test)]
mod spring_tests {
    use super::super::{diagonal_and_rho, solve, ActiveSetSettings, Contact, Piece};
    use crate::assemble::{assemble, AssembleOptions};
    use crate::bench::{generate, perturb, Noise, PackingSpec};
    use crate::infer::{cones, ConeModel};
    use crate::solver::sparse_ls::{EqualityLeastSquares, Ordering, STALE_TOL};

    /// Spring stiffness k = (1 − κ)/(κρ) of a piece (0 off the boundary).
    fn stiffness(piece: Piece, rho: f64) -> f64 {
        match piece {
            Piece::Boundary { kappa, .. } => (1.0 - kappa) / (kappa * rho),
            _ => 0.0,
        }
    }

    /// The guess gives 3D sliding contacts the spring of the cone's force,
    /// close to the optimum's; with κ = 1 (no spring, as before) the first
    /// solve's springs all differed from the second's.
    #[test]
    fn guessed_springs_are_near_the_optimum_springs() {
        let mut spec = PackingSpec::new(3, 1000);
        spec.shear = 0.5 * spec.mu;
        spec.sliding = 0.3;
        let packing = generate(&spec).unwrap();
        let scene = perturb(&packing.scene, Noise::Stress, 18);
        let assembly = assemble(&scene, &AssembleOptions::default()).unwrap();
        let system = assembly.systems.iter().max_by_key(|s| s.n).unwrap();
        let cone_list = cones(system, ConeModel::Exact);
        let problem = system.least_squares(0.0);
        let mut ls = EqualityLeastSquares::with_ordering(
            problem.a,
            problem.c,
            &system.contact_blocks(),
            Ordering::for_dim(3),
        )
        .unwrap();
        let start = ls
            .solve(problem.a, problem.c, problem.b, problem.d, 0.0)
            .unwrap();
        let optimum = solve(
            &mut ls,
            &problem,
            &cone_list,
            &start.x,
            &ActiveSetSettings::default(),
        )
        .unwrap();
        assert!(optimum.converged, "{:?}", optimum.reason);

        let contacts: Vec<Contact> = cone_list.iter().map(|c| Contact::of(c).unwrap()).collect();
        let (diag, rho) = diagonal_and_rho(&problem, &contacts);
        let guess = super::pieces(&problem, &contacts, &start.x, None, &diag, &rho).unwrap();
        // Guessed/optimal stiffness where both slide.
        let ratios: Vec<f64> = (0..contacts.len())
            .filter_map(|k| {
                let (g, o) = (
                    stiffness(guess[k], rho[k]),
                    stiffness(optimum.pieces.0[k], rho[k]),
                );
                (g > 0.0 && o > 0.0).then_some(g / o)
            })
            .collect();
        let sliding = optimum.sliding;
        assert!(
            ratios.len() >= sliding * 9 / 10,
            "{} of {sliding} sliding contacts have a guessed spring",
            ratios.len()
        );
        // What counts is that the factor can keep them. Its own test is on
        // the spring's entries (√k times the direction across the sliding
        // one), relative to at least 1: a stiffness within STALE_TOL moves
        // √k by at most 17 %. A proxy: the turn of the direction, which the
        // factor's test also counts, is left out (measured: 355 of 419).
        let kept = ratios
            .iter()
            .filter(|r| (*r - 1.0).abs() <= STALE_TOL)
            .count();
        eprintln!(
            "{kept} of {} guessed springs within {STALE_TOL} of the optimum's",
            ratios.len()
        );
        assert!(4 * kept >= 3 * ratios.len(), "{kept} of {}", ratios.len());
    }
}
