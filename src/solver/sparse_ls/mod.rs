//! Sparse equality-constrained least squares — the fast floor of the method:
//!
//! ```text
//!     minimise ‖A x − b‖² + λ²‖x‖²   subject to   C x = d
//! ```
//!
//! Solved through the quasi-definite KKT system
//! `[[AᵀA + λ²I + δI, Cᵀ], [C, −δI]]` (AᵀA formed sparsely; it is local) with a
//! fill-reducing [`Ordering`] (AMD by default, nested dissection on request) and
//! faer's sparse LDLᵀ, followed by iterative refinement against
//! the *unregularised* system until the residual stops decreasing.
//!
//! Before factorising, columns of x are equilibrated (unit norm of `[A; C]`
//! columns) and rows of C are normalised; this changes neither the solution nor
//! the constraint set, but makes an absolute δ = 1e-10 meaningful and lets
//! badly scaled data refine to full accuracy. Row scales of A are the user's
//! weights and are left alone; since AᵀA squares them, weights spanning more than
//! ~1e6 can defeat the method — then δ is raised (1e-8, 1e-6) and, if refinement
//! still fails, the result says `converged: false` or an `Error::Solver` explains.
//!
//! The symbolic analysis (pattern of the KKT matrix, ordering, elimination tree)
//! lives in [`EqualityLeastSquares`] and is reused by every numeric factorisation
//! (λ sweeps, many frames with the same contact network).

mod compressed;
mod identifiability;
mod nodes;
mod ordering;

pub use identifiability::{identifiability, Identifiability};

use compressed::{
    abs_mul_scaled, abs_mul_t_scaled, gram_upper_pattern, gram_upper_values, mul_scaled,
    mul_t_scaled, Compressed,
};
use faer::dyn_stack::{MemBuffer, MemStack};
use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, LltRef, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nodes::{Factor, FactorNodes, SparseColumn};
use rayon::prelude::*;

use super::Triplets;
use crate::{Error, Result};

/// Static regularisation δ of the equilibrated KKT matrix (diag of AᵀA ≤ 1 there),
/// tried in this order until refinement converges.
pub const DELTA_LADDER: [f64; 3] = [1e-10, 1e-8, 1e-6];
/// Refinement is declared converged when the relative KKT residual (a normwise
/// backward error of the unregularised system) is at most this.
pub const CONVERGED_TOL: f64 = 1e-10;
/// Refinement stops early once the residual is at round-off level.
const ROUNDOFF_FLOOR: f64 = 1e-15;
const MAX_REFINEMENT_STEPS: usize = 60;
const EQUILIBRATION_PASSES: usize = 4;
/// Consecutive steps without a 10 % decrease before refinement gives up.
const STALL_STEPS: usize = 3;
/// Constraint rows whose terms |C_i||y| + |d_i| fall below this × (KKT size) × u
/// × (‖C_i‖∞‖y‖∞ + |d_i|) are at round-off level (Arioli–Demmel–Duff's τ).
const ADD_FACTOR: f64 = 1000.0;
/// Below this many KKT unknowns faer runs sequentially by default.
const PARALLEL_MIN_SIZE: usize = 200_000;

/// Fill-reducing ordering of the KKT matrix used by the symbolic analysis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Ordering {
    /// faer's approximate minimum degree.
    #[default]
    Amd,
    /// Recursive graph bisection by BFS level structures, separators last,
    /// small pieces by AMD (suits the 2D/3D spatial graphs of packings).
    NestedDissection,
}

impl Ordering {
    /// The measured choice by dimension: nested dissection in 3D (0.6× AMD's
    /// fill and refactorisation time at 10⁴ spheres, half the memory at 10⁵),
    /// AMD in 2D (where computing the dissection costs more than it saves).
    pub fn for_dim(dim: usize) -> Self {
        if dim == 3 {
            Ordering::NestedDissection
        } else {
            Ordering::Amd
        }
    }
}

/// How [`EqualityLeastSquares::solve_with_active`] takes active rows that
/// differ by a few from those of the kept factor (of the same A, C and λ):
/// rows added and rows no longer active are bordered around it, or a new
/// factor holds them all (the same answer either way, to the refinement
/// tolerance).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Bordering {
    /// Border the k changed rows (one sparse forward solve each, over the
    /// part of the factor it reaches) when that is estimated to take less
    /// than the numeric factorisation did, else factorise anew.
    #[default]
    Auto,
    /// Always a new numeric factorisation with the rows as penalties.
    Never,
    /// Border whenever a factor of the same values is at hand (at most 256
    /// changed rows, no spring taken out).
    Always,
}

/// Result of [`EqualityLeastSquares::solve`].
#[derive(Debug, Clone)]
pub struct LsSolution {
    pub x: Vec<f64>,
    /// ‖A x − b‖₂.
    pub residual: f64,
    /// ‖C x − d‖∞.
    pub equality_residual: f64,
    /// Number of refinement corrections applied after the first solve.
    pub refinement_steps: usize,
    /// True when the relative KKT residual reached [`CONVERGED_TOL`]. False means
    /// the constraints are inconsistent (see `equality_residual`) or the system is
    /// too ill-conditioned for refinement to reach the tolerance.
    pub converged: bool,
    /// Final relative KKT residual in the equilibrated system: the larger of the
    /// stationarity residual ‖r‖∞ / ‖|K||z| + |rhs|‖∞ and the worst constraint row
    /// |C_i x − d_i| / (|C_i||x| + |d_i|). Rows whose own terms are at round-off
    /// level relative to the solution (e.g. a single-entry row with d_i = 0, which
    /// pins one unknown to zero) add ‖C_i‖∞‖x‖∞ to that denominator (Arioli,
    /// Demmel & Duff 1989), since no solve resolves them better than round-off.
    pub kkt_residual: f64,
}

