//! Data that do not balance: exact momentum balance (with the friction cones)
//! then admits only (near-)zero forces, an answer that must never pass
//! silently. Detected after a hard-balance solve; diagnosed with a soft solve
//! (momentum as a penalty), which also gives the answer `infer` switches to.

use super::{InferOptions, Inference, Method};
use crate::error::Result;
use crate::scene::{self, Body, Scene};

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
