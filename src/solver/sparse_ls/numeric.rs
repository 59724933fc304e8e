//! The numeric stage: LDLᵀ of the KKT values on the symbolic analysis, the
//! state cached with it, and faer's workspace and parallelism.

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::sparse::linalg::cholesky::SymbolicCholesky;
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Par, Side};

use super::active_rows::ActiveRows;
use super::border::Bordered;
use super::kkt::Base;
use super::nodes::{Factor, FactorNodes};
use super::{EqualityLeastSquares, PARALLEL_MIN_SIZE};
use crate::solver::Triplets;
use crate::{Error, Result};

/// Numeric state tied to one set of values, one λ and one δ.
pub(super) struct Numeric {
    pub(super) base: Base,
    /// The rows and springs of the current solve.
    pub(super) active: ActiveRows,
    /// The rows (as penalties ĝᵀĝ/δ) and springs inside the factor; the
    /// current ones may differ from them by a few rows bordered around it.
    pub(super) in_factor: ActiveRows,
    pub(super) l_values: Vec<f64>,
    /// The factor's nodes, for split and sparse solves.
    pub(super) nodes: FactorNodes,
    /// The last border solved around this factor, whose columns the next
    /// border may reuse.
    pub(super) last_border: Option<Bordered>,
    /// What a new numeric factorisation costs in full solves on this
    /// factor, modelled from its nodes ([`factorisation_in_solves`]): a
    /// border costs the share of a solve its columns reach, GMRES on a
    /// stale factor a few solves. A model and not a clock, so that the same
    /// data take the same route, and give the same bits, on every run.
    pub(super) factor_solves: f64,
}

impl Numeric {
    pub(super) fn same_values(&self, a: &Triplets, c: &Triplets, lambda: f64, delta: f64) -> bool {
        self.base.same(a, c, lambda, delta)
    }

    /// This factor with its symbolic part, for split and sparse solves.
    pub(super) fn factor<'a>(&'a self, symbolic: &'a SymbolicCholesky<usize>) -> Factor<'a> {
        Factor {
            symbolic,
            values: &self.l_values,
            nodes: &self.nodes,
        }
    }
}

impl EqualityLeastSquares {
    /// Equilibration, KKT values and numeric LDLᵀ, unless cached.
    pub(super) fn factorise(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        lambda: f64,
        delta: f64,
        g: &Triplets,
        springs: &Triplets,
    ) -> Result<()> {
        if let Some(num) = &self.numeric {
            if num.same_values(a, c, lambda, delta) && num.in_factor.same(g, springs) {
                return Ok(());
            }
        }
        // Only the active rows changed: start from the last factorisation's
        // base (and its L storage) instead of equilibrating and forming AᵀA again.
        let clock = std::time::Instant::now();
        let (base, l_values) = match self.numeric.take() {
            Some(num) if num.same_values(a, c, lambda, delta) => (num.base, num.l_values),
            old => (
                self.base(a, c, lambda, delta)?,
                old.map(|num| num.l_values).unwrap_or_default(),
            ),
        };
        let n = self.n;
        let size = n + c.nrows;
        let active = ActiveRows::new(n, g, springs, &base.col_scale);
        let mut values = base.values.clone();
        // Penalty ĝᵀĝ/δ of each active row ĝ = T G S, and the springs (R S)ᵀ(R S),
        // both on the contact blocks of the analysed pattern.
        let penalty_scale: Vec<f64> = active.row_scale.iter().map(|t| t / delta.sqrt()).collect();
        for (rows, row_scale, name) in [
            (&active.csr, penalty_scale.as_slice(), "active row"),
            (&active.springs, &vec![1.0; springs.nrows][..], "spring row"),
        ] {
            self.add_row_products(&mut values, rows, row_scale, &base.col_scale, name)?;
        }
        if let Some(p) = values.iter().position(|v| !v.is_finite()) {
            return Err(Error::Solver(format!(
                "KKT entry {p} is not finite after equilibration (values of A or C overflow when squared)"
            )));
        }

        let formed = clock.elapsed().as_secs_f64();
        let symbolic = self
            .symbolic
            .as_ref()
            .expect("non-empty KKT has a symbolic factor");
        let signs: Vec<i8> = (0..size).map(|k| if k < n { 1 } else { -1 }).collect();
        let regularization = LdltRegularization {
            dynamic_regularization_signs: Some(&signs),
            dynamic_regularization_delta: delta,
            dynamic_regularization_epsilon: 1e-3 * delta,
        };
        let mut l_values = l_values;
        l_values.resize(symbolic.len_val(), 0.0);
        let mut stack_buf = workspace(
            symbolic.factorize_numeric_ldlt_scratch::<f64>(self.par, Default::default()),
            || format!("the LDLᵀ workspace ({} factor entries)", symbolic.len_val()),
        )?;
        let matrix = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(
                size,
                size,
                &self.kkt_col_ptr,
                None,
                &self.kkt_row_idx,
            ),
            &values,
        );
        symbolic
            .factorize_numeric_ldlt(
                &mut l_values,
                matrix,
                Side::Upper,
                regularization,
                self.par,
                MemStack::new(&mut stack_buf),
                Default::default(),
            )
            .map_err(|e| {
                Error::Solver(format!(
                    "sparse LDLᵀ of the {size}×{size} KKT matrix failed ({e:?}); λ = {lambda}, δ = {delta}"
                ))
            })?;
        let factored = clock.elapsed().as_secs_f64();
        let nodes = FactorNodes::new(symbolic, &l_values);
        let factor = Factor {
            symbolic,
            values: &l_values,
            nodes: &nodes,
        };
        let factor_solves = factorisation_in_solves(&factor);
        if super::profiling() {
            eprintln!(
                "ls-profile factorise δ {delta:e} form {formed:.4} ldlt {:.4} nodes {:.4} s",
                factored - formed,
                clock.elapsed().as_secs_f64() - factored
            );
        }
        self.numeric = Some(Numeric {
            base,
            in_factor: active.clone(),
            active,
            nodes,
            l_values,
            last_border: None,
            factor_solves,
        });
        Ok(())
    }
}

