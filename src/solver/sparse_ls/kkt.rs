//! Forming the KKT system: its upper pattern (A's Gram matrix, widened by the
//! coupling, then the rows of C) and its values in equilibrated variables.

use super::compressed::{gram_upper_pattern, gram_upper_values, stacked_entries, Compressed};
use super::symbolic::symbolic_analysis;
use super::{
    check_pair, check_triplets, Bordering, EqualityLeastSquares, Ordering, EQUILIBRATION_PASSES,
    ROUNDOFF_FLOOR,
};
use crate::solver::Triplets;
use crate::{Error, Result};
use faer::sparse::linalg::cholesky::SymbolicCholesky;
use faer::Par;
use std::sync::Arc;

/// Block labels of the KKT's vertices for nested dissection, each a vertex of
/// its block: the unknowns of one row of `coupling` (a contact) are labelled
/// by the first of them, every other unknown and every row of C by itself.
pub(super) fn kkt_blocks(n: usize, c_rows: usize, coupling: &Triplets) -> Vec<usize> {
    let mut first = vec![usize::MAX; coupling.nrows];
    for (&row, &col) in coupling.rows.iter().zip(&coupling.cols) {
        first[row] = first[row].min(col);
    }
    let mut labels: Vec<usize> = (0..n + c_rows).collect();
    for (&row, &col) in coupling.rows.iter().zip(&coupling.cols) {
        labels[col] = labels[col].min(first[row]);
    }
    labels
}

/// A's and C's patterns compressed, and the upper pattern of the KKT matrix
/// they make: [A; coupling]ᵀ[A; coupling], then the rows of C (each with its
/// diagonal entry).
struct Patterns {
    a_csr: Compressed,
    a_csc: Compressed,
    c_csr: Compressed,
    kkt: (Vec<usize>, Vec<usize>),
}

impl Patterns {
    /// After validating A, C and the coupling.
    fn new(a: &Triplets, c: &Triplets, coupling: &Triplets) -> Result<Self> {
        check_pair(a, c)?;
        check_triplets(coupling, "coupling")?;
        if coupling.ncols != a.ncols {
            return Err(Error::Invalid(format!(
                "the coupling pattern has {} columns but A has {}",
                coupling.ncols, a.ncols
            )));
        }
        let n = a.ncols;
        let a_csr = Compressed::from_entries(a.nrows, n, &a.rows, &a.cols);
        let a_csc = Compressed::from_entries(n, a.nrows, &a.cols, &a.rows);
        let c_csr = Compressed::from_entries(c.nrows, n, &c.rows, &c.cols);
        let (stacked_rows, stacked_cols) = stacked_entries(a, coupling);
        let stacked_m = a.nrows + coupling.nrows;
        let (mut col_ptr, mut row_idx) = if coupling.nrows == 0 {
            gram_upper_pattern(&a_csr, &a_csc)
        } else {
            gram_upper_pattern(
                &Compressed::from_entries(stacked_m, n, &stacked_rows, &stacked_cols),
                &Compressed::from_entries(n, stacked_m, &stacked_cols, &stacked_rows),
            )
        };
        for i in 0..c.nrows {
            row_idx.extend_from_slice(&c_csr.idx[c_csr.range(i)]);
            row_idx.push(n + i);
            col_ptr.push(row_idx.len());
        }
        Ok(Patterns {
            a_csr,
            a_csc,
            c_csr,
            kkt: (col_ptr, row_idx),
        })
    }
}

/// What every factorisation of one A, C, λ and δ starts from, whatever the
/// active rows: the equilibration and the KKT values without those rows.
pub(super) struct Base {
    pub(super) delta: f64,
    pub(super) lambda: f64,
    pub(super) a_vals: Vec<f64>,
    pub(super) c_vals: Vec<f64>,
    /// x = S y: column equilibration.
    pub(super) col_scale: Vec<f64>,
    /// Row normalisation of C.
    pub(super) c_row_scale: Vec<f64>,
    /// λ² s_j², the Tikhonov term in scaled variables.
    pub(super) lambda2_s2: Vec<f64>,
    /// ‖row i of T C S‖∞, for the round-off-level rows of the primal residual.
    pub(super) c_row_max: Vec<f64>,
    /// Upper KKT values, regularised, before the active rows' penalties and
    /// the springs are added.
    pub(super) values: Vec<f64>,
}

impl Base {
    /// Built for these A, C and λ (whatever δ).
    pub(super) fn same_problem(&self, a: &Triplets, c: &Triplets, lambda: f64) -> bool {
        self.lambda == lambda && self.a_vals == a.vals && self.c_vals == c.vals
    }

