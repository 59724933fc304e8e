//! The automatic Tikhonov λ (eq. 2.17) on noisy scenes with measured wall
//! forces: the λ chosen, its relative error against the exact forces, the
//! time, and the solves the search spent, for the default search and any
//! other configuration; or (`profile`) the wall mismatch and relerr of the
//! constrained and the unconstrained answer over a fine λ grid.
//!
//! Run: `cargo run --release --example lambda_search -- [profile] CASE…`
//! where a CASE is `2d:1000`, `3d:2000` (the bench packing, `--sliding`
//! default of its dimension, stress noise seed 18 like `grainforce bench`)
//! or a scene folder with `forces.csv` and `walls.csv` (stress noise seed 18).
//! Configurations compared by `search`: `GRID:REFINE` pairs in the env var
//! `LAMBDA_CONFIGS` (e.g. `19:16:constrained,9:4`), default: the default
//! search and the former one (19 constrained points + 16 golden steps).
//! `LAMBDA_SEED` sets the noise seed; `LAMBDA_TRACE=1` prints every λ tried.

use grainforce::bench::{generate, perturb, Noise, PackingSpec};
use grainforce::infer::{infer, InferOptions, LambdaSearch, Method};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{read_forces, read_scene, Scene, Vec3};
use std::path::Path;
use std::time::Instant;

/// `grainforce bench`'s noise seed, unless LAMBDA_SEED says otherwise.
fn noise_seed() -> u64 {
    std::env::var("LAMBDA_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(18)
}

fn load(case: &str) -> grainforce::Result<(Scene, Vec<Vec3>)> {
    if let Some((dim, size)) = case.split_once(':').filter(|(d, _)| d.ends_with('d')) {
        let dim: usize = dim.trim_end_matches('d').parse().expect("dimension");
        let grains = size.parse::<f64>().expect("size") as usize;
        let mut spec = PackingSpec::new(dim, grains);
        spec.sliding = if dim == 3 { 0.3 } else { 0.0 };
        let packing = generate(&spec)?;
        let scene = perturb(&packing.scene, Noise::Stress, noise_seed());
        Ok((scene, packing.truth))
    } else {
        let dir = Path::new(case);
        let scene = read_scene(dir)?;
        let file = dir.join("forces.csv");
        let truth = read_forces(&file)?.for_scene(&scene, &file)?;
        Ok((perturb(&scene, Noise::Stress, noise_seed()), truth))
    }
}

/// Relative wall mismatch of an answer (walls with a measured force).
fn mismatch(report: &grainforce::infer::InferenceReport) -> f64 {
    let (mut d2, mut m2) = (0.0, 0.0);
    for w in &report.walls {
        if let Some(m) = &w.measured {
            for (a, b) in w.inferred.iter().zip(m) {
                d2 += (a - b) * (a - b);
                m2 += b * b;
            }
        }
    }
    (d2 / m2.max(f64::MIN_POSITIVE)).sqrt()
}

fn parse_config(s: &str) -> LambdaSearch {
    let mut parts = s.split(':');
    let mut search = LambdaSearch::default();
    if let Some(g) = parts.next() {
        search.grid = g.parse().expect("grid");
    }
    if let Some(r) = parts.next() {
        search.refine = r.parse().expect("refine");
    }
    search.constrained_scan = parts.next() == Some("constrained");
    search
}

fn main() -> grainforce::Result<()> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let profile = args.first().is_some_and(|a| a == "profile");
    if profile {
        args.remove(0);
    }
    let configs: Vec<LambdaSearch> = match std::env::var("LAMBDA_CONFIGS") {
        Ok(list) => list.split(',').map(parse_config).collect(),
        Err(_) => vec![LambdaSearch::default(), LambdaSearch::former()],
    };
    for case in &args {
        let (scene, truth) = load(case)?;
        if profile {
            let length = infer(
                &scene,
                &InferOptions {
                    method: Method::Ls,
                    ..InferOptions::default()
                },
            )?
            .report
            .length_scale;
            println!("{case}: λ/L  J(constrained) relerr(constrained)  J(ls) relerr(ls)");
            for k in 0..=24 {
                let rel = 10f64.powf(-5.0 + 0.25 * k as f64);
                let mut line = format!("{rel:9.2e}");
                for method in [Method::Tikhonov, Method::Ls] {
                    let r = infer(
                        &scene,
                        &InferOptions {
                            method,
                            lambda: Some(rel * length),
                            ..InferOptions::default()
                        },
                    )?;
                    let e = relative_error(&truth, &r.forces_or_zero());
                    line.push_str(&format!("  {:.5e} {e:.5}", mismatch(&r.report)));
                }
                println!("{line}");
            }
            continue;
        }
        // The floor and one constrained solve, for the ratios.
        for method in [Method::Ls, Method::Qs] {
            let start = Instant::now();
            let r = infer(
                &scene,
                &InferOptions {
                    method,
                    ..InferOptions::default()
                },
            )?;
            println!(
                "{case} {method:?}: relerr {:.6} | {:.3} s, {} active-set solves",
                relative_error(&truth, &r.forces_or_zero()),
                start.elapsed().as_secs_f64(),
                r.report.iterations
            );
        }
        for search in &configs {
            let start = Instant::now();
            let r = infer(
                &scene,
                &InferOptions {
                    method: Method::Tikhonov,
                    lambda_search: search.clone(),
                    ..InferOptions::default()
                },
            )?;
            let time = start.elapsed().as_secs_f64();
            let trace = r.report.lambda_trace.as_ref();
            let constrained = trace.map_or(0, |t| t.points.len());
            let unconstrained = trace.map_or(0, |t| t.unconstrained.len());
            println!(
                "{case} grid {} refine {} {}: λ/L {:.4e} relerr {:.6} J {:.4e} | {time:.3} s, {} constrained solves, {} least squares, {} active-set solves, {:?}",
                search.grid,
                search.refine,
                if search.constrained_scan { "constrained scan" } else { "ls scan" },
                r.report.lambda.unwrap_or(f64::NAN) / r.report.length_scale,
                relative_error(&truth, &r.forces_or_zero()),
                mismatch(&r.report),
                constrained,
                unconstrained,
                r.report.iterations,
                r.report.solver_status,
            );
            if std::env::var("LAMBDA_TRACE").is_ok() {
                println!("    attempts: {:?}", r.report.solver_attempts);
                if let Some(t) = trace {
                    let l = r.report.length_scale;
                    for (x, j) in &t.unconstrained {
                        println!("    ls  {:.6e} {j:.6e}", x / l);
                    }
                    for (x, j) in &t.points {
                        println!("    con {:.6e} {j:.6e}", x / l);
                    }
                }
            }
        }
    }
    Ok(())
}
