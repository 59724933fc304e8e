//! The one route of every friction-constrained least squares in the crate —
//! the formulations of `infer` (quasi-static, Tikhonov, dynamic, soft,
//! scaled, the joint time fit, the collapse retry and the infeasibility
//! diagnosis) and the fringe fit's steps:
//!
//! 1. the least squares without inequalities on the sparse factorisation (its
//!    symbolic analysis done once per cluster and kept across λ), returned
//!    when it already meets every cone;
//! 2. the active set on the same factorisation, warm-started from the previous
//!    solve's active pieces, then cold;
//! 3. when it does not converge, the sparse interior point on the same pattern
//!    (`solver::sparse_interior_point`: statically determinate grains with
//!    contacts at the edge of their pieces defeat the active set, not it);
//! 4. clarabel when that does not converge either, or when the caller gives
//!    no sparse pattern, its answer projected onto the cones;
//! 5. on request, [`polish`] of an interior-point answer.
//!
//! Callers build one [`ConicProblem`] and read the route taken from the
//! solution's [`SolveStatus`] and its typed `attempts`.

use super::polish as polishing;
use crate::error::{Error, Result};
use crate::solver::active_set::{self, ActivePieces, ActiveSetSettings};
use crate::solver::clarabel::{self, ConicSettings};
use crate::solver::sparse_interior_point::{self, InteriorPointSettings, RestartPoint};
use crate::solver::sparse_ls::{self, EqualityLeastSquares, Ordering};
use crate::solver::{
    ActiveSetMiss, Attempt, InteriorPointFailure, LeastSquares, Solution, SolveStatus, Triplets,
};
use crate::solver::{Cone, ConicProblem};
use std::sync::Mutex;
use std::time::Instant;

/// The cascade's own settings (an inference fills them from its options).
#[derive(Debug, Clone, Copy)]
pub struct CascadeSettings {
    /// Try the active set after the least squares (else the interior points
    /// follow it directly).
    pub active_set: bool,
    /// Return the least squares when it already meets every cone.
    pub exact_first: bool,
    /// The fill-reducing ordering of the sparse stages (`None`: by dimension).
    pub ordering: Option<Ordering>,
    pub active_set_settings: ActiveSetSettings,
    /// clarabel's settings; their tolerance and noise share are the sparse
    /// interior point's too.
    pub interior_point: ConicSettings,
}

impl Default for CascadeSettings {
    fn default() -> Self {
        CascadeSettings {
            active_set: true,
            exact_first: true,
            ordering: None,
            active_set_settings: ActiveSetSettings::default(),
            interior_point: ConicSettings::default(),
        }
    }
}

/// What the sparse stages need of a problem besides its terms: which
/// unknowns belong to one contact (coupled in the factorisation) and the
/// dimension (the default ordering).
#[derive(Debug, Clone)]
pub struct Pattern {
    pub dim: usize,
    /// One row per contact, a 1 at each of its unknowns.
    pub contact_blocks: Triplets,
}

/// What the cascade found.
pub(crate) struct Solved {
    /// The answer; its status names the stage that produced it.
    pub solution: Solution,
    /// The answer without inequalities, when the sparse stage ran (even
    /// unconverged, it shows how well the data can be fitted).
    pub unconstrained: Option<Solution>,
}

/// Solves `problem`. `sparse` (the cluster's pattern and cached state)
/// allows the sparse stages; without it (or when the problem has no sparse
/// form) clarabel solves it.
pub(crate) fn solve(
    problem: &ConicProblem,
    sparse: Option<(&Pattern, &FactorSlot)>,
    settings: &CascadeSettings,
) -> Result<Solved> {
    let mut note = None;
    let mut unconstrained = None;
    let stacked = sparse.and_then(|s| problem.least_squares().map(|ls| (s, ls)));
    if let Some(((pattern, slot), stacked)) = stacked {
        let route = sparse_route(
            pattern,
            stacked.view(),
            &problem.cones,
            settings,
            slot,
            true,
        )?;
        if problem.cones.is_empty() {
            return Ok(Solved {
                solution: route.unconstrained.clone(),
                unconstrained: Some(route.unconstrained),
            });
        }
        if let Some(solution) = route.constrained {
            return Ok(Solved {
                solution,
                unconstrained: Some(route.unconstrained),
            });
        }
        note = route.note;
        unconstrained = Some(route.unconstrained);
    }
    Ok(Solved {
        solution: clarabel_stage(problem, &settings.interior_point, note)?,
        unconstrained,
    })
}

