//! Sparse Cholesky of symmetric positive definite matrices.

use faer::dyn_stack::MemStack;
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{LltRef, SymbolicCholesky};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};

use super::numeric::{default_parallelism, solve_parallelism, workspace};
use super::symbolic::symbolic_analysis;
use super::Ordering;
use crate::{Error, Result};

/// Sparse Cholesky LLᵀ of a symmetric positive definite matrix (its upper
/// triangle, CSC, sorted rows, diagonal present), with the same orderings as
/// the KKT factorisation — for the uniqueness probe and the benchmark's
/// projection onto momentum balance.
pub struct SpdFactor {
    symbolic: Option<SymbolicCholesky<usize>>,
    l_values: Vec<f64>,
    par: Par,
}

impl SpdFactor {
    /// `shift` > 0 lets faer raise pivots below it (to 2·shift … shift):
    /// a regularised factor of a semidefinite matrix. 0 requires definiteness.
    pub fn new(
        size: usize,
        col_ptr: &[usize],
        row_idx: &[usize],
        values: &[f64],
        ordering: Ordering,
        shift: f64,
    ) -> Result<Self> {
        let sorted_upper = col_ptr.len() == size + 1
            && col_ptr.first() == Some(&0)
            && col_ptr.windows(2).all(|w| w[0] < w[1])
            && col_ptr[size] == row_idx.len()
            && values.len() == row_idx.len()
            && (0..size).all(|j| {
                let rows = &row_idx[col_ptr[j]..col_ptr[j + 1]];
                rows.windows(2).all(|w| w[0] < w[1]) && rows.last() == Some(&j)
            });
        if !sorted_upper {
            return Err(Error::Invalid(format!(
                "SpdFactor needs the upper triangle of a {size}×{size} matrix in CSC with sorted rows, \
                 each column ending on its diagonal, and one value per entry"
            )));
        }
        let par = default_parallelism(size);
        let symbolic = symbolic_analysis(size, col_ptr, row_idx, ordering, None)?
            .map(|(symbolic, _)| symbolic);
        let Some(sym) = &symbolic else {
            return Ok(SpdFactor {
                symbolic,
                l_values: Vec::new(),
                par,
            });
        };
        let mut l_values = vec![0.0; sym.len_val()];
        let mut stack_buf = workspace(
            sym.factorize_numeric_llt_scratch::<f64>(par, Default::default()),
            || format!("the LLᵀ workspace ({} factor entries)", sym.len_val()),
        )?;
        let matrix = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(size, size, col_ptr, None, row_idx),
            values,
        );
        let regularization = LltRegularization {
            dynamic_regularization_delta: shift,
            dynamic_regularization_epsilon: 0.5 * shift,
        };
        sym.factorize_numeric_llt(
            &mut l_values,
            matrix,
            Side::Upper,
            regularization,
            par,
            MemStack::new(&mut stack_buf),
            Default::default(),
        )
        .map_err(|e| {
            Error::Solver(format!(
                "Cholesky of the {size}×{size} matrix failed: not positive definite ({e:?})"
            ))
        })?;
        Ok(SpdFactor {
            symbolic,
            l_values,
            par,
        })
    }

    /// X ← M⁻¹ X for the `ncols` columns of X (column-major, size × ncols).
    pub fn solve_in_place(&self, x: &mut [f64], ncols: usize) -> Result<()> {
        let Some(sym) = &self.symbolic else {
            return Ok(());
        };
        let size = sym.nrows();
        if x.len() != size * ncols {
            return Err(Error::Invalid(format!(
                "{} values for {ncols} columns of {size} rows",
                x.len()
            )));
        }
        let par = solve_parallelism(self.par, ncols);
        let mut stack_buf = workspace(sym.solve_in_place_scratch::<f64>(ncols, par), || {
            format!("{ncols} triangular solves")
        })?;
        LltRef::<usize, f64>::new(sym, &self.l_values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(x, size, ncols),
            par,
            MemStack::new(&mut stack_buf),
        );
        Ok(())
    }
}
