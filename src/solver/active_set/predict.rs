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
//! each contact's 2×2 problem over its wedge exactly. The correction is local
//! (each grain's stress pins its own contacts), so some tens of sweeps, each
//! O(nnz), settle which piece of its cone each contact lands on. Only that
//! guess is used: the Newton iteration that follows still solves the exact
//! problem, so a wrong guess costs solves, never accuracy. 2D and
//! frictionless contacts only (the 3D cone has no closed-form local
//! projection in a metric).

use super::{Contact, Piece};
use crate::solver::{LeastSquares, Triplets};

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

/// A 2D contact: its normal unknown, its tangential one if frictional, μ.
struct Wedge {
    normal: usize,
    tangent: Option<usize>,
    mu: f64,
}

/// Each contact's rows of [A; C], packed: row index (C rows after A's) and
/// the entries of its normal and tangential unknowns.
struct Stencils {
    offset: Vec<usize>,
    row: Vec<u32>,
    val: Vec<[f64; 2]>,
}

impl Stencils {
    fn of(a: &Triplets, c: &Triplets, contacts: &[Contact]) -> Option<Stencils> {
        if a.nrows + c.nrows > u32::MAX as usize {
            return None;
        }
        // Which contact and slot (0 normal, 1 tangent) each unknown is.
        let mut owner = vec![None; a.ncols];
        for (k, ct) in contacts.iter().enumerate() {
            owner[ct.normal] = Some((k, 0));
            if let Some(&t) = ct.tangents.first() {
                owner[t] = Some((k, 1));
            }
        }
        let mut entries: Vec<Vec<(u32, [f64; 2])>> = vec![Vec::new(); contacts.len()];
        let a_entries = (0..a.nnz()).map(|q| (a.rows[q], a.cols[q], a.vals[q]));
        let c_entries = (0..c.nnz()).map(|q| (a.nrows + c.rows[q], c.cols[q], c.vals[q]));
        for (r, j, v) in a_entries.chain(c_entries) {
            let Some((k, slot)) = owner[j] else { continue };
            let list = &mut entries[k];
            let r = r as u32;
            match list.iter_mut().find(|(row, _)| *row == r) {
                Some((_, vals)) => vals[slot] += v,
                None => {
                    let mut vals = [0.0; 2];
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

    fn of_contact(&self, k: usize) -> impl Iterator<Item = (usize, [f64; 2])> + '_ {
        (self.offset[k]..self.offset[k + 1]).map(move |p| (self.row[p] as usize, self.val[p]))
    }
}

/// The pieces the relaxed correction lands on, or `None` when some contact is
/// 3D (no guess; the caller starts from the pieces of x₀). `diag` is
/// diag(AᵀA + λ²I).
pub(super) fn pieces(
    problem: &LeastSquares,
    contacts: &[Contact],
    start: &[f64],
    diag: &[f64],
) -> Option<Vec<Piece>> {
    if contacts.iter().any(|ct| ct.tangents.len() > 1) {
        return None;
    }
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
    let mut stencils = Stencils::of(a, c, contacts)?;
    // A flat copy: the sweeps visit every contact a hundred times, and
    // chasing each contact's own tangent list through the heap dominated
    // their cost (3.7 s against 1.1 s at 2D 10⁵ on a scene read from CSV).
    let wedges: Vec<Wedge> = contacts
        .iter()
        .map(|ct| Wedge {
            normal: ct.normal,
            tangent: ct.tangents.first().copied(),
            mu: ct.mu,
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
        *v = [v[0] * root, v[1] * root];
    }
    // Each contact's block [h_nn, h_nt, h_tt] of M = AᵀA + λ²I + ρCᵀT²C.
    let blocks: Vec<[f64; 3]> = (0..contacts.len())
        .map(|k| {
            let mut h = [lambda2, 0.0, lambda2];
            for (_, [vn, vt]) in stencils.of_contact(k) {
                h[0] += vn * vn;
                h[1] += vn * vt;
                h[2] += vt * vt;
            }
            h
        })
        .collect();

    // δ per contact and, per row of [A; C] (scaled by √w), the residual
    // plus the multiplier's shift of the penalty's centre, and the residual
    // alone: [√w (r + s), √w r].
    let mut delta = vec![[0.0; 2]; contacts.len()];
    let mut rows = vec![[0.0; 2]; a.nrows + c.nrows];
    let mut settled = 0;
    let mut flips_since_update = 0;
    for sweep in 1..=MAX_SWEEPS {
        for (k, ct) in wedges.iter().enumerate() {
            let tangent = ct.tangent;
            let mut grad = [lambda2 * delta[k][0], lambda2 * delta[k][1]];
            for (r, [vn, vt]) in stencils.of_contact(k) {
                grad[0] += vn * rows[r][0];
                grad[1] += vt * rows[r][0];
            }
            let current = [
                start[ct.normal] + delta[k][0],
                tangent.map_or(0.0, |t| start[t] + delta[k][1]),
            ];
            let Some((piece, next)) = local_minimum(ct, &blocks[k], &current, &grad) else {
                continue;
            };
            if pieces[k] != piece {
                flips_since_update += 1;
                pieces[k] = piece;
            }
            let step = [next[0] - current[0], next[1] - current[1]];
            if step == [0.0; 2] {
                continue;
            }
            delta[k] = [delta[k][0] + step[0], delta[k][1] + step[1]];
            for (r, [vn, vt]) in stencils.of_contact(k) {
                let change = vn * step[0] + vt * step[1];
                rows[r] = [rows[r][0] + change, rows[r][1] + change];
            }
        }
        if sweep % SWEEPS_PER_UPDATE == 0 {
            for row in &mut rows[a.nrows..] {
                row[0] += row[1];
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
    Some(pieces)
}

/// Minimises the local quadratic with Hessian `block` ([h_nn, h_nt, h_tt]) and
/// gradient `grad` at `current` over the contact's cone: the unconstrained
/// minimum when admissible, else the best of the faces and the apex.
fn local_minimum(
    ct: &Wedge,
    block: &[f64; 3],
    current: &[f64; 2],
    grad: &[f64; 2],
) -> Option<(Piece, [f64; 2])> {
    let [hnn, hnt, htt] = *block;
    // q(z) = ½ zᵀHz + hᵀz with h = g − H x (the same quadratic, origin at 0).
    if ct.tangent.is_none() {
        if hnn <= 0.0 {
            return None;
        }
        let h = grad[0] - hnn * current[0];
        let z = -h / hnn;
        return Some(if z > 0.0 {
            (Piece::Interior, [z, 0.0])
        } else {
            (Piece::Apex, [0.0; 2])
        });
    }
    let det = hnn * htt - hnt * hnt;
    if !(hnn > 0.0 && htt > 0.0 && det > 1e-12 * hnn * htt) {
        return None;
    }
    let hn = grad[0] - (hnn * current[0] + hnt * current[1]);
    let ht = grad[1] - (hnt * current[0] + htt * current[1]);
    let zn = -(htt * hn - hnt * ht) / det;
    let zt = -(hnn * ht - hnt * hn) / det;
    if zt.abs() <= ct.mu * zn {
        return Some((Piece::Interior, [zn, zt]));
    }
    // Faces z = s (1, ±μ), s ≥ 0; the apex is s = 0 on either.
    let mut best = (Piece::Apex, [0.0; 2], 0.0);
    for sign in [1.0, -1.0] {
        let e = [1.0, sign * ct.mu];
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
