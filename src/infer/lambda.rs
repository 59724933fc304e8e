//! Automatic Tikhonov λ (eq. 2.17): the λ whose inferred wall forces best
//! match the load cells. The mismatch is often flat over decades and may have
//! several local minima, so the search scans a log-spaced grid first and then
//! refines the best bracket in log λ.
//!
//! Constrained solves are the expensive part (each runs an active set), and
//! the mismatch of the unconstrained least squares follows the constrained
//! one closely (the friction cones move the wall totals little). So the grid
//! and the refinement (Brent's parabolic steps on the squared mismatch) use
//! the unconstrained least squares (one numeric refactorisation per λ on the
//! one symbolic analysis), and only the last steps are constrained: three
//! solves around the unconstrained optimum, warm-started from one another,
//! then up to three Brent steps from them (the first at the vertex of the
//! parabola through their squared mismatches). The answer is the best
//! constrained solve. At [`LambdaPrecision::Coarse`] (the default) the constrained solve
//! at the unconstrained optimum is the answer. The grid is scanned from the largest
//! λ down and stops once the mismatch no longer changes: below that it varies
//! as λ², so it stays flat. `constrained_scan` keeps the former search (a
//! constrained solve at every grid point and golden-section step).

use std::cell::Cell;

use super::context::Context;
use super::qs::{solve_all, solve_all_least_squares};
use super::{collect_forces, wall_totals, InferenceReport};
use crate::assemble::Assembly;
use crate::error::{Error, Result};
use crate::scene::Scene;

/// The search range is dimensionless (λ / length scale), where ‖K f − b‖ and
/// λ‖f‖ compare as numbers of order one.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LambdaSearch {
    pub min: f64,
    pub max: f64,
    /// Points of the coarse log-spaced scan (fewer when the low end is flat).
    pub grid: usize,
    /// Refinement steps after the scan, at most: Brent's (stopping at a
    /// precision of 2e-3 decades), or golden-section steps with
    /// `constrained_scan`.
    pub refine: usize,
    /// Scan and refine with constrained solves (the former search: 37
    /// constrained solves at its defaults), rather than with the unconstrained
    /// least squares and at most 6 constrained solves).
    pub constrained_scan: bool,
    /// How finely the constrained answer's mismatch is minimised after the
    /// unconstrained scan.
    pub precision: LambdaPrecision,
}

/// Speed against precision of λ after the unconstrained scan.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
#[serde(rename_all = "snake_case")]
pub enum LambdaPrecision {
    /// The constrained answer's mismatch minimised to 10⁻⁴ decades of λ:
    /// three constrained solves around the unconstrained optimum and up to
    /// three of Brent's steps.
    Fine,
    /// One constrained solve, at the unconstrained least squares' optimum
    /// (the default: the fine steps buy a λ the data do not determine).
    /// On the DEM fixtures with eq. 2.16 noise its forces lay 0.04–0.9 %
    /// from the fine search's, their error against the truth within ±0.001
    /// of it (as often better as worse), for 0.28 (sheared 10³ spheres,
    /// interior point) to 0.52 (10⁴ sliding spheres, active set) of the
    /// time (docs/bench.md). When the cones move the mismatch too much for
    /// the unconstrained scan to guide (the constrained fallback), the
    /// search is the fine one.
    #[default]
    Coarse,
}

impl Default for LambdaSearch {
    fn default() -> Self {
        LambdaSearch {
            min: 1e-5,
            max: 10.0,
            grid: 7,
            refine: 12,
            constrained_scan: false,
            precision: LambdaPrecision::Coarse,
        }
    }
}

impl LambdaSearch {
    /// The range is usable: 0 < min < max, at least 3 grid points.
    fn check(&self) -> Result<()> {
        if !(self.min > 0.0 && self.max > self.min && self.grid >= 3 && self.max.is_finite()) {
            return Err(Error::Invalid(format!(
                "λ search range must satisfy 0 < min < max with at least 3 points, got {}..{} ({} points)",
                self.min, self.max, self.grid
            )));
        }
        Ok(())
    }

