//! Active-set polishing of an interior-point answer.
//!
//! An interior-point solution is accurate to its tolerance (~1e-8 in the gap,
//! often 1e-6 in the forces). The constraints it finds tight — a contact
//! sliding on its Coulomb cone, or opening (f_n = 0) — are imposed as linear
//! equalities and the least squares is solved exactly by the sparse
//! factorisation. The polished answer is kept only if it satisfies every cone
//! and its objective is no worse; otherwise the interior-point answer stands.

use super::cascade::{ordering, Pattern};
use crate::error::Result;
use crate::solver::{sparse_ls, Triplets};
use crate::solver::{Cone, ConicProblem};

/// Slack (relative to the largest unknown) under which a constraint counts as tight.
const ACTIVE: f64 = 1e-6;

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
                for (m, c, s) in crate::solver::pyramid_facets(facets, mu) {
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
    pattern: &Pattern,
    problem: &ConicProblem,
    x: &[f64],
) -> Result<Option<Vec<f64>>> {
    let n = problem.n;
    let Some(stacked) = problem.least_squares() else {
        return Ok(None);
    };
    let ls = stacked.view();
    let active = active_rows(x, &problem.cones, n);
    // The problem's equalities, then the tight constraints.
    let mut c = ls.c.clone();
    c.nrows += active.nrows;
    for k in 0..active.nnz() {
        c.push(ls.c.nrows + active.rows[k], active.cols[k], active.vals[k]);
    }
    let mut d = ls.d.to_vec();
    d.resize(c.nrows, 0.0);
    // Contacts coupled so nested dissection cuts contacts (see cascade).
    let mut factor = sparse_ls::EqualityLeastSquares::with_ordering(
        ls.a,
        &c,
        &pattern.contact_blocks,
        ordering(pattern.dim, None),
    )?;
    let sol = factor.solve(ls.a, &c, ls.b, &d, ls.lambda)?;
    if !sol.converged || sol.x.iter().any(|v| !v.is_finite()) {
        return Ok(None);
    }
    let scale = sol
        .x
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    if problem
        .cones
        .iter()
        .any(|c| c.violation(&sol.x) > 1e-9 * scale)
    {
        return Ok(None);
    }
    // The interior-point answer meets the equalities only to its tolerance, so
    // its objective may sit slightly below the exact constrained optimum.
    let (before, after) = (problem.objective(x), problem.objective(&sol.x));
    let floor = 1e-12 * ls.b.iter().map(|v| v * v).sum::<f64>().max(1.0);
    if after > before * (1.0 + 1e-6) + floor {
        return Ok(None);
    }
    let mut polished = sol.x;
    for c in &problem.cones {
        c.project(&mut polished);
    }
    Ok(Some(polished))
}