/// The model of a numeric factorisation's cost in solves on the same
/// factor, R = [`FACTOR_PER_SHARE`] · share + [`FACTOR_FIXED`], where share
/// is the factorisation's multiply-adds over a solve's
/// ([`Factor::factorisation_share`]; dense kernels on supernodes run them
/// faster than the memory-bound sweeps of a solve, hence the slope < 1).
/// Fitted to the seconds of a factorisation over a solve measured on
/// 2 cores (faer parallel from 2·10⁵ KKT rows), share → measured (model):
/// 2D 10⁴ grains 27.5 → 9.2 (7.8), 2D 10⁵ 95 → 16.9 (14.5), 3D 2·10³
/// spheres 88 → 12.3 (13.8), 3D 10⁴ 322 → 43.8 (37.2), 3D 10⁵ 1 177 →
/// 107.6 (122.7): within 16 %, while repeated measurements of one ratio
/// spread by up to 30 %. Checked on the interior point's KKT of a sheared
/// 3D packing of 10⁴ spheres (share ~140): measured 15–23 (model 19).
const FACTOR_PER_SHARE: f64 = 0.1;
const FACTOR_FIXED: f64 = 5.0;

/// The numeric factorisation's modelled cost in solves on `factor`.
pub(super) fn factorisation_in_solves(factor: &Factor<'_>) -> f64 {
    FACTOR_PER_SHARE * factor.factorisation_share() + FACTOR_FIXED
}

pub(super) fn thread_count(par: Par) -> usize {
    match par {
        Par::Seq => 1,
        Par::Rayon(n) => n.get(),
    }
}

/// A faer scratch buffer, or a solver error naming what it was for.
pub(super) fn workspace(
    request: faer::dyn_stack::StackReq,
    what: impl FnOnce() -> String,
) -> Result<MemBuffer> {
    MemBuffer::try_new(request).map_err(|_| Error::Solver(format!("out of memory for {}", what())))
}

/// Parallelism of a triangular solve with `ncols` right-hand sides: faer's
/// parallel solve of several columns is far slower than its sequential one
/// (LDLᵀ, 2D 10⁵, 2 threads: 8 columns 3.3–4.1 s against 0.26 s; LLᵀ of a
/// 360 000-row grid: 3.0 s against 0.042 s for one column), while one column
/// costs the same either way.
pub(super) fn solve_parallelism(par: Par, ncols: usize) -> Par {
    if ncols > 1 {
        Par::Seq
    } else {
        par
    }
}

/// Sequential below [`PARALLEL_MIN_SIZE`] KKT unknowns, all threads above.
pub(super) fn default_parallelism(kkt_size: usize) -> Par {
    if kkt_size >= PARALLEL_MIN_SIZE {
        Par::rayon(0)
    } else {
        Par::Seq
    }
}
