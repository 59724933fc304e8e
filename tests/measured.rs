//! Measured-like data that do not balance (issue 19).

use grainforce::bench::measured::{measured_frame, MeasuredConfig, MeasuredFrame};
use grainforce::bench::{generate, PackingSpec};
use grainforce::infer::{infer, InferOptions, LambdaRule, Method};
use grainforce::report::metrics::score;
use grainforce::scene::{read_forces, read_scene};
use std::path::Path;

fn fixture(name: &str, cfg: &MeasuredConfig) -> MeasuredFrame {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name);
    let scene = read_scene(&dir).unwrap();
    let truth = read_forces(&dir.join("forces.csv"))
        .unwrap()
        .for_scene(&scene, &dir)
        .unwrap();
    let truth: Vec<_> = truth.iter().map(|f| *f).collect();
    measured_frame(&scene, &truth, cfg).unwrap()
}

fn generated(dim: usize, grains: usize, cfg: &MeasuredConfig) -> MeasuredFrame {
    let mut spec = PackingSpec::new(dim, grains);
    spec.mu = 0.3;
    let p = generate(&spec).unwrap();
    measured_frame(&p.scene, &p.truth, cfg).unwrap()
}

fn run(frame: &MeasuredFrame, opts: &InferOptions) -> String {
    match infer(&frame.scene, opts) {
        Ok(inf) => {
            let s = score(&frame.scene, &frame.truth, &inf.forces_or_zero()).unwrap();
            let m = score(&frame.scene, &frame.measured, &inf.forces_or_zero()).unwrap();
            format!(
                "relerr {:.4} normal {:.4} vs measured {:.4} {:.4} stress_res {:.3} unique {:?} w {:?}",
                s.relerr(),
                s.normal.map(|n| n.relative).unwrap_or(f64::NAN),
                m.relerr(),
                m.normal.map(|n| n.relative).unwrap_or(f64::NAN),
                inf.report.stress_residual,
                inf.report.unique,
                inf.report.momentum_weight
            )
        }
        Err(e) => format!("error: {e}"),
    }
}

#[test]
fn probe() {
    let env = |k: &str, d: f64| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let cfg = MeasuredConfig {
        drop_weakest: env("DROP", 0.2),
        force_noise: env("NOISE", 0.15),
        per_side: env("PERSIDE", 1.0) > 0.5,
        seed: 1,
    };
    let n = env("NGEN", 600.0) as usize;
    let mut cases = vec![
        ("oed2d", fixture("oedometer", &cfg)),
        ("oed3d", fixture("regression/oedometer3d_seed1", &cfg)),
        ("gen2d", generated(2, n, &cfg)),
    ];
    if let Ok(dir) = std::env::var("EXTRA") {
        let dir = Path::new(&dir);
        let scene = read_scene(dir).unwrap();
        let truth = read_forces(&dir.join("forces.csv"))
            .unwrap()
            .for_scene(&scene, dir)
            .unwrap();
        cases.push(("extra", measured_frame(&scene, &truth, &cfg).unwrap()));
    }
    for (name, f) in &cases {
        eprintln!(
            "{name}: dropped {} imbalance {:.3}",
            f.dropped, f.median_imbalance
        );
        for (label, o) in [
            ("qs", InferOptions::default()),
            (
                "ls",
                InferOptions {
                    method: Method::Ls,
                    ..Default::default()
                },
            ),
            ("knee", {
                let mut o = InferOptions {
                    method: Method::Dynamic,
                    ..Default::default()
                };
                o.dynamic.rule = LambdaRule::Knee;
                o
            }),
            (
                "soft",
                InferOptions {
                    method: Method::Soft,
                    ..Default::default()
                },
            ),
            ("stress-only", {
                let mut o = InferOptions {
                    method: Method::Dynamic,
                    ..Default::default()
                };
                o.dynamic.rule = LambdaRule::Fixed(1e-6);
                o
            }),
        ] {
            eprintln!("  {label}: {}", run(f, &o));
        }
    }
}

#[test]
fn sweep_probe() {
    let env = |k: &str, d: f64| {
        std::env::var(k)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(d)
    };
    let cfg = MeasuredConfig {
        drop_weakest: env("DROP", 0.2),
        force_noise: env("NOISE", 0.15),
        per_side: env("PERSIDE", 1.0) > 0.5,
        seed: 1,
    };
    let mut cases = vec![
        ("oed2d", fixture("oedometer", &cfg)),
        ("oed3d", fixture("regression/oedometer3d_seed1", &cfg)),
    ];
    if let Ok(dir) = std::env::var("EXTRA") {
        let dir = Path::new(&dir);
        let scene = read_scene(dir).unwrap();
        let truth = read_forces(&dir.join("forces.csv"))
            .unwrap()
            .for_scene(&scene, dir)
            .unwrap();
        cases.push(("extra", measured_frame(&scene, &truth, &cfg).unwrap()));
    }
    for (name, f) in &cases {
        eprintln!(
            "{name}: dropped {} of {} imbalance {:.3}",
            f.dropped,
            f.scene.contacts.len() + f.dropped,
            f.median_imbalance
        );
        for i in 0..=20 {
            let l = 10f64.powf(-4.0 + 0.5 * i as f64);
            let mut o = InferOptions {
                method: Method::Dynamic,
                ..Default::default()
            };
            o.dynamic.rule = LambdaRule::Fixed(l);
            eprintln!("  λ {l:.1e}: {}", run(f, &o));
        }
    }
}
