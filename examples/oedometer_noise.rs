//! The original study's noise experiment (§2.4, eq. 2.16) on the bundled
//! oedometer: each stress component b ← b + (0.15 + N(0, 0.1))·b, 10 draws;
//! relative error (eq. 2.15) of qs, automatic Tikhonov, and `scaled` (which
//! estimates the global stress scale from the wall forces).
//!
//!     cargo run --release --example oedometer_noise [SCENE_DIR] [DRAWS]

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::infer::{infer, InferOptions, Method};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{read_forces, read_scene};
use std::path::PathBuf;

fn main() -> grainforce::Result<()> {
    let dir = PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "fixtures/oedometer".into()),
    );
    let draws: u64 = std::env::args()
        .nth(2)
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let scene = read_scene(&dir)?;
    let truth_file = dir.join("forces.csv");
    let truth = read_forces(&truth_file)?.for_scene(&scene, &truth_file)?;
    let methods = [Method::Qs, Method::Tikhonov, Method::Scaled];
    let mut errors: Vec<Vec<f64>> = vec![Vec::new(); methods.len()];
    println!(
        "draw  {:>10} {:>10} {:>10}   λ (tikhonov)   scale (scaled)",
        "qs", "tikhonov", "scaled"
    );
    for seed in 1..=draws {
        let config = PerturbConfig {
            stress_bias: 0.15,
            stress_noise: 0.1,
            seed,
            ..Default::default()
        };
        let noisy = perturb(std::slice::from_ref(&scene), &config)?.remove(0);
        let mut line = format!("{seed:>4}  ");
        let mut extra = String::new();
        for (k, &method) in methods.iter().enumerate() {
            let r = infer(
                &noisy,
                &InferOptions {
                    method,
                    ..InferOptions::default()
                },
            )?;
            let e = relative_error(&truth, &r.forces_or_zero());
            errors[k].push(e);
            line.push_str(&format!("{e:>10.4} "));
            if let Some(l) = r.report.lambda.filter(|_| method == Method::Tikhonov) {
                extra.push_str(&format!("  {l:.3e}"));
            }
            if let Some(s) = r.report.stress_scale {
                extra.push_str(&format!("     {s:.4}"));
            }
        }
        println!("{line}{extra}");
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    };
    let m: Vec<f64> = errors.iter_mut().map(median).collect();
    println!("median {:>10.4} {:>10.4} {:>10.4}", m[0], m[1], m[2]);
    Ok(())
}
