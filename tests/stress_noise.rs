//! Stress noise models (issue 19): `relative` (IRLS) on eq. 2.16's noise,
//! `columns` (sd_s_* per grain), and `absolute` (today's) kept as good.

mod common;
use common::fixture;
use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::infer::{infer, InferOptions, Method, StressNoise};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{sym, Scene, Vec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

fn relerr(scene: &Scene, truth: &[Vec3], method: Method, model: StressNoise) -> f64 {
    let o = InferOptions {
        method,
        stress_noise: model,
        ..InferOptions::default()
    };
    relative_error(truth, &infer(scene, &o).unwrap().forces_or_zero())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median relerr of `scaled` over 5 draws of eq. 2.16 (absolute, relative).
fn eq_2_16(name: &str) -> (f64, f64) {
    let (scene, truth) = fixture(name);
    let (mut abs, mut rel) = (vec![], vec![]);
    for seed in 1..=5 {
        let noisy = perturb(
            std::slice::from_ref(&scene),
            &PerturbConfig::original_study(seed),
        )
        .unwrap()
        .remove(0);
        abs.push(relerr(
            &noisy,
            &truth,
            Method::Scaled,
            StressNoise::Absolute,
        ));
        rel.push(relerr(
            &noisy,
            &truth,
            Method::Scaled,
            StressNoise::Relative,
        ));
    }
    (median(abs), median(rel))
}

#[test]
fn relative_model_on_eq_2_16_noise_2d() {
    let (abs, rel) = eq_2_16("oedometer");
    eprintln!("2D oedometer, scaled: absolute {abs:.4}, relative {rel:.4}");
    assert!(rel <= 0.02, "relative {rel}");
    assert!(rel < 0.5 * abs, "relative {rel} vs absolute {abs}");
}

#[test]
fn relative_model_on_eq_2_16_noise_3d() {
    let (abs, rel) = eq_2_16("regression/oedometer3d_seed1");
    eprintln!("3D oedometer, scaled: absolute {abs:.4}, relative {rel:.4}");
    assert!(rel <= 0.02, "relative {rel}");
    assert!(rel < 0.5 * abs, "relative {rel} vs absolute {abs}");
}

/// Stresses with a known, uneven sd per component (sd_s_* columns).
fn heteroscedastic(scene: &Scene, seed: u64) -> Scene {
    let mut s = scene.clone();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let comps = sym::components(s.dim);
    for (i, g) in s.grains.iter_mut().enumerate() {
        let size = comps.iter().map(|&k| g.stress[k].abs()).fold(0.0, f64::max);
        // Every third grain is measured ten times worse.
        let level = if i % 3 == 0 { 0.3 } else { 0.03 };
        let mut sd = [0.0; 6];
        for &k in comps {
            sd[k] = level * size;
            let e: f64 = StandardNormal.sample(&mut rng);
            g.stress[k] += sd[k] * e;
        }
        g.stress_sd = Some(sd);
    }
    s
}

#[test]
fn columns_model_uses_the_stated_sds() {
    let (scene, truth) = fixture("oedometer");
    let (mut abs, mut col) = (vec![], vec![]);
    for seed in 1..=5 {
        let noisy = heteroscedastic(&scene, seed);
        abs.push(relerr(&noisy, &truth, Method::Qs, StressNoise::Absolute));
        col.push(relerr(&noisy, &truth, Method::Qs, StressNoise::Columns));
    }
    let (abs, col) = (median(abs), median(col));
    eprintln!("uneven sds, qs: absolute {abs:.4}, columns {col:.4}");
    assert!(col < 0.6 * abs, "columns {col} vs absolute {abs}");
}

#[test]
fn columns_model_needs_the_columns() {
    let (scene, _) = fixture("oedometer");
    let o = InferOptions {
        stress_noise: StressNoise::Columns,
        ..InferOptions::default()
    };
    let err = infer(&scene, &o).unwrap_err().to_string();
    assert!(err.contains("sd_s_") && err.contains("grain"), "{err}");
}

#[test]
fn under_absolute_noise_the_absolute_model_stays_the_right_choice() {
    // Additive noise, the same sd on every component: the default (absolute)
    // keeps today's accuracy, and the relative model, which would down-weight
    // the small components that carry the same noise, is measurably worse —
    // the model has to match the data (README, measured data).
    let (scene, truth) = fixture("oedometer");
    let (mut abs, mut rel) = (vec![], vec![]);
    for seed in 1..=5 {
        let mut noisy = scene.clone();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let comps = sym::components(noisy.dim);
        let rms = (noisy
            .grains
            .iter()
            .flat_map(|g| comps.iter().map(move |&k| g.stress[k].powi(2)))
            .sum::<f64>()
            / (noisy.grains.len() * comps.len()) as f64)
            .sqrt();
        for g in &mut noisy.grains {
            for &k in comps {
                let e: f64 = StandardNormal.sample(&mut rng);
                g.stress[k] += 0.1 * rms * e;
            }
        }
        abs.push(relerr(&noisy, &truth, Method::Qs, StressNoise::Absolute));
        rel.push(relerr(&noisy, &truth, Method::Qs, StressNoise::Relative));
    }
    let (abs, rel) = (median(abs), median(rel));
    eprintln!("absolute noise, qs: absolute model {abs:.4}, relative model {rel:.4}");
    assert!(abs <= 0.05, "absolute {abs}");
    assert!(rel > 1.5 * abs, "relative {rel} vs absolute {abs}");
}

#[test]
fn relative_model_on_eq_2_16_noise_dem_box_600_disks() {
    let (abs, rel) = eq_2_16("measured/box2d600_mu03");
    eprintln!("2D box 600, scaled: absolute {abs:.4}, relative {rel:.4}");
    assert!(rel <= 0.02, "relative {rel}");
    assert!(rel < 0.5 * abs, "relative {rel} vs absolute {abs}");
}

#[test]
fn relative_model_on_eq_2_16_noise_dem_box_300_spheres() {
    let (abs, rel) = eq_2_16("measured/box3d300");
    eprintln!("3D box 300, scaled: absolute {abs:.4}, relative {rel:.4}");
    assert!(rel <= 0.02, "relative {rel}");
    assert!(rel < 0.5 * abs, "relative {rel} vs absolute {abs}");
}

/// Fraction of true force components within ±1 sd of the inferred ones.
fn coverage(scene: &Scene, truth: &[Vec3], opts: &InferOptions) -> f64 {
    use grainforce::infer::uncertainty::{force_uncertainty, NoiseEstimate, UncertaintyOptions};
    let inf = infer(scene, opts).unwrap();
    let noise = if opts.stress_noise == StressNoise::Columns {
        NoiseEstimate::Relative(0.0)
    } else {
        NoiseEstimate::FromResidual
    };
    let u = force_uncertainty(
        scene,
        opts,
        &inf,
        &UncertaintyOptions {
            draws: 40,
            seed: 3,
            noise,
        },
    )
    .unwrap();
    let (mut inside, mut total) = (0usize, 0usize);
    for c in 0..truth.len() {
        let (Some(f), Some(sd)) = (inf.forces[c], u.sd[c]) else {
            continue;
        };
        for k in 0..scene.dim {
            total += 1;
            inside += usize::from((f[k] - truth[c][k]).abs() <= sd[k]);
        }
    }
    inside as f64 / total as f64
}

#[test]
fn coverage_at_one_sd_under_the_relative_and_columns_models() {
    let (scene, truth) = fixture("regression/oedometer3d_seed1");
    let (mut rel, mut col) = (vec![], vec![]);
    for seed in 1..=3 {
        let noisy = perturb(
            std::slice::from_ref(&scene),
            &PerturbConfig {
                stress_noise: 0.1,
                seed,
                ..Default::default()
            },
        )
        .unwrap()
        .remove(0);
        let o = InferOptions {
            stress_noise: StressNoise::Relative,
            ..InferOptions::default()
        };
        rel.push(coverage(&noisy, &truth, &o));
        let o = InferOptions {
            stress_noise: StressNoise::Columns,
            ..InferOptions::default()
        };
        col.push(coverage(&heteroscedastic(&scene, seed), &truth, &o));
    }
    let (rel, col) = (median(rel), median(col));
    eprintln!("coverage at ±1 sd: relative {rel:.3}, columns {col:.3}");
    assert!((0.58..0.78).contains(&rel), "relative {rel}");
    assert!((0.58..0.78).contains(&col), "columns {col}");
}
