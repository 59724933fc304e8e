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
//!
//! Layout: `kkt` forms the KKT pattern and its equilibrated values;
//! `symbolic` (ordering, symbolic Cholesky; `ordering` holds nested
//! dissection) and `numeric` (LDLᵀ and its cached state) are faer's two
//! stages; `active_rows` and `border` take active rows in as penalties or
//! around the kept factor (`nodes`: sparse solves on its supernodes); `refine`
//! solves and refines (`krylov`: GMRES when the factor holds stale rows); `spd` is the Cholesky path for definite matrices,
//! `identifiability` the uniqueness probe, `checks` the input checks,
//! `compressed` the CSR/CSC kernels.

mod active_rows;
mod border;
mod checks;
mod compressed;
mod identifiability;
mod kkt;
mod krylov;
mod nodes;
mod numeric;
mod ordering;
mod refine;
mod spd;
mod symbolic;

pub use identifiability::{identifiability, identifiability_with, Identifiability};
pub use spd::SpdFactor;

#[cfg(test)]
pub(crate) use active_rows::STALE_TOL;
pub(crate) use checks::{check_finite, check_pair, check_triplets};

use checks::{norm2, sub};
use compressed::Compressed;
use faer::sparse::linalg::cholesky::SymbolicCholesky;
use faer::Par;
use numeric::{default_parallelism, Numeric};
use refine::Attempt;
use symbolic::symbolic_analysis;

use super::Triplets;
use crate::{Error, Result};

/// Static regularisation δ of the equilibrated KKT matrix (diag of AᵀA ≤ 1 there),
/// tried in this order until refinement converges.
pub(crate) const DELTA_LADDER: [f64; 3] = [1e-10, 1e-8, 1e-6];
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

/// Whether `GRAINFORCE_IP_PROFILE` asks for the factorisations' split on stderr.
pub(crate) fn profiling() -> bool {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ON.get_or_init(|| std::env::var_os("GRAINFORCE_IP_PROFILE").is_some())
}

/// Fill-reducing ordering of the KKT matrix used by the symbolic analysis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Ordering {
    /// faer's approximate minimum degree.
    #[default]
    Amd,
    /// METIS's multilevel nested dissection on supervariables (a contact's
    /// unknowns, a grain's momentum rows), separators last (suits the 2D/3D
    /// spatial graphs of packings).
    NestedDissection,
}

impl Ordering {
    /// The measured choice by dimension: nested dissection in 3D (at 10⁴
    /// spheres 0.42× AMD's fill and 0.34× its refactorisation and solve
    /// time), AMD in 2D (where computing the dissection costs more than it
    /// saves: at 10⁵ disks METIS takes 2.7 s for 0.78× the fill, against
    /// 0.2–0.4 s saved per solve).
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
    /// part of the factor it reaches) when that is modelled to cost less
    /// than a new numeric factorisation, else factorise anew. The model
    /// counts the factor's entries and multiply-adds, not seconds, so a run
    /// is reproducible to the bit. Rows and
    /// springs with the same entries but values within 30 % are not
    /// changed: the factor keeps its copies and GMRES corrects for them.
    #[default]
    Auto,
    /// Always a new numeric factorisation with the rows as penalties.
    Never,
    /// Border whenever a factor of the same values is at hand (at most 256
    /// changed rows).
    Always,
}

/// Result of [`EqualityLeastSquares::solve`].
#[derive(Debug, Clone)]
pub struct LsSolution {
    pub x: Vec<f64>,
    /// Multiplier ν of C x = d: at the solution ∇(½‖Ax − b‖² + ½λ²‖x‖²)
    /// = Cᵀν (+ Gᵀy with active rows).
    pub equality_multipliers: Vec<f64>,
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
    /// No new numeric factorisation: the kept factor served, the active rows
    /// that changed since bordered around it and those that only turned a
    /// little (a 3D sliding direction) held stale, GMRES on the factor then
    /// solving the exact system; see [`Bordering`].
    pub reused_factor: bool,
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
    /// Shared with solvers made by [`Self::sharing_analysis`].
    symbolic: Option<std::sync::Arc<SymbolicCholesky<usize>>>,
    par: Par,
    /// Refinement stops once the relative KKT residual is below this.
    refine_to: f64,
    /// The first δ tried (then the larger ones of [`DELTA_LADDER`]).
    first_delta: f64,
    bordering: Bordering,
    numeric: Option<Numeric>,
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

