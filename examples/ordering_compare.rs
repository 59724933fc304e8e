//! AMD against nested dissection for the sparse least-squares KKT factorisation
//! of a synthetic packing: factor entries, symbolic time, first solve (numeric
//! factorisation + refinement) and a refactorisation (new λ) + solve.
//!
//! Run: `cargo run --release --example ordering_compare [grains] [dim] [both|amd|nd]`
//! (defaults: 10000 2 both).

use grainforce::assemble::{assemble, AssembleOptions};
use grainforce::bench::{generate, perturb, Noise, PackingSpec};
use grainforce::solver::sparse_ls::{EqualityLeastSquares, Ordering};
use std::time::Instant;

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.into());
    let grains: usize = arg(1, "10000").parse().expect("grains");
    let dim: usize = arg(2, "2").parse().expect("dim");
    let orderings: Vec<Ordering> = match arg(3, "both").as_str() {
        "amd" => vec![Ordering::Amd],
        "nd" => vec![Ordering::NestedDissection],
        _ => vec![Ordering::Amd, Ordering::NestedDissection],
    };
    let packing = generate(&PackingSpec::new(dim, grains))?;
    let scene = perturb(&packing.scene, Noise::Stress, 18);
    let assembly = assemble(&scene, &AssembleOptions::default())?;
    let system = assembly
        .systems
        .iter()
        .max_by_key(|s| s.n)
        .expect("a packing has a cluster");
    let t = Instant::now();
    let mut ls = EqualityLeastSquares::with_coupling(
        &system.stress,
        &system.momentum,
        &system.contact_blocks(),
    )?;
    println!(
        "{grains} grains, {dim}D: {} unknowns, {} momentum rows; default analysis {:.2} s",
        system.n,
        system.momentum.nrows,
        t.elapsed().as_secs_f64()
    );
    println!("ordering          factor_nnz  symbolic_s  first_solve_s  refactor_solve_s  steps  residual");
    let mut reference: Option<Vec<f64>> = None;
    for ordering in orderings {
        let t = Instant::now();
        ls.set_ordering(ordering)?;
        let t_symbolic = t.elapsed().as_secs_f64();
        let solve = |ls: &mut EqualityLeastSquares, lambda: f64| {
            ls.solve(
                &system.stress,
                &system.momentum,
                &system.stress_rhs,
                &system.momentum_rhs,
                lambda,
            )
        };
        let t = Instant::now();
        let first = solve(&mut ls, 0.0)?;
        let t_first = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let again = solve(&mut ls, 1e-9)?;
        let t_again = t.elapsed().as_secs_f64();
        println!(
            "{:<16} {:>11} {:>11.2} {:>14.2} {:>17.2} {:>3}/{:<3} {:.3e} (converged {}, kkt {:.1e})",
            format!("{ordering:?}"),
            ls.factor_nnz(),
            t_symbolic,
            t_first,
            t_again,
            first.refinement_steps,
            again.refinement_steps,
            first.residual,
            first.converged,
            first.kkt_residual
        );
        match &reference {
            None => reference = Some(first.x),
            Some(x0) => {
                let diff = x0
                    .iter()
                    .zip(&first.x)
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>()
                    .sqrt();
                let norm = x0.iter().map(|a| a * a).sum::<f64>().sqrt();
                println!(
                    "  relative difference of x from the first ordering: {:.1e}",
                    diff / norm
                );
            }
        }
    }
    Ok(())
}
