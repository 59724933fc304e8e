//! Force inference: the formulations of the method and the choice of λ.
//!
//! - `qs` (eq. 2.13): min ‖K_st f − b_st‖² s.t. K_eq f = b_eq and friction.
//! - `tikhonov` (eq. 2.14): adds λ²‖f‖²; λ fixed, or chosen so the inferred wall
//!   forces match the load cells (eq. 2.17).
//! - `scaled`: min ‖K_st f − s b_st‖² + ω‖W f − F_walls‖² over f and a global
//!   stress scale s — the measured wall forces pin down a global bias of the
//!   stresses (e.g. a wrong Young's modulus).
//! - `ls`: the equality-constrained least squares without inequalities: the fast floor.
//! - `dynamic` (eq. 3.18): ‖K_s f − b_s‖² + λ‖K_m f − b_m‖², λ by a rule (see [`dynamic`]).

pub mod collapse;
pub mod config;
pub mod dynamic;
pub mod kinematics;
mod lambda;
pub mod noise;
mod report;
pub mod run;
pub mod sequence;
pub mod shards;
pub mod time_fit;
pub mod uncertainty;

pub use crate::solver::active_set::ActiveSetSettings;
pub use collapse::{Collapse, OnCollapse};
pub use config::{ConfigError, InferConfig};
pub use dynamic::{DynamicOptions, Front, LambdaRule};
pub use lambda::{LambdaPrecision, LambdaSearch, LambdaTrace};
pub use noise::StressNoise;
pub use report::InferenceReport;
pub use sequence::{infer_frames, infer_sequence, Progress};

use crate::assemble::{self, AssembleOptions, Assembly, Friction, System};
use crate::error::{Error, Result};
use crate::scene::{Scene, Vec3};
pub(crate) use crate::solver::cascade::{
    self, ordering, CascadeSettings, FactorCache, FactorSlot, Pattern,
};
use crate::solver::clarabel::ConicSettings;
use crate::solver::sparse_ls::{self, Ordering};
use crate::solver::{Cone, ConicProblem, Term};
use crate::solver::{Solution, SolveStatus, Triplets};
use std::time::Instant;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum Method {
    Qs,
    Tikhonov,
    Scaled,
    Ls,
    Dynamic,
    /// Static data, momentum balance as a weighted penalty (data that do not
    /// balance, e.g. photoelastic frames with missed contacts).
    Soft,
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::Qs => "qs",
            Method::Tikhonov => "tikhonov",
            Method::Scaled => "scaled",
            Method::Ls => "ls",
            Method::Dynamic => "dynamic",
            Method::Soft => "soft",
        })
    }
}

/// How friction-constrained problems are solved.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum ConstrainedSolver {
    /// Primal–dual active set on the sparse factorisation, warm-started from the
    /// unconstrained answer; when it does not settle, an interior point on the
    /// same sparse factorisation, then clarabel.
    ActiveSet,
    /// Clarabel's interior point (lifted QP/SOCP), then active-set polishing.
    InteriorPoint,
}

/// How the 3D Coulomb cone is modelled. Written `exact` or `pyramidK`
/// (K facets, at least 3) in a configuration; the CLI offers 4, 8 and 16.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum ConeModel {
    /// The exact second-order cone (SOCP).
    Exact,
    /// An inscribed pyramid with this many facets (a linear QP).
    Pyramid(usize),
}

impl std::fmt::Display for ConeModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ConeModel::Exact => f.write_str("exact"),
            ConeModel::Pyramid(k) => write!(f, "pyramid{k}"),
        }
    }
}

impl std::str::FromStr for ConeModel {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        if s == "exact" {
            return Ok(ConeModel::Exact);
        }
        s.strip_prefix("pyramid")
            .and_then(|k| k.parse::<usize>().ok())
            .filter(|&k| k >= 3)
            .map(ConeModel::Pyramid)
            .ok_or_else(|| format!("unknown cone `{s}`: expected exact or pyramidK (K ≥ 3 facets)"))
    }
}

impl TryFrom<String> for ConeModel {
    type Error = String;
    fn try_from(s: String) -> std::result::Result<Self, String> {
        s.parse()
    }
}

impl From<ConeModel> for String {
    fn from(c: ConeModel) -> String {
        c.to_string()
    }
}

