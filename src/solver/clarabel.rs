//! Constrained least squares with clarabel, in the lifted form: each
//! least-squares term w‖K x − b‖² becomes residual variables r with the equality
//! K x − r = b and the objective w‖r‖², so KᵀK is never formed.
//!
//! Every clarabel status is mapped to an outcome: solved; almost solved (kept,
//! with a warning); infeasible (an error); anything else is retried with looser
//! tolerances, then with the hard equalities softened into heavy penalties, and
//! reported as an error with the diagnostics if all attempts fail. Garbage is
//! never passed on.

use super::{pyramid_facets, Attempt, Cone, ConicProblem, Solution, SolveStatus, Term, Triplets};
use crate::error::{Error, Result};
use ::clarabel::algebra::CscMatrix;
use ::clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ConicSettings {
    /// Gap and feasibility tolerance of the first attempt.
    pub tolerance: f64,
    pub max_iter: u32,
    /// Retry with looser tolerances and softened equalities when the first attempt fails.
    pub retry: bool,
    /// Where the active set cannot settle, the sparse interior point stops
    /// once its certified distance to the optimum (in the fit's norm) is this
    /// share of what the stress residual says the noise moves the answer by
    /// (`sparse_interior_point::noise_size`), or at `tolerance`, whichever comes
    /// first. `None` (a tolerance asked for): at `tolerance` alone.
    pub noise_share: Option<f64>,
}

/// The default [`ConicSettings::noise_share`]: the answer moves by a
/// hundredth of what the noise moves it.
pub const DEFAULT_NOISE_SHARE: f64 = 0.01;

impl Default for ConicSettings {
    fn default() -> Self {
        ConicSettings {
            tolerance: 1e-8,
            max_iter: 200,
            retry: true,
            noise_share: Some(DEFAULT_NOISE_SHARE),
        }
    }
}

impl ConicSettings {
    /// An error unless the tolerance lies in (0, 1) and one iteration at
    /// least is allowed (clarabel takes any value and answers "almost
    /// solved" at a tolerance of 0).
    pub fn check(&self) -> Result<()> {
        if !(self.tolerance > 0.0 && self.tolerance < 1.0) || self.max_iter == 0 {
            return Err(Error::Invalid(format!(
                "interior point: the tolerance must lie in (0, 1) and at least one iteration be allowed, got {} and {}",
                self.tolerance, self.max_iter
            )));
        }
        Ok(())
    }
}

/// Weight of a softened equality relative to the least-squares terms.
const SOFTENED_WEIGHT: f64 = 1e6;

/// clarabel's answer (not projected onto the cones: it meets them to its
/// tolerance), with each attempt it took.
pub fn solve(problem: &ConicProblem, settings: &ConicSettings) -> Result<Solution> {
    settings.check()?;
    validate(problem)?;
    let mut attempts = Vec::new();
    let first = attempt(problem, settings.tolerance, settings.max_iter)?;
    attempts.push(Attempt::Clarabel {
        tolerance: settings.tolerance,
        status: first.status,
    });
    if let Some(sol) = accept(&first, &attempts, false)? {
        return Ok(sol);
    }
    if settings.retry {
        let loose = (settings.tolerance * 100.0).max(1e-6);
        let second = attempt(problem, loose, settings.max_iter * 2)?;
        attempts.push(Attempt::Clarabel {
            tolerance: loose,
            status: second.status,
        });
        if let Some(mut sol) = accept(&second, &attempts, false)? {
            sol.warnings
                .push(format!("solved only at the looser tolerance {loose:.0e}"));
            return Ok(sol);
        }
        if !problem.equalities.is_empty() {
            let softened = soften(problem);
            let third = attempt(&softened, loose, settings.max_iter * 2)?;
            attempts.push(Attempt::ClarabelSoftened {
                weight: SOFTENED_WEIGHT,
                status: third.status,
            });
            if let Some(mut sol) = accept(&third, &attempts, true)? {
                sol.warnings.push(
                    "the hard momentum equalities had no strictly feasible interior; solved with them softened into heavy penalties"
                        .into(),
                );
                return Ok(sol);
            }
        }
    }
    Err(Error::Solver(format!(
        "clarabel did not converge ({}); primal residual {:.2e}, dual residual {:.2e} after {} iterations",
        attempts
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join("; "),
        first.r_prim,
        first.r_dual,
        first.iterations
    )))
}

