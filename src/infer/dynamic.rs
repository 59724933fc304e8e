//! Dynamic inference (eq. 3.18): min ‖K_s f − b_s‖² + λ‖K_m f − b_m‖² s.t.
//! friction, with λ chosen by a rule:
//!
//! - `knee`: sweep λ, draw the Pareto front (momentum residual vs stress
//!   residual) and take its point of maximum curvature — the original study's rule;
//! - `weights`: λ = (σ_s/σ_m)², the maximum-likelihood weight for the stated
//!   relative noise of stresses and of m·a — accurate accelerations make it large;
//! - `hard`: momentum as an exact constraint (accelerations trusted fully);
//! - `fixed`: a given λ.

use super::context::{cones, pattern, Context};
use super::{qs, InferOptions, InferenceReport};
use crate::assemble::{Assembly, System};
use crate::error::{Error, Result};
use crate::report::pareto::ParetoPoint;
use crate::solver::cascade::{self, FactorSlot};
use crate::solver::Solution;
use crate::solver::{ConicProblem, Term};

/// How λ (the weight of the momentum rows) is chosen.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum LambdaRule {
    /// Maximum curvature of the log–log Pareto front.
    Knee,
    /// λ = (σ_s/σ_m)² from relative noise levels of the stresses and of m·a.
    Weights { stress_sd: f64, momentum_sd: f64 },
    /// Momentum rows as hard equalities.
    Hard,
    /// This dimensionless λ.
    Fixed(f64),
    /// λ from variance components estimated from the residuals.
    Variance,
}

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct DynamicOptions {
    pub rule: LambdaRule,
    /// Dimensionless λ range of the sweep (log-spaced).
    pub sweep_min: f64,
    pub sweep_max: f64,
    pub sweep_points: usize,
}

impl Default for DynamicOptions {
    fn default() -> Self {
        DynamicOptions {
            rule: LambdaRule::Weights {
                stress_sd: 0.1,
                momentum_sd: 0.0,
            },
            sweep_min: 1e-4,
            sweep_max: 1e6,
            sweep_points: 31,
        }
    }
}

/// The swept front and the chosen point.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Front {
    pub points: Vec<ParetoPoint>,
    pub knee: Option<usize>,
}

/// Solves all clusters with momentum weight `lambda`; returns the solutions and
/// the (stress, momentum) residual norms (dimensionless).
pub(crate) fn solve_weighted(
    cx: &Context,
    lambda: f64,
    report: &mut InferenceReport,
) -> Result<(Vec<Vec<f64>>, f64, f64)> {
    use rayon::prelude::*;
    let (assembly, opts, factors) = (cx.assembly, cx.opts, cx.factors);
    let results: Vec<Result<(Vec<f64>, Solution)>> = assembly
        .systems
        .par_iter()
        .zip(factors.slots(assembly.systems.len()).par_iter())
        .map(|(s, slot)| solve_one(s, opts, lambda, slot))
        .collect();
    let (mut xs, mut rs, mut rm) = (Vec::new(), 0.0, 0.0);
    for (r, system) in results.into_iter().zip(&assembly.systems) {
        let (x, sol) = r?;
        report.absorb(&sol);
        rs += residual_sq(&system.stress, &system.stress_rhs, &x);
        rm += residual_sq(&system.momentum, &system.momentum_rhs, &x);
        xs.push(x);
    }
    Ok((xs, rs.sqrt(), rm.sqrt()))
}

fn residual_sq(m: &crate::solver::Triplets, b: &[f64], x: &[f64]) -> f64 {
    m.mul(x).iter().zip(b).map(|(a, b)| (a - b).powi(2)).sum()
}

fn solve_one(
    system: &System,
    opts: &InferOptions,
    lambda: f64,
    factor: &FactorSlot,
) -> Result<(Vec<f64>, Solution)> {
    let problem = ConicProblem {
        n: system.n,
        terms: vec![
            Term {
                matrix: &system.stress,
                rhs: &system.stress_rhs,
                weight: 1.0,
            },
            Term {
                matrix: &system.momentum,
                rhs: &system.momentum_rhs,
                weight: lambda,
            },
        ],
        equalities: Vec::new(),
        lambda: 0.0,
        regularized: 0,
        cones: cones(system, opts.cone),
    };
    // Stacking squares the weight: beyond ~1e6 the normal equations lose the
    // stress rows to round-off, so only moderate λ take the sparse stages
    // (and polishing, which solves the same stacked system).
    let moderate = (1e-6..=1e6).contains(&lambda);
    let sparse =
        moderate && (opts.exact_first || opts.solver == super::ConstrainedSolver::ActiveSet);
    let pattern = pattern(system);
    let sparse = sparse.then_some((&pattern, factor));
    let mut sol = cascade::solve(&problem, sparse, &opts.cascade())?.solution;
    if opts.polish && moderate {
        cascade::polish(&pattern, &problem, &mut sol)?;
    }
    Ok((sol.x.clone(), sol))
}