    /// The most constrained solves the search makes (the answer is the best
    /// of them, so no solve follows). With the unconstrained scan:
    /// [`Self::GUIDED_SOLVES`]: three around the unconstrained optimum, then
    /// up to three of Brent's steps from them (one solve alone when the
    /// mismatch is flat at the low end).
    /// When the constrained mismatch there differs from the unconstrained
    /// one by more than 0.05 (the cones move the wall totals, e.g. a feasible
    /// set that nearly collapses), the search falls back to constrained
    /// solves: one on each grid point and up to twice `refine` Brent steps.
    pub fn max_constrained_solves(&self) -> usize {
        if self.constrained_scan {
            self.grid + 2 + self.refine
        } else {
            1 + self.grid + 2 * self.refine
        }
    }

    /// The constrained solves of the unconstrained scan when its mismatch
    /// follows the constrained one (no fallback), at most, at
    /// [`LambdaPrecision::Fine`] (one at `Coarse`).
    pub const GUIDED_SOLVES: usize = 3 + CONSTRAINED_STEPS;

    /// The search before issue 20: 19 constrained solves on the grid and 16
    /// golden-section steps (37 constrained solves).
    pub fn former() -> Self {
        LambdaSearch {
            min: 1e-5,
            max: 10.0,
            grid: 19,
            refine: 16,
            constrained_scan: true,
            precision: LambdaPrecision::Fine,
        }
    }
}

/// Every λ tried and its relative wall mismatch.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LambdaTrace {
    /// (λ in the units of the equation, relative wall mismatch) of each
    /// constrained solve, in the order solved.
    pub points: Vec<(f64, f64)>,
    /// The same for the unconstrained least squares of the scan and refinement.
    pub unconstrained: Vec<(f64, f64)>,
    /// The best λ lies at an end of the search range (not said of a flat
    /// low end, where every smaller λ gives the same answer).
    pub at_edge: bool,
}

/// Precision (decades of λ) of the constrained steps and of the fallback;
/// the former search's final bracket was 3e-4 decades.
const FINE: f64 = 1e-4;

/// Brent's steps on constrained solves after the three around the
/// unconstrained optimum.
const CONSTRAINED_STEPS: usize = 3;

/// Difference between the constrained and the unconstrained relative wall
/// mismatch at the unconstrained optimum beyond which the unconstrained scan
/// is no guide (it is ~1e-3 on the packings measured; a collapsing feasible
/// set gives ~1) and the search falls back to constrained solves.
const PROXY: f64 = 0.05;

/// How far (in units of [`SPREAD`]) the constrained steps may go beyond the
/// constrained point they start from when it is a side one (the constrained
/// optimum lay 0.015 decade from the unconstrained one on the 3D oedometer).
const EXTRAPOLATION: f64 = 3.0;

/// A change of the mismatch between neighbouring grid points, relative to the
/// largest mismatch seen, below which the scan treats the low end as flat.
const FLAT: f64 = 1e-5;

/// Spacing (decades of λ) of the constrained points around the unconstrained
/// optimum: the two optima differ by less on the packings measured
/// (docs/bench.md, issue 20), and close points keep the warm starts short.
const SPREAD: f64 = 0.01;

/// Interior-point tolerance of the constrained solves that only rank λ
/// (when the user's is finer): on a sheared 2 000-sphere packing the same λ
/// to four digits as at 1e-8, in 42 iterations instead of 58 with the
/// chosen λ solved again.
const SEARCH_TOLERANCE: f64 = 1e-4;

/// Precision (decades of λ) of the unconstrained refinement: well inside
/// [`SPREAD`], so the constrained steps start around their optimum.
const TOLERANCE: f64 = 2e-3;

