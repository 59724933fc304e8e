//! The active rows G x = 0 and springs ‖R x‖² of a solve, and how they
//! differ from those inside the kept factor.

use super::compressed::Compressed;
use super::kkt::row_inverse_norms;
use crate::solver::Triplets;

/// Homogeneous equalities G x = 0 eliminated by a penalty inside the KKT
/// pattern (each row may only couple unknowns that already share a row of A),
/// so changing them needs a new numeric factorisation (or a border) but no
/// new analysis.
#[derive(Clone)]
pub(super) struct ActiveRows {
    pub(super) pattern: (usize, Vec<usize>, Vec<usize>),
    pub(super) vals: Vec<f64>,
    pub(super) csr: Compressed,
    /// Row normalisation of G S.
    pub(super) row_scale: Vec<f64>,
    /// ‖row i of T G S‖∞.
    pub(super) row_max: Vec<f64>,
    /// Extra least-squares rows ‖R x‖² (zero right-hand side), e.g. the
    /// curvature of a Coulomb cone at a sliding contact.
    pub(super) springs_pattern: (usize, Vec<usize>, Vec<usize>),
    pub(super) springs_vals: Vec<f64>,
    pub(super) springs: Compressed,
}

impl ActiveRows {
    /// G and R in CSR with the row scales of the equilibrated system.
    pub(super) fn new(n: usize, g: &Triplets, springs: &Triplets, col_scale: &[f64]) -> Self {
        let mut csr = Compressed::from_entries(g.nrows, n, &g.rows, &g.cols);
        csr.refill(&g.vals);
        let row_scale = row_inverse_norms(&csr, col_scale);
        let row_max = (0..csr.nmajor)
            .map(|i| {
                csr.range(i)
                    .map(|q| (csr.val[q] * col_scale[csr.idx[q]] * row_scale[i]).abs())
                    .fold(0.0, f64::max)
            })
            .collect();
        let mut springs_csr =
            Compressed::from_entries(springs.nrows, n, &springs.rows, &springs.cols);
        springs_csr.refill(&springs.vals);
        ActiveRows {
            pattern: (g.nrows, g.rows.clone(), g.cols.clone()),
            vals: g.vals.clone(),
            csr,
            row_scale,
            row_max,
            springs_pattern: (springs.nrows, springs.rows.clone(), springs.cols.clone()),
            springs_vals: springs.vals.clone(),
            springs: springs_csr,
        }
    }

    pub(super) fn same(&self, g: &Triplets, springs: &Triplets) -> bool {
        self.pattern.0 == g.nrows
            && self.pattern.1 == g.rows
            && self.pattern.2 == g.cols
            && self.vals == g.vals
            && self.springs_pattern.0 == springs.nrows
            && self.springs_pattern.1 == springs.rows
            && self.springs_pattern.2 == springs.cols
            && self.springs_vals == springs.vals
    }

    pub(super) fn len(&self) -> usize {
        self.pattern.0
    }

    /// The columns of row i of G (`springs`: of R).
    pub(super) fn columns(&self, springs: bool, i: usize) -> Vec<usize> {
        let m = if springs { &self.springs } else { &self.csr };
        m.idx[m.range(i)].to_vec()
    }

    /// Row i of G (`springs`: of R) as a key: its sorted columns and the bits
    /// of its values.
    pub(super) fn key(&self, springs: bool, i: usize) -> Vec<(usize, u64)> {
        let m = if springs { &self.springs } else { &self.csr };
        m.range(i).map(|q| (m.idx[q], m.val[q].to_bits())).collect()
    }
}

/// Largest change of a row (entries of T G S, each row of unit norm) or of a
/// spring (entries of R S, relative to the larger of 1, the equilibrated
/// Hessian's diagonal, and its largest entry) that the factor may go on
/// holding: GMRES on the factor absorbs it. A 3D sliding contact's row and
/// spring turn with its sliding direction at every Newton step; before, that
/// alone made every 3D solve a new factorisation. Measured (3D, 10⁴ spheres,
/// 30 % sliding, stress noise): 0.05 and 0.3 both reuse the factor in the
/// last three of six solves, 0.3 with 10 Krylov steps each against 7;
/// 1 fails over to a new factor once.
pub(crate) const STALE_TOL: f64 = 0.3;

