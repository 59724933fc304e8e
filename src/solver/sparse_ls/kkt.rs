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
            fixed_rows: 0,
            fixed: None,
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
        let a_col_sq = if self.fixed_rows > 0 {
            self.refresh_fixed_rows(a)
        } else {
            let mut col_sq = vec![0.0; n];
            for (q, &j) in self.a_csr.idx.iter().enumerate() {
                col_sq[j] += self.a_csr.val[q] * self.a_csr.val[q];
            }
            col_sq
        };
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
        match self.fixed.as_ref().filter(|_| self.fixed_rows > 0) {
            Some(fixed) => {
                for j in 0..n {
                    for p in self.kkt_col_ptr[j]..self.kkt_col_ptr[j + 1] {
                        let i = self.kkt_row_idx[p];
                        values[p] = fixed.gram[p] * col_scale[i] * col_scale[j];
                    }
                }
                let ones = vec![1.0; fixed.rest.nmajor];
                self.add_row_products(&mut values, &fixed.rest, &ones, &col_scale, "row")?;
            }
            None => gram_upper_values(
                &self.a_csr,
                &self.a_csc,
                &vec![1.0; ma],
                &col_scale,
                &self.kkt_col_ptr,
                &self.kkt_row_idx,
                &mut values,
                &mut vec![0.0; n],
            ),
        }
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

impl EqualityLeastSquares {
    /// The fixed rows' Gram kept from the last call when their values are
    /// the same, else formed (see [`Self::keep_rows_fixed`]); the other
    /// rows' values taken in. A's squared column norms.
    fn refresh_fixed_rows(&mut self, a: &Triplets) -> Vec<f64> {
        let mut fixed = match self.fixed.take() {
            Some(fixed) if fixed.holds(a) => fixed,
            _ => FixedRows::new(a, self.fixed_rows, &self.kkt_col_ptr, &self.kkt_row_idx),
        };
        let rest_vals: Vec<f64> = fixed.rest_at.iter().map(|&k| a.vals[k]).collect();
        fixed.rest.refill(&rest_vals);
        let mut col_sq = fixed.col_sq.clone();
        for (q, &j) in fixed.rest.idx.iter().enumerate() {
            col_sq[j] += fixed.rest.val[q] * fixed.rest.val[q];
        }
        self.fixed = Some(fixed);
        col_sq
    }
}

/// The leading rows of A that keep their values across solves: their
/// unscaled Gram matrix on the KKT pattern, formed once, and the other
/// rows' pattern.
pub(super) struct FixedRows {
    /// Triplets of the fixed rows (their indices in A's triplets) and their
    /// values when the Gram was formed.
    fixed_at: Vec<usize>,
    vals: Vec<f64>,
    /// Triplets of the other rows, and those rows compressed (rows renumbered
    /// from 0).
    rest_at: Vec<usize>,
    rest: Compressed,
    /// Σ_r a_ri a_rj over the fixed rows on the upper KKT pattern (zero in
    /// C's columns), and Σ_r a_rj².
    gram: Vec<f64>,
    col_sq: Vec<f64>,
}

impl FixedRows {
    fn new(a: &Triplets, rows: usize, col_ptr: &[usize], row_idx: &[usize]) -> Self {
        let (n, rows) = (a.ncols, rows.min(a.nrows));
        let (fixed_at, rest_at): (Vec<usize>, Vec<usize>) =
            (0..a.rows.len()).partition(|&k| a.rows[k] < rows);
        let pick = |at: &[usize], of: &[usize]| at.iter().map(|&k| of[k]).collect::<Vec<_>>();
        let (f_rows, f_cols) = (pick(&fixed_at, &a.rows), pick(&fixed_at, &a.cols));
        let vals: Vec<f64> = fixed_at.iter().map(|&k| a.vals[k]).collect();
        let mut csr = Compressed::from_entries(rows, n, &f_rows, &f_cols);
        let mut csc = Compressed::from_entries(n, rows, &f_cols, &f_rows);
        csr.refill(&vals);
        csc.refill(&vals);
        let mut gram = vec![0.0; row_idx.len()];
        gram_upper_values(
            &csr,
            &csc,
            &vec![1.0; rows],
            &vec![1.0; n],
            col_ptr,
            row_idx,
            &mut gram,
            &mut vec![0.0; n],
        );
        let mut col_sq = vec![0.0; n];
        for (q, &j) in csr.idx.iter().enumerate() {
            col_sq[j] += csr.val[q] * csr.val[q];
        }
        let rest_rows: Vec<usize> = rest_at.iter().map(|&k| a.rows[k] - rows).collect();
        let rest =
            Compressed::from_entries(a.nrows - rows, n, &rest_rows, &pick(&rest_at, &a.cols));
        FixedRows {
            fixed_at,
            vals,
            rest_at,
            rest,
            gram,
            col_sq,
        }
    }

