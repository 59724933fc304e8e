//! Bordering: rows that changed since the kept factor are taken around it
//! through a dense Schur complement instead of a new factorisation.

use rayon::prelude::*;

use super::active_rows::{ActiveRows, Changes};
use super::nodes::{Factor, SparseColumn};
use super::numeric::Numeric;
use crate::{Error, Result};

/// At most this many active rows + springs are bordered around the base
/// factor: the dense Schur complement costs k² sparse products to form and
/// k³/3 to factorise. Tried 4096 (3D, 10⁴ spheres, 30 % sliding): the third
/// solve bordered 260 rows, and the three after it, bordered on the same
/// factor with their changes piling up, took 2.0–3.0 s each, against 0.7–1.2 s
/// after a new factorisation (2.2–2.5 s) at 256.
pub(super) const BORDER_MAX_ROWS: usize = 256;

/// The bordered system `[[F, B], [Bᵀ, −D]]` around the kept factor
/// F = Pᵀ L D Lᵀ P: B's columns are the scaled active rows added since F
/// (D = δ, the base regularisation), the springs added (D = 1, so that they
/// add BᵀB to the Hessian block) and the rows F holds that are no longer
/// active (D = −δ: eliminating them subtracts the penalty ĝᵀĝ/δ that F
/// holds; springs F holds that are gone, D = −1). Holds W = L⁻¹ P B, sparse (each column reaches few nodes of the
/// factor), and the LU of the Schur complement BᵀF⁻¹B + D = Wᵀ D⁻¹ W + D.
pub(super) struct Bordered {
    /// B's columns (sparse) and their D.
    pub(super) columns: Vec<Vec<(usize, f64)>>,
    pub(super) d: Vec<f64>,
    pub(super) w: Vec<SparseColumn>,
    pub(super) schur: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

/// The columns of B for the rows that changed since the factor, each with
/// its D (see [`Bordered`]).
pub(super) fn border_columns(num: &Numeric, changes: &Changes, delta: f64) -> Vec<BorderColumn> {
    let s = &num.base.col_scale;
    (changes.added.iter())
        .map(|&i| (scaled_row(&num.active, false, i, s), delta))
        .chain((changes.added_springs.iter()).map(|&i| (scaled_row(&num.active, true, i, s), 1.0)))
        .chain((changes.removed.iter()).map(|&i| (scaled_row(&num.in_factor, false, i, s), -delta)))
        .chain(
            (changes.removed_springs.iter())
                .map(|&i| (scaled_row(&num.in_factor, true, i, s), -1.0)),
        )
        .collect()
}

/// A column of B (sparse) and its D.
pub(super) type BorderColumn = (Vec<(usize, f64)>, f64);

impl Bordered {
    /// Whether this border already solved that column.
    pub(super) fn holds(&self, column: &BorderColumn) -> bool {
        self.position(column).is_some()
    }

    /// Where this border holds that column.
    pub(super) fn position(&self, (entries, d): &BorderColumn) -> Option<usize> {
        (self.columns.iter().zip(&self.d)).position(|(e, pd)| e == entries && pd == d)
    }

    /// `columns`: the entries of each column of B with its D. Columns that
    /// `previous` (a border on the same factor) already solved are copied,
    /// not solved again: consecutive bordered solves share most columns.
    pub(super) fn new(
        columns: Vec<BorderColumn>,
        factor: &Factor<'_>,
        previous: Option<&Bordered>,
    ) -> Result<Self> {
        let k = columns.len();
        let size = factor.rows();
        let w: Vec<SparseColumn> = columns
            .par_iter()
            .map_init(
                || (vec![0.0; size], vec![false; factor.node_total()]),
                |(scratch, marked), column| {
                    let known = previous.and_then(|p| Some((p, p.position(column)?)));
                    match known {
                        Some((p, j)) => p.w[j].clone(),
                        None => factor.forward_sparse(&column.0, scratch, marked),
                    }
                },
            )
            .collect();
        // Row i of WᵀD⁻¹W from column i scattered densely, rows in parallel.
        let upper: Vec<Vec<f64>> = (0..k)
            .into_par_iter()
            .map_init(
                || vec![0.0; size],
                |dense, i| {
                    factor.scatter_scaled(&w[i], dense);
                    let row = w[i..].iter().map(|wj| factor.dot(wj, dense)).collect();
                    factor.clear(&w[i], dense);
                    row
                },
            )
            .collect();
        let mut m = nalgebra::DMatrix::<f64>::zeros(k, k);
        for (i, row) in upper.iter().enumerate() {
            for (offset, &v) in row.iter().enumerate() {
                m[(i, i + offset)] = v;
                m[(i + offset, i)] = v;
            }
        }
        for (i, (_, d)) in columns.iter().enumerate() {
            m[(i, i)] += d;
        }
        if m.iter().any(|v| !v.is_finite()) {
            return Err(Error::Solver(
                "the bordered Schur complement is not finite".into(),
            ));
        }
        let d = columns.iter().map(|(_, d)| *d).collect();
        Ok(Bordered {
            columns: columns.into_iter().map(|(entries, _)| entries).collect(),
            d,
            w,
            schur: m.lu(),
        })
    }

    /// Given v = D⁻¹ L⁻¹ P h, the middle of the solve of F z = h, and the
    /// border's right-hand side r, completes the bordered solve in place:
    /// t = S⁻¹(Wᵀ v − r), v −= D⁻¹ W t (the backward half then gives
    /// z = F⁻¹(h − B t)); returns t.
    pub(super) fn correct(
        &self,
        factor: &Factor<'_>,
        v: &mut [f64],
        r: &[f64],
    ) -> nalgebra::DVector<f64> {
        let k = self.columns.len();
        let u = nalgebra::DVector::from_iterator(
            k,
            (self.w.iter().zip(r)).map(|(w, ri)| factor.dot(w, v) - ri),
        );
        let t = self
            .schur
            .solve(&u)
            .unwrap_or_else(|| nalgebra::DVector::from_element(k, f64::NAN));
        for (w, tj) in self.w.iter().zip(t.iter()) {
            factor.sub_scaled(v, *tj, w);
        }
        t
    }
}

/// Entries of row i of T G S (`springs`: of R S, unit row scale), a column
/// of a border.
fn scaled_row(rows: &ActiveRows, springs: bool, i: usize, col_scale: &[f64]) -> Vec<(usize, f64)> {
    let (m, t) = if springs {
        (&rows.springs, 1.0)
    } else {
        (&rows.csr, rows.row_scale[i])
    };
    m.range(i)
        .map(|q| (m.idx[q], m.val[q] * col_scale[m.idx[q]] * t))
        .collect()
}
