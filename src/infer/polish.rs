//! Active-set polishing of an interior-point answer.
//!
//! An interior-point solution is accurate to its tolerance (~1e-8 in the gap,
//! often 1e-6 in the forces). The constraints it finds tight — a contact
//! sliding on its Coulomb cone, or opening (f_n = 0) — are imposed as linear
//! equalities and the least squares is solved exactly by the sparse
//! factorisation. The polished answer is kept only if it satisfies every cone
//! and its objective is no worse; otherwise the interior-point answer stands.

use crate::assemble::System;
use crate::error::Result;
use crate::solver::conic::Cone;
use crate::solver::{sparse_ls, Triplets};

/// Slack (relative to the largest unknown) under which a constraint counts as tight.
const ACTIVE: f64 = 1e-6;

/// The objective being polished: Σ w‖K x − b‖² with hard equalities.
pub(crate) struct Objective<'a> {
    /// (matrix, rhs, weight) terms.
    pub terms: Vec<(&'a Triplets, &'a [f64], f64)>,
    /// Hard equalities C x = d.
    pub equalities: Vec<(&'a Triplets, &'a [f64])>,
    /// λ² on every unknown.
    pub tikhonov: f64,
}

impl Objective<'_> {
    fn value(&self, x: &[f64]) -> f64 {
        let mut v = self.tikhonov * x.iter().map(|a| a * a).sum::<f64>();
        for (m, b, w) in &self.terms {
            v += w * m
                .mul(x)
                .iter()
                .zip(*b)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>();
        }
        v
    }
}

/// Rows a·x = 0 for each constraint tight at `x`.
fn active_rows(x: &[f64], cones: &[Cone], n: usize) -> Triplets {
    let scale = x
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    let tight = ACTIVE * scale;
    let mut rows = Triplets::new(0, n);
    let mut add = |coefs: &[(usize, f64)]| {
        let r = rows.nrows;
        rows.nrows += 1;
        for &(j, v) in coefs {
            rows.push(r, j, v);
        }
    };
    for cone in cones {
        match *cone {
            Cone::NonNegative { normal } => {
                if x[normal] <= tight {
                    add(&[(normal, 1.0)]);
                }
            }
            Cone::Wedge {
                normal,
                tangent,
                mu,
            } => {
                if x[normal] <= tight {
                    add(&[(normal, 1.0)]);
                    add(&[(tangent, 1.0)]);
                } else if mu * x[normal] - x[tangent].abs() <= tight {
                    add(&[(tangent, 1.0), (normal, -mu * x[tangent].signum())]);
                }
            }
            Cone::Circular { normal, t1, t2, mu } => {
                let t = x[t1].hypot(x[t2]);
                if x[normal] <= tight {
                    add(&[(normal, 1.0)]);
                    add(&[(t1, 1.0)]);
                    add(&[(t2, 1.0)]);
                } else if mu * x[normal] - t <= tight {
                    // Sliding: the tangential force keeps its direction at magnitude μ f_n.
                    let (c1, c2) = (x[t1] / t, x[t2] / t);
                    add(&[(t1, 1.0), (normal, -mu * c1)]);
                    add(&[(t2, 1.0), (normal, -mu * c2)]);
                }
            }
            Cone::Pyramid {
                normal,
                t1,
                t2,
                mu,
                facets,
            } => {
                if x[normal] <= tight {
                    add(&[(normal, 1.0)]);
                    add(&[(t1, 1.0)]);
                    add(&[(t2, 1.0)]);
                    continue;
                }
                for (m, c, s) in crate::solver::conic::pyramid_facets(facets, mu) {
                    if m * x[normal] - c * x[t1] - s * x[t2] <= tight {
                        add(&[(normal, m), (t1, -c), (t2, -s)]);
                    }
                }
            }
        }
    }
    rows
}

/// Returns the polished unknowns, or `None` when polishing does not improve
/// on `x` (the caller keeps `x`).
pub(crate) fn polish(
    system: &System,
    objective: &Objective,
    cones: &[Cone],
    x: &[f64],
) -> Result<Option<Vec<f64>>> {
    let n = system.n;
    let active = active_rows(x, cones, n);
    // A = stacked √w K, b = stacked √w b.
    let rows: usize = objective.terms.iter().map(|t| t.0.nrows).sum();
    let mut a = Triplets::new(rows, n);
    let mut b = Vec::with_capacity(rows);
    let mut offset = 0;
    for (m, rhs, w) in &objective.terms {
        let s = w.sqrt();
        for k in 0..m.nnz() {
            a.push(offset + m.rows[k], m.cols[k], s * m.vals[k]);
        }
        b.extend(rhs.iter().map(|v| s * v));
        offset += m.nrows;
    }
    let zeros = vec![0.0; active.nrows];
    let mut c = Triplets::new(0, n);
    let mut d = Vec::new();
    for (m, rhs) in objective
        .equalities
        .iter()
        .copied()
        .chain(std::iter::once((&active, &zeros[..])))
    {
        let base = c.nrows;
        c.nrows += m.nrows;
        for k in 0..m.nnz() {
            c.push(base + m.rows[k], m.cols[k], m.vals[k]);
        }
        d.extend_from_slice(rhs);
    }
    let none = crate::solver::Triplets::new(0, a.ncols);
    let mut ls = sparse_ls::EqualityLeastSquares::with_ordering(
        &a,
        &c,
        &none,
        super::ordering(system, None),
    )?;
    let sol = ls.solve(&a, &c, &b, &d, objective.tikhonov.sqrt())?;
    if !sol.converged || sol.x.iter().any(|v| !v.is_finite()) {
        return Ok(None);
    }
    let scale = sol
        .x
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    if cones.iter().any(|c| c.violation(&sol.x) > 1e-9 * scale) {
        return Ok(None);
    }
    // The interior-point answer meets the equalities only to its tolerance, so
    // its objective may sit slightly below the exact constrained optimum.
    let (before, after) = (objective.value(x), objective.value(&sol.x));
    let floor = 1e-12 * b.iter().map(|v| v * v).sum::<f64>().max(1.0);
    if after > before * (1.0 + 1e-6) + floor {
        return Ok(None);
    }
    let mut polished = sol.x;
    for c in cones {
        c.project(&mut polished);
    }
    Ok(Some(polished))
}