/// The route of a least squares already factored by its caller (the time
/// fit keeps its own loosening loop on `factor`, whose pattern must couple
/// each contact's unknowns): from its unconstrained answer, stages 2–4 on
/// `factor` (stages 1–3), then clarabel (stage 4).
pub(crate) fn solve_on_factor(
    factor: &mut EqualityLeastSquares,
    problem: &ConicProblem,
    unconstrained: &Solution,
    settings: &CascadeSettings,
) -> Result<Solution> {
    let start = Instant::now();
    if let Some(stacked) = problem.least_squares() {
        let stages = Stages {
            feasible_as_is: settings.exact_first,
            active_set: settings.active_set,
        };
        let (constrained, note) = constrained_on_factor(
            factor,
            &stacked.view(),
            &problem.cones,
            unconstrained,
            &mut WarmStart::default(),
            stages,
            &settings.active_set_settings,
            &interior_point_settings(settings),
            start,
        )?;
        if let Some(solution) = constrained {
            return Ok(solution);
        }
        let text = note.as_ref().map(ToString::to_string).unwrap_or_default();
        return clarabel_stage(problem, &settings.interior_point, note)
            .map_err(|e| with_note(e, &text));
    }
    clarabel_stage(problem, &settings.interior_point, None)
}

/// `e` with `note` (why the sparse stages did not deliver) appended.
fn with_note(e: Error, note: &str) -> Error {
    match e {
        Error::Solver(m) => Error::Solver(format!("{m}; {note}")),
        Error::Infeasible(m) => Error::Infeasible(format!("{m}; {note}")),
        other => other,
    }
}

/// Stage 4: clarabel, its answer projected onto the cones (it meets them only
/// to its tolerance; the output must meet them exactly). `note` says why the
/// active set did not deliver.
fn clarabel_stage(
    problem: &ConicProblem,
    settings: &ConicSettings,
    note: Option<Attempt>,
) -> Result<Solution> {
    let mut sol = clarabel::solve(problem, settings)?;
    for c in &problem.cones {
        c.project(&mut sol.x);
    }
    sol.attempts.extend(note);
    Ok(sol)
}

/// Stage 5: an interior-point answer sharpened by imposing the constraints it
/// found tight; other answers are exact already and stay as they are, and so
/// does one that stopped at the data's accuracy: polishing would move it by
/// less than its certified distance, which the noise makes meaningless, and
/// on sheared packings it fails anyway (balance pins forces just outside the
/// tight cones) after a new analysis and factorisation.
pub(crate) fn polish(pattern: &Pattern, problem: &ConicProblem, sol: &mut Solution) -> Result<()> {
    if !sol.status.is_interior_point() || sol.softened || at_data_accuracy(sol) {
        return Ok(());
    }
    if let Some(x) = polishing::polish(pattern, problem, &sol.x)? {
        sol.x = x;
        sol.status = sol.status.polished();
    }
    Ok(())
}

/// Whether the sparse interior point stopped at the data's accuracy.
fn at_data_accuracy(sol: &Solution) -> bool {
    sol.attempts.iter().any(|a| {
        matches!(
            a,
            Attempt::SparseInteriorPoint {
                at_data_accuracy: true,
                ..
            }
        )
    })
}

/// What the sparse stages found.
pub(crate) struct SparseRoute {
    /// The least squares without inequalities.
    pub unconstrained: Solution,
    /// The friction-constrained optimum, when found: the unconstrained answer
    /// if admissible (status `LeastSquares`), else the converged active set.
    pub constrained: Option<Solution>,
    /// Why the active set did not deliver, for the report.
    pub note: Option<Attempt>,
}

/// What one cluster keeps between its solves: the sparse factorisation and
/// what its last constrained solve taught.
#[derive(Default)]
pub(crate) struct ClusterState {
    factor: Option<EqualityLeastSquares>,
    warm: WarmStart,
}