/// The dimensionless λ, the trace, and the constrained solution at that λ
/// (every cluster's unknowns), so that the caller need not solve again.
pub(crate) fn search(
    cx: &Context,
    report: &mut InferenceReport,
) -> Result<(f64, LambdaTrace, Vec<Vec<f64>>)> {
    let (scene, assembly, opts) = (cx.scene, cx.assembly, cx.opts);
    let s = &opts.lambda_search;
    s.check()?;
    let walls = WallMismatch::new(scene)?;
    let mismatch = |xs: &[Vec<f64>]| walls.of(scene, assembly, xs);
    let length = assembly.scales.length;
    // Several constrained solves only rank λ: where an interior point answers
    // them, to a looser tolerance, and the chosen λ once more to the user's.
    // (Not when one solve is all: coarse precision, or a flat low end.)
    let several = s.constrained_scan || s.precision == LambdaPrecision::Fine;
    let loosened = Cell::new(several && opts.conic.tolerance < SEARCH_TOLERANCE);
    let mut ranking_opts = opts.clone();
    ranking_opts.conic.tolerance = SEARCH_TOLERANCE;
    let mut search = Search::default();
    let mut probe = |log_lambda: f64,
                     constrained: bool,
                     report: &mut InferenceReport|
     -> Result<f64> {
        let lambda = 10f64.powf(log_lambda);
        if constrained {
            let solve_opts = if loosened.get() { &ranking_opts } else { opts };
            let xs = solve_all(
                &Context {
                    opts: solve_opts,
                    ..*cx
                },
                lambda,
                report,
            )?;
            let j = mismatch(&xs);
            search.points.push((lambda * length, j.sqrt()));
            if search.best.as_ref().is_none_or(|b| j < b.1) {
                search.best = Some((log_lambda, j, xs));
            }
            Ok(j)
        } else {
            let xs = solve_all_least_squares(cx, lambda, report)?.ok_or_else(|| {
                Error::Invalid("the λ scan needs the sparse least squares of every cluster".into())
            })?;
            let j = mismatch(&xs);
            search.unconstrained.push((lambda * length, j.sqrt()));
            Ok(j)
        }
    };

    let (lo, hi) = (s.min.log10(), s.max.log10());
    let step = (hi - lo) / (s.grid - 1) as f64;
    let at = |i: usize| lo + step * i as f64;
    let mut cheap = !s.constrained_scan;
    let at_edge = loop {
        let (values, largest, lowest) = scan(s, &at, cheap, &mut probe, report)?;
        let best = (lowest..s.grid)
            .min_by(|&a, &b| values[a].total_cmp(&values[b]))
            .unwrap_or(lowest);
        // On a flat low end the range is not too short.
        let at_edge = best == s.grid - 1 || (best == 0 && lowest == 0 && values[0] < values[1]);
        let (a, b) = (at(best.saturating_sub(1)), at((best + 1).min(s.grid - 1)));
        let neighbours = [
            (a, values[best.saturating_sub(1)]),
            (b, values[(best + 1).min(s.grid - 1)]),
        ];
        if s.constrained_scan {
            golden(a, b, s.refine, |u| probe(u, true, report))?;
            break at_edge;
        }
        if !cheap {
            // The fallback: Brent's steps on constrained solves, about as
            // fine as the former golden section (the optimum may sit at the
            // edge of a collapse, where steps are golden, hence twice the
            // budget).
            let refine = |u| probe(u, true, report);
            let (start, steps) = ((at(best), values[best]), 2 * s.refine);
            brent((a, b), start, neighbours, steps, FINE, refine)?;
            break at_edge;
        }
        // The scan stopped on a flat low end that is as good as any point:
        // every smaller λ gives the same mismatch, so one constrained solve
        // at the smallest λ of the range (the former search's choice, the
        // closest to λ = 0 on exact data) is all.
        let plateau = lowest > 0 && values[lowest] - values[best] <= FLAT * largest;
        let (optimum, unconstrained) = if plateau {
            (lo, values[lowest])
        } else {
            // Parabolic steps on the squared mismatch (smooth in log λ,
            // unlike the mismatch, which has a kink where it nearly vanishes).
            brent(
                (a, b),
                (at(best), values[best]),
                neighbours,
                s.refine,
                TOLERANCE,
                |u| probe(u, false, report),
            )?
        };
        // Constrained: the unconstrained optimum first (cold) ...
        if plateau {
            loosened.set(false);
        }
        let centre = probe(optimum, true, report)?;
        let gap = (centre.sqrt() - unconstrained.sqrt()).abs();
        if gap > PROXY {
            report.solver_attempts.push(format!(
                "λ search: the friction cones change the wall mismatch by {gap:.2} at the unconstrained \
                 optimum, so every λ was solved with them"
            ));
            // The cones move the wall totals (e.g. the feasible set nearly
            // collapses): the unconstrained mismatch says nothing; search
            // with constrained solves.
            cheap = false;
            continue;
        }
        if plateau || s.precision == LambdaPrecision::Coarse {
            break at_edge;
        }
        // ... then its neighbours (warm) and Brent's steps.
        refine_constrained(optimum, centre, &mut probe, report)?;
        break at_edge;
    };
    let Search {
        points,
        unconstrained,
        best,
    } = search;
    let (best_log, _, mut xs) =
        best.ok_or_else(|| Error::Invalid("λ search made no constrained solve".into()))?;
    // Active-set answers are exact whatever the tolerance; an interior
    // point's is sharpened (restarted mid-path from the last λ's iterate).
    if loosened.get() && report.solver_status.is_interior_point() {
        xs = solve_all(cx, 10f64.powf(best_log), report)?;
        report.solver_attempts.push(format!(
            "λ search: λ ranked with the interior point at tolerance {SEARCH_TOLERANCE:.0e}, the chosen λ solved again at {:.0e}",
            opts.conic.tolerance
        ));
    }
    Ok((
        10f64.powf(best_log),
        LambdaTrace {
            points,
            unconstrained,
            at_edge,
        },
        xs,
    ))
}