#[cfg(feature = "cli")]
impl clap::ValueEnum for ConeModel {
    fn value_variants<'a>() -> &'a [Self] {
        &[
            ConeModel::Exact,
            ConeModel::Pyramid(4),
            ConeModel::Pyramid(8),
            ConeModel::Pyramid(16),
        ]
    }

    fn to_possible_value(&self) -> Option<clap::builder::PossibleValue> {
        Some(clap::builder::PossibleValue::new(match self {
            ConeModel::Exact => "exact",
            ConeModel::Pyramid(4) => "pyramid4",
            ConeModel::Pyramid(8) => "pyramid8",
            ConeModel::Pyramid(16) => "pyramid16",
            ConeModel::Pyramid(_) => return None,
        }))
    }
}

#[derive(Debug, Clone)]
pub struct InferOptions {
    pub method: Method,
    pub assemble: AssembleOptions,
    /// Tikhonov λ in the units of the equation (a length: ‖K f − b‖ is force × length).
    pub lambda: Option<f64>,
    pub lambda_search: LambdaSearch,
    pub cone: ConeModel,
    pub conic: ConicSettings,
    /// Weight ω of the wall rows in `scaled`, relative to the stress rows.
    pub wall_weight: f64,
    /// On infeasible data, return the least-violation answer (momentum softened).
    pub allow_infeasible: bool,
    pub dynamic: DynamicOptions,
    /// Dynamic: sweep and report the Pareto front even when the rule is not `knee`.
    pub dynamic_front: bool,
    /// Solve the least squares without inequalities first (sparse LDLᵀ); when it
    /// satisfies friction it is the constrained optimum and the QP is skipped.
    pub exact_first: bool,
    /// Check uniqueness (N(K_st) ∩ N(K_eq) = {0}) up to this many unknowns.
    pub identifiability_limit: usize,
    /// Refine interior-point answers by solving exactly on their active set.
    pub polish: bool,
    /// Algorithm for the friction-constrained problems.
    pub solver: ConstrainedSolver,
    pub active_set: ActiveSetSettings,
    /// Fill-reducing ordering of the sparse factorisation; `None` picks by
    /// dimension ([`Ordering::for_dim`]). The answer is the same either way.
    pub ordering: Option<Ordering>,
    /// What a hard-balance method does when its forces collapse (data out of
    /// balance): fail, switch to `soft`, or accept (flagged in the report).
    pub on_collapse: OnCollapse,
    /// Noise model of the stress rows (how they are weighted).
    pub stress_noise: StressNoise,
}

impl InferOptions {
    /// The cascade's settings from these options.
    pub(crate) fn cascade(&self) -> CascadeSettings {
        CascadeSettings {
            active_set: self.solver == ConstrainedSolver::ActiveSet,
            exact_first: self.exact_first,
            ordering: self.ordering,
            active_set_settings: self.active_set,
            interior_point: self.conic,
        }
    }
}

/// What the cascade's sparse stages need of a cluster: its contacts' unknowns.
pub(crate) fn pattern(system: &System) -> Pattern {
    Pattern {
        dim: system.dim,
        contact_blocks: system.contact_blocks(),
    }
}

impl Default for InferOptions {
    fn default() -> Self {
        InferOptions {
            method: Method::Qs,
            assemble: AssembleOptions::default(),
            lambda: None,
            lambda_search: LambdaSearch::default(),
            cone: ConeModel::Exact,
            conic: ConicSettings::default(),
            wall_weight: 100.0,
            allow_infeasible: false,
            dynamic: DynamicOptions::default(),
            dynamic_front: false,
            exact_first: true,
            identifiability_limit: 200_000,
            polish: true,
            solver: ConstrainedSolver::ActiveSet,
            active_set: ActiveSetSettings::default(),
            ordering: None,
            on_collapse: OnCollapse::Fail,
            stress_noise: StressNoise::Absolute,
        }
    }
}

/// The result of one scene (frame).
#[derive(Debug, Clone)]
pub struct Inference {
    /// Force on grain `a` by `b` per scene contact; `None` for contacts outside
    /// the inferred sub-assembly.
    pub forces: Vec<Option<Vec3>>,
    pub report: InferenceReport,
}

impl Inference {
    /// Forces with `None` replaced by zero (for metrics on the whole scene).
    pub fn forces_or_zero(&self) -> Vec<Vec3> {
        self.forces.iter().map(|f| f.unwrap_or([0.0; 3])).collect()
    }
}