/// What a constrained solve leaves for the next one of a nearby problem.
#[derive(Default)]
pub(crate) struct WarmStart {
    /// The active set of the last answer, when the active set gave it.
    pieces: Option<ActivePieces>,
    /// λ of the last solve whose active set did not settle: at a λ close to
    /// it (the steps of a λ search) the next one goes straight to the
    /// interior point (on a sheared 10³ packing the failed attempt cost
    /// 0.14 s of each of the search's six solves).
    active_set_failed_at: Option<f64>,
    /// The interior point's mid-path iterate at that λ, to start from at a
    /// nearby one.
    interior_point: Option<RestartPoint>,
}

/// λ within this factor of a failed active set's counts as close to it.
const NEARBY_LAMBDA: f64 = 2.0;

impl WarmStart {
    fn expects_active_set_to_fail(&self, lambda: f64) -> bool {
        self.active_set_failed_at.is_some_and(|failed| {
            let ratio = if failed > 0.0 && lambda > 0.0 {
                lambda / failed
            } else if failed == lambda {
                1.0
            } else {
                f64::INFINITY
            };
            (1.0 / NEARBY_LAMBDA..=NEARBY_LAMBDA).contains(&ratio)
        })
    }
}

pub(crate) type FactorSlot = Mutex<ClusterState>;

/// State kept across the solves of one inference (λ search, Pareto sweep,
/// final solve): each cluster's symbolic analysis (ordering, elimination tree)
/// is done once, not once per λ, and each active set starts from the pieces
/// of the previous λ's answer.
#[derive(Default)]
pub(crate) struct FactorCache {
    slots: Vec<FactorSlot>,
}

impl FactorCache {
    /// One slot for each of `clusters` clusters.
    pub(crate) fn new(clusters: usize) -> Self {
        FactorCache {
            slots: (0..clusters)
                .map(|_| Mutex::new(ClusterState::default()))
                .collect(),
        }
    }

    /// One slot per cluster; `clusters` must be the count it was made for.
    pub(crate) fn slots(&self, clusters: usize) -> &[FactorSlot] {
        debug_assert_eq!(self.slots.len(), clusters);
        &self.slots
    }
}

/// The user's ordering, else [`Ordering::for_dim`].
pub(crate) fn ordering(dim: usize, choice: Option<Ordering>) -> Ordering {
    choice.unwrap_or(Ordering::for_dim(dim))
}

/// Stage 1 alone: the least squares without inequalities on the cluster's
/// cached factorisation, built as the constrained stages need it so that they
/// can follow on the same analysis. `None` when the problem has no sparse form.
pub(crate) fn least_squares_only(
    pattern: &Pattern,
    problem: &ConicProblem,
    settings: &CascadeSettings,
    slot: &FactorSlot,
) -> Result<Option<Solution>> {
    match problem.least_squares() {
        Some(stacked) => Ok(Some(
            sparse_route(
                pattern,
                stacked.view(),
                &problem.cones,
                settings,
                slot,
                false,
            )?
            .unconstrained,
        )),
        None => Ok(None),
    }
}