    pub(super) fn same(&self, a: &Triplets, c: &Triplets, lambda: f64, delta: f64) -> bool {
        self.delta == delta && self.same_problem(a, c, lambda)
    }
}

impl EqualityLeastSquares {
    pub(super) fn analyse(
        a: &Triplets,
        c: &Triplets,
        coupling: &Triplets,
        par: Par,
        ordering: Ordering,
    ) -> Result<Self> {
        let patterns = Patterns::new(a, c, coupling)?;
        let blocks = kkt_blocks(a.ncols, c.nrows, coupling);
        let (symbolic, used) = match symbolic_analysis(
            a.ncols + c.nrows,
            &patterns.kkt.0,
            &patterns.kkt.1,
            ordering,
            Some(&blocks),
        )? {
            Some((symbolic, used)) => (Some(Arc::new(symbolic)), used),
            None => (None, ordering),
        };
        Ok(Self::on_analysis(
            a, c, coupling, patterns, symbolic, par, used,
        ))
    }

    /// A solver for another A whose KKT pattern (with this coupling and C) is
    /// the analysed one — e.g. A with rows appended on single contacts — that
    /// shares this symbolic analysis instead of redoing the ordering. `None`
    /// when the patterns differ.
    pub fn sharing_analysis(&self, a: &Triplets, c: &Triplets) -> Result<Option<Self>> {
        if c.nrows != self.c_pattern.0
            || c.rows != self.c_pattern.1
            || c.cols != self.c_pattern.2
            || a.ncols != self.n
        {
            return Ok(None);
        }
        let patterns = Patterns::new(a, c, &self.coupling)?;
        if patterns.kkt.0 != self.kkt_col_ptr || patterns.kkt.1 != self.kkt_row_idx {
            return Ok(None);
        }
        let mut shared = Self::on_analysis(
            a,
            c,
            &self.coupling,
            patterns,
            self.symbolic.clone(),
            self.par,
            self.ordering,
        );
        (shared.refine_to, shared.first_delta, shared.bordering) =
            (self.refine_to, self.first_delta, self.bordering);
        Ok(Some(shared))
    }

    fn on_analysis(
        a: &Triplets,
        c: &Triplets,
        coupling: &Triplets,
        patterns: Patterns,
        symbolic: Option<Arc<SymbolicCholesky<usize>>>,
        par: Par,
        ordering: Ordering,
    ) -> Self {
        let Patterns {
            a_csr,
            a_csc,
            c_csr,
            kkt: (kkt_col_ptr, kkt_row_idx),
        } = patterns;
        EqualityLeastSquares {
            n: a.ncols,
            a_pattern: (a.nrows, a.rows.clone(), a.cols.clone()),
            c_pattern: (c.nrows, c.rows.clone(), c.cols.clone()),
            coupling: coupling.clone(),
            a_csr,
            a_csc,
            c_csr,
            kkt_col_ptr,
            kkt_row_idx,
            ordering,
            symbolic,
            par,
            refine_to: ROUNDOFF_FLOOR,
            first_delta: super::DELTA_LADDER[0],
            bordering: Bordering::Auto,
            numeric: None,
        }
    }

    pub(super) fn same_pattern(&self, a: &Triplets, c: &Triplets) -> bool {
        let same = |p: &(usize, Vec<usize>, Vec<usize>), t: &Triplets| {
            p.0 == t.nrows && p.1 == t.rows && p.2 == t.cols
        };
        self.n == a.ncols && same(&self.a_pattern, a) && same(&self.c_pattern, c)
    }

    /// Position of entry (i, j), i ≤ j, in the upper KKT pattern.
    fn kkt_position(&self, i: usize, j: usize) -> Option<usize> {
        let range = self.kkt_col_ptr[j]..self.kkt_col_ptr[j + 1];
        self.kkt_row_idx[range.clone()]
            .binary_search(&i)
            .ok()
            .map(|k| range.start + k)
    }

    /// Adds (T B S)ᵀ(T B S) of the rows of `rows` (CSR) to the upper KKT values;
    /// each row may only couple unknowns present in the analysed pattern.
    pub(super) fn add_row_products(
        &self,
        values: &mut [f64],
        rows: &Compressed,
        row_scale: &[f64],
        col_scale: &[f64],
        name: &str,
    ) -> Result<()> {
        for (i, t) in row_scale.iter().enumerate() {
            for p in rows.range(i) {
                let cp = rows.idx[p];
                let vp = rows.val[p] * col_scale[cp] * t;
                for q in rows.range(i) {
                    let cq = rows.idx[q];
                    if cq < cp {
                        continue;
                    }
                    let Some(pos) = self.kkt_position(cp, cq) else {
                        return Err(Error::Invalid(format!(
                            "{name} {i} couples unknowns {cp} and {cq}, which share no row of A"
                        )));
                    };
                    values[pos] += vp * rows.val[q] * col_scale[cq] * t;
                }
            }
        }
        Ok(())
    }