/// How the current rows differ from those inside the factor.
pub(super) struct Changes {
    /// Per current row: it is inside the factor (same entries, or within
    /// [`STALE_TOL`] of them: see `stale`).
    pub(super) kept: Vec<bool>,
    /// Current rows and springs not in the factor.
    pub(super) added: Vec<usize>,
    pub(super) added_springs: Vec<usize>,
    /// Rows and springs of the factor no longer current.
    pub(super) removed: Vec<usize>,
    pub(super) removed_springs: Vec<usize>,
    /// Kept rows whose factor copy differs from them: (current row, factor row).
    pub(super) stale: Vec<(usize, usize)>,
    /// Springs whose factor copy differs from them.
    pub(super) stale_springs: usize,
}

/// One side of [`Changes`]: rows matched exactly, then (same columns) within
/// [`STALE_TOL`].
struct RowDiff {
    kept: Vec<bool>,
    added: Vec<usize>,
    removed: Vec<usize>,
    stale: Vec<(usize, usize)>,
}

impl Changes {
    pub(super) fn between(in_factor: &ActiveRows, current: &ActiveRows, col_scale: &[f64]) -> Self {
        let rows = RowDiff::new(in_factor, current, false, col_scale);
        let springs = RowDiff::new(in_factor, current, true, col_scale);
        Changes {
            kept: rows.kept,
            added: rows.added,
            added_springs: springs.added,
            removed: rows.removed,
            removed_springs: springs.removed,
            stale: rows.stale,
            stale_springs: springs.stale.len(),
        }
    }

    /// No change: a factor just computed holds exactly the current rows.
    pub(super) fn unchanged(rows: usize) -> Self {
        Changes {
            kept: vec![true; rows],
            added: Vec::new(),
            added_springs: Vec::new(),
            removed: Vec::new(),
            removed_springs: Vec::new(),
            stale: Vec::new(),
            stale_springs: 0,
        }
    }

    /// Rows and springs to border (stale ones are not).
    pub(super) fn count(&self) -> usize {
        self.added.len()
            + self.added_springs.len()
            + self.removed.len()
            + self.removed_springs.len()
    }

    /// Whether the factor holds any row or spring that differs from the current one.
    pub(super) fn any_stale(&self) -> bool {
        !self.stale.is_empty() || self.stale_springs > 0
    }
}

impl RowDiff {
    fn new(in_factor: &ActiveRows, current: &ActiveRows, springs: bool, col_scale: &[f64]) -> Self {
        use std::collections::HashMap;
        let (old_len, new_len) = if springs {
            (in_factor.springs.nmajor, current.springs.nmajor)
        } else {
            (in_factor.len(), current.len())
        };
        let mut old: HashMap<Vec<(usize, u64)>, Vec<usize>> = HashMap::with_capacity(old_len);
        for i in 0..old_len {
            old.entry(in_factor.key(springs, i)).or_default().push(i);
        }
        let mut kept = vec![false; new_len];
        let mut unmatched = Vec::new();
        for (i, kept_i) in kept.iter_mut().enumerate() {
            match old.get_mut(&current.key(springs, i)).and_then(|v| v.pop()) {
                Some(_) => *kept_i = true,
                None => unmatched.push(i),
            }
        }
        // The factor's rows left over, by their columns alone.
        let mut by_columns: HashMap<Vec<usize>, Vec<usize>> = HashMap::new();
        for j in old.into_values().flatten() {
            by_columns
                .entry(in_factor.columns(springs, j))
                .or_default()
                .push(j);
        }
        let (mut added, mut stale) = (Vec::new(), Vec::new());
        for i in unmatched {
            let close = (by_columns.get_mut(&current.columns(springs, i))).and_then(|js| {
                let at = js.iter().position(|&j| {
                    row_change(in_factor, j, current, i, springs, col_scale) <= STALE_TOL
                })?;
                Some(js.swap_remove(at))
            });
            match close {
                Some(j) => {
                    kept[i] = true;
                    stale.push((i, j));
                }
                None => added.push(i),
            }
        }
        let mut removed: Vec<usize> = by_columns.into_values().flatten().collect();
        removed.sort_unstable();
        RowDiff {
            kept,
            added,
            removed,
            stale,
        }
    }
}

