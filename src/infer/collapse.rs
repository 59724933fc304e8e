//! Data that do not balance: exact momentum balance (with the friction cones)
//! then admits only (near-)zero forces, an answer that must never pass
//! silently. Detected after a hard-balance solve; diagnosed with a soft solve
//! (momentum as a penalty), which also gives the answer `infer` switches to.

use super::{InferOptions, Inference, Method};
use crate::assemble::{Friction, System};
use crate::error::{Error, Result};
use crate::scene::{self, Body, Scene};
use crate::solver::cascade;
use crate::solver::{Cone, ConicProblem, Solution, Term};

/// What to do when the hard-balance answer collapses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum OnCollapse {
    /// Fail with the diagnosis (an explicitly requested hard-balance method).
    Fail,
    /// Return the soft-equilibrium answer instead (the default `infer`).
    Switch,
    /// Return the collapsed answer, flagged in the report.
    Accept,
}

/// Stress residual beyond which the forces explain too little of the stresses
/// (0.8: less than 36 % of ‖b‖² fitted; exact data fit to ~0, 10–20 % noise to 0.1–0.2).
pub(crate) const COLLAPSE_RESIDUAL: f64 = 0.8;

/// Momentum weight of the stress-only fit of the diagnosis (small enough not
/// to pull the fit towards balance, large enough to fix what stresses leave free).
const STRESS_ONLY_WEIGHT: f64 = 1e-4;

/// Mean |f| over the force scale the stresses imply below which forces count
/// as "zero" (balanced data give 0.2–2).
pub(crate) const COLLAPSE_FORCE_RATIO: f64 = 1e-2;

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct GrainImbalance {
    pub grain: String,
    /// |Σ f − target| of the stress-only fit over its mean contact force.
    pub imbalance: f64,
}

/// The report's account of a collapse.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Collapse {
    /// The method whose answer collapsed.
    pub method: Method,
    /// Its stress residual (1 = no better than zero forces).
    pub stress_residual: f64,
    /// Its mean |f| over the force scale the stresses imply.
    pub force_ratio: f64,
    /// How far the data are from balance: per grain, the net force of the
    /// forces that best fit the stresses alone, over their mean contact force
    /// (median, 90th percentile).
    pub imbalance_median: f64,
    pub imbalance_p90: f64,
    /// The grains worst out of balance (at most 10).
    pub worst_grains: Vec<GrainImbalance>,
    /// Likely causes, most likely first.
    pub causes: Vec<String>,
    /// failed, switched to soft, or accepted.
    pub action: String,
}

impl std::fmt::Display for Collapse {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "COLLAPSE    with momentum balance exact ({}), the forces collapse: stress residual {:.3}, mean force {:.1e} of the scale the stresses imply",
            self.method, self.stress_residual, self.force_ratio
        )?;
        writeln!(
            f,
            "            the data are out of balance: per grain |Σf| is a median {:.2} (90th percentile {:.2}) of the mean contact force in the forces that best fit the stresses",
            self.imbalance_median, self.imbalance_p90
        )?;
        let worst: Vec<String> = self
            .worst_grains
            .iter()
            .map(|g| format!("{} ({:.2})", g.grain, g.imbalance))
            .collect();
        writeln!(f, "            worst grains: {}", worst.join(", "))?;
        for c in &self.causes {
            writeln!(f, "            likely: {c}")?;
        }
        writeln!(f, "            action: {}", self.action)
    }
}

/// Whether an answer with hard balance collapsed.
pub(crate) fn detected(scene: &Scene, inference: &Inference) -> Option<(f64, f64)> {
    let r = &inference.report;
    let loaded = scene
        .grains
        .iter()
        .any(|g| g.stress.iter().any(|&s| s != 0.0));
    if !loaded || r.modelled_contacts == 0 {
        return None;
    }
    let ratio = force_ratio(inference);
    (r.stress_residual > COLLAPSE_RESIDUAL || ratio < COLLAPSE_FORCE_RATIO)
        .then_some((r.stress_residual, ratio))
}

fn force_ratio(inference: &Inference) -> f64 {
    let (sum, n) = inference
        .forces
        .iter()
        .flatten()
        .fold((0.0, 0usize), |(s, n), f| (s + scene::norm(*f), n + 1));
    if n == 0 || inference.report.force_scale <= 0.0 {
        return 0.0;
    }
    sum / n as f64 / inference.report.force_scale
}

