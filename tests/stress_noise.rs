//! Stress noise models (issue 19): `relative` (IRLS) on eq. 2.16's noise,
//! `columns` (sd_s_* per grain), and `absolute` (today's) kept as good.

mod common;
use common::fixture;
use grainforce::bench::noise::{STRESS_BIAS, STRESS_SCATTER};
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

/// rms of every stress component of every grain.
fn rms_stress(scene: &Scene) -> f64 {
    let comps = sym::components(scene.dim);
    let sum: f64 = scene
        .grains
        .iter()
        .flat_map(|g| comps.iter().map(move |&k| g.stress[k].powi(2)))
        .sum();
    (sum / (scene.grains.len() * comps.len()) as f64).sqrt()
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
        let rms = rms_stress(&noisy);
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
    let scale = truth
        .iter()
        .map(|f| f.iter().map(|v| v * v).sum::<f64>().sqrt())
        .sum::<f64>()
        / truth.len() as f64;
    let (mut inside, mut total) = (0usize, 0usize);
    for c in 0..truth.len() {
        let (Some(f), Some(sd)) = (inf.forces[c], u.sd[c]) else {
            continue;
        };
        for k in 0..scene.dim {
            // Components the model fixes (the tangential ones at frictionless
            // walls: 22 % here) are certain and right; counting them as
            // covered would inflate the coverage of the uncertain ones.
            let error = (f[k] - truth[c][k]).abs();
            if sd[k] <= 1e-12 * scale && error <= 1e-9 * scale {
                continue;
            }
            total += 1;
            inside += usize::from((f[k] - truth[c][k]).abs() <= sd[k]);
        }
    }
    inside as f64 / total as f64
}

/// Noise draws of the coverage test. The coverage of one draw scatters by
/// ~0.06 (a few modes carry most of a packing's error, so one draw's errors
/// are all large or all small together): 3 draws are not enough to tell 0.68
/// from 0.76. With 20 the mean is within ~0.015 (30 draws: relative 0.636,
/// absolute 0.657, columns 0.667).
const COVERAGE_DRAWS: u64 = 20;

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn coverage_at_one_sd_under_each_model() {
    let (scene, truth) = fixture("regression/oedometer3d_seed1");
    let (mut rel, mut abs, mut col) = (vec![], vec![], vec![]);
    for seed in 1..=COVERAGE_DRAWS {
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
        for (model, out) in [
            (StressNoise::Relative, &mut rel),
            (StressNoise::Absolute, &mut abs),
        ] {
            let o = InferOptions {
                stress_noise: model,
                ..InferOptions::default()
            };
            out.push(coverage(&noisy, &truth, &o));
        }
        let o = InferOptions {
            stress_noise: StressNoise::Columns,
            ..InferOptions::default()
        };
        col.push(coverage(&heteroscedastic(&scene, seed), &truth, &o));
    }
    let (rel, abs, col) = (mean(&rel), mean(&abs), mean(&col));
    eprintln!("coverage at ±1 sd, mean of {COVERAGE_DRAWS} draws: relative {rel:.3}, absolute {abs:.3}, columns {col:.3}");
    // Target 0.63–0.73, widened by two standard errors of the mean (0.015).
    for (name, c) in [("relative", rel), ("absolute", abs), ("columns", col)] {
        assert!((0.60..0.76).contains(&c), "{name} {c}");
    }
}

#[test]
fn relative_model_on_eq_2_16_noise_sheared_dem_1000_spheres() {
    // A 10³ DEM packing with friction at the limit (fixtures/regression).
    let (abs, rel) = eq_2_16("regression/box3d_sheared");
    eprintln!("3D sheared box 1000, scaled: absolute {abs:.4}, relative {rel:.4}");
    assert!(rel <= 0.02, "relative {rel}");
    assert!(rel < 0.5 * abs, "relative {rel} vs absolute {abs}");
}

/// The best a row weighting can do on eq. 2.16 data: the 15 % scale removed
/// and every component weighted by its true sd (the scatter times |exact|,
/// as `columns`).
fn oracle(exact: &Scene, noisy: &Scene) -> Scene {
    let mut s = noisy.clone();
    let comps = sym::components(s.dim);
    let rms = rms_stress(exact);
    for (g, e) in s.grains.iter_mut().zip(&exact.grains) {
        let mut sd = [0.0; 6];
        for &k in comps {
            g.stress[k] /= 1.0 + STRESS_BIAS;
            sd[k] = STRESS_SCATTER * e.stress[k].abs() + 1e-3 * rms;
        }
        g.stress_sd = Some(sd);
    }
    s
}

#[test]
fn on_lattice_packings_the_relative_model_reaches_the_oracle() {
    // The bench's lattices miss the 0.02 target (README): their near-square
    // systems carry the noise into the forces. Weighting every row by its
    // true sd with the scale known does no better, so the limit is the data's.
    use grainforce::bench::{generate, perturb, Noise, PackingSpec};
    for dim in [2, 3] {
        let packing = generate(&PackingSpec::new(dim, 1000)).unwrap();
        let (mut ours, mut best) = (vec![], vec![]);
        for seed in 1..=3 {
            let noisy = perturb(&packing.scene, Noise::Stress, seed);
            ours.push(relerr(
                &noisy,
                &packing.truth,
                Method::Scaled,
                StressNoise::Relative,
            ));
            best.push(relerr(
                &oracle(&packing.scene, &noisy),
                &packing.truth,
                Method::Qs,
                StressNoise::Columns,
            ));
        }
        let (ours, best) = (median(ours), median(best));
        eprintln!("{dim}D lattice 10³: scaled relative {ours:.4}, oracle {best:.4}");
        assert!(ours <= 1.1 * best, "{dim}D: {ours} vs oracle {best}");
        assert!(
            best > 0.02,
            "{dim}D: the oracle {best} meets the target after all"
        );
    }
}