/// Result of [`EqualityLeastSquares::solve_with_active`].
#[derive(Debug, Clone)]
pub struct ActiveLsSolution {
    pub solution: LsSolution,
    /// Multiplier y_i of each active row G_i x = 0, signed for the inequality
    /// G_i x ≥ 0: at a constrained optimum ∇(½‖Ax − b‖² + ½λ²‖x‖²) = Cᵀν + Gᵀy,
    /// and y_i > 0 means the row really holds the solution back.
    pub multipliers: Vec<f64>,
    /// The active rows that changed since the kept factor were bordered
    /// around it (no new numeric factorisation), see [`Bordering`].
    pub bordered: bool,
}

/// Symbolic analysis of the KKT pattern plus the cached numeric factorisation.
pub struct EqualityLeastSquares {
    n: usize,
    a_pattern: (usize, Vec<usize>, Vec<usize>),
    c_pattern: (usize, Vec<usize>, Vec<usize>),
    coupling: Triplets,
    a_csr: Compressed,
    a_csc: Compressed,
    c_csr: Compressed,
    kkt_col_ptr: Vec<usize>,
    kkt_row_idx: Vec<usize>,
    ordering: Ordering,
    symbolic: Option<SymbolicCholesky<usize>>,
    par: Par,
    /// Refinement stops once the relative KKT residual is below this.
    refine_to: f64,
    bordering: Bordering,
    numeric: Option<Numeric>,
}

/// Outcome of one factorisation + refinement.
struct Attempt {
    x: Vec<f64>,
    multipliers: Vec<f64>,
    dual: f64,
    primal: f64,
    steps: usize,
    bordered: bool,
}

impl Attempt {
    fn rho(&self) -> f64 {
        self.dual.max(self.primal)
    }
}

/// What every factorisation of one A, C, λ and δ starts from, whatever the
/// active rows: the equilibration and the KKT values without those rows.
struct Base {
    delta: f64,
    lambda: f64,
    a_vals: Vec<f64>,
    c_vals: Vec<f64>,
    /// x = S y: column equilibration.
    col_scale: Vec<f64>,
    /// Row normalisation of C.
    c_row_scale: Vec<f64>,
    /// λ² s_j², the Tikhonov term in scaled variables.
    lambda2_s2: Vec<f64>,
    /// ‖row i of T C S‖∞, for the round-off-level rows of the primal residual.
    c_row_max: Vec<f64>,
    /// Upper KKT values, regularised, before the active rows' penalties and
    /// the springs are added.
    values: Vec<f64>,
}

impl Base {
    /// Built for these A, C and λ (whatever δ).
    fn same_problem(&self, a: &Triplets, c: &Triplets, lambda: f64) -> bool {
        self.lambda == lambda && self.a_vals == a.vals && self.c_vals == c.vals
    }

    fn same(&self, a: &Triplets, c: &Triplets, lambda: f64, delta: f64) -> bool {
        self.delta == delta && self.same_problem(a, c, lambda)
    }
}

/// Numeric state tied to one set of values, one λ and one δ.
struct Numeric {
    base: Base,
    /// The rows and springs of the current solve.
    active: ActiveRows,
    /// The rows (as penalties ĝᵀĝ/δ) and springs inside the factor; the
    /// current ones may differ from them by a few rows bordered around it.
    in_factor: ActiveRows,
    l_values: Vec<f64>,
    /// The factor's nodes, for split and sparse solves.
    nodes: FactorNodes,
    /// The last border solved around this factor, whose columns the next
    /// border may reuse.
    last_border: Option<Bordered>,
    /// Time of the numeric factorisation and of one solve [s]: a border
    /// costs the share of a solve its columns reach, a new factor one
    /// factorisation.
    factor_seconds: f64,
    solve_seconds: f64,
}

impl Numeric {
    fn same_values(&self, a: &Triplets, c: &Triplets, lambda: f64, delta: f64) -> bool {
        self.base.same(a, c, lambda, delta)
    }

    /// This factor with its symbolic part, for split and sparse solves.
    fn factor<'a>(&'a self, symbolic: &'a SymbolicCholesky<usize>) -> Factor<'a> {
        Factor {
            symbolic,
            values: &self.l_values,
            nodes: &self.nodes,
        }
    }
}

/// Homogeneous equalities G x = 0 eliminated by a penalty inside the KKT
/// pattern (each row may only couple unknowns that already share a row of A),
/// so changing them needs a new numeric factorisation (or a border) but no
/// new analysis.
#[derive(Clone)]
struct ActiveRows {
    pattern: (usize, Vec<usize>, Vec<usize>),
    vals: Vec<f64>,
    csr: Compressed,
    /// Row normalisation of G S.
    row_scale: Vec<f64>,
    /// ‖row i of T G S‖∞.
    row_max: Vec<f64>,
    /// Extra least-squares rows ‖R x‖² (zero right-hand side), e.g. the
    /// curvature of a Coulomb cone at a sliding contact.
    springs_pattern: (usize, Vec<usize>, Vec<usize>),
    springs_vals: Vec<f64>,
    springs: Compressed,
}

