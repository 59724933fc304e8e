//! Per-contact uncertainty of inferred forces by a parametric bootstrap.
//!
//! Model: every measured stress component is b = b_true · (1 + σ ε) with
//! independent ε ~ N(0, 1) (the noise model of eq. 2.16 without bias). The
//! relative level σ is stated by the user or estimated from the stress residual
//! ρ = ‖K f̂ − b‖/‖b‖ of the inference: with m stress rows and p = unknowns −
//! momentum rows degrees of freedom left to fit them, ρ² ≈ σ² (m − p)/m, so
//! σ ≈ ρ √(m / (m − p)).
//!
//! Bootstrap: the model's reconstruction of the stresses, V σ̂ = Σ sym(r ⊗ f̂)
//! over each grain's contacts, stands in for the true stresses; each draw
//! perturbs it by the noise model, infers again with the same options, and the
//! per-component standard deviation over the draws is reported.
//!
//! Under `--stress-noise columns` each draw perturbs the fitted stresses by
//! the stated per-component sds (`sd_s_*`) instead.
//!
//! Assumptions (see docs/uncertainty.md): noise independent between components
//! and grains; positions, normals, accelerations and wall loads exact; the
//! residual contains noise only (model error inflates σ, which is conservative);
//! and a *global* bias of the stresses is invisible to the bootstrap — it moves
//! every draw alike.

use super::{infer, InferOptions, Inference, InferenceReport, StressNoise};
use crate::error::{Error, Result};
use crate::scene::{self, Body, Scene, Sym, Vec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::time::Instant;

/// Where the relative stress noise level σ comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum NoiseEstimate {
    /// From the stress residual of the inference, corrected for the degrees of freedom.
    FromResidual,
    /// Stated: relative standard deviation of each stress component (0.1 = 10 %).
    Relative(f64),
}

#[derive(Debug, Clone, PartialEq)]
pub struct UncertaintyOptions {
    /// Number of bootstrap draws (at least 2; 50–200 is typical).
    pub draws: usize,
    pub seed: u64,
    pub noise: NoiseEstimate,
}

impl Default for UncertaintyOptions {
    fn default() -> Self {
        UncertaintyOptions {
            draws: 100,
            seed: 1,
            noise: NoiseEstimate::FromResidual,
        }
    }
}

/// Standard deviations of the inferred forces and how they were obtained.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Uncertainty {
    /// Per-component standard deviation per scene contact (same order and
    /// `None`s as [`Inference::forces`]).
    pub sd: Vec<Option<Vec3>>,
    /// Relative stress noise level σ used.
    pub noise_level: f64,
    /// Whether σ was estimated from the residual (else stated).
    pub estimated: bool,
    /// Draws that were solved and enter the standard deviations.
    pub draws: usize,
    /// Draws the solver rejected (e.g. infeasible under friction).
    pub failed_draws: usize,
    /// Wall-clock time of all draws [s].
    pub time: f64,
}

/// σ ≈ ρ √(m / (m − p)) from the report of an inference; `None` when the stress
/// rows leave no residual degrees of freedom (the residual says nothing then).
pub fn residual_noise_level(report: &InferenceReport) -> Option<f64> {
    let dim = report.dim;
    let stress_rows_per_grain = crate::assemble::stress_rows(dim);
    let momentum_rows_per_grain = crate::assemble::momentum_rows(dim);
    let grains = report.grains_with_equations;
    let m = (grains * stress_rows_per_grain) as f64;
    // With hard momentum, the unknowns left free for the stress rows.
    let p = report
        .unknowns
        .saturating_sub(grains * momentum_rows_per_grain) as f64;
    // Under the relative model its own residual measures the level (the plain
    // residual of a weighted answer overstates it).
    let residual = report
        .relative_stress_residual
        .unwrap_or(report.stress_residual);
    if m - p < 1.0 || !residual.is_finite() {
        return None;
    }
    // Fewer than a tenth of the rows left: the estimate would be mostly noise.
    let ratio = ((m - p) / m).max(0.1);
    Some(residual / ratio.sqrt())
}

/// The stresses the inferred forces reproduce: V σ̂ = Σ sym(r ⊗ f) over each
/// grain's contacts. Grains with a contact outside the inference, or without
/// any force, keep their measured stress.
pub(crate) fn fitted_stresses(scene: &Scene, forces: &[Option<Vec3>]) -> Vec<Sym> {
    let n = scene.grains.len();
    let mut sums = vec![[0.0; 6]; n];
    let mut complete = vec![true; n];
    let mut loaded = vec![false; n];
    let mut add = |g: usize, point: Vec3, f: Option<Vec3>, sign: f64| match f {
        Some(f) => {
            let x = scene.grains[g].position;
            let r = [point[0] - x[0], point[1] - x[1], point[2] - x[2]];
            let t = scene::sym_outer(r, [sign * f[0], sign * f[1], sign * f[2]]);
            for k in 0..6 {
                sums[g][k] += t[k];
            }
            loaded[g] |= f.iter().any(|v| *v != 0.0);
        }
        None => complete[g] = false,
    };
    for (c, f) in scene.contacts.iter().zip(forces) {
        add(c.a, c.point, *f, 1.0);
        if let Body::Grain(b) = c.b {
            add(b, c.point, *f, -1.0);
        }
    }
    scene
        .grains
        .iter()
        .enumerate()
        .map(|(i, g)| {
            if complete[i] && loaded[i] && g.volume > 0.0 {
                sums[i].map(|s| s / g.volume)
            } else {
                g.stress
            }
        })
        .collect()
}

