//! Timing of the sparse equality-constrained least-squares floor on a synthetic
//! 2D GEM-like system: disks on a jittered triangular lattice, each lattice bond
//! kept with probability 2/3 (≈ 2 contacts per grain, 2 force components per
//! contact), 3 stress rows (A) and 3 equilibrium rows (C) per grain, centroid arms.
//!
//! Run: `cargo run --release --example sparse_ls_scaling [max_grains] [seq|rayon]`
//! (default parallelism: the library's choice by size).

use std::time::Instant;

use grainforce::solver::sparse_ls::{identifiability, EqualityLeastSquares};
use grainforce::solver::Triplets;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct System {
    a: Triplets,
    c: Triplets,
    grains: usize,
    contacts: usize,
}

fn lattice_system(side: usize, seed: u64) -> System {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let grains = side * side;
    let index = |i: usize, j: usize| i * side + j;
    let pos: Vec<[f64; 2]> = (0..grains)
        .map(|g| {
            let (i, j) = (g / side, g % side);
            let x = 2.0 * j as f64 + if i % 2 == 1 { 1.0 } else { 0.0 };
            let y = 3f64.sqrt() * i as f64;
            [
                x + rng.gen_range(-0.05..0.05),
                y + rng.gen_range(-0.05..0.05),
            ]
        })
        .collect();
    let mut contacts = Vec::new();
    for i in 0..side {
        for j in 0..side {
            let mut bonds = Vec::with_capacity(3);
            if j + 1 < side {
                bonds.push(index(i, j + 1));
            }
            if i + 1 < side {
                bonds.push(index(i + 1, j));
                let diag = if i % 2 == 0 {
                    j.checked_sub(1)
                } else {
                    (j + 1 < side).then_some(j + 1)
                };
                if let Some(jj) = diag {
                    bonds.push(index(i + 1, jj));
                }
            }
            for other in bonds {
                if rng.gen::<f64>() < 2.0 / 3.0 {
                    contacts.push((index(i, j), other));
                }
            }
        }
    }
    let nc = contacts.len();
    let mut a = Triplets::new(3 * grains, 2 * nc);
    let mut c = Triplets::new(3 * grains, 2 * nc);
    for (k, &(g1, g2)) in contacts.iter().enumerate() {
        let mid = [
            (pos[g1][0] + pos[g2][0]) / 2.0,
            (pos[g1][1] + pos[g2][1]) / 2.0,
        ];
        for (g, sign) in [(g1, 1.0), (g2, -1.0)] {
            let r = [mid[0] - pos[g][0], mid[1] - pos[g][1]];
            // Equilibrium: force rows [1,0;0,1], moment r × f.
            c.push(3 * g, 2 * k, sign);
            c.push(3 * g + 1, 2 * k + 1, sign);
            c.push(3 * g + 2, 2 * k, -sign * r[1]);
            c.push(3 * g + 2, 2 * k + 1, sign * r[0]);
            // Stress: xx = r_x f_x, yy = r_y f_y, 2xy = r_x f_y + r_y f_x.
            a.push(3 * g, 2 * k, sign * r[0]);
            a.push(3 * g + 1, 2 * k + 1, sign * r[1]);
            a.push(3 * g + 2, 2 * k, sign * r[1]);
            a.push(3 * g + 2, 2 * k + 1, sign * r[0]);
        }
    }
    System {
        a,
        c,
        grains,
        contacts: nc,
    }
}

fn main() -> grainforce::Result<()> {
    let max_grains: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    let forced_par = match std::env::args().nth(2).as_deref() {
        Some("seq") => Some(faer::Par::Seq),
        Some("rayon") => Some(faer::Par::rayon(0)),
        _ => None,
    };
    println!(
        "rayon threads available: {}, parallelism: {forced_par:?} (None = by size)",
        rayon::current_num_threads()
    );
    println!(
        "{:>8} {:>8} {:>8} {:>8} {:>9} {:>9} {:>9} {:>9} {:>5} {:>9} {:>9} {:>9}",
        "grains",
        "contacts",
        "unknowns",
        "kkt",
        "nnz(L)",
        "symbolic",
        "num+solve",
        "λ-solve",
        "steps",
        "rel.err",
        "‖Cx−d‖∞",
        "ident."
    );
    let mut grains = 1_000;
    while grains <= max_grains {
        let side = (grains as f64).sqrt().round() as usize;
        let sys = lattice_system(side, 42);
        let (a, c) = (&sys.a, &sys.c);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let x_true: Vec<f64> = (0..a.ncols).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let (b, d) = (a.mul(&x_true), c.mul(&x_true));

        let t0 = Instant::now();
        let mut solver = match forced_par {
            Some(par) => EqualityLeastSquares::with_parallelism(a, c, par)?,
            None => EqualityLeastSquares::new(a, c)?,
        };
        let t_symbolic = t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        let sol = solver.solve(a, c, &b, &d, 0.0)?;
        let t_numeric = t1.elapsed().as_secs_f64();
        let t2 = Instant::now();
        let swept = solver.solve(a, c, &b, &d, 0.05)?;
        let t_lambda = t2.elapsed().as_secs_f64();
        assert!(swept.x.iter().all(|v| v.is_finite()));
        let err = {
            let num: f64 = sol
                .x
                .iter()
                .zip(&x_true)
                .map(|(p, q)| (p - q).powi(2))
                .sum();
            let den: f64 = x_true.iter().map(|q| q * q).sum();
            (num / den).sqrt()
        };
        let t3 = Instant::now();
        let id = identifiability(a, c)?;
        let t_ident = t3.elapsed().as_secs_f64();
        println!(
            "{:>8} {:>8} {:>8} {:>8} {:>9} {:>8.3}s {:>8.3}s {:>8.3}s {:>5} {:>9.1e} {:>9.1e} {:>8.2}s {}",
            sys.grains,
            sys.contacts,
            a.ncols,
            a.ncols + c.nrows,
            solver.factor_nnz(),
            t_symbolic,
            t_numeric,
            t_lambda,
            sol.refinement_steps,
            err,
            sol.equality_residual,
            t_ident,
            if id.unique {
                format!("unique σ={:.1e}", id.sigma_min_relative)
            } else {
                format!("null dim ≥ {}", id.null_dimension_estimate)
            }
        );
        grains *= 10;
    }
    Ok(())
}
