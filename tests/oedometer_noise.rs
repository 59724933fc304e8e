//! The original study's noise experiment on the bundled DEM oedometer (58 disks):
//! b ← b + (0.15 + N(0, 0.1))·b on every stress component, 10 draws.
//! The study reports 0.154 for qs and 0.053 for hand-tuned Tikhonov on one draw.

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::infer::{infer, InferOptions, Method};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{read_forces, read_scene};
use std::path::Path;

fn medians() -> (f64, f64, f64, Vec<f64>) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/oedometer");
    let scene = read_scene(&dir).unwrap();
    let truth = read_forces(&dir.join("forces.csv"))
        .unwrap()
        .for_scene(&scene, &dir)
        .unwrap();
    let (mut qs, mut tik, mut scaled, mut scales) = (vec![], vec![], vec![], vec![]);
    for seed in 1..=10 {
        let config = PerturbConfig {
            stress_bias: 0.15,
            stress_noise: 0.1,
            seed,
            ..Default::default()
        };
        let noisy = perturb(std::slice::from_ref(&scene), &config)
            .unwrap()
            .remove(0);
        let run = |method| {
            infer(
                &noisy,
                &InferOptions {
                    method,
                    ..InferOptions::default()
                },
            )
            .unwrap()
        };
        qs.push(relative_error(&truth, &run(Method::Qs).forces_or_zero()));
        let t = run(Method::Tikhonov);
        assert!(t.report.lambda.is_some_and(|l| l > 0.0));
        tik.push(relative_error(&truth, &t.forces_or_zero()));
        let s = run(Method::Scaled);
        scales.push(s.report.stress_scale.unwrap());
        scaled.push(relative_error(&truth, &s.forces_or_zero()));
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        0.5 * (v[4] + v[5])
    };
    (median(qs), median(tik), median(scaled), scales)
}

#[test]
fn automatic_tikhonov_and_scaled_beat_the_original_study() {
    let (qs, tik, scaled, scales) = medians();
    eprintln!("median relerr: qs {qs:.4}, tikhonov {tik:.4}, scaled {scaled:.4}");
    // qs has no defence against the 15 % bias: the study's 0.154.
    assert!((0.10..0.25).contains(&qs), "qs {qs}");
    assert!(tik <= 0.04, "automatic tikhonov {tik}");
    assert!(scaled <= 0.04, "scaled {scaled}");
    // The wall forces pin the global scale: the truth is 1/1.15 of the data.
    for s in scales {
        assert!((s - 1.0 / 1.15).abs() < 0.05, "scale {s}");
    }
}