impl ActiveRows {
    /// G and R in CSR with the row scales of the equilibrated system.
    fn new(n: usize, g: &Triplets, springs: &Triplets, col_scale: &[f64]) -> Self {
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

    fn same(&self, g: &Triplets, springs: &Triplets) -> bool {
        self.pattern.0 == g.nrows
            && self.pattern.1 == g.rows
            && self.pattern.2 == g.cols
            && self.vals == g.vals
            && self.springs_pattern.0 == springs.nrows
            && self.springs_pattern.1 == springs.rows
            && self.springs_pattern.2 == springs.cols
            && self.springs_vals == springs.vals
    }

    fn len(&self) -> usize {
        self.pattern.0
    }

    /// Row i of G (`springs`: of R) as a key: its sorted columns and the bits
    /// of its values.
    fn key(&self, springs: bool, i: usize) -> Vec<(usize, u64)> {
        let m = if springs { &self.springs } else { &self.csr };
        m.range(i).map(|q| (m.idx[q], m.val[q].to_bits())).collect()
    }
}

/// How the current rows differ from those inside the factor.
struct Changes {
    /// Per current row: it is inside the factor (same entries).
    kept: Vec<bool>,
    /// Current rows and springs not in the factor.
    added: Vec<usize>,
    added_springs: Vec<usize>,
    /// Rows and springs of the factor no longer current.
    removed: Vec<usize>,
    removed_springs: Vec<usize>,
}

impl Changes {
    fn between(in_factor: &ActiveRows, current: &ActiveRows) -> Self {
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

    fn count(&self) -> usize {
        self.added.len()
            + self.added_springs.len()
            + self.removed.len()
            + self.removed_springs.len()
    }
}

impl EqualityLeastSquares {
    /// Validates sizes and indices and analyses the KKT pattern (AMD + symbolic
    /// Cholesky). Values are not looked at.
    pub fn new(a: &Triplets, c: &Triplets) -> Result<Self> {
        Self::with_parallelism(a, c, default_parallelism(a.ncols + c.nrows))
    }

    /// As [`new`](Self::new) with an explicit faer parallelism for the numeric
    /// factorisation and solves.
    pub fn with_parallelism(a: &Triplets, c: &Triplets, par: Par) -> Result<Self> {
        Self::analyse(a, c, &Triplets::new(0, a.ncols), par, Ordering::default())
    }

    /// As [`new`](Self::new), with the KKT pattern widened so that the unknowns
    /// of each row of `coupling` are coupled (values are ignored): rows of G in
    /// [`solve_with_active`](Self::solve_with_active) may then couple them even
    /// where A does not (e.g. a contact whose normal and tangential unknowns
    /// meet no common stress component).
    pub fn with_coupling(a: &Triplets, c: &Triplets, coupling: &Triplets) -> Result<Self> {
        Self::analyse(
            a,
            c,
            coupling,
            default_parallelism(a.ncols + c.nrows),
            Ordering::default(),
        )
    }

    /// As [`with_coupling`](Self::with_coupling) with an explicit fill-reducing
    /// ordering.
    pub fn with_ordering(
        a: &Triplets,
        c: &Triplets,
        coupling: &Triplets,
        ordering: Ordering,
    ) -> Result<Self> {
        Self::analyse(
            a,
            c,
            coupling,
            default_parallelism(a.ncols + c.nrows),
            ordering,
        )
    }

    fn analyse(
        a: &Triplets,
        c: &Triplets,
        coupling: &Triplets,
        par: Par,
        ordering: Ordering,
    ) -> Result<Self> {
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
        // Pattern of [A; coupling]ᵀ[A; coupling].
        let stacked_rows: Vec<usize> = a
            .rows
            .iter()
            .copied()
            .chain(coupling.rows.iter().map(|r| r + a.nrows))
            .collect();
        let stacked_cols: Vec<usize> = a.cols.iter().chain(&coupling.cols).copied().collect();
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
        let symbolic = symbolic_analysis(n + c.nrows, &col_ptr, &row_idx, ordering)?;
        Ok(EqualityLeastSquares {
            n,
            a_pattern: (a.nrows, a.rows.clone(), a.cols.clone()),
            c_pattern: (c.nrows, c.rows.clone(), c.cols.clone()),
            coupling: coupling.clone(),
            a_csr,
            a_csc,
            c_csr,
            kkt_col_ptr: col_ptr,
            kkt_row_idx: row_idx,
            ordering,
            symbolic,
            par,
            refine_to: ROUNDOFF_FLOOR,
            bordering: Bordering::Auto,
            numeric: None,
        })
    }

    /// Redoes the symbolic analysis with this fill-reducing ordering (and keeps
    /// it when a new pattern is analysed); drops the cached factorisation.
    pub fn set_ordering(&mut self, ordering: Ordering) -> Result<()> {
        self.symbolic = symbolic_analysis(
            self.n + self.c_pattern.0,
            &self.kkt_col_ptr,
            &self.kkt_row_idx,
            ordering,
        )?;
        self.ordering = ordering;
        self.numeric = None;
        Ok(())
    }

    /// The fill-reducing ordering of the symbolic analysis.
    pub fn ordering(&self) -> Ordering {
        self.ordering
    }

    /// How few active rows are taken on the base factor (see [`Bordering`]).
    pub fn set_bordering(&mut self, bordering: Bordering) {
        self.bordering = bordering;
    }

