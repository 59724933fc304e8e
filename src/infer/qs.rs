//! `qs` (eq. 2.13), `tikhonov` (eq. 2.14) at a given λ and `ls`: per cluster,
//! the stress rows as the objective, momentum balance as equalities (as a
//! heavy penalty under `allow_infeasible`) and the friction cones (none for
//! `ls`). The automatic λ is searched in [`super::lambda`].

use super::context::{cones, pattern, Context};
use super::{collapse, ConstrainedSolver, InferOptions, InferenceReport, Method};
use crate::assemble::{Assembly, System};
use crate::error::{Error, Result};
use crate::solver::cascade::{self, FactorSlot};
use crate::solver::{Cone, ConicProblem, Solution, SolveStatus, Term};

/// The λ of `ls` and of `tikhonov` at a given λ, dimensionless.
pub(crate) fn scaled_lambda(opts: &InferOptions, assembly: &Assembly) -> f64 {
    opts.lambda
        .map(|l| l / assembly.scales.length)
        .unwrap_or(0.0)
}

/// Solves every cluster at dimensionless Tikhonov parameter `lambda`.
pub(crate) fn solve_all(
    cx: &Context,
    lambda: f64,
    report: &mut InferenceReport,
) -> Result<Vec<Vec<f64>>> {
    use rayon::prelude::*;
    let (assembly, opts, factors) = (cx.assembly, cx.opts, cx.factors);
    let results: Vec<Result<(Vec<f64>, Option<Solution>)>> = assembly
        .systems
        .par_iter()
        .zip(factors.slots(assembly.systems.len()).par_iter())
        .map(|(s, slot)| solve_system(s, opts, lambda, slot))
        .collect();
    let mut xs = Vec::with_capacity(results.len());
    for r in results {
        let (x, sol) = r?;
        if let Some(sol) = sol {
            report.absorb(&sol);
        }
        xs.push(x);
    }
    Ok(xs)
}

/// The unconstrained least squares of every cluster at dimensionless Tikhonov
/// parameter `lambda`, on the factorisations the constrained solves use (a
/// numeric refactorisation each, no active set): the λ search's cheap scan.
/// `None` when a cluster has no sparse form.
pub(crate) fn solve_all_least_squares(
    cx: &Context,
    lambda: f64,
    report: &mut InferenceReport,
) -> Result<Option<Vec<Vec<f64>>>> {
    use rayon::prelude::*;
    let (assembly, opts, factors) = (cx.assembly, cx.opts, cx.factors);
    let solved = assembly
        .systems
        .par_iter()
        .zip(factors.slots(assembly.systems.len()).par_iter())
        .map(|(system, slot)| {
            let cone_list = if opts.method != Method::Ls {
                cones(system, opts.cone)
            } else {
                Vec::new()
            };
            let problem = system_problem(system, opts, lambda, cone_list);
            cascade::least_squares_only(&pattern(system), &problem, &opts.cascade(), slot)
        })
        .collect::<Result<Vec<_>>>()?;
    let mut xs = Vec::with_capacity(solved.len());
    for sol in solved {
        let Some(sol) = sol else { return Ok(None) };
        // Its time and warnings, not its refinement steps: `iterations`
        // counts the constrained solves' work.
        report.solver_time += sol.solve_time;
        for w in sol.warnings {
            if !report.warnings.contains(&w) {
                report.warnings.push(w);
            }
        }
        xs.push(sol.x);
    }
    Ok(Some(xs))
}

/// One cluster's friction-constrained least squares (eq. 2.14) as a conic problem.
fn system_problem<'a>(
    system: &'a System,
    opts: &InferOptions,
    lambda: f64,
    cone_list: Vec<Cone>,
) -> ConicProblem<'a> {
    let mut problem = ConicProblem {
        n: system.n,
        terms: vec![Term {
            matrix: &system.stress,
            rhs: &system.stress_rhs,
            weight: 1.0,
        }],
        equalities: vec![(&system.momentum, system.momentum_rhs.as_slice())],
        lambda,
        regularized: system.n,
        cones: cone_list,
    };
    if opts.allow_infeasible {
        problem.equalities.clear();
        problem.terms.push(Term {
            matrix: &system.momentum,
            rhs: &system.momentum_rhs,
            weight: LEAST_VIOLATION_WEIGHT,
        });
    }
    problem
}

fn solve_system(
    system: &System,
    opts: &InferOptions,
    lambda: f64,
    factor: &FactorSlot,
) -> Result<(Vec<f64>, Option<Solution>)> {
    let with_cones = opts.method != Method::Ls;
    let cone_list = if with_cones {
        cones(system, opts.cone)
    } else {
        Vec::new()
    };
    // Fit of the stress rows relative to fitting them with zero forces.
    let fit = |x: &[f64]| {
        let b2: f64 = system.stress_rhs.iter().map(|v| v * v).sum();
        let r2: f64 = system
            .stress
            .mul(x)
            .iter()
            .zip(&system.stress_rhs)
            .map(|(a, b)| (a - b).powi(2))
            .sum();
        if b2 > 0.0 {
            r2 / b2
        } else {
            0.0
        }
    };
    let problem = system_problem(system, opts, lambda, cone_list);
    let use_active_set = with_cones && opts.solver == ConstrainedSolver::ActiveSet;
    let sparse = !opts.allow_infeasible && (opts.exact_first || !with_cones || use_active_set);
    let settings = opts.cascade();
    let pattern = sparse.then(|| pattern(system));
    let solved = match cascade::solve(&problem, pattern.as_ref().map(|p| (p, factor)), &settings) {
        Ok(solved) => solved,
        Err(Error::Infeasible(_)) => {
            return Err(collapse::diagnose_infeasible(system, opts, &problem))
        }
        Err(e) => return Err(e),
    };
    let unconstrained_fit = solved.unconstrained.as_ref().map(|u| fit(&u.x));
    let mut sol = solved.solution;
    if opts.allow_infeasible
        || sol.status == SolveStatus::LeastSquares
        || !collapse::degenerate(fit(&sol.x), unconstrained_fit)
    {
        if opts.polish && !opts.allow_infeasible {
            let pattern = pattern.unwrap_or_else(|| self::pattern(system));
            cascade::polish(&pattern, &problem, &mut sol)?;
        }
        return Ok((sol.x.clone(), Some(sol)));
    }
    collapse::retry_soft(system, opts, &problem, sol, fit, unconstrained_fit)
}

/// Weight of the momentum rows under --allow-infeasible: heavy enough that
/// balance gives only where it must, light enough for clarabel (1e6 failed
/// numerically on a thin μ = 1e-3 wedge).
const LEAST_VIOLATION_WEIGHT: f64 = 1e4;