/// Infers one scene. A hard-balance answer that collapses (data out of
/// balance) is never returned silently: see [`InferOptions::on_collapse`].
pub fn infer(scene: &Scene, opts: &InferOptions) -> Result<Inference> {
    // Before any work: the active set may answer without reading it.
    opts.conic.check()?;
    let hard = matches!(
        opts.method,
        Method::Qs | Method::Tikhonov | Method::Ls | Method::Scaled
    ) && !opts.allow_infeasible;
    let first = infer_once(scene, opts);
    if !hard {
        return first;
    }
    let (inference, collapsed, error) = match first {
        Ok(mut inf) => match collapse::detected(scene, &inf) {
            None => return Ok(inf),
            Some(c) => {
                // A large Tikhonov λ shrinks balanced forces towards zero: a
                // collapse only if momentum balance alone (qs) collapses too.
                if opts.method == Method::Tikhonov {
                    let qs = InferOptions {
                        method: Method::Qs,
                        ..opts.clone()
                    };
                    if infer_once(scene, &qs)
                        .map(|q| collapse::detected(scene, &q).is_none())
                        .unwrap_or(false)
                    {
                        inf.report.warnings.push(format!(
                            "λ shrinks the forces to {:.1e} of the scale the stresses imply (stress residual {:.3}); \
                             qs fits these data",
                            c.1, c.0
                        ));
                        return Ok(inf);
                    }
                }
                (Some(inf), Some(c), None)
            }
        },
        // The cone-collapse error of the solve: soft equilibrium answers it too.
        Err(Error::Infeasible(msg)) if opts.on_collapse == OnCollapse::Switch => {
            (None, None, Some(msg))
        }
        Err(e) => return Err(e),
    };
    let (mut diagnosis, soft) = collapse::diagnose(scene, opts, collapsed, error.as_deref())?;
    match (opts.on_collapse, inference) {
        (OnCollapse::Accept, Some(mut inf)) => {
            diagnosis.action =
                "accepted (`accept_degenerate`): the forces above are not an answer".into();
            inf.report.warnings.push(format!(
                "the forces collapsed (stress residual {:.3}): the data do not balance; `method` = soft fits them",
                diagnosis.stress_residual
            ));
            inf.report.collapse = Some(diagnosis);
            Ok(inf)
        }
        (OnCollapse::Fail, _) => {
            diagnosis.action = "failed".into();
            Err(Error::Infeasible(format!(
                "the data do not balance.\n{diagnosis}            use `method` = soft (momentum balance as a penalty), or \
                 `accept_degenerate` to keep the collapsed answer"
            )))
        }
        (_, _) => {
            let mut soft = soft;
            diagnosis.action = format!(
                "switched to soft equilibrium (momentum weight λ = {:.3e}); stress residual {:.3}",
                soft.report.momentum_weight.unwrap_or(f64::NAN),
                soft.report.stress_residual
            );
            soft.report.warnings.insert(
                0,
                format!(
                    "{} collapsed on data out of balance: the soft-equilibrium answer is returned instead",
                    opts.method
                ),
            );
            soft.report.collapse = Some(diagnosis);
            Ok(soft)
        }
    }
}

/// One inference with the given method, no collapse handling.
pub(crate) fn infer_once(scene: &Scene, opts: &InferOptions) -> Result<Inference> {
    let start = Instant::now();
    let soft_opts;
    let opts = if opts.method == Method::Soft {
        soft_opts = InferOptions {
            dynamic: DynamicOptions {
                rule: soft_rule(opts.dynamic.rule),
                ..opts.dynamic.clone()
            },
            ..opts.clone()
        };
        &soft_opts
    } else {
        opts
    };
    let mut assemble_opts = opts.assemble.clone();
    // Pruning relies on momentum being a hard constraint; `scaled` couples all
    // clusters through one scale factor.
    let hard_momentum = match opts.method {
        Method::Dynamic | Method::Soft => dynamic_lambda(opts).is_none(),
        _ => true,
    };
    assemble_opts.prune_single_contacts = hard_momentum && !opts.allow_infeasible;
    assemble_opts.single_system = opts.method == Method::Scaled;
    let assembly = assemble::assemble(scene, &assemble_opts)?;
    let mut report = InferenceReport::new(scene, opts, &assembly);
    let factors = FactorCache::new(assembly.systems.len());
    // The uniqueness check has its own factorisation and does not depend on
    // the solve, so it runs beside it: mostly sequential, the solve leaves a
    // second core idle (3D 10⁴ spheres: check 9 s, `ls` solve 10 s).
    let (identifiable, solved) = std::thread::scope(|scope| {
        let check = scope.spawn(|| check_identifiability(&assembly, opts));
        let solved = solve_with_noise_model(scene, &assembly, opts, &factors, &mut report);
        let identifiable = check
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        (identifiable, solved)
    });
    (report.unique, report.conditioning) = identifiable?;
    let (solutions, lambda_trace) = solved?;
    let forces = collect_forces(scene, &assembly, &solutions);
    report.finish(
        scene,
        &assembly,
        &solutions,
        &forces,
        lambda_trace,
        start.elapsed().as_secs_f64(),
    );
    Ok(Inference { forces, report })
}