    /// Made for these fixed rows' values (the pattern is the analysed one).
    fn holds(&self, a: &Triplets) -> bool {
        self.fixed_at.len() + self.rest_at.len() == a.vals.len()
            && self
                .fixed_at
                .iter()
                .zip(&self.vals)
                .all(|(&k, &v)| a.vals[k] == v)
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The interior point's shape: 90 data rows, then 20 rows whose values
    /// change between solves (on the data rows' pattern), 10 equalities.
    fn problem(rng: &mut ChaCha8Rng) -> (Triplets, Triplets, Vec<f64>, Vec<f64>) {
        let (n, m, mc, moving) = (60, 90, 10, 20);
        let mut a = Triplets::new(m + moving, n);
        for i in 0..m {
            for _ in 0..5 {
                a.push(i, rng.gen_range(0..n), rng.gen_range(-1.0..1.0));
            }
        }
        for i in 0..moving {
            // Each on a pair of unknowns that some data row already couples.
            let k = rng.gen_range(0..5 * m);
            let (row, j) = (a.rows[k], a.cols[k]);
            let other = (0..a.rows.len())
                .find(|&q| a.rows[q] == row && a.cols[q] != j)
                .map_or(j, |q| a.cols[q]);
            a.push(m + i, j, 1.0);
            a.push(m + i, other, 1.0);
        }
        let mut c = Triplets::new(mc, n);
        for i in 0..mc {
            for j in 0..4 {
                c.push(i, (6 * i + j) % n, rng.gen_range(0.5..1.5));
            }
        }
        let b = (0..m + moving).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let d = (0..mc).map(|_| rng.gen_range(-1.0..1.0)).collect();
        (a, c, b, d)
    }

    /// With the data rows' Gram kept, the moving rows' new values (over
    /// four orders of magnitude, as the interior point's scaling) and a
    /// change of the data rows themselves give the answers of a solver
    /// that forms every Gram anew, to rounding.
    #[test]
    fn fixed_rows_give_the_full_grams_answers() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let (mut a, c, b, d) = problem(&mut rng);
        let data = 90;
        let mut kept = EqualityLeastSquares::new(&a, &c).unwrap();
        kept.keep_rows_fixed(data);
        for step in 0..4 {
            for (k, v) in a.vals.iter_mut().enumerate() {
                if a.rows[k] >= data {
                    *v = rng.gen_range(-1.0..1.0) * 10f64.powi(step - 1);
                } else if step == 3 {
                    *v *= 1.5;
                }
            }
            let mut fresh = EqualityLeastSquares::new(&a, &c).unwrap();
            let expected = fresh.solve(&a, &c, &b, &d, 0.1).unwrap().x;
            let got = kept.solve(&a, &c, &b, &d, 0.1).unwrap().x;
            let gap = expected
                .iter()
                .zip(&got)
                .map(|(e, g)| (e - g).abs())
                .fold(0.0, f64::max);
            let size = expected.iter().map(|e| e.abs()).fold(0.0, f64::max);
            assert!(gap <= 1e-10 * size, "step {step}: {gap:.2e} of {size:.2e}");
        }
    }
}