/// `dynamic` and `soft`: the momentum weight by the rule, then the solve at it
/// (hard momentum, as `qs`, when the rule gives none). Returns every cluster's
/// unknowns.
pub(crate) fn solve(cx: &Context, report: &mut InferenceReport) -> Result<Vec<Vec<f64>>> {
    let (assembly, opts) = (cx.assembly, cx.opts);
    let mut soft_solution = None;
    if opts.dynamic_front && opts.dynamic.rule != LambdaRule::Knee {
        report.pareto = Some(sweep(cx, report)?);
    }
    let lambda = match opts.dynamic.rule {
        LambdaRule::Knee => {
            let front = sweep(cx, report)?;
            let lambda = front.knee.map(|k| front.points[k].lambda);
            report.pareto = Some(front);
            lambda
        }
        LambdaRule::Weights {
            stress_sd,
            momentum_sd,
        } => weight_from_noise(assembly, stress_sd, momentum_sd),
        LambdaRule::Variance => {
            let (lambda, xs, steps) = variance_components(cx, report)?;
            soft_solution = Some(xs);
            report.variance_steps = steps;
            Some(lambda)
        }
        _ => dynamic_lambda(opts),
    };
    report.momentum_weight = lambda;
    Ok(match lambda {
        Some(_) if soft_solution.is_some() => soft_solution.unwrap_or_default(),
        Some(l) => solve_weighted(cx, l, report)?.0,
        None => qs::solve_all(cx, 0.0, report)?,
    })
}

/// The rule of `soft`: the user's if it weights momentum, else variance
/// components (momentum exact would defeat the method).
pub(crate) fn soft_rule(rule: LambdaRule) -> LambdaRule {
    match rule {
        LambdaRule::Hard => LambdaRule::Variance,
        LambdaRule::Weights { momentum_sd, .. } if momentum_sd <= 0.0 => LambdaRule::Variance,
        r => r,
    }
}

/// The momentum weight a dynamic rule fixes before any solve; `None` means
/// hard momentum (or a weight the data decide later: knee, weights).
pub(crate) fn dynamic_lambda(opts: &InferOptions) -> Option<f64> {
    match opts.dynamic.rule {
        LambdaRule::Hard => None,
        LambdaRule::Fixed(l) => Some(l),
        LambdaRule::Knee | LambdaRule::Variance => Some(1.0),
        LambdaRule::Weights { momentum_sd, .. } => (momentum_sd > 0.0).then_some(1.0),
    }
}

/// Sweeps λ and returns the front (λ dimensionless).
pub(crate) fn sweep(cx: &Context, report: &mut InferenceReport) -> Result<Front> {
    let d = &cx.opts.dynamic;
    if !(d.sweep_min > 0.0
        && d.sweep_max > d.sweep_min
        && d.sweep_points >= 2
        && d.sweep_max.is_finite())
    {
        return Err(Error::Invalid(format!(
            "λ sweep must satisfy 0 < min < max with at least 2 points, got {}..{} ({} points)",
            d.sweep_min, d.sweep_max, d.sweep_points
        )));
    }
    let (lo, hi) = (d.sweep_min.log10(), d.sweep_max.log10());
    let mut points = Vec::with_capacity(d.sweep_points);
    for i in 0..d.sweep_points {
        let lambda = 10f64.powf(lo + (hi - lo) * i as f64 / (d.sweep_points - 1) as f64);
        let (_, s, m) = solve_weighted(cx, lambda, report)?;
        points.push(ParetoPoint {
            lambda,
            stress_residual: s,
            momentum_residual: m,
        });
    }
    let knee = knee(&points);
    Ok(Front { points, knee })
}