    /// Redoes the symbolic analysis with this fill-reducing ordering, or AMD
    /// when METIS cannot give one (see [`ordering`](Self::ordering)), and keeps
    /// the one used for new patterns; drops the cached factorisation.
    pub fn set_ordering(&mut self, ordering: Ordering) -> Result<()> {
        let blocks = kkt::kkt_blocks(self.n, self.c_pattern.0, &self.coupling);
        let analysed = symbolic_analysis(
            self.n + self.c_pattern.0,
            &self.kkt_col_ptr,
            &self.kkt_row_idx,
            ordering,
            Some(&blocks),
        )?;
        self.ordering = analysed.as_ref().map_or(ordering, |(_, used)| *used);
        self.symbolic = analysed.map(|(symbolic, _)| std::sync::Arc::new(symbolic));
        self.numeric = None;
        Ok(())
    }

    /// The rows whose unknowns the analysed pattern couples beyond A's.
    pub fn coupling(&self) -> &Triplets {
        &self.coupling
    }

    /// The fill-reducing ordering of the symbolic analysis: AMD when nested
    /// dissection was asked for but METIS could not order this pattern (the
    /// same forces, at more fill and time). A new pattern keeps it.
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
    pub(crate) fn set_refinement_target(&mut self, target: f64) {
        self.refine_to = target.max(ROUNDOFF_FLOOR);
    }

    /// Try this static regularisation first (then the larger δ of the
    /// ladder). A smaller δ suits systems whose Schur complement on C is
    /// tiny in some directions — the interior point's near its end: there
    /// refinement of C x = d contracts by about δ/σ_min per step (measured on
    /// a sheared 10³ packing: 60 steps at 1e-10, 4 at 1e-12).
    pub(crate) fn set_first_regularisation(&mut self, delta: f64) {
        self.first_delta = delta.clamp(1e-14, DELTA_LADDER[0]);
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
            let kept = (self.refine_to, self.first_delta, self.bordering);
            *self = Self::analyse(a, c, &coupling, self.par, self.ordering)?;
            (self.refine_to, self.first_delta, self.bordering) = kept;
        }
        let n = self.n;
        if n == 0 {
            // Nothing to choose: C x = 0 for every x, so consistent iff d = 0.
            let equality_residual = d.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            return Ok(ActiveLsSolution {
                solution: LsSolution {
                    x: Vec::new(),
                    equality_multipliers: vec![0.0; c.nrows],
                    residual: norm2(b),
                    equality_residual,
                    refinement_steps: 0,
                    converged: equality_residual == 0.0,
                    kkt_residual: if equality_residual == 0.0 { 0.0 } else { 1.0 },
                },
                multipliers: vec![0.0; g.nrows],
                reused_factor: false,
            });
        }
        // δ ladder: the first δ suits almost everything; a larger one trades
        // refinement steps for a smaller growth factor in the LDLᵀ when the
        // first attempt breaks down. Inconsistent constraints (dual residual
        // converged, primal stuck) are not helped by a larger δ.
        let mut ladder: Vec<f64> = DELTA_LADDER.to_vec();
        if self.first_delta < ladder[0] {
            ladder.insert(0, self.first_delta);
        }
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
                    // A caller content with a looser residual (the interior
                    // point at the data's accuracy) takes it on this δ.
                    let enough = CONVERGED_TOL.max(self.refine_to);
                    let stop = att.rho() <= enough || att.dual <= CONVERGED_TOL;
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
        let (x, equality_multipliers) = (best.x, best.equality_multipliers);
        let residual = norm2(&sub(&a.mul(&x), b));
        let equality_residual = sub(&c.mul(&x), d)
            .iter()
            .chain(g.mul(&x).iter())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        let kkt_residual = best.dual.max(best.primal);
        Ok(ActiveLsSolution {
            solution: LsSolution {
                x,
                equality_multipliers,
                residual,
                equality_residual,
                refinement_steps: best.steps,
                converged: kkt_residual <= CONVERGED_TOL,
                kkt_residual,
            },
            multipliers: best.multipliers,
            reused_factor: best.reused_factor,
        })
    }
}
