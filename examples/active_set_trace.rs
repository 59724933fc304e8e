//! The active-set solver step by step on a synthetic packing, beside the
//! interior point: solves, damping, changed contacts, fixed-point residual.
//!
//! Run: `cargo run --release --example active_set_trace [grains] [dim] [stress|geometry] [mu] [seed]`
//! (defaults: 1000 2 stress 0.5 18 — noise seed 18 is `grainforce bench`'s; the
//! interior point is skipped above 20 000 grains).

use grainforce::assemble::{assemble, AssembleOptions};
use grainforce::bench::{generate, perturb, Noise, PackingSpec};
use grainforce::infer::{infer, ConstrainedSolver, InferOptions};
use grainforce::report::metrics::relative_error;
use grainforce::solver::sparse_ls::{EqualityLeastSquares, Ordering};
use grainforce::solver::{active_set, LeastSquares};
use std::time::Instant;

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.into());
    let grains: usize = arg(1, "1000").parse().expect("grains");
    let dim: usize = arg(2, "2").parse().expect("dim");
    let noise = match arg(3, "stress").as_str() {
        "geometry" => Noise::Geometry,
        _ => Noise::Stress,
    };
    let mut spec = PackingSpec::new(dim, grains);
    spec.mu = arg(4, "0.5").parse().expect("mu");
    spec.shear = 0.5 * spec.mu;
    let packing = generate(&spec)?;
    let scene = perturb(&packing.scene, noise, arg(5, "18").parse().expect("seed"));

    // The bare solver on the largest cluster, to print its iterations.
    let assembly = assemble(&scene, &AssembleOptions::default())?;
    if let Some(system) = assembly.systems.iter().max_by_key(|s| s.n) {
        let cones = grainforce::infer::cones(system, grainforce::infer::ConeModel::Exact);
        // Cold (pieces of the unconstrained answer) against predicted (Gauss–Seidel guess).
        for predict in [false, true] {
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
            let problem = LeastSquares {
                a: &system.stress,
                b: &system.stress_rhs,
                c: &system.momentum,
                d: &system.momentum_rhs,
                lambda: 0.0,
            };
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
                    if h.bordered { "bordered" } else { "factorised" }
                );
            }
            if let Some(r) = sol.reason {
                println!("stopped: {r}");
            }
        }
    }
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
        let e = relative_error(&packing.truth, &r.forces_or_zero());
        println!(
            "infer {solver:?}: {:.2} s, relerr {e:.4e}, {} {:?}",
            t.elapsed().as_secs_f64(),
            r.report.solver_status,
            r.report.solver_attempts
        );
    }
    Ok(())
}