/// Largest entry of the difference of two rows with the same columns: of
/// the scaled rows T G S, or of springs relative to the old one's largest entry.
fn row_change(
    old: &ActiveRows,
    j: usize,
    new: &ActiveRows,
    i: usize,
    springs: bool,
    col_scale: &[f64],
) -> f64 {
    let (mo, mn) = if springs {
        (&old.springs, &new.springs)
    } else {
        (&old.csr, &new.csr)
    };
    let scaled = |m: &Compressed, q: usize| m.val[q] * col_scale[m.idx[q]];
    let (to, tn) = if springs {
        // The equilibrated Hessian's diagonal is ~1: a spring far weaker
        // than that may change by any factor.
        let size = (mo.range(j))
            .map(|p| scaled(mo, p).abs())
            .fold(0.0, f64::max);
        let t = 1.0 / size.max(1.0);
        (t, t)
    } else {
        (old.row_scale[j], new.row_scale[i])
    };
    (mo.range(j).zip(mn.range(i)))
        .map(|(p, q)| (scaled(mo, p) * to - scaled(mn, q) * tn).abs())
        .fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 3D sliding contact on unknowns (0, 1, 2): its face row and the spring
    /// across its sliding direction θ.
    fn contact(theta: f64, stiffness: f64) -> ActiveRows {
        let (mut g, mut r) = (Triplets::new(1, 3), Triplets::new(1, 3));
        let norm = 1.25f64.sqrt();
        g.push(0, 0, 0.5 / norm);
        g.push(0, 1, -theta.cos() / norm);
        g.push(0, 2, -theta.sin() / norm);
        r.push(0, 1, -theta.sin() * stiffness.sqrt());
        r.push(0, 2, theta.cos() * stiffness.sqrt());
        ActiveRows::new(3, &g, &r, &[1.0; 3])
    }

    #[test]
    fn rows_that_turned_a_little_are_stale_and_far_ones_change() {
        let old = contact(0.3, 4.0);
        let same = Changes::between(&old, &contact(0.3, 4.0), &[1.0; 3]);
        assert!(same.kept == [true] && same.count() == 0 && !same.any_stale());

        let turned = Changes::between(&old, &contact(0.35, 4.4), &[1.0; 3]);
        assert_eq!(turned.kept, [true]);
        assert_eq!(
            (turned.stale.as_slice(), turned.stale_springs),
            (&[(0, 0)][..], 1)
        );
        assert_eq!(turned.count(), 0);

        // A radian: row and spring both replaced, bordered both ways.
        let far = Changes::between(&old, &contact(1.3, 4.0), &[1.0; 3]);
        assert_eq!(far.kept, [false]);
        assert!(!far.any_stale());
        assert_eq!((far.added.len(), far.removed.len()), (1, 1));
        assert_eq!((far.added_springs.len(), far.removed_springs.len()), (1, 1));

        // A spring far weaker than the Hessian's unit diagonal may change by
        // any factor; a stiff one by the same factor may not.
        let weak = Changes::between(&contact(0.3, 1e-4), &contact(0.3, 4e-4), &[1.0; 3]);
        assert_eq!((weak.stale_springs, weak.added_springs.len()), (1, 0));
        let stiff = Changes::between(&contact(0.3, 4.0), &contact(0.3, 16.0), &[1.0; 3]);
        assert_eq!((stiff.stale_springs, stiff.added_springs.len()), (0, 1));

        let none = Changes::unchanged(2);
        assert!(none.kept == [true, true] && none.count() == 0 && !none.any_stale());
    }
}