/// The chosen method's solve under the chosen stress-noise model.
fn solve_with_noise_model(
    scene: &Scene,
    assembly: &Assembly,
    opts: &InferOptions,
    factors: &FactorCache,
    report: &mut InferenceReport,
) -> Result<(Vec<Vec<f64>>, Option<LambdaTrace>)> {
    Ok(match opts.stress_noise {
        StressNoise::Absolute => solve_method(scene, assembly, opts, factors, report)?,
        StressNoise::Columns => {
            let weights = noise::column_weights(scene, assembly)?;
            let weighted = noise::weight_stress_rows(assembly, &weights);
            solve_method(scene, &weighted, opts, factors, report)?
        }
        StressNoise::Relative => {
            let mut solved = solve_method(scene, assembly, opts, factors, report)?;
            for _ in 0..noise::IRLS_STEPS {
                let weights = noise::relative_weights(assembly, &solved.0);
                let weighted = noise::weight_stress_rows(assembly, &weights);
                solved = solve_method(scene, &weighted, opts, factors, report)?;
            }
            report.relative_stress_residual = Some(noise::relative_residual(assembly, &solved.0));
            solved
        }
    })
}

/// The chosen method's solve on an assembly (its stress rows possibly weighted).
fn solve_method(
    scene: &Scene,
    assembly: &Assembly,
    opts: &InferOptions,
    factors: &FactorCache,
    report: &mut InferenceReport,
) -> Result<(Vec<Vec<f64>>, Option<LambdaTrace>)> {
    let solved = match opts.method {
        Method::Qs => (solve_all(assembly, opts, 0.0, factors, report)?, None),
        Method::Tikhonov if opts.lambda.is_none() => {
            let (lam, trace, xs) = lambda::search(scene, assembly, opts, factors, report)?;
            report.lambda = Some(lam * assembly.scales.length);
            (xs, Some(trace))
        }
        // `ls` (λ given or 0) and Tikhonov at a given λ.
        Method::Ls | Method::Tikhonov => (
            solve_all(
                assembly,
                opts,
                scaled_lambda(opts, assembly),
                factors,
                report,
            )?,
            None,
        ),
        Method::Scaled => {
            let (x, s) = solve_scaled(scene, assembly, opts, report)?;
            report.stress_scale = Some(s);
            (vec![x], None)
        }
        Method::Dynamic | Method::Soft => {
            let mut soft_solution = None;
            if opts.dynamic_front && opts.dynamic.rule != LambdaRule::Knee {
                report.pareto = Some(dynamic::sweep(assembly, opts, factors, report)?);
            }
            let lambda = match opts.dynamic.rule {
                LambdaRule::Knee => {
                    let front = dynamic::sweep(assembly, opts, factors, report)?;
                    let lambda = front.knee.map(|k| front.points[k].lambda);
                    report.pareto = Some(front);
                    lambda
                }
                LambdaRule::Weights {
                    stress_sd,
                    momentum_sd,
                } => dynamic::weight_from_noise(assembly, stress_sd, momentum_sd),
                LambdaRule::Variance => {
                    let (lambda, xs, steps) =
                        dynamic::variance_components(assembly, opts, factors, report)?;
                    soft_solution = Some(xs);
                    report.variance_steps = steps;
                    Some(lambda)
                }
                _ => dynamic_lambda(opts),
            };
            report.momentum_weight = lambda;
            match lambda {
                Some(_) if soft_solution.is_some() => (soft_solution.unwrap_or_default(), None),
                Some(l) => (
                    dynamic::solve_weighted(assembly, opts, l, factors, report)?.0,
                    None,
                ),
                None => (solve_all(assembly, opts, 0.0, factors, report)?, None),
            }
        }
    };
    Ok(solved)
}