    /// The equilibration of [A; C] and the regularised KKT values without
    /// active rows (see [`Base`]).
    pub(super) fn base(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        lambda: f64,
        delta: f64,
    ) -> Result<Base> {
        let n = self.n;
        let (ma, mc) = (a.nrows, c.nrows);
        self.a_csr.refill(&a.vals);
        self.a_csc.refill(&a.vals);
        self.c_csr.refill(&c.vals);

        // Alternate C-row normalisation and column equilibration of [A; T C]; a
        // few passes settle the scales so that units of the unknowns drop out.
        // G is left out: the scales must not depend on the active set.
        let mut col_scale = vec![1.0; n];
        let mut c_row_scale = vec![1.0; mc];
        let mut a_col_sq = vec![0.0; n];
        for (q, &j) in self.a_csr.idx.iter().enumerate() {
            a_col_sq[j] += self.a_csr.val[q] * self.a_csr.val[q];
        }
        for _ in 0..EQUILIBRATION_PASSES {
            c_row_scale = row_inverse_norms(&self.c_csr, &col_scale);
            // s_j = 1 / ‖column j of [A; T C]‖.
            let mut col_sq = a_col_sq.clone();
            for (i, t) in c_row_scale.iter().enumerate() {
                for q in self.c_csr.range(i) {
                    col_sq[self.c_csr.idx[q]] += (self.c_csr.val[q] * t).powi(2);
                }
            }
            for (s, sq) in col_scale.iter_mut().zip(&col_sq) {
                *s = if *sq > 0.0 { 1.0 / sq.sqrt() } else { 1.0 };
            }
        }
        if let Some(j) = col_scale.iter().position(|s| !s.is_finite() || *s == 0.0) {
            return Err(Error::Solver(format!(
                "column {j} of [A; C] cannot be equilibrated (values overflow)"
            )));
        }
        c_row_scale = row_inverse_norms(&self.c_csr, &col_scale);
        let lambda2_s2: Vec<f64> = col_scale.iter().map(|s| lambda * lambda * s * s).collect();
        let row_max = |csr: &Compressed, row_scale: &[f64]| -> Vec<f64> {
            (0..csr.nmajor)
                .map(|i| {
                    let scaled =
                        |q: usize| (csr.val[q] * col_scale[csr.idx[q]] * row_scale[i]).abs();
                    csr.range(i).map(scaled).fold(0.0, f64::max)
                })
                .collect()
        };
        let c_row_max = row_max(&self.c_csr, &c_row_scale);
        let mut values = vec![0.0; self.kkt_row_idx.len()];
        let mut work = vec![0.0; n];
        gram_upper_values(
            &self.a_csr,
            &self.a_csc,
            &vec![1.0; ma],
            &col_scale,
            &self.kkt_col_ptr,
            &self.kkt_row_idx,
            &mut values,
            &mut work,
        );
        for j in 0..n {
            // Rows are sorted with i ≤ j: the diagonal closes the column.
            values[self.kkt_col_ptr[j + 1] - 1] += lambda2_s2[j] + delta;
        }
        for (i, t) in c_row_scale.iter().enumerate() {
            let mut p = self.kkt_col_ptr[n + i];
            for q in self.c_csr.range(i) {
                values[p] = t * self.c_csr.val[q] * col_scale[self.c_csr.idx[q]];
                p += 1;
            }
            values[p] = -delta;
        }
        Ok(Base {
            delta,
            lambda,
            a_vals: a.vals.clone(),
            c_vals: c.vals.clone(),
            col_scale,
            c_row_scale,
            lambda2_s2,
            c_row_max,
            values,
        })
    }
}

/// 1/‖(B S)_r‖ per row of a CSR matrix (1 for empty rows).
pub(super) fn row_inverse_norms(csr: &Compressed, col_scale: &[f64]) -> Vec<f64> {
    (0..csr.nmajor)
        .map(|r| {
            let sq: f64 = csr
                .range(r)
                .map(|q| (csr.val[q] * col_scale[csr.idx[q]]).powi(2))
                .sum();
            if sq > 0.0 && sq.is_finite() {
                1.0 / sq.sqrt()
            } else {
                1.0
            }
        })
        .collect()
}