/// Stages 1–3 on the cluster's cached factorisation (stage 1 alone unless
/// `constrained`).
fn sparse_route(
    pattern: &Pattern,
    p: LeastSquares,
    cone_list: &[Cone],
    settings: &CascadeSettings,
    slot: &FactorSlot,
    constrained: bool,
) -> Result<SparseRoute> {
    let start = Instant::now();
    let use_active_set = !cone_list.is_empty() && settings.active_set;
    // Each contact's unknowns coupled: the active set's rows then fit the
    // pattern, and nested dissection cuts contacts, not unknowns (METIS at
    // 10⁴ spheres: 0.4 s against 2.6 s on the unknowns, the same fill).
    let coupling = &pattern.contact_blocks;
    // A poisoned slot only means another cluster's solve panicked; its factor
    // is still a valid analysis (or is rebuilt when the pattern differs).
    let mut state = slot.lock().unwrap_or_else(|e| e.into_inner());
    let ClusterState { factor, warm } = &mut *state;
    let factor = match factor {
        Some(factor) => factor,
        empty => empty.insert(EqualityLeastSquares::with_ordering(
            p.a,
            p.c,
            coupling,
            ordering(pattern.dim, settings.ordering),
        )?),
    };
    // The scan's answers (stage 1 alone) only rank λ by their wall mismatch,
    // and an answer that violates the cones is only the active set's start:
    // the accuracy at which a solve counts as converged serves, not
    // round-off. One that nearly meets them (exact data) is refined on.
    let start_only = constrained && use_active_set;
    if !constrained || start_only {
        factor.set_refinement_target(sparse_ls::CONVERGED_TOL);
    }
    let sol = factor.solve(p.a, p.c, p.b, p.d, p.lambda);
    factor.set_refinement_target(0.0);
    let mut sol = sol?;
    if start_only && within_cones(&sol.x, cone_list, NEARLY_FEASIBLE) {
        sol = factor.solve(p.a, p.c, p.b, p.d, p.lambda)?;
    }
    let mut warnings = Vec::new();
    let asked = ordering(pattern.dim, settings.ordering);
    let ordering_note = (factor.ordering() != asked).then(|| {
        format!(
            "ordering: {asked:?} could not order this {}-unknown system (METIS failed); {:?} used instead: the same forces, at more fill and time",
            p.a.ncols,
            factor.ordering()
        )
    });
    warnings.extend(ordering_note.clone());
    if !sol.converged {
        warnings.push(format!(
            "least squares: refinement stopped at KKT residual {:.1e} (momentum rows inconsistent or the forces not unique)",
            sol.kkt_residual
        ));
    }
    let (unconstrained, converged) = as_solution(sol, start, warnings);
    if cone_list.is_empty() || !constrained {
        return Ok(SparseRoute {
            unconstrained,
            constrained: None,
            note: None,
        });
    }
    let stages = Stages {
        feasible_as_is: converged && settings.exact_first,
        active_set: use_active_set,
    };
    let (mut constrained, note) = constrained_on_factor(
        factor,
        &p,
        cone_list,
        &unconstrained,
        warm,
        stages,
        &settings.active_set_settings,
        &interior_point_settings(settings),
        start,
    )?;
    if let (Some(solution), Some(w)) = (constrained.as_mut(), ordering_note) {
        solution.warnings.push(w);
    }
    Ok(SparseRoute {
        unconstrained,
        constrained,
        note,
    })
}

/// Whether to return an admissible least squares (stage 1) and to try the
/// active set (stage 2).
#[derive(Debug, Clone, Copy)]
struct Stages {
    feasible_as_is: bool,
    active_set: bool,
}

/// Stages 1 (its end) to 3 from an unconstrained answer on its factorisation (which must
/// couple each contact's unknowns): the constrained optimum when found, else
/// why not (for the report). `warm` (from the previous solve of a nearby
/// problem) warm-starts the active set, or skips it where it failed, and
/// learns from this solve.
#[allow(clippy::too_many_arguments)]
fn constrained_on_factor(
    factor: &mut EqualityLeastSquares,
    p: &LeastSquares,
    cone_list: &[Cone],
    unconstrained: &Solution,
    warm: &mut WarmStart,
    stages: Stages,
    settings: &ActiveSetSettings,
    ip_settings: &InteriorPointSettings,
    start: Instant,
) -> Result<(Option<Solution>, Option<Attempt>)> {
    if stages.feasible_as_is {
        if let Some(x) = feasible_as_is(&unconstrained.x, cone_list) {
            let mut sol = unconstrained.clone();
            sol.x = x;
            return Ok((Some(sol), None));
        }
    }
    if !stages.active_set {
        return Ok((None, None));
    }
    let sol = if warm.expects_active_set_to_fail(p.lambda) {
        None
    } else {
        let mut sol = active_set::solve_from(
            factor,
            p,
            cone_list,
            &unconstrained.x,
            warm.pieces.as_ref(),
            settings,
        )?;
        if !sol.converged && warm.pieces.is_some() {
            // The previous answer's pieces misled it: start cold.
            sol = active_set::solve(factor, p, cone_list, &unconstrained.x, settings)?;
        }
        Some(sol)
    };
    let sol = match sol {
        Some(sol) if sol.converged => sol,
        failed => {
            let why = match failed {
                Some(sol) => sol
                    .reason
                    .map_or(ActiveSetMiss::NotConverged, ActiveSetMiss::Stopped),
                None => ActiveSetMiss::Skipped,
            };
            return Ok(sparse_interior_point(
                factor,
                p,
                cone_list,
                unconstrained,
                warm,
                why,
                ip_settings,
                start,
            ));
        }
    };
    *warm = WarmStart {
        pieces: Some(sol.pieces),
        ..Default::default()
    };
    Ok((
        Some(Solution {
            x: sol.x,
            status: SolveStatus::ActiveSet,
            iterations: sol.iterations as u32,
            solve_time: start.elapsed().as_secs_f64(),
            attempts: vec![Attempt::ActiveSet {
                solves: sol.iterations,
                sliding: sol.sliding,
                open: sol.open,
            }],
            softened: false,
            warnings: Vec::new(),
        }),
        None,
    ))
}