/// Diagnoses a collapse; returns it and the soft answer.
pub(crate) fn diagnose(
    scene: &Scene,
    opts: &InferOptions,
    collapsed: Option<(f64, f64)>,
    error: Option<&str>,
) -> Result<(Collapse, Inference)> {
    let soft_opts = InferOptions {
        method: Method::Soft,
        ..opts.clone()
    };
    let soft = super::infer_once(scene, &soft_opts)?;
    // The forces the stresses alone imply (momentum nearly free): their net
    // force per grain is how far the data are from balance.
    let mut fit_opts = soft_opts.clone();
    fit_opts.dynamic.rule = super::LambdaRule::Fixed(STRESS_ONLY_WEIGHT);
    let fit = super::infer_once(scene, &fit_opts)?;
    let forces = fit.forces_or_zero();
    let dim = scene.dim;
    let gravity = opts.assemble.gravity.unwrap_or_else(|| scene.gravity());
    let mut net = vec![[0.0; 3]; scene.grains.len()];
    let mut contacts_of = vec![0usize; scene.grains.len()];
    for (c, f) in scene.contacts.iter().zip(&forces) {
        contacts_of[c.a] += 1;
        for k in 0..3 {
            net[c.a][k] += f[k];
        }
        if let Body::Grain(b) = c.b {
            contacts_of[b] += 1;
            for k in 0..3 {
                net[b][k] -= f[k];
            }
        }
    }
    let mean = {
        let (s, n) = fit
            .forces
            .iter()
            .flatten()
            .fold((0.0, 0usize), |(s, n), f| (s + scene::norm(*f), n + 1));
        (s / n.max(1) as f64).max(f64::MIN_POSITIVE)
    };
    let mut per_grain: Vec<(usize, f64)> = (0..scene.grains.len())
        .filter(|&p| contacts_of[p] > 0)
        .map(|p| {
            let (target, _) = scene.momentum_target_with(&scene.grains[p], gravity);
            let d = scene::sub(net[p], target);
            (p, scene::norm(d) / mean)
        })
        .collect();
    let mut values: Vec<f64> = per_grain.iter().map(|g| g.1).collect();
    values.sort_by(f64::total_cmp);
    let quantile = |q: f64| {
        if values.is_empty() {
            0.0
        } else {
            values[((q * (values.len() - 1) as f64).round() as usize).min(values.len() - 1)]
        }
    };
    per_grain.sort_by(|a, b| b.1.total_cmp(&a.1));
    let worst_grains = per_grain
        .iter()
        .take(10)
        .map(|&(p, v)| GrainImbalance {
            grain: scene.grains[p].id.clone(),
            imbalance: v,
        })
        .collect();

    let mut causes = Vec::new();
    if let Some(e) = error {
        causes.push(format!("the hard-balance solve reported: {e}"));
    }
    // A loaded grain needs d+1 contacts in general position to balance.
    let few = (0..scene.grains.len())
        .filter(|&p| contacts_of[p] <= dim && scene.grains[p].stress.iter().any(|&s| s != 0.0))
        .count();
    if few > 0 {
        causes.push(format!(
            "missing contacts: {few} grains report stress on {dim} or fewer contacts (a balanced loaded grain needs \
             more); detectors miss weak contacts"
        ));
    }
    let ls_opts = InferOptions {
        method: Method::Ls,
        ..opts.clone()
    };
    if opts.method != Method::Ls {
        if let Ok(ls) = super::infer_once(scene, &ls_opts) {
            if ls.report.stress_residual < 0.5 * COLLAPSE_RESIDUAL && detected(scene, &ls).is_none()
            {
                causes.push(format!(
                    "friction too low: without the friction cones balance fits the stresses to {:.3}; check μ (`mu`)",
                    ls.report.stress_residual
                ));
            }
        }
    }
    if few == 0 {
        causes.push(
            "contact normals or points off (noisy detection), or stresses from a different state than the contacts"
                .into(),
        );
    }
    let (stress_residual, force_ratio) = collapsed.unwrap_or((1.0, 0.0));
    Ok((
        Collapse {
            method: opts.method,
            stress_residual,
            force_ratio,
            imbalance_median: quantile(0.5),
            imbalance_p90: quantile(0.9),
            worst_grains,
            causes,
            action: String::new(),
        },
        soft,
    ))
}

/// Settles a hard-balance method's answer (`first`): returned when it does not
/// collapse, else diagnosed and failed, switched or accepted by
/// [`InferOptions::on_collapse`].
pub(crate) fn settle(
    scene: &Scene,
    opts: &InferOptions,
    first: Result<Inference>,
) -> Result<Inference> {
    let (inference, collapsed, error) = match first {
        Ok(mut inf) => match detected(scene, &inf) {
            None => return Ok(inf),
            Some(c) => {
                // A large Tikhonov λ shrinks balanced forces towards zero: a
                // collapse only if momentum balance alone (qs) collapses too.
                if opts.method == Method::Tikhonov {
                    let qs = InferOptions {
                        method: Method::Qs,
                        ..opts.clone()
                    };
                    if super::infer_once(scene, &qs)
                        .map(|q| detected(scene, &q).is_none())
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
    let (mut diagnosis, soft) = diagnose(scene, opts, collapsed, error.as_deref())?;
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

/// The hard-balance answer of one cluster fits far worse than the data allow
/// (`fit` is the stress rows' relative squared misfit; `unconstrained_fit`
/// that of the least squares without cones).
pub(crate) fn retry_soft(
    system: &System,
    opts: &InferOptions,
    problem: &ConicProblem,
    mut sol: Solution,
    fit: impl Fn(&[f64]) -> f64,
    unconstrained_fit: Option<f64>,
) -> Result<(Vec<f64>, Option<Solution>)> {
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
pub(crate) fn degenerate(constrained: f64, unconstrained: Option<f64>) -> bool {
    constrained > 1e-12 && unconstrained.is_some_and(|u| constrained > 100.0 * u)
}

/// Explains an infeasible problem: is it friction (μ too small) or the sign of
/// the loads (tension needed)?
pub(crate) fn diagnose_infeasible(
    system: &System,
    opts: &InferOptions,
    problem: &ConicProblem,
) -> Error {
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