/// The measured walls the grains touch, and the squared norm of their forces.
struct WallMismatch {
    measured: Vec<usize>,
    norm: f64,
}

impl WallMismatch {
    fn new(scene: &Scene) -> Result<Self> {
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
                 for walls its grains touch; give `lambda`"
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
        Ok(WallMismatch { measured, norm })
    }

    /// Squared relative mismatch of the wall totals of an answer.
    fn of(&self, scene: &Scene, assembly: &Assembly, xs: &[Vec<f64>]) -> f64 {
        let forces = collect_forces(scene, assembly, xs);
        let totals = wall_totals(scene, &forces);
        self.measured
            .iter()
            .map(|&w| {
                let m = scene.walls[w].measured_force.unwrap_or_default();
                (0..3).map(|k| (totals[w][k] - m[k]).powi(2)).sum::<f64>()
            })
            .sum::<f64>()
            / self.norm
    }
}

/// The grid, from the largest λ down; when `cheap`, until the low end is
/// flat. Returns the mismatches (∞ where not probed), the largest of them and
/// the lowest index probed.
fn scan(
    s: &LambdaSearch,
    at: &impl Fn(usize) -> f64,
    cheap: bool,
    probe: &mut impl FnMut(f64, bool, &mut InferenceReport) -> Result<f64>,
    report: &mut InferenceReport,
) -> Result<(Vec<f64>, f64, usize)> {
    let mut values = vec![f64::INFINITY; s.grid];
    let mut largest = 0.0f64;
    let mut lowest = s.grid - 1;
    for i in (0..s.grid).rev() {
        values[i] = probe(at(i), !cheap, report)?;
        largest = largest.max(values[i]);
        lowest = i;
        // Flat after a descent from larger mismatches: the low end, where
        // the answer changes as λ². (The high end flattens too, toward the
        // minimum-norm balanced forces, but from above.)
        if cheap
            && i + 1 < s.grid
            && (values[i] - values[i + 1]).abs() <= FLAT * largest
            && largest - values[i] > FLAT * largest
        {
            break;
        }
    }
    Ok((values, largest, lowest))
}

/// After the constrained solve at the unconstrained `optimum` (mismatch
/// `centre`): its two neighbours (warm), then Brent's steps from the three,
/// the first at the vertex of their parabola. The probe keeps the best.
fn refine_constrained(
    optimum: f64,
    centre: f64,
    probe: &mut impl FnMut(f64, bool, &mut InferenceReport) -> Result<f64>,
    report: &mut InferenceReport,
) -> Result<()> {
    let left = probe(optimum - SPREAD, true, report)?;
    let right = probe(optimum + SPREAD, true, report)?;
    let mut three = [
        (optimum - SPREAD, left),
        (optimum, centre),
        (optimum + SPREAD, right),
    ];
    three.sort_by(|p, q| p.1.total_cmp(&q.1));
    let reach = EXTRAPOLATION * SPREAD;
    let bracket = match three[0].0 - optimum {
        d if d < 0.0 => (optimum - reach, optimum),
        d if d > 0.0 => (optimum, optimum + reach),
        _ => (optimum - SPREAD, optimum + SPREAD),
    };
    let refine = |u| probe(u, true, report);
    brent(
        bracket,
        three[0],
        [three[1], three[2]],
        CONSTRAINED_STEPS,
        FINE,
        refine,
    )?;
    Ok(())
}

/// What the search has found so far.
#[derive(Default)]
struct Search {
    points: Vec<(f64, f64)>,
    unconstrained: Vec<(f64, f64)>,
    /// (log₁₀ λ, squared mismatch, solution) of the best constrained solve.
    best: Option<(f64, f64, Vec<Vec<f64>>)>,
}