/// Stage 3, after the active set did not settle (`why`): the interior point
/// on the cluster's analysis, restarted mid-path from a nearby λ's solve when
/// there was one. Its answer, else why it failed too (clarabel follows).
#[allow(clippy::too_many_arguments)]
fn sparse_interior_point(
    factor: &EqualityLeastSquares,
    p: &LeastSquares,
    cone_list: &[Cone],
    unconstrained: &Solution,
    warm: &mut WarmStart,
    why: ActiveSetMiss,
    settings: &InteriorPointSettings,
    start: Instant,
) -> (Option<Solution>, Option<Attempt>) {
    // Only a nearby λ's mid-path iterate is a good start.
    let restart = if warm.expects_active_set_to_fail(p.lambda) {
        warm.interior_point.take()
    } else {
        None
    };
    *warm = WarmStart {
        active_set_failed_at: Some(p.lambda),
        ..Default::default()
    };
    // A failure of this stage (e.g. its own analysis) is a reason to fall
    // back to clarabel, not an error of the inference.
    let outcome = sparse_interior_point::solve(
        p,
        cone_list,
        &unconstrained.x,
        factor,
        restart.as_ref(),
        settings,
    );
    let mut ip = match outcome {
        Ok(ip) if ip.converged => ip,
        Ok(ip) => {
            let failure = match ip.stop {
                Some(stop) => InteriorPointFailure::Stopped {
                    stop,
                    iterations: ip.iterations,
                    gap: ip.gap,
                    primal_residual: ip.primal_residual,
                    dual_residual: ip.dual_residual,
                },
                None => InteriorPointFailure::Error("not converged".into()),
            };
            return (None, Some(ip_failed(why, failure)));
        }
        Err(e) => {
            let failure = InteriorPointFailure::Error(e.to_string());
            return (None, Some(ip_failed(why, failure)));
        }
    };
    warm.interior_point = ip.restart.take();
    let attempt = Attempt::SparseInteriorPoint {
        active_set: why,
        iterations: ip.iterations,
        gap: ip.gap,
        distance: ip.noise.map(|_| ip.distance),
        estimate: ip.noise.and(ip.estimate.is_finite().then_some(ip.estimate)),
        noise: ip.noise,
        at_data_accuracy: ip.at_distance,
        refinement_steps: ip.refinement_steps,
        solve_residual: ip.solve_residual,
    };
    let solution = Solution {
        x: ip.x,
        status: SolveStatus::SparseInteriorPoint { polished: false },
        iterations: ip.iterations as u32,
        solve_time: start.elapsed().as_secs_f64(),
        attempts: vec![attempt],
        softened: false,
        warnings: Vec::new(),
    };
    (Some(solution), None)
}

/// The sparse interior point to the user's interior-point tolerance
/// (`--tolerance`), as clarabel after it, or sooner at the data's accuracy.
fn interior_point_settings(settings: &CascadeSettings) -> InteriorPointSettings {
    InteriorPointSettings {
        tolerance: settings.interior_point.tolerance,
        noise_share: settings.interior_point.noise_share,
        ..Default::default()
    }
}

fn ip_failed(why: ActiveSetMiss, failure: InteriorPointFailure) -> Attempt {
    Attempt::SparseInteriorPointFailed {
        active_set: why,
        failure,
    }
}

/// Relative size of a cone violation treated as round-off of an exact answer.
const ROUND_OFF: f64 = 1e-9;