/// The point of maximum curvature of the front in log–log coordinates, both
/// axes normalised to [0, 1] and lightly smoothed so noise does not win over
/// the corner. `None` only for
/// an empty front; a degenerate one (all points equal, or fewer than three)
/// gives its middle point.
pub fn knee(points: &[ParetoPoint]) -> Option<usize> {
    if points.is_empty() {
        return None;
    }
    let floor = f64::MIN_POSITIVE;
    let xy: Vec<(f64, f64)> = points
        .iter()
        .map(|p| {
            (
                p.stress_residual.max(floor).log10(),
                p.momentum_residual.max(floor).log10(),
            )
        })
        .collect();
    let normalise = |v: Vec<f64>| -> Vec<f64> {
        let (lo, hi) = v
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            });
        if hi - lo <= 1e-12 * (1.0 + hi.abs()) {
            vec![0.0; v.len()]
        } else {
            v.iter().map(|x| (x - lo) / (hi - lo)).collect()
        }
    };
    let xs = smooth(&normalise(xy.iter().map(|p| p.0).collect()));
    let ys = smooth(&normalise(xy.iter().map(|p| p.1).collect()));
    let n = points.len();
    if n < 3 {
        return Some(n / 2);
    }
    let mut best: Option<(usize, f64)> = None;
    for i in 1..n - 1 {
        let (a, b, c) = (
            (xs[i - 1], ys[i - 1]),
            (xs[i], ys[i]),
            (xs[i + 1], ys[i + 1]),
        );
        let cross = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
        let denom = dist(a, b) * dist(b, c) * dist(c, a);
        // Menger curvature: 4·area / (product of the sides).
        let curvature = if denom > 1e-15 {
            2.0 * cross.abs() / denom
        } else {
            0.0
        };
        if curvature > best.map_or(0.0, |b| b.1) {
            best = Some((i, curvature));
        }
    }
    Some(best.map_or(n / 2, |b| b.0))
}

/// A 1-2-1 moving average (ends kept): damps noise without moving a corner.
fn smooth(v: &[f64]) -> Vec<f64> {
    (0..v.len())
        .map(|i| {
            if i == 0 || i + 1 == v.len() {
                v[i]
            } else {
                0.25 * v[i - 1] + 0.5 * v[i] + 0.25 * v[i + 1]
            }
        })
        .collect()
}

fn dist(a: (f64, f64), b: (f64, f64)) -> f64 {
    ((a.0 - b.0).powi(2) + (a.1 - b.1).powi(2)).sqrt()
}

/// λ from relative noise levels: rows are dimensionless, so σ per row is the
/// relative level times the rms of that block's right-hand side.
pub(crate) fn weight_from_noise(
    assembly: &Assembly,
    stress_sd: f64,
    momentum_sd: f64,
) -> Option<f64> {
    let sigma_s = stress_sd * rms(assembly, &|s: &System| &s.stress_rhs);
    let sigma_m = momentum_sd * momentum_row_scale(assembly);
    if sigma_m <= 0.0 {
        None
    } else {
        Some((sigma_s / sigma_m).powi(2).clamp(1e-12, 1e12))
    }
}

fn rms(assembly: &Assembly, f: &dyn Fn(&System) -> &Vec<f64>) -> f64 {
    let (sum, n) = assembly.systems.iter().fold((0.0, 0usize), |(s, n), sys| {
        let v = f(sys);
        (s + v.iter().map(|x| x * x).sum::<f64>(), n + v.len())
    });
    if n > 0 {
        (sum / n as f64).sqrt()
    } else {
        0.0
    }
}

/// What `LambdaRule::Weights` multiplies its momentum_sd by to get σ of a
/// (dimensionless) momentum row: the rms of the momentum right-hand sides,
/// with a floor so grains at rest (b_m = 0) still get a finite weight.
pub(crate) fn momentum_row_scale(assembly: &Assembly) -> f64 {
    rms(assembly, &|s: &System| &s.momentum_rhs)
        .max(1e-3 * rms(assembly, &|s: &System| &s.stress_rhs))
}

/// Random probes of the Hutchinson estimate of the hat-matrix trace: its
/// relative error is ~√(2/(probes·rank)), well below 1 % on any real cluster.
const TRACE_PROBES: usize = 16;

/// Fixed-point steps of the variance-component estimate (it settles in 3–6).
const VARIANCE_STEPS: usize = 20;

/// One step of the variance-component iteration (dimensionless row sds).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct VarianceStep {
    pub lambda: f64,
    /// Estimated sd of a stress row and of a momentum row.
    pub stress_sd: f64,
    pub momentum_sd: f64,
}

