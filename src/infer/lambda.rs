//! Automatic Tikhonov λ (eq. 2.17): the λ whose inferred wall forces best
//! match the load cells. The mismatch is often flat over decades and may have
//! several local minima, so the search scans a log-spaced grid first and then
//! refines the best bracket by golden-section search in log λ.

use super::{collect_forces, solve_all, wall_totals, FactorCache, InferOptions, InferenceReport};
use crate::assemble::Assembly;
use crate::error::{Error, Result};
use crate::scene::Scene;

/// The search range is dimensionless (λ / length scale), where ‖K f − b‖ and
/// λ‖f‖ compare as numbers of order one.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LambdaSearch {
    pub min: f64,
    pub max: f64,
    /// Points of the coarse log-spaced scan.
    pub grid: usize,
    /// Golden-section steps after the scan.
    pub refine: usize,
}

impl Default for LambdaSearch {
    fn default() -> Self {
        LambdaSearch {
            min: 1e-5,
            max: 10.0,
            grid: 19,
            refine: 16,
        }
    }
}

/// Every λ tried and its relative wall mismatch.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LambdaTrace {
    /// (λ in the units of the equation, relative wall mismatch).
    pub points: Vec<(f64, f64)>,
    /// The best λ lies at an end of the search range.
    pub at_edge: bool,
}

/// Returns the dimensionless λ and the trace.
pub(crate) fn search(
    scene: &Scene,
    assembly: &Assembly,
    opts: &InferOptions,
    factors: &FactorCache,
    report: &mut InferenceReport,
) -> Result<(f64, LambdaTrace)> {
    let s = &opts.lambda_search;
    if !(s.min > 0.0 && s.max > s.min && s.grid >= 3 && s.max.is_finite()) {
        return Err(Error::Invalid(format!(
            "λ search range must satisfy 0 < min < max with at least 3 points, got {}..{} ({} points)",
            s.min, s.max, s.grid
        )));
    }
    let measured: Vec<usize> = scene
        .walls
        .iter()
        .enumerate()
        .filter(|(w, wall)| {
            wall.measured_force.is_some()
                && scene
                    .contacts
                    .iter()
                    .any(|c| c.b == crate::scene::Body::Wall(*w))
        })
        .map(|(w, _)| w)
        .collect();
    if measured.is_empty() {
        return Err(Error::Invalid(
            "λ cannot be chosen: it is matched to measured wall forces (walls.csv), and this scene has none \
             for walls its grains touch; give --lambda"
                .into(),
        ));
    }
    let norm: f64 = measured
        .iter()
        .map(|&w| {
            let f = scene.walls[w].measured_force.unwrap_or_default();
            f.iter().map(|x| x * x).sum::<f64>()
        })
        .sum::<f64>()
        .max(f64::MIN_POSITIVE);
    let length = assembly.scales.length;
    let mut trace = Vec::new();
    let mut mismatch = |log_lambda: f64, report: &mut InferenceReport| -> Result<f64> {
        let lambda = 10f64.powf(log_lambda);
        let xs = solve_all(assembly, opts, lambda, factors, report)?;
        let forces = collect_forces(scene, assembly, &xs);
        let totals = wall_totals(scene, &forces);
        let j = measured
            .iter()
            .map(|&w| {
                let m = scene.walls[w].measured_force.unwrap_or_default();
                (0..3).map(|k| (totals[w][k] - m[k]).powi(2)).sum::<f64>()
            })
            .sum::<f64>()
            / norm;
        trace.push((lambda * length, j.sqrt()));
        Ok(j)
    };

    let (lo, hi) = (s.min.log10(), s.max.log10());
    let step = (hi - lo) / (s.grid - 1) as f64;
    let mut values = Vec::with_capacity(s.grid);
    for i in 0..s.grid {
        values.push(mismatch(lo + step * i as f64, report)?);
    }
    let best = (0..s.grid)
        .min_by(|&a, &b| values[a].total_cmp(&values[b]))
        .unwrap_or(0);
    let at_edge = best == 0 || best == s.grid - 1;
    // Golden-section search inside the bracket around the best grid point.
    let (mut a, mut b) = (
        lo + step * best.saturating_sub(1) as f64,
        lo + step * (best + 1).min(s.grid - 1) as f64,
    );
    let phi = 0.5 * (5f64.sqrt() - 1.0);
    let mut c = b - phi * (b - a);
    let mut d = a + phi * (b - a);
    let mut fc = mismatch(c, report)?;
    let mut fd = mismatch(d, report)?;
    for _ in 0..s.refine {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - phi * (b - a);
            fc = mismatch(c, report)?;
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + phi * (b - a);
            fd = mismatch(d, report)?;
        }
    }
    let mut best_log = lo + step * best as f64;
    let mut best_value = values[best];
    for (x, v) in [(c, fc), (d, fd)] {
        if v < best_value {
            best_log = x;
            best_value = v;
        }
    }
    Ok((
        10f64.powf(best_log),
        LambdaTrace {
            points: trace,
            at_edge,
        },
    ))
}