fn validate(problem: &ConicProblem) -> Result<()> {
    let n = problem.n;
    for t in &problem.terms {
        if t.matrix.ncols != n
            || t.rhs.len() != t.matrix.nrows
            || !(t.weight >= 0.0 && t.weight.is_finite())
        {
            return Err(Error::Invalid(
                "conic problem: a least-squares term does not fit".into(),
            ));
        }
    }
    for (c, d) in &problem.equalities {
        if c.ncols != n || d.len() != c.nrows {
            return Err(Error::Invalid(
                "conic problem: an equality block does not fit".into(),
            ));
        }
    }
    if !(problem.lambda >= 0.0 && problem.lambda.is_finite()) || problem.regularized > n {
        return Err(Error::Invalid("conic problem: bad Tikhonov term".into()));
    }
    let all_rhs = problem
        .terms
        .iter()
        .flat_map(|t| t.rhs.iter())
        .chain(problem.equalities.iter().flat_map(|(_, d)| d.iter()));
    if all_rhs.clone().any(|v| !v.is_finite()) {
        return Err(Error::Invalid(
            "conic problem: non-finite right-hand side".into(),
        ));
    }
    Ok(())
}

/// What one clarabel run gave.
struct Outcome {
    status: SolverStatus,
    x: Vec<f64>,
    iterations: u32,
    solve_time: f64,
    r_prim: f64,
    r_dual: f64,
}

fn accept(a: &Outcome, attempts: &[Attempt], softened: bool) -> Result<Option<Solution>> {
    let ok = matches!(a.status, SolverStatus::Solved | SolverStatus::AlmostSolved)
        && a.x.iter().all(|v| v.is_finite());
    if matches!(
        a.status,
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible
    ) {
        return Err(Error::Infeasible(
            "no force field satisfies the constraints (momentum balance with compressive, Coulomb-bounded contacts)".into(),
        ));
    }
    if !ok {
        return Ok(None);
    }
    let mut warnings = Vec::new();
    if a.status == SolverStatus::AlmostSolved {
        warnings.push("clarabel reached only reduced accuracy (AlmostSolved)".into());
    }
    Ok(Some(Solution {
        x: a.x.clone(),
        status: if a.status == SolverStatus::AlmostSolved {
            SolveStatus::AlmostSolved { polished: false }
        } else {
            SolveStatus::Solved { polished: false }
        },
        iterations: a.iterations,
        solve_time: a.solve_time,
        attempts: attempts.to_vec(),
        softened,
        warnings,
    }))
}

fn soften<'a>(problem: &ConicProblem<'a>) -> ConicProblem<'a> {
    let mut p = problem.clone();
    for (c, d) in p.equalities.drain(..) {
        p.terms.push(Term {
            matrix: c,
            rhs: d,
            weight: SOFTENED_WEIGHT,
        });
    }
    p
}