/// The rule of `soft`: the user's if it weights momentum, else variance
/// components (momentum exact would defeat the method).
fn soft_rule(rule: LambdaRule) -> LambdaRule {
    match rule {
        LambdaRule::Hard => LambdaRule::Variance,
        LambdaRule::Weights { momentum_sd, .. } if momentum_sd <= 0.0 => LambdaRule::Variance,
        r => r,
    }
}

/// The momentum weight a dynamic rule fixes before any solve; `None` means
/// hard momentum (or a weight the data decide later: knee, weights).
fn dynamic_lambda(opts: &InferOptions) -> Option<f64> {
    match opts.dynamic.rule {
        LambdaRule::Hard => None,
        LambdaRule::Fixed(l) => Some(l),
        LambdaRule::Knee | LambdaRule::Variance => Some(1.0),
        LambdaRule::Weights { momentum_sd, .. } => (momentum_sd > 0.0).then_some(1.0),
    }
}

fn scaled_lambda(opts: &InferOptions, assembly: &Assembly) -> f64 {
    opts.lambda
        .map(|l| l / assembly.scales.length)
        .unwrap_or(0.0)
}

/// The cones of a system's unknowns under the chosen friction and cone model.
pub fn cones(system: &System, cone_model: ConeModel) -> Vec<Cone> {
    system
        .unknowns
        .iter()
        .map(|u| {
            let o = u.offset;
            match (u.friction, system.dim) {
                (Friction::Coulomb(mu), 2) => Cone::Wedge {
                    normal: o,
                    tangent: o + 1,
                    mu,
                },
                (Friction::Coulomb(mu), _) => match cone_model {
                    ConeModel::Exact => Cone::Circular {
                        normal: o,
                        t1: o + 1,
                        t2: o + 2,
                        mu,
                    },
                    ConeModel::Pyramid(facets) => Cone::Pyramid {
                        normal: o,
                        t1: o + 1,
                        t2: o + 2,
                        mu,
                        facets,
                    },
                },
                _ => Cone::NonNegative { normal: o },
            }
        })
        .collect()
}