    /// Stop refinement at this relative KKT residual instead of round-off
    /// (≥ round-off; a value above [`CONVERGED_TOL`] leaves solutions unconverged).
    /// Iterative callers that only need [`CONVERGED_TOL`] save solves.
    pub fn set_refinement_target(&mut self, target: f64) {
        self.refine_to = target.max(ROUNDOFF_FLOOR);
    }

    /// Number of stored entries in the factor L (0 for an empty problem).
    pub fn factor_nnz(&self) -> usize {
        self.symbolic.as_ref().map_or(0, |s| s.len_val())
    }

    /// Numeric factorisation (skipped when λ and the values of A and C are the
    /// ones of the previous call), solve and refinement. If the pattern of A or C
    /// differs from the analysed one, the analysis is redone first.
    pub fn solve(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        b: &[f64],
        d: &[f64],
        lambda: f64,
    ) -> Result<LsSolution> {
        let none = Triplets::new(0, a.ncols);
        Ok(self
            .solve_with_active(a, c, b, d, lambda, &none, &none)?
            .solution)
    }

    /// As [`solve`](Self::solve) with the extra homogeneous equalities G x = 0
    /// (an active set of inequalities G x ≥ 0), returning their multipliers, and
    /// the extra term ‖R x‖² (`springs`) in the objective.
    /// Each row of G may only couple unknowns that share a row of A (a contact's
    /// own unknowns do): G enters the factorisation as a penalty GᵀG/δ on the
    /// analysed pattern (rows that changed since the kept factor may instead
    /// be bordered around it, see [`Bordering`]), and iterative refinement
    /// then solves the exact augmented system
    /// `[[AᵀA + λ²I, Cᵀ, Gᵀ], [C, 0, 0], [G, 0, 0]]`.
    #[allow(clippy::too_many_arguments)]
    pub fn solve_with_active(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        b: &[f64],
        d: &[f64],
        lambda: f64,
        g: &Triplets,
        springs: &Triplets,
    ) -> Result<ActiveLsSolution> {
        check_pair(a, c)?;
        check_triplets(g, "G")?;
        check_triplets(springs, "R")?;
        for (name, m) in [("G", g), ("R", springs)] {
            if m.ncols != a.ncols {
                return Err(Error::Invalid(format!(
                    "{name} has {} columns but A has {}; both act on the same unknowns",
                    m.ncols, a.ncols
                )));
            }
        }
        if b.len() != a.nrows {
            return Err(Error::Invalid(format!(
                "b has {} entries but A has {} rows",
                b.len(),
                a.nrows
            )));
        }
        if d.len() != c.nrows {
            return Err(Error::Invalid(format!(
                "d has {} entries but C has {} rows",
                d.len(),
                c.nrows
            )));
        }
        if !(lambda.is_finite() && lambda >= 0.0) {
            return Err(Error::Invalid(format!(
                "λ must be finite and ≥ 0, got {lambda}"
            )));
        }
        check_finite(&a.vals, "A value")?;
        check_finite(&c.vals, "C value")?;
        check_finite(&g.vals, "G value")?;
        check_finite(&springs.vals, "R value")?;
        check_finite(b, "b")?;
        check_finite(d, "d")?;
        if !self.same_pattern(a, c) {
            let coupling = std::mem::take(&mut self.coupling);
            let (refine_to, bordering) = (self.refine_to, self.bordering);
            *self = Self::analyse(a, c, &coupling, self.par, self.ordering)?;
            (self.refine_to, self.bordering) = (refine_to, bordering);
        }
        let n = self.n;
        if n == 0 {
            // Nothing to choose: C x = 0 for every x, so consistent iff d = 0.
            let equality_residual = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            return Ok(ActiveLsSolution {
                solution: LsSolution {
                    x: Vec::new(),
                    residual: norm2(b),
                    equality_residual,
                    refinement_steps: 0,
                    converged: equality_residual == 0.0,
                    kkt_residual: if equality_residual == 0.0 { 0.0 } else { 1.0 },
                },
                multipliers: vec![0.0; g.nrows],
                bordered: false,
            });
        }
        // δ ladder: the first δ suits almost everything; a larger one trades
        // refinement steps for a smaller growth factor in the LDLᵀ when the
        // first attempt breaks down. Inconsistent constraints (dual residual
        // converged, primal stuck) are not helped by a larger δ.
        let mut ladder: Vec<f64> = DELTA_LADDER.to_vec();
        if let Some(num) = &self.numeric {
            if num.base.same_problem(a, c, lambda) && num.active.same(g, springs) {
                ladder.retain(|&delta| delta >= num.base.delta);
            }
        }
        let mut best: Option<Attempt> = None;
        let mut failures = Vec::new();
        for &delta in &ladder {
            match self.attempt(a, c, b, d, lambda, delta, g, springs) {
                Ok(att) => {
                    let stop = att.rho() <= CONVERGED_TOL || att.dual <= CONVERGED_TOL;
                    let better = match &best {
                        Some(previous) => att.rho() < previous.rho(),
                        None => true,
                    };
                    if better {
                        best = Some(att);
                    }
                    if stop {
                        break;
                    }
                }
                Err(Error::Solver(message)) => failures.push(format!("δ = {delta:e}: {message}")),
                Err(e) => return Err(e),
            }
        }
        let Some(best) = best else {
            return Err(Error::Solver(format!(
                "sparse KKT solve failed for every regularisation tried ({n} unknowns, {} constraints, {} active rows, λ = {lambda}): {}",
                c.nrows,
                g.nrows,
                failures.join("; ")
            )));
        };
        let x = best.x;
        let residual = norm2(&sub(&a.mul(&x), b));
        let equality_residual = sub(&c.mul(&x), d)
            .iter()
            .chain(g.mul(&x).iter())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        let kkt_residual = best.dual.max(best.primal);
        Ok(ActiveLsSolution {
            solution: LsSolution {
                x,
                residual,
                equality_residual,
                refinement_steps: best.steps,
                converged: kkt_residual <= CONVERGED_TOL,
                kkt_residual,
            },
            multipliers: best.multipliers,
            bordered: best.bordered,
        })
    }

