//! The active-set solver step by step on a synthetic packing, beside the
//! interior point: solves, damping, changed contacts, fixed-point residual.
//!
//! Run: `cargo run --release --example active_set_trace [grains] [dim] [stress|geometry] [mu] [seed] [sliding]`
//! (defaults: 1000 2 stress 0.5 18 0 — noise seed 18 is `grainforce bench`'s; the
//! interior point is skipped above 20 000 grains), or with a scene folder
//! instead of the grain count (e.g. `fixtures/regression/box3d_sheared`): that
//! scene with the same noise, forces compared with the interior point's, and
//! a probe of that optimum: its tight constraints (at several thresholds)
//! imposed as equalities on the sparse factorisation — do they solve
//! consistently and give the optimum back?

use grainforce::assemble::{assemble, AssembleOptions};
use grainforce::bench::{generate, perturb, Noise, PackingSpec};
use grainforce::infer::{infer, ConstrainedSolver, InferOptions};
use grainforce::report::metrics::relative_error;
use grainforce::scene::read_scene;
use grainforce::solver::active_set;
use grainforce::solver::sparse_ls::{EqualityLeastSquares, Ordering};
use std::time::Instant;

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.into());
    let noise = match arg(3, "stress").as_str() {
        "geometry" => Noise::Geometry,
        _ => Noise::Stress,
    };
    let seed = arg(5, "18").parse().expect("seed");
    let folder = std::path::PathBuf::from(arg(1, "1000"));
    // A scene folder: no truth; the interior point's answer stands in for it.
    let (scene, truth) = if folder.is_dir() {
        (perturb(&read_scene(&folder)?, noise, seed), None)
    } else {
        let mut spec = PackingSpec::new(
            arg(2, "2").parse().expect("dim"),
            arg(1, "1000").parse().expect("grains"),
        );
        spec.mu = arg(4, "0.5").parse().expect("mu");
        spec.shear = 0.5 * spec.mu;
        spec.sliding = arg(6, "0").parse().expect("sliding share");
        let packing = generate(&spec)?;
        (perturb(&packing.scene, noise, seed), Some(packing.truth))
    };
    let (grains, dim) = (scene.grains.len(), scene.dim);

    // The bare solver on the largest cluster, to print its iterations.
    let assembly = assemble(&scene, &AssembleOptions::default())?;
    if let Some(system) = assembly.systems.iter().max_by_key(|s| s.n) {
        let cones = grainforce::infer::cones(system, grainforce::infer::ConeModel::Exact);
        if truth.is_none() {
            probe_optimum(system, &cones)?;
        }
        // Cold (pieces of the unconstrained answer) against predicted (Gauss–Seidel guess).
        // The cold start is far too slow at the largest sizes (> 15 min at 10⁵ spheres).
        for predict in [false, true] {
            if !predict && grains > 20_000 {
                continue;
            }
            let t = Instant::now();
            let mut ls = EqualityLeastSquares::with_ordering(
                &system.stress,
                &system.momentum,
                &system.contact_blocks(),
                Ordering::for_dim(dim),
            )?;
            let start = ls.solve(
                &system.stress,
                &system.momentum,
                &system.stress_rhs,
                &system.momentum_rhs,
                0.0,
            )?;
            let t_ls = t.elapsed().as_secs_f64();
            let problem = system.least_squares(0.0);
            let settings = active_set::ActiveSetSettings {
                predict,
                ..Default::default()
            };
            let sol = active_set::solve(&mut ls, &problem, &cones, &start.x, &settings)?;
            println!(
                "{} unknowns, first active set {}: least squares {t_ls:.2} s, then {} active-set solves in {:.2} s (converged: {})",
                system.n,
                if predict { "predicted" } else { "projected" },
                sol.iterations,
                t.elapsed().as_secs_f64() - t_ls,
                sol.converged
            );
            println!("solve  rows  step  changed  residual  seconds  route");
            for (k, h) in sol.history.iter().enumerate() {
                println!(
                    "{:>5} {:>5} {:>5} {:>8} {:>9.1e} {:>8.3} {}",
                    k + 1,
                    h.active_rows,
                    h.step,
                    h.changed,
                    h.residual,
                    h.seconds,
                    if h.reused_factor {
                        "reused"
                    } else {
                        "factorised"
                    }
                );
            }
            if let Some(r) = sol.reason {
                println!("stopped: {r}");
            }
        }
    }
    let mut first: Option<Vec<grainforce::scene::Vec3>> = None;
    for solver in [
        ConstrainedSolver::ActiveSet,
        ConstrainedSolver::InteriorPoint,
    ] {
        if solver == ConstrainedSolver::InteriorPoint && grains > 20_000 {
            break;
        }
        let t = Instant::now();
        let r = infer(
            &scene,
            &InferOptions {
                solver,
                ..InferOptions::default()
            },
        )?;
        let forces = r.forces_or_zero();
        let e = match (&truth, &first) {
            (Some(truth), _) => relative_error(truth, &forces),
            (None, Some(active)) => relative_error(&forces, active),
            (None, None) => f64::NAN,
        };
        first.get_or_insert(forces);
        println!(
            "infer {solver:?}: {:.2} s, relerr {e:.4e} (to {}), {} {:?}",
            t.elapsed().as_secs_f64(),
            if truth.is_some() {
                "the truth"
            } else {
                "the active set"
            },
            r.report.solver_status,
            r.report.solver_attempts
        );
    }
    Ok(())
}