/// Standard deviation of each inferred force by a parametric bootstrap (see the
/// module docs); draws run in parallel and are reproducible from the seed.
pub fn force_uncertainty(
    scene: &Scene,
    opts: &InferOptions,
    inference: &Inference,
    uncertainty: &UncertaintyOptions,
) -> Result<Uncertainty> {
    use rayon::prelude::*;
    let start = Instant::now();
    if uncertainty.draws < 2 {
        return Err(Error::Invalid(format!(
            "the uncertainty needs at least 2 draws, got {}",
            uncertainty.draws
        )));
    }
    if inference.forces.len() != scene.contacts.len() {
        return Err(Error::Invalid(
            "the inference does not belong to this scene (contact counts differ)".into(),
        ));
    }
    let (noise_level, estimated) = match uncertainty.noise {
        NoiseEstimate::Relative(s) => {
            if !(s.is_finite() && s >= 0.0) {
                return Err(Error::Invalid(format!(
                    "the noise level must be finite and ≥ 0, got {s}"
                )));
            }
            (s, false)
        }
        NoiseEstimate::FromResidual => (
            residual_noise_level(&inference.report).ok_or_else(|| {
                Error::Invalid(
                    "the stress residual cannot reveal the noise level here (no residual degrees of \
                     freedom): state it with `noise_level`"
                        .into(),
                )
            })?,
            true,
        ),
    };
    let fitted = fitted_stresses(scene, &inference.forces);
    // The draws change stresses only: uniqueness depends on the geometry and
    // was reported by the inference being assessed.
    let draw_opts = InferOptions {
        identifiability_limit: 0,
        ..opts.clone()
    };
    let components = scene::sym::components(scene.dim);
    let draw = |d: usize| -> Result<Vec<Option<Vec3>>> {
        let mut rng = ChaCha8Rng::seed_from_u64(
            uncertainty
                .seed
                .wrapping_add((d as u64 + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15)),
        );
        let mut noisy = scene.clone();
        for (g, s) in noisy.grains.iter_mut().zip(&fitted) {
            // Under `--stress-noise columns` the stated sds are the noise.
            let stated = g
                .stress_sd
                .filter(|_| opts.stress_noise == StressNoise::Columns);
            for &k in components {
                let e: f64 = StandardNormal.sample(&mut rng);
                g.stress[k] = match stated {
                    Some(sd) => s[k] + sd[k] * e,
                    None => s[k] * (1.0 + noise_level * e),
                };
            }
        }
        Ok(infer(&noisy, &draw_opts)?.forces)
    };
    let results: Vec<Result<Vec<Option<Vec3>>>> =
        (0..uncertainty.draws).into_par_iter().map(draw).collect();
    let mut first_error = None;
    let mut solved = Vec::with_capacity(results.len());
    for r in results {
        match r {
            Ok(f) => solved.push(f),
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    let failed_draws = uncertainty.draws - solved.len();
    if solved.len() < 2 || 2 * failed_draws > uncertainty.draws {
        return Err(Error::Solver(format!(
            "uncertainty: {failed_draws} of {} bootstrap draws failed (first: {})",
            uncertainty.draws,
            first_error.map(|e| e.to_string()).unwrap_or_default()
        )));
    }
    let sd = (0..scene.contacts.len())
        .map(|c| {
            inference.forces[c]?;
            let samples: Vec<Vec3> = solved.iter().filter_map(|f| f[c]).collect();
            (samples.len() >= 2).then(|| standard_deviation(&samples))
        })
        .collect();
    Ok(Uncertainty {
        sd,
        noise_level,
        estimated,
        draws: solved.len(),
        failed_draws,
        time: start.elapsed().as_secs_f64(),
    })
}

/// Sample standard deviation (n − 1) of each component.
fn standard_deviation(samples: &[Vec3]) -> Vec3 {
    let n = samples.len() as f64;
    let mut mean = [0.0; 3];
    for s in samples {
        for k in 0..3 {
            mean[k] += s[k] / n;
        }
    }
    let mut var = [0.0; 3];
    for s in samples {
        for k in 0..3 {
            var[k] += (s[k] - mean[k]).powi(2) / (n - 1.0);
        }
    }
    var.map(f64::sqrt)
}

/// [`force_uncertainty`] of every frame of a sequence, frames in parallel;
/// an error names its frame.
pub fn frames_uncertainty(
    frames: &[Scene],
    per_frame: &[InferOptions],
    results: &[Inference],
    uncertainty: &UncertaintyOptions,
) -> Result<Vec<Uncertainty>> {
    use rayon::prelude::*;
    frames
        .par_iter()
        .zip(per_frame.par_iter())
        .zip(results.par_iter())
        .map(|((frame, opts), result)| {
            force_uncertainty(frame, opts, result, uncertainty).map_err(|e| match frame.frame {
                Some(k) => Error::Solver(format!("frame {k}: {e}")),
                None => e,
            })
        })
        .collect()
}
