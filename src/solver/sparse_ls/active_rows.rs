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

    /// Row i of G (`springs`: of R) as a key: its sorted columns and the bits
    /// of its values.
    pub(super) fn key(&self, springs: bool, i: usize) -> Vec<(usize, u64)> {
        let m = if springs { &self.springs } else { &self.csr };
        m.range(i).map(|q| (m.idx[q], m.val[q].to_bits())).collect()
    }
}

/// How the current rows differ from those inside the factor.
pub(super) struct Changes {
    /// Per current row: it is inside the factor (same entries).
    pub(super) kept: Vec<bool>,
    /// Current rows and springs not in the factor.
    pub(super) added: Vec<usize>,
    pub(super) added_springs: Vec<usize>,
    /// Rows and springs of the factor no longer current.
    pub(super) removed: Vec<usize>,
    pub(super) removed_springs: Vec<usize>,
}

impl Changes {
    pub(super) fn between(in_factor: &ActiveRows, current: &ActiveRows) -> Self {
        let diff = |springs: bool, old_len: usize, new_len: usize| {
            let mut old: std::collections::HashMap<Vec<(usize, u64)>, Vec<usize>> =
                std::collections::HashMap::with_capacity(old_len);
            for i in 0..old_len {
                old.entry(in_factor.key(springs, i)).or_default().push(i);
            }
            let mut kept = vec![false; new_len];
            let mut added = Vec::new();
            for (i, kept_i) in kept.iter_mut().enumerate() {
                match old.get_mut(&current.key(springs, i)).and_then(|v| v.pop()) {
                    Some(_) => *kept_i = true,
                    None => added.push(i),
                }
            }
            let mut removed: Vec<usize> = old.into_values().flatten().collect();
            removed.sort_unstable();
            (kept, added, removed)
        };
        let (kept, added, removed) = diff(false, in_factor.len(), current.len());
        let (_, added_springs, removed_springs) =
            diff(true, in_factor.springs.nmajor, current.springs.nmajor);
        Changes {
            kept,
            added,
            added_springs,
            removed,
            removed_springs,
        }
    }

    pub(super) fn count(&self) -> usize {
        self.added.len()
            + self.added_springs.len()
            + self.removed.len()
            + self.removed_springs.len()
    }
}