fn attempt(problem: &ConicProblem, tolerance: f64, max_iter: u32) -> Result<Outcome> {
    let n = problem.n;
    let residuals: usize = problem.terms.iter().map(|t| t.matrix.nrows).sum();
    let nz = n + residuals;

    // Objective: ½ zᵀ P z with P = 2·diag(λ² on x, w on each residual block).
    let mut p_rows = Vec::new();
    let mut p_vals = Vec::new();
    let tikhonov = problem.lambda * problem.lambda;
    if tikhonov > 0.0 {
        for i in 0..problem.regularized {
            p_rows.push(i);
            p_vals.push(2.0 * tikhonov);
        }
    }
    let mut offset = n;
    for t in &problem.terms {
        for i in 0..t.matrix.nrows {
            p_rows.push(offset + i);
            p_vals.push(2.0 * t.weight);
        }
        offset += t.matrix.nrows;
    }
    let p = CscMatrix::new_from_triplets(nz, nz, p_rows.clone(), p_rows, p_vals);
    let q = vec![0.0; nz];

    // Constraints A z + s = b: zero-cone rows first, then non-negative rows, then cones.
    let mut rows = ConstraintRows::default();
    let mut offset = n;
    for t in &problem.terms {
        rows.block(t.matrix, t.rhs);
        let first = rows.count - t.matrix.nrows;
        for i in 0..t.matrix.nrows {
            rows.entry(first + i, offset + i, -1.0);
        }
        offset += t.matrix.nrows;
    }
    for (c, d) in &problem.equalities {
        rows.block(c, d);
    }
    let zero_rows = rows.count;
    for cone in &problem.cones {
        match *cone {
            Cone::NonNegative { normal } => rows.at_least_zero(&[(normal, 1.0)]),
            Cone::Wedge {
                normal,
                tangent,
                mu,
            } => {
                rows.at_least_zero(&[(normal, mu), (tangent, -1.0)]);
                rows.at_least_zero(&[(normal, mu), (tangent, 1.0)]);
            }
            Cone::Pyramid {
                normal,
                t1,
                t2,
                mu,
                facets,
            } => {
                for (m, c, s) in pyramid_facets(facets, mu) {
                    rows.at_least_zero(&[(normal, m), (t1, -c), (t2, -s)]);
                }
            }
            Cone::Circular { .. } => {}
        }
    }
    let nonneg_rows = rows.count - zero_rows;
    let mut socs = 0;
    for cone in &problem.cones {
        if let Cone::Circular { normal, t1, t2, mu } = *cone {
            // s = −A z = (μ u₀, u₁, u₂) in the second-order cone.
            for (j, v) in [(normal, mu), (t1, 1.0), (t2, 1.0)] {
                rows.entry(rows.count, j, -v);
                rows.b.push(0.0);
                rows.count += 1;
            }
            socs += 1;
        }
    }
    let row = rows.count;
    let ConstraintRows { ai, aj, av, b, .. } = rows;
    let a = CscMatrix::new_from_triplets(row, nz, ai, aj, av);
    let mut cones = Vec::new();
    if zero_rows > 0 {
        cones.push(SupportedConeT::ZeroConeT(zero_rows));
    }
    if nonneg_rows > 0 {
        cones.push(SupportedConeT::NonnegativeConeT(nonneg_rows));
    }
    cones.extend(std::iter::repeat_n(
        SupportedConeT::SecondOrderConeT(3),
        socs,
    ));

    if row == 0 {
        // Nothing constrains x: the minimiser of the (possibly absent) objective is 0.
        return Ok(Outcome {
            status: SolverStatus::Solved,
            x: vec![0.0; n],
            iterations: 0,
            solve_time: 0.0,
            r_prim: 0.0,
            r_dual: 0.0,
        });
    }

    let settings: DefaultSettings<f64> = DefaultSettingsBuilder::default()
        .verbose(false)
        .max_iter(max_iter)
        .tol_gap_abs(tolerance)
        .tol_gap_rel(tolerance)
        .tol_feas(tolerance)
        .build()
        .map_err(|e| Error::Solver(format!("clarabel settings: {e:?}")))?;
    let mut solver = DefaultSolver::new(&p, &q, &a, &b, &cones, settings)
        .map_err(|e| Error::Solver(format!("clarabel rejected the problem: {e:?}")))?;
    solver.solve();
    let s = &solver.solution;
    Ok(Outcome {
        status: s.status,
        x: s.x[..n].to_vec(),
        iterations: s.iterations,
        solve_time: s.solve_time,
        r_prim: s.r_prim,
        r_dual: s.r_dual,
    })
}

/// Rows of A and b under construction.
#[derive(Default)]
struct ConstraintRows {
    ai: Vec<usize>,
    aj: Vec<usize>,
    av: Vec<f64>,
    b: Vec<f64>,
    count: usize,
}

impl ConstraintRows {
    fn entry(&mut self, row: usize, col: usize, val: f64) {
        self.ai.push(row);
        self.aj.push(col);
        self.av.push(val);
    }

    /// Rows M x = d (zero cone).
    fn block(&mut self, m: &Triplets, d: &[f64]) {
        for k in 0..m.nnz() {
            self.entry(self.count + m.rows[k], m.cols[k], m.vals[k]);
        }
        self.b.extend_from_slice(d);
        self.count += m.nrows;
    }

    /// One row Σ c_j u_j ≥ 0 (non-negative cone: s = −A z).
    fn at_least_zero(&mut self, coefs: &[(usize, f64)]) {
        for &(j, v) in coefs {
            self.entry(self.count, j, -v);
        }
        self.b.push(0.0);
        self.count += 1;
    }
}