/// Solves every cluster at dimensionless Tikhonov parameter `lambda`.
pub(crate) fn solve_all(
    assembly: &Assembly,
    opts: &InferOptions,
    lambda: f64,
    factors: &FactorCache,
    report: &mut InferenceReport,
) -> Result<Vec<Vec<f64>>> {
    use rayon::prelude::*;
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
    assembly: &Assembly,
    opts: &InferOptions,
    lambda: f64,
    factors: &FactorCache,
    report: &mut InferenceReport,
) -> Result<Option<Vec<Vec<f64>>>> {
    use rayon::prelude::*;
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
        Err(Error::Infeasible(_)) => return Err(diagnose_infeasible(system, opts, &problem)),
        Err(e) => return Err(e),
    };
    let unconstrained_fit = solved.unconstrained.as_ref().map(|u| fit(&u.x));
    let mut sol = solved.solution;
    if opts.allow_infeasible
        || sol.status == SolveStatus::LeastSquares
        || !degenerate(fit(&sol.x), unconstrained_fit)
    {
        if opts.polish && !opts.allow_infeasible {
            let pattern = pattern.unwrap_or_else(|| self::pattern(system));
            cascade::polish(&pattern, &problem, &mut sol)?;
        }
        return Ok((sol.x.clone(), Some(sol)));
    }
    // Equilibrium and the cones leave almost no room (data slightly out of
    // balance with contacts at their friction limit): the hard answer fits far
    // worse than the data allow. Try momentum as a heavy penalty and keep it if
    // it balances to data precision and fits clearly better.
    let hard_fit = fit(&sol.x);
    let mut soft_problem = problem.clone();
    soft_problem.equalities.clear();
    soft_problem.terms.push(Term {
        matrix: &system.momentum,
        rhs: &system.momentum_rhs,
        weight: COLLAPSE_WEIGHT,
    });
    let mut soft = cascade::solve(&soft_problem, None, &opts.cascade())?.solution;
    let residual = system
        .momentum
        .mul(&soft.x)
        .iter()
        .zip(&system.momentum_rhs)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
    let mean = mean_magnitude(system, &soft.x);
    if residual <= BALANCE_PRECISION * mean && fit(&soft.x) < 0.1 * hard_fit {
        soft.softened = true;
        soft.warnings.push(format!(
            "momentum balance and the friction cones leave almost no room (data slightly out of balance \
             with contacts at their friction limit): with momentum exact the stress rows fit {:.1e}, with \
             momentum as a penalty {:.1e} at a momentum residual of {:.1e} of the mean force; the latter is returned",
            hard_fit.sqrt(),
            fit(&soft.x).sqrt(),
            residual / mean
        ));
        Ok((soft.x.clone(), Some(soft)))
    } else if hard_fit > 0.9 {
        // Only (near-)zero forces balance: returning them would be garbage.
        Err(Error::Infeasible(format!(
            "momentum balance with compressive, Coulomb-bounded contacts admits only near-zero forces for {} \
             grains (their stresses fit no better than with zero forces, while {:.1e} is possible without \
             friction) — typically a missing contact or a misplaced grain; check the contact list, or pass \
             `allow_infeasible` for the least-violation answer",
            system.grains.len(),
            unconstrained_fit.unwrap_or(0.0).sqrt()
        )))
    } else {
        sol.warnings.push(format!(
            "with momentum exact and friction the stress rows fit {:.1e}, far worse than the {:.1e} possible \
             without friction: the data are out of balance somewhere (check contacts and accelerations)",
            hard_fit.sqrt(),
            unconstrained_fit.unwrap_or(0.0).sqrt()
        ));
        Ok((sol.x.clone(), Some(sol)))
    }
}

/// Weight of the momentum rows under --allow-infeasible: heavy enough that
/// balance gives only where it must, light enough for clarabel (1e6 failed
/// numerically on a thin μ = 1e-3 wedge).
const LEAST_VIOLATION_WEIGHT: f64 = 1e4;

/// Weight of the momentum rows when the hard-equality feasible set collapses.
const COLLAPSE_WEIGHT: f64 = 1e6;

/// Largest momentum residual (relative to the mean contact force) accepted from
/// the penalty form: beyond it the data are not "slightly" out of balance.
const BALANCE_PRECISION: f64 = 1e-2;

/// Mean magnitude of the (dimensionless) contact forces of a solution.
fn mean_magnitude(system: &System, x: &[f64]) -> f64 {
    let forces = system.forces(x);
    let total: f64 = forces.iter().map(|(_, f)| crate::scene::norm(*f)).sum();
    (total / forces.len().max(1) as f64 / system.scales.force).max(f64::MIN_POSITIVE)
}

/// The constrained fit (relative, squared) is far worse than the unconstrained
/// one: the feasible set is (nearly) degenerate.
fn degenerate(constrained: f64, unconstrained: Option<f64>) -> bool {
    constrained > 1e-12 && unconstrained.is_some_and(|u| constrained > 100.0 * u)
}

/// Whether the data determine the forces (N(K_st) ∩ N(K_eq) = {0} in every
/// cluster), and the smallest σ_min/σ_max of the clusters' equilibrated
/// [K_st; K_eq].
fn check_identifiability(
    assembly: &Assembly,
    opts: &InferOptions,
) -> Result<(Option<bool>, Option<f64>)> {
    let n: usize = assembly.systems.iter().map(|s| s.n).sum();
    if n > opts.identifiability_limit {
        return Ok((None, None));
    }
    let mut unique = true;
    let mut conditioning = 1.0f64;
    for s in &assembly.systems {
        let ordering = cascade::ordering(s.dim, opts.ordering);
        let check = sparse_ls::identifiability_with(&s.stress, &s.momentum, ordering)?;
        unique &= check.unique;
        conditioning = conditioning.min(check.sigma_min_relative);
    }
    Ok((Some(unique), Some(conditioning)))
}

