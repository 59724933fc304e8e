//! Noise models of the stress rows: how each row is weighted.
//!
//! - `absolute`: every row alike (the same sd for every component);
//! - `relative`: sd ∝ the component itself (eq. 2.16's kind; photoelastic and
//!   strain-gauge data), by iteratively reweighted least squares with
//!   w = 1/(|K_st f| + 0.05·rms(K_st f)) from the previous answer — the
//!   floor keeps near-zero components from taking all the weight;
//! - `columns`: the per-component sds of grains.csv (`sd_s_xx` …).
//!
//! Weights are normalised to mean square 1, so λ (Tikhonov, momentum weight)
//! keeps its meaning across models.

use crate::assemble::Assembly;
use crate::error::{Error, Result};
use crate::scene::{sym, Scene};

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum StressNoise {
    Absolute,
    Relative,
    Columns,
}

/// Reweighting steps after the first (unweighted) solve: the weights settle
/// after one or two (see the README's measured-data section).
pub(crate) const IRLS_STEPS: usize = 2;

/// Floor of the relative model's sd, as a fraction of the rms component.
pub(crate) const RELATIVE_FLOOR: f64 = 0.05;

/// A copy of the assembly with stress row i of each system scaled by w[system][i].
pub(crate) fn weight_stress_rows(assembly: &Assembly, weights: &[Vec<f64>]) -> Assembly {
    let mut out = assembly.clone();
    for (system, w) in out.systems.iter_mut().zip(weights) {
        for k in 0..system.stress.vals.len() {
            system.stress.vals[k] *= w[system.stress.rows[k]];
        }
        for (b, wi) in system.stress_rhs.iter_mut().zip(w) {
            *b *= wi;
        }
    }
    out
}

/// K_st f per cluster, and the floor RELATIVE_FLOOR·rms(K_st f) that keeps
/// near-zero rows from taking all the weight.
fn fitted_stresses(assembly: &Assembly, solutions: &[Vec<f64>]) -> (Vec<Vec<f64>>, f64) {
    let fitted: Vec<Vec<f64>> = assembly
        .systems
        .iter()
        .zip(solutions)
        .map(|(s, x)| s.stress.mul(x))
        .collect();
    let (sq, n) = fitted
        .iter()
        .flatten()
        .fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    let rms = (sq / n.max(1) as f64).sqrt();
    (fitted, (RELATIVE_FLOOR * rms).max(f64::MIN_POSITIVE))
}

/// w = 1/(|K_st f| + floor·rms), normalised.
pub(crate) fn relative_weights(assembly: &Assembly, solutions: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let (fitted, floor) = fitted_stresses(assembly, solutions);
    let weights = fitted
        .iter()
        .map(|f| f.iter().map(|v| 1.0 / (v.abs() + floor)).collect())
        .collect();
    normalise(weights)
}

/// w = 1/sd from the grains' `sd_s_*` columns, in the rows' units.
pub(crate) fn column_weights(scene: &Scene, assembly: &Assembly) -> Result<Vec<Vec<f64>>> {
    let dim = scene.dim;
    let comps = sym::components(dim);
    let mut weights = Vec::with_capacity(assembly.systems.len());
    for system in &assembly.systems {
        let per = comps.len();
        let mut w = vec![0.0; system.stress.nrows];
        for (block, &p) in system.grains.iter().enumerate() {
            let g = &scene.grains[p];
            let sd = g.stress_sd.ok_or_else(|| {
                Error::Invalid(format!(
                    "`stress_noise` = columns needs sd_s_* columns for every grain; grain {} has none",
                    g.id
                ))
            })?;
            // Row units: V·σ_k/(F·L), off-diagonal rows doubled (as assembled).
            let v = g.volume / (system.scales.force * system.scales.length);
            for (m, &k) in comps.iter().enumerate() {
                let factor = if m < dim { 1.0 } else { 2.0 };
                let row_sd = factor * v * sd[k];
                if !(row_sd > 0.0 && row_sd.is_finite()) {
                    return Err(Error::Invalid(format!(
                        "grain {}: stress sd of component {m} must be positive and finite, got {}",
                        g.id, sd[k]
                    )));
                }
                w[block * per + m] = 1.0 / row_sd;
            }
        }
        weights.push(w);
    }
    Ok(normalise(weights))
}

fn normalise(mut weights: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    let (sq, n) = weights
        .iter()
        .flatten()
        .fold((0.0, 0usize), |(s, n), v| (s + v * v, n + 1));
    let rms = (sq / n.max(1) as f64).sqrt();
    if rms > 0.0 && rms.is_finite() {
        for w in weights.iter_mut().flatten() {
            *w /= rms;
        }
    }
    weights
}

/// rms of the relative stress residual, (K_st f − b)/(|K_st f| + floor·rms):
/// the relative noise level the answer implies (before the degrees-of-freedom
/// correction the uncertainty applies).
pub(crate) fn relative_residual(assembly: &Assembly, solutions: &[Vec<f64>]) -> f64 {
    let (fitted, floor) = fitted_stresses(assembly, solutions);
    let mut total = 0.0;
    for (system, kx) in assembly.systems.iter().zip(&fitted) {
        for (k, b) in kx.iter().zip(&system.stress_rhs) {
            total += ((k - b) / (k.abs() + floor)).powi(2);
        }
    }
    let n: usize = fitted.iter().map(Vec::len).sum();
    (total / n.max(1) as f64).sqrt()
}