/// Every cone violated by at most this much of the largest force: a least
/// squares answer refined to the converged tolerance may still be
/// admissible at round-off.
const NEARLY_FEASIBLE: f64 = 1e-6;

/// Whether every cone's violation is at most `relative` × the largest entry of x.
fn within_cones(x: &[f64], cones: &[Cone], relative: f64) -> bool {
    let scale = x
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs()))
        .max(f64::MIN_POSITIVE);
    cones.iter().all(|c| c.violation(x) <= relative * scale)
}

/// The unconstrained optimum, when it already satisfies every cone (up to
/// round-off, then projected): it is then the constrained optimum too.
pub(crate) fn feasible_as_is(x: &[f64], cones: &[Cone]) -> Option<Vec<f64>> {
    if !within_cones(x, cones, ROUND_OFF) {
        return None;
    }
    let mut x = x.to_vec();
    for c in cones {
        c.project(&mut x);
    }
    Some(x)
}

/// A sparse least-squares result in the form the report absorbs, and whether
/// its refinement converged.
pub(crate) fn as_solution(
    sol: sparse_ls::LsSolution,
    start: Instant,
    warnings: Vec<String>,
) -> (Solution, bool) {
    let converged = sol.converged;
    (
        Solution {
            x: sol.x,
            status: SolveStatus::LeastSquares,
            iterations: sol.refinement_steps as u32,
            solve_time: start.elapsed().as_secs_f64(),
            attempts: vec![Attempt::LeastSquares],
            softened: false,
            warnings,
        },
        converged,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::Term;

    /// Two contacts fitted directly (A = I): the first pulled open (its
    /// optimum the apex), the second inside its cone. The interior point's
    /// answer a little off it is polished to the optimum, unless it stopped
    /// at the data's accuracy, where it stays as certified.
    #[test]
    fn answers_at_the_datas_accuracy_are_not_polished() {
        let n = 6;
        let mut a = Triplets::new(n, n);
        let mut blocks = Triplets::new(2, n);
        for j in 0..n {
            a.push(j, j, 1.0);
            blocks.push(j / 3, j, 1.0);
        }
        let b = [-1.0, 0.0, 0.0, 2.0, 0.1, 0.0];
        let cones: Vec<Cone> = (0..2)
            .map(|k| Cone::Circular {
                normal: 3 * k,
                t1: 3 * k + 1,
                t2: 3 * k + 2,
                mu: 0.5,
            })
            .collect();
        let problem = ConicProblem {
            n,
            terms: vec![Term {
                matrix: &a,
                rhs: &b,
                weight: 1.0,
            }],
            equalities: Vec::new(),
            lambda: 0.0,
            regularized: 0,
            cones,
        };
        let pattern = Pattern {
            dim: 3,
            contact_blocks: blocks,
        };
        let near = vec![1e-9, 0.0, 0.0, 2.0 + 1e-7, 0.1, 1e-7];
        for at_data_accuracy in [false, true] {
            let mut sol = Solution {
                x: near.clone(),
                status: SolveStatus::SparseInteriorPoint { polished: false },
                iterations: 9,
                solve_time: 0.0,
                attempts: vec![Attempt::SparseInteriorPoint {
                    active_set: ActiveSetMiss::Skipped,
                    iterations: 9,
                    gap: 1e-7,
                    distance: Some(1e-6),
                    estimate: None,
                    noise: Some(1e-2),
                    at_data_accuracy,
                    refinement_steps: 0,
                    solve_residual: 0.0,
                }],
                softened: false,
                warnings: Vec::new(),
            };
            polish(&pattern, &problem, &mut sol).unwrap();
            let polished = !at_data_accuracy;
            assert_eq!(
                sol.status,
                SolveStatus::SparseInteriorPoint { polished },
                "at the data's accuracy: {at_data_accuracy}"
            );
            let expected = if polished {
                vec![0.0, 0.0, 0.0, 2.0, 0.1, 0.0]
            } else {
                near.clone()
            };
            for (x, e) in sol.x.iter().zip(&expected) {
                assert!((x - e).abs() < 1e-12, "{:?} against {expected:?}", sol.x);
            }
        }
    }
}