/// Clarabel's optimum of the qs problem, its constraints tight to a relative
/// threshold imposed as equalities (face rows for sliding contacts, the apex
/// for open ones), and the equality-constrained least squares with them: a
/// consistent solve there gives the optimum back; an inconsistent one shows
/// that near-tight contacts cannot be pinned (issue 20, docs/bench.md).
fn probe_optimum(
    system: &grainforce::assemble::System,
    cones: &[grainforce::solver::Cone],
) -> grainforce::Result<()> {
    use grainforce::solver::clarabel::{self, ConicSettings};
    use grainforce::solver::Triplets;
    use grainforce::solver::{Cone, ConicProblem, Term};
    let problem = ConicProblem {
        n: system.n,
        terms: vec![Term {
            matrix: &system.stress,
            rhs: &system.stress_rhs,
            weight: 1.0,
        }],
        equalities: vec![(&system.momentum, system.momentum_rhs.as_slice())],
        lambda: 0.0,
        regularized: system.n,
        cones: cones.to_vec(),
    };
    let settings = ConicSettings {
        tolerance: 1e-10,
        ..ConicSettings::default()
    };
    let x = clarabel::solve(&problem, &settings)?.x;
    let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let norm = x.iter().map(|v| v * v).sum::<f64>().sqrt();
    let mut ls = EqualityLeastSquares::with_ordering(
        &system.stress,
        &system.momentum,
        &system.contact_blocks(),
        Ordering::for_dim(system.dim),
    )?;
    for threshold in [1e-4, 1e-6, 1e-8] {
        let tight = threshold * scale;
        let mut g = Triplets::new(0, system.n);
        let mut pin = |entries: &[(usize, f64)]| {
            g.nrows += 1;
            for &(j, v) in entries {
                g.push(g.nrows - 1, j, v);
            }
        };
        let (mut sliding, mut open) = (0, 0);
        for cone in cones {
            match *cone {
                Cone::Circular { normal, t1, t2, mu } if x[normal] > tight => {
                    let t = x[t1].hypot(x[t2]);
                    if mu * x[normal] - t <= tight {
                        pin(&[(normal, mu), (t1, -x[t1] / t), (t2, -x[t2] / t)]);
                        sliding += 1;
                    }
                }
                Cone::Circular { normal, t1, t2, .. } => {
                    for j in [normal, t1, t2] {
                        pin(&[(j, 1.0)]);
                    }
                    open += 1;
                }
                Cone::NonNegative { normal } if x[normal] <= tight => {
                    pin(&[(normal, 1.0)]);
                    open += 1;
                }
                _ => {}
            }
        }
        let sol = ls.solve_with_active(
            &system.stress,
            &system.momentum,
            &system.stress_rhs,
            &system.momentum_rhs,
            0.0,
            &g,
            &Triplets::new(0, system.n),
        )?;
        let gap = (sol.solution.x.iter().zip(&x))
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt()
            / norm;
        println!(
            "optimum's constraints tight to {threshold:.0e}: {sliding} sliding, {open} open; pinned solve converged: {} (KKT residual {:.1e}), gap to the optimum {gap:.1e}",
            sol.solution.converged, sol.solution.kkt_residual
        );
    }
    Ok(())
}