/// Explains an infeasible problem: is it friction (μ too small) or the sign of
/// the loads (tension needed)?
fn diagnose_infeasible(system: &System, opts: &InferOptions, problem: &ConicProblem) -> Error {
    let mut normal_only = problem.clone();
    normal_only.cones = system
        .unknowns
        .iter()
        .map(|u| Cone::NonNegative { normal: u.offset })
        .collect();
    let friction_bound = system
        .unknowns
        .iter()
        .any(|u| u.friction != Friction::NormalOnly);
    let hint = "or pass `allow_infeasible` for the least-violation answer";
    if friction_bound && cascade::solve(&normal_only, None, &opts.cascade()).is_ok() {
        Error::Infeasible(format!(
            "the measured loads need tangential forces beyond μ·f_n at some contacts (μ too small for these stresses \
             and accelerations); raise `mu`, check the data, {hint}"
        ))
    } else {
        Error::Infeasible(format!(
            "the loads on {} grains cannot be balanced by compressive contact forces alone (tension would be needed); \
             check that normals point from a to b and that stress is tension-positive, {hint}",
            system.grains.len()
        ))
    }
}

/// `scaled`: one system; unknowns [x, s].
fn solve_scaled(
    scene: &Scene,
    assembly: &Assembly,
    opts: &InferOptions,
    report: &mut InferenceReport,
) -> Result<(Vec<f64>, f64)> {
    let Some(system) = assembly.systems.first() else {
        return Err(Error::Invalid(
            "no contacts carry load: nothing to infer".into(),
        ));
    };
    let n = system.n;
    // Stress term K x − s b = 0 with s the (n+1)-th unknown.
    let mut stress = Triplets::new(system.stress.nrows, n + 1);
    for k in 0..system.stress.nnz() {
        stress.push(
            system.stress.rows[k],
            system.stress.cols[k],
            system.stress.vals[k],
        );
    }
    for (i, &b) in system.stress_rhs.iter().enumerate() {
        stress.push(i, n, -b);
    }
    let zeros = vec![0.0; system.stress.nrows];
    let dim = scene.dim;
    let mut walls = Triplets::new(0, n + 1);
    let mut wall_rhs = Vec::new();
    for w in &system.walls {
        let Some(measured) = scene.walls[w.wall].measured_force else {
            continue;
        };
        let base = walls.nrows;
        walls.nrows += dim;
        for k in 0..w.rows.nnz() {
            walls.push(base + w.rows.rows[k], w.rows.cols[k], w.rows.vals[k]);
        }
        wall_rhs.extend(measured[..dim].iter().map(|f| f / assembly.scales.force));
    }
    if wall_rhs.is_empty() {
        return Err(Error::Invalid(
            "`method` = scaled needs measured wall forces (walls.csv) for walls that touch the grains".into(),
        ));
    }
    let momentum = widen(&system.momentum, n + 1);
    let mut cone_list = cones(system, opts.cone);
    cone_list.push(Cone::NonNegative { normal: n });
    let problem = ConicProblem {
        n: n + 1,
        terms: vec![
            Term {
                matrix: &stress,
                rhs: &zeros,
                weight: 1.0,
            },
            Term {
                matrix: &walls,
                rhs: &wall_rhs,
                weight: opts.wall_weight,
            },
        ],
        equalities: vec![(&momentum, system.momentum_rhs.as_slice())],
        lambda: 0.0,
        regularized: 0,
        cones: cone_list,
    };
    let sol = cascade::solve(&problem, None, &opts.cascade())?.solution;
    report.absorb(&sol);
    let s = sol.x[n];
    if s <= 0.0 {
        return Err(Error::Invalid(
            "the wall forces and the stresses disagree in sign (estimated stress scale ≤ 0)".into(),
        ));
    }
    Ok((sol.x[..n].to_vec(), s))
}

fn widen(m: &Triplets, ncols: usize) -> Triplets {
    let mut w = m.clone();
    w.ncols = ncols;
    w
}

fn collect_forces(scene: &Scene, assembly: &Assembly, solutions: &[Vec<f64>]) -> Vec<Option<Vec3>> {
    let mut forces = vec![None; scene.contacts.len()];
    for (system, x) in assembly.systems.iter().zip(solutions) {
        for (c, f) in system.forces(x) {
            forces[c] = Some(f);
        }
    }
    for &c in &assembly.zero_contacts {
        forces[c] = Some([0.0; 3]);
    }
    forces
}

pub use crate::scene::wall_totals;