    /// One factorisation with static regularisation δ (or a border of the
    /// kept one), first solve, refinement. A border that does not refine to
    /// [`CONVERGED_TOL`] is replaced by a factorisation: taking a row out
    /// cancels its penalty ĝᵀĝ/δ, which could cost the accuracy refinement
    /// needs.
    #[allow(clippy::too_many_arguments)]
    fn attempt(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        b: &[f64],
        d: &[f64],
        lambda: f64,
        delta: f64,
        g: &Triplets,
        springs: &Triplets,
    ) -> Result<Attempt> {
        match self.attempt_on(a, c, b, d, lambda, delta, g, springs, true) {
            Ok(att) if !att.bordered || att.rho() <= CONVERGED_TOL => Ok(att),
            Ok(_) | Err(Error::Solver(_)) => {
                self.attempt_on(a, c, b, d, lambda, delta, g, springs, false)
            }
            Err(e) => Err(e),
        }
    }

    /// [`attempt`](Self::attempt), bordering the changed rows only when
    /// `may_border`.
    #[allow(clippy::too_many_arguments)]
    fn attempt_on(
        &mut self,
        a: &Triplets,
        c: &Triplets,
        b: &[f64],
        d: &[f64],
        lambda: f64,
        delta: f64,
        g: &Triplets,
        springs: &Triplets,
        may_border: bool,
    ) -> Result<Attempt> {
        let n = self.n;
        // On a factor of the same A, C, λ and δ, the rows that changed since
        // it was computed (rows added, rows it holds that are no longer
        // active) are bordered around it — one sparse forward solve each —
        // instead of a new numeric factorisation, when those solves cost less
        // than the factorisation did.
        let mut changes = None;
        // The border's columns, when the choice below already built them.
        let mut built = None;
        if let (Some(num), Some(symbolic)) = (self.numeric.as_mut(), self.symbolic.as_ref()) {
            if num.same_values(a, c, lambda, delta) {
                if !num.active.same(g, springs) {
                    num.active = ActiveRows::new(n, g, springs, &num.base.col_scale);
                }
                let diff = Changes::between(&num.in_factor, &num.active);
                let k = diff.count();
                // Removing a spring would subtract a stiffness of any size.
                let may =
                    may_border && k > 0 && k <= BORDER_MAX_ROWS && diff.removed_springs.is_empty();
                let border = may
                    && match self.bordering {
                        Bordering::Auto => {
                            // Only the columns the last border did not solve cost solves.
                            let columns = border_columns(num, &diff, delta);
                            let factor = num.factor(symbolic);
                            let fresh = (columns.iter())
                                .filter(|col| {
                                    !num.last_border.as_ref().is_some_and(|b| b.holds(col))
                                })
                                .map(|(entries, _)| entries.as_slice());
                            let share = factor.reach_share(fresh);
                            let seconds = share * num.solve_seconds / thread_count(self.par) as f64;
                            built = Some(columns);
                            seconds < num.factor_seconds
                        }
                        Bordering::Never => false,
                        Bordering::Always => true,
                    };
                if k == 0 || border {
                    changes = Some(diff);
                }
            }
        }
        let changes = match changes {
            Some(changes) => changes,
            None => {
                self.factorise(a, c, lambda, delta, g, springs)?;
                let num = self.numeric.as_ref().expect("factorised above");
                Changes::between(&num.in_factor, &num.active)
            }
        };
        let border = changes.count() > 0;
        let previous = self.numeric.as_mut().and_then(|n| n.last_border.take());
        let num = self.numeric.as_ref().expect("factorised above");
        let factor = num.factor(
            self.symbolic
                .as_ref()
                .expect("non-empty KKT has a symbolic factor"),
        );
        let size = factor.rows();
        let mg = num.active.len();
        let bordered = if border {
            let columns = built.unwrap_or_else(|| border_columns(num, &changes, delta));
            Some(Bordered::new(columns, &factor, previous.as_ref())?)
        } else {
            None
        };
        let kept: Vec<f64> = changes
            .kept
            .iter()
            .map(|&k| if k { 1.0 } else { 0.0 })
            .collect();
        let any_kept = changes.kept.iter().any(|&k| k);
        let mut border_rhs = vec![0.0; changes.count()];
        // Solves the regularised augmented system in place: the active rows
        // the factor holds are eliminated through their penalty, the others
        // bordered around it, between the two halves of the factor's solve.
        let mut kkt_solve = |rhs: &mut [f64]| {
            let (head, r3) = rhs.split_at_mut(size);
            if any_kept {
                let shifted: Vec<f64> = (r3.iter().zip(&num.active.row_scale))
                    .map(|(r, t)| r * t / delta)
                    .collect();
                let lift = mul_t_scaled(&num.active.csr, &kept, &num.base.col_scale, &shifted, n);
                for (h, l) in head.iter_mut().zip(&lift) {
                    *h += l;
                }
            }
            factor.solve_with(head, |v| {
                if let Some(bordered) = &bordered {
                    for (slot, &i) in border_rhs.iter_mut().zip(&changes.added) {
                        *slot = r3[i];
                    }
                    let t = bordered.correct(&factor, v, &border_rhs);
                    for (&i, ti) in changes.added.iter().zip(t.iter()) {
                        r3[i] = *ti;
                    }
                }
            });
            if any_kept {
                let gy = mul_scaled(
                    &num.active.csr,
                    &num.active.row_scale,
                    &num.base.col_scale,
                    &head[..n],
                );
                for ((r, gyi), &k) in r3.iter_mut().zip(&gy).zip(&changes.kept) {
                    if k {
                        *r = (gyi - *r) / delta;
                    }
                }
            }
        };

        let ones_a = vec![1.0; a.nrows];
        let d_hat: Vec<f64> = d
            .iter()
            .zip(&num.base.c_row_scale)
            .map(|(v, t)| v * t)
            .collect();
        // The right-hand side (the residual at z = 0): (S Aᵀb, T d, 0).
        let mut z = mul_t_scaled(&self.a_csr, &ones_a, &num.base.col_scale, b, n);
        z.extend_from_slice(&d_hat);
        z.resize(size + mg, 0.0);
        let clock = std::time::Instant::now();
        kkt_solve(&mut z);
        let first_solve_seconds = clock.elapsed().as_secs_f64();
        let (mut r, mut dual, mut primal) = self.kkt_residual(num, &ones_a, b, &d_hat, &z);
        if !(dual.is_finite() && primal.is_finite()) {
            return Err(Error::Solver(
                "the first KKT solve produced non-finite values (factor growth; the data are too badly scaled \
                 for the normal-equations KKT)"
                    .into(),
            ));
        }
        let mut best = (dual.max(primal), dual, primal, z.clone());
        let mut steps = 0;
        let mut stalled = 0;
        while steps < MAX_REFINEMENT_STEPS && best.0 > self.refine_to && stalled < STALL_STEPS {
            kkt_solve(&mut r);
            for (zi, ri) in z.iter_mut().zip(&r) {
                *zi += ri;
            }
            steps += 1;
            (r, dual, primal) = self.kkt_residual(num, &ones_a, b, &d_hat, &z);
            let rho = dual.max(primal);
            if !rho.is_finite() {
                break;
            }
            stalled = if rho < 0.9 * best.0 { 0 } else { stalled + 1 };
            if rho < best.0 {
                best = (rho, dual, primal, z.clone());
            }
        }
        let x: Vec<f64> = best.3[..n]
            .iter()
            .zip(&num.base.col_scale)
            .map(|(y, s)| y * s)
            .collect();
        if x.iter().any(|v| !v.is_finite()) {
            return Err(Error::Solver(
                "the solution overflows after unscaling".into(),
            ));
        }
        // The refined system reads (AᵀA + λ²)x + … + Gᵀ(T w) = Aᵀb, so the
        // multiplier of G x ≥ 0 in ∇ = Cᵀν + Gᵀy is y = −T w.
        let multipliers = best.3[size..]
            .iter()
            .zip(&num.active.row_scale)
            .map(|(w, t)| -w * t)
            .collect();
        if let Some(num) = self.numeric.as_mut() {
            if !border {
                // A plain solve on the factor: the unit of a border's cost.
                num.solve_seconds = first_solve_seconds;
            }
            num.last_border = bordered.or(previous);
        }
        Ok(Attempt {
            x,
            multipliers,
            dual: best.1,
            primal: best.2,
            steps,
            bordered: border,
        })
    }