/// Golden-section search of `f` (log λ) on [a, b] with `steps` steps after
/// the first two points; the caller keeps the best point.
fn golden(
    mut a: f64,
    mut b: f64,
    steps: usize,
    mut f: impl FnMut(f64) -> Result<f64>,
) -> Result<()> {
    let phi = 0.5 * (5f64.sqrt() - 1.0);
    let mut c = b - phi * (b - a);
    let mut d = a + phi * (b - a);
    let mut fc = f(c)?;
    let mut fd = f(d)?;
    for _ in 0..steps {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - phi * (b - a);
            fc = f(c)?;
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + phi * (b - a);
            fd = f(d)?;
        }
    }
    Ok(())
}

/// Brent's minimisation (parabolic interpolation, golden section when it
/// does not shrink the bracket) of `f` on `bracket`, from the best point
/// known and its two known neighbours, in at most `steps` evaluations, to
/// absolute precision `tolerance`. Returns the best point and its value.
fn brent(
    (mut a, mut b): (f64, f64),
    (mut x, mut fx): (f64, f64),
    [(mut w, mut fw), (mut v, mut fv)]: [(f64, f64); 2],
    steps: usize,
    tolerance: f64,
    mut f: impl FnMut(f64) -> Result<f64>,
) -> Result<(f64, f64)> {
    let golden = 0.5 * (3.0 - 5f64.sqrt());
    let (mut d, mut e) = (0.0f64, b - a);
    for _ in 0..steps {
        let mid = 0.5 * (a + b);
        let tol2 = 2.0 * tolerance;
        if (x - mid).abs() <= tol2 - 0.5 * (b - a) {
            break;
        }
        let mut parabolic = false;
        if e.abs() > tolerance {
            let r = (x - w) * (fx - fv);
            let mut q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            } else {
                q = -q;
            }
            let last = e;
            e = d;
            if p.abs() < (0.5 * q * last).abs() && p > q * (a - x) && p < q * (b - x) {
                d = p / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = if x < mid { tolerance } else { -tolerance };
                }
                parabolic = true;
            }
        }
        if !parabolic {
            e = if x < mid { b - x } else { a - x };
            d = golden * e;
        }
        let u = x + if d.abs() >= tolerance {
            d
        } else {
            tolerance.copysign(d)
        };
        let fu = f(u)?;
        if fu <= fx {
            if u < x {
                b = x;
            } else {
                a = x;
            }
            (v, fv, w, fw, x, fx) = (w, fw, x, fx, u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv, w, fw) = (w, fw, u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
    Ok((x, fx))
}

#[cfg(test)]
mod tests {
    use super::brent;

    /// Evaluations of `f` by Brent's search from the grid triple (−1, 0, 1).
    fn minimise(f: impl Fn(f64) -> f64, steps: usize, tolerance: f64) -> (f64, usize) {
        let mut calls = 0;
        let (x, _) = brent(
            (-1.0, 1.0),
            (0.0, f(0.0)),
            [(-1.0, f(-1.0)), (1.0, f(1.0))],
            steps,
            tolerance,
            |u| {
                calls += 1;
                Ok(f(u))
            },
        )
        .unwrap();
        (x, calls)
    }

    #[test]
    fn brent_finds_a_parabola_vertex_in_a_few_steps() {
        let (x, calls) = minimise(|u| (u - 0.3).powi(2) + 1.0, 12, 1e-4);
        assert!((x - 0.3).abs() < 1e-4, "{x}");
        assert!(calls <= 4, "{calls} evaluations");
    }

    #[test]
    fn brent_reaches_the_edge_of_a_cliff() {
        // Decreasing toward a jump, as the mismatch does where the feasible
        // set collapses (fixtures/regression/box3d_ungated).
        let cliff = |u: f64| if u < 0.48 { 0.48 - u } else { 1.0 };
        let (x, calls) = minimise(cliff, 40, 1e-4);
        assert!((0.4795..0.48).contains(&x), "{x}");
        assert!(calls <= 40);
    }

    #[test]
    fn brent_keeps_to_its_budget() {
        let (_, calls) = minimise(|u: f64| (u - 0.3).abs(), 3, 1e-9);
        assert_eq!(calls, 3);
    }
}