/// λ by variance components; returns the solutions at the final λ as well.
pub(crate) fn variance_components(
    cx: &Context,
    report: &mut InferenceReport,
) -> Result<(f64, Vec<Vec<f64>>, Vec<VarianceStep>)> {
    let assembly = cx.assembly;
    let rows_s: usize = assembly.systems.iter().map(|s| s.stress.nrows).sum();
    let rows_m: usize = assembly.systems.iter().map(|s| s.momentum.nrows).sum();
    let n: usize = assembly.systems.iter().map(|s| s.n).sum();
    let mut lambda = 1.0;
    let mut steps = Vec::new();
    let mut xs;
    for _ in 0..VARIANCE_STEPS {
        let (sol, rs, rm) = solve_weighted(cx, lambda, report)?;
        xs = sol;
        let mut trace_s = 0.0;
        for system in &assembly.systems {
            trace_s += stress_hat_trace(system, lambda)?;
        }
        let trace_s = trace_s.clamp(0.0, n as f64);
        // Redundancies: each block's rows less the unknowns it "uses".
        let red_s = (rows_s as f64 - trace_s).max(1.0);
        let red_m = (rows_m as f64 - (n as f64 - trace_s)).max(1.0);
        let var_s = rs * rs / red_s;
        let var_m = (rm * rm / red_m).max(f64::MIN_POSITIVE);
        steps.push(VarianceStep {
            lambda,
            stress_sd: var_s.sqrt(),
            momentum_sd: var_m.sqrt(),
        });
        let next = (var_s / var_m).clamp(1e-6, 1e6);
        let settled = (next / lambda).ln().abs() < 0.02;
        if settled {
            return Ok((lambda, xs, steps));
        }
        lambda = next;
    }
    // Not settled (oscillating between nearby values): the last λ's answer.
    let (sol, _, _) = solve_weighted(cx, lambda, report)?;
    xs = sol;
    report.warnings.push(format!(
        "the variance-component estimate of the momentum weight did not settle in {VARIANCE_STEPS} steps; λ = {lambda:.3e} used"
    ));
    Ok((lambda, xs, steps))
}

/// tr(N⁻¹ K_sᵀK_s) with N = K_sᵀK_s + λ K_mᵀK_m: the stress rows' share of
/// the hat matrix's trace (friction cones ignored), by Hutchinson's estimate.
fn stress_hat_trace(system: &System, lambda: f64) -> Result<f64> {
    use crate::solver::sparse_ls::SpdFactor;
    use rand::{Rng, SeedableRng};
    let n = system.n;
    if n == 0 {
        return Ok(0.0);
    }
    let (col_ptr, row_idx, mut values) =
        gram_upper(n, &[(&system.stress, 1.0), (&system.momentum, lambda)]);
    // A tiny shift keeps a (nearly) singular N factorable; it changes the
    // trace by far less than the estimate's own error.
    let diag_max = (0..n)
        .map(|j| values[col_ptr[j + 1] - 1])
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE);
    let shift = 1e-10 * diag_max;
    for j in 0..n {
        values[col_ptr[j + 1] - 1] += shift;
    }
    let factor = SpdFactor::new(
        n,
        &col_ptr,
        &row_idx,
        &values,
        cascade::ordering(system.dim, None),
        shift,
    )?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(19);
    let probes = TRACE_PROBES;
    let z: Vec<f64> = (0..n * probes)
        .map(|_| if rng.gen::<bool>() { 1.0 } else { -1.0 })
        .collect();
    let mut w = Vec::with_capacity(n * probes);
    for col in z.chunks(n) {
        let kz = system.stress.mul(col);
        w.extend(transpose_mul(&system.stress, &kz));
    }
    factor.solve_in_place(&mut w, probes)?;
    let total: f64 = z.iter().zip(&w).map(|(a, b)| a * b).sum();
    Ok(total / probes as f64)
}

fn transpose_mul(m: &crate::solver::Triplets, y: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; m.ncols];
    for k in 0..m.vals.len() {
        out[m.cols[k]] += m.vals[k] * y[m.rows[k]];
    }
    out
}

/// Upper triangle (CSC, sorted rows, diagonal present) of Σ wᵢ MᵢᵀMᵢ.
fn gram_upper(
    n: usize,
    parts: &[(&crate::solver::Triplets, f64)],
) -> (Vec<usize>, Vec<usize>, Vec<f64>) {
    let mut entries: std::collections::HashMap<(usize, usize), f64> =
        std::collections::HashMap::new();
    for j in 0..n {
        entries.insert((j, j), 0.0);
    }
    for (m, weight) in parts {
        let mut by_row: Vec<Vec<(usize, f64)>> = vec![Vec::new(); m.nrows];
        for k in 0..m.vals.len() {
            by_row[m.rows[k]].push((m.cols[k], m.vals[k]));
        }
        for row in &by_row {
            for &(ci, vi) in row {
                for &(cj, vj) in row {
                    if ci <= cj {
                        *entries.entry((cj, ci)).or_insert(0.0) += weight * vi * vj;
                    }
                }
            }
        }
    }
    let mut keys: Vec<(usize, usize)> = entries.keys().copied().collect();
    keys.sort_unstable();
    let mut col_ptr = vec![0usize; n + 1];
    let mut row_idx = Vec::with_capacity(keys.len());
    let mut values = Vec::with_capacity(keys.len());
    for (col, row) in keys {
        col_ptr[col + 1] += 1;
        row_idx.push(row);
        values.push(entries[&(col, row)]);
    }
    for j in 0..n {
        col_ptr[j + 1] += col_ptr[j];
    }
    (col_ptr, row_idx, values)
}