    fn same_pattern(&self, a: &Triplets, c: &Triplets) -> bool {
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
    fn add_row_products(
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

    /// Equilibration, KKT values and numeric LDLᵀ, unless cached.
    fn factorise(
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
        let (base, l_values) = match self.numeric.take() {
            Some(num) if num.same_values(a, c, lambda, delta) => (num.base, num.l_values),
            old => (
                self.base(a, c, lambda, delta)?,
                old.map(|num| num.l_values).unwrap_or_default(),
            ),
        };
        let clock = std::time::Instant::now();
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
        self.numeric = Some(Numeric {
            base,
            in_factor: active.clone(),
            active,
            nodes: FactorNodes::new(symbolic, &l_values),
            l_values,
            last_border: None,
            factor_seconds: clock.elapsed().as_secs_f64(),
            solve_seconds: f64::INFINITY,
        });
        Ok(())
    }

    /// The equilibration of [A; C] and the regularised KKT values without
    /// active rows (see [`Base`]).
    fn base(&mut self, a: &Triplets, c: &Triplets, lambda: f64, delta: f64) -> Result<Base> {
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

    /// Residual of the unregularised equilibrated KKT system at z = (y, μ, w), and
    /// the relative sizes of the dual (stationarity, normwise) and primal (C x = d
    /// and G x = 0, per row) parts.
    fn kkt_residual(
        &self,
        num: &Numeric,
        ones_a: &[f64],
        b: &[f64],
        d_hat: &[f64],
        z: &[f64],
    ) -> (Vec<f64>, f64, f64) {
        let n = self.n;
        let mc = d_hat.len();
        let (y, rest) = z.split_at(n);
        let (mu, w) = rest.split_at(mc);
        let (s, t) = (&num.base.col_scale, &num.base.c_row_scale);
        let (g_csr, tg) = (&num.active.csr, &num.active.row_scale);
        let ay = mul_scaled(&self.a_csr, ones_a, s, y);
        let ra: Vec<f64> = b.iter().zip(&ay).map(|(bi, ai)| bi - ai).collect();
        let atr = mul_t_scaled(&self.a_csr, ones_a, s, &ra, n);
        let ctmu = mul_t_scaled(&self.c_csr, t, s, mu, n);
        let gtw = mul_t_scaled(g_csr, tg, s, w, n);
        let springs = &num.active.springs;
        let ones_r = vec![1.0; springs.nmajor];
        let ry = mul_scaled(springs, &ones_r, s, y);
        let rtry = mul_t_scaled(springs, &ones_r, s, &ry, n);
        let rtry_bound = abs_mul_t_scaled(
            springs,
            &ones_r,
            s,
            &abs_mul_scaled(springs, &ones_r, s, y),
            n,
        );
        let cy = mul_scaled(&self.c_csr, t, s, y);
        let gy = mul_scaled(g_csr, tg, s, y);

        let abs_ay = abs_mul_scaled(&self.a_csr, ones_a, s, y);
        let b_bound: Vec<f64> = b
            .iter()
            .zip(&abs_ay)
            .map(|(bi, ai)| bi.abs() + ai)
            .collect();
        let dual_bound = abs_mul_t_scaled(&self.a_csr, ones_a, s, &b_bound, n);
        let ctmu_bound = abs_mul_t_scaled(&self.c_csr, t, s, mu, n);
        let gtw_bound = abs_mul_t_scaled(g_csr, tg, s, w, n);
        let primal_bound = abs_mul_scaled(&self.c_csr, t, s, y);
        let g_bound = abs_mul_scaled(g_csr, tg, s, y);

        let mut r = Vec::with_capacity(z.len());
        let (mut dual_num, mut dual_den) = (0.0f64, 0.0f64);
        for j in 0..n {
            let reg = num.base.lambda2_s2[j] * y[j];
            let g = atr[j] - reg - ctmu[j] - gtw[j] - rtry[j];
            dual_num = dual_num.max(g.abs());
            dual_den = dual_den
                .max(dual_bound[j] + reg.abs() + ctmu_bound[j] + gtw_bound[j] + rtry_bound[j]);
            r.push(g);
        }
        // Constraints are checked row by row (componentwise): each equation must
        // hold to round-off relative to its own terms. A row whose terms are
        // themselves round-off of the solution (d_i = 0 and C_i y ≈ 0, e.g. one
        // entry pinning y_j = 0) cannot do better than |y_j| ~ u‖y‖, and the pure
        // componentwise ratio would then read 1 forever; such rows are measured
        // against ‖C_i‖∞‖y‖∞ as well (Arioli, Demmel & Duff, SIMAX 1989).
        let ratio = |num: f64, den: f64| {
            if num == 0.0 {
                0.0
            } else {
                (num / den).min(1.0)
            }
        };
        let y_max = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let roundoff_level = ADD_FACTOR * z.len() as f64 * f64::EPSILON;
        let mut primal = 0.0f64;
        let mut row_check = |rc: f64, own: f64, rhs: f64, row_max: f64| {
            let own_terms = own + rhs.abs();
            let normwise = row_max * y_max;
            let den = if own_terms > roundoff_level * (normwise + rhs.abs()) {
                own_terms
            } else {
                own_terms + normwise
            };
            primal = primal.max(ratio(rc.abs(), den));
        };
        for i in 0..mc {
            let rc = d_hat[i] - cy[i];
            row_check(rc, primal_bound[i], d_hat[i], num.base.c_row_max[i]);
            r.push(rc);
        }
        for i in 0..gy.len() {
            row_check(gy[i], g_bound[i], 0.0, num.active.row_max[i]);
            r.push(-gy[i]);
        }
        (r, ratio(dual_num, dual_den), primal)
    }
}

fn thread_count(par: Par) -> usize {
    match par {
        Par::Seq => 1,
        Par::Rayon(n) => n.get(),
    }
}

/// At most this many active rows + springs are bordered around the base
/// factor: the dense Schur complement costs k² sparse products to form.
const BORDER_MAX_ROWS: usize = 256;

/// The bordered system `[[F, B], [Bᵀ, −D]]` around the kept factor
/// F = Pᵀ L D Lᵀ P: B's columns are the scaled active rows added since F
/// (D = δ, the base regularisation), the springs added (D = 1, so that they
/// add BᵀB to the Hessian block) and the rows F holds that are no longer
/// active (D = −δ: eliminating them subtracts the penalty ĝᵀĝ/δ that F
/// holds). Holds W = L⁻¹ P B, sparse (each column reaches few nodes of the
/// factor), and the LU of the Schur complement BᵀF⁻¹B + D = Wᵀ D⁻¹ W + D.
struct Bordered {
    /// B's columns (sparse) and their D.
    columns: Vec<Vec<(usize, f64)>>,
    d: Vec<f64>,
    w: Vec<SparseColumn>,
    schur: nalgebra::LU<f64, nalgebra::Dyn, nalgebra::Dyn>,
}

/// The columns of B for the rows that changed since the factor, each with
/// its D (see [`Bordered`]).
fn border_columns(num: &Numeric, changes: &Changes, delta: f64) -> Vec<BorderColumn> {
    let s = &num.base.col_scale;
    (changes.added.iter())
        .map(|&i| (scaled_row(&num.active, false, i, s), delta))
        .chain((changes.added_springs.iter()).map(|&i| (scaled_row(&num.active, true, i, s), 1.0)))
        .chain((changes.removed.iter()).map(|&i| (scaled_row(&num.in_factor, false, i, s), -delta)))
        .collect()
}

/// A column of B (sparse) and its D.
type BorderColumn = (Vec<(usize, f64)>, f64);

impl Bordered {
    /// Whether this border already solved that column.
    fn holds(&self, column: &BorderColumn) -> bool {
        self.position(column).is_some()
    }

    /// Where this border holds that column.
    fn position(&self, (entries, d): &BorderColumn) -> Option<usize> {
        (self.columns.iter().zip(&self.d)).position(|(e, pd)| e == entries && pd == d)
    }

    /// `columns`: the entries of each column of B with its D. Columns that
    /// `previous` (a border on the same factor) already solved are copied,
    /// not solved again: consecutive bordered solves share most columns.
    fn new(
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
        let mut m = nalgebra::DMatrix::<f64>::zeros(k, k);
        let mut dense = vec![0.0; size];
        for (i, wi) in w.iter().enumerate() {
            factor.scatter_scaled(wi, &mut dense);
            for (j, wj) in w.iter().enumerate().skip(i) {
                let v = factor.dot(wj, &dense);
                m[(i, j)] = v;
                m[(j, i)] = v;
            }
            factor.clear(wi, &mut dense);
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
    fn correct(&self, factor: &Factor<'_>, v: &mut [f64], r: &[f64]) -> nalgebra::DVector<f64> {
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

/// Ordering and symbolic Cholesky of the upper KKT pattern (None when empty).
fn symbolic_analysis(
    size: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
    ordering: Ordering,
) -> Result<Option<SymbolicCholesky<usize>>> {
    if size == 0 {
        return Ok(None);
    }
    let pattern = SymbolicSparseColMatRef::new_checked(size, size, col_ptr, None, row_idx);
    let perm = match ordering {
        Ordering::Amd => None,
        Ordering::NestedDissection => {
            let fwd = ordering::nested_dissection(size, col_ptr, row_idx);
            let mut inv = vec![0usize; size];
            for (new, &old) in fwd.iter().enumerate() {
                inv[old] = new;
            }
            Some((fwd, inv))
        }
    };
    let method = match &perm {
        None => SymmetricOrdering::Amd,
        Some((fwd, inv)) => SymmetricOrdering::Custom(PermRef::new_checked(fwd, inv, size)),
    };
    factorize_symbolic_cholesky(pattern, Side::Upper, method, Default::default())
        .map(Some)
        .map_err(|e| {
            Error::Solver(format!(
                "symbolic analysis of the {size}×{size} KKT matrix ({} stored entries, {ordering:?} ordering) failed: {e:?}",
                row_idx.len()
            ))
        })
}

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
                "SpdFactor needs the upper triangle of a {size}×{size} matrix in CSC with sorted rows,                  each column ending on its diagonal, and one value per entry"
            )));
        }
        let par = default_parallelism(size);
        let symbolic = symbolic_analysis(size, col_ptr, row_idx, ordering)?;
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

/// A faer scratch buffer, or a solver error naming what it was for.
fn workspace(
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
fn solve_parallelism(par: Par, ncols: usize) -> Par {
    if ncols > 1 {
        Par::Seq
    } else {
        par
    }
}

/// Sequential below [`PARALLEL_MIN_SIZE`] KKT unknowns, all threads above.
fn default_parallelism(kkt_size: usize) -> Par {
    if kkt_size >= PARALLEL_MIN_SIZE {
        Par::rayon(0)
    } else {
        Par::Seq
    }
}

/// 1/‖(B S)_r‖ per row of a CSR matrix (1 for empty rows).
fn row_inverse_norms(csr: &Compressed, col_scale: &[f64]) -> Vec<f64> {
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

/// Sizes and indices of one triplet matrix.
pub(crate) fn check_triplets(t: &Triplets, name: &str) -> Result<()> {
    if t.rows.len() != t.vals.len() || t.cols.len() != t.vals.len() {
        return Err(Error::Invalid(format!(
            "{name}: {} row indices, {} column indices and {} values",
            t.rows.len(),
            t.cols.len(),
            t.vals.len()
        )));
    }
    for (k, (&r, &c)) in t.rows.iter().zip(&t.cols).enumerate() {
        if r >= t.nrows || c >= t.ncols {
            return Err(Error::Invalid(format!(
                "{name}: entry {k} at ({r}, {c}) lies outside the {}×{} matrix",
                t.nrows, t.ncols
            )));
        }
    }
    Ok(())
}

pub(crate) fn check_pair(a: &Triplets, c: &Triplets) -> Result<()> {
    check_triplets(a, "A")?;
    check_triplets(c, "C")?;
    if a.ncols != c.ncols {
        return Err(Error::Invalid(format!(
            "A has {} columns but C has {}; both act on the same unknowns",
            a.ncols, c.ncols
        )));
    }
    Ok(())
}

pub(crate) fn check_finite(v: &[f64], name: &str) -> Result<()> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(k) => Err(Error::Invalid(format!(
            "{name} {k} is not finite ({})",
            v[k]
        ))),
        None => Ok(()),
    }
}

fn norm2(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn sub(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| x - y).collect()
}
