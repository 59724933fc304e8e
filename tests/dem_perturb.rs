//! `perturb` applies exactly the noise model asked for.

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::scene::{self, Contact, Grain, Scene};

/// A synthetic scene with many grains and varied stresses (no physics needed).
fn scene(dim: usize, n: usize) -> Scene {
    let mut s = Scene::new(dim);
    for i in 0..n {
        let t = i as f64;
        let mut stress = [-1000.0 - t, -2000.0 + 0.5 * t, 0.0, 300.0 + t, 0.0, 0.0];
        if dim == 3 {
            stress[2] = -1500.0 - 0.3 * t;
            stress[4] = 50.0 + t;
            stress[5] = -70.0 - t;
        }
        let mut g = Grain::new(i.to_string(), [t * 0.01, 0.5 * t * 0.01, 0.0], 1e-4, stress);
        g.acceleration = Some([1.0, 2.0, if dim == 3 { 3.0 } else { 0.0 }]);
        s.grains.push(g);
    }
    for i in 0..n - 1 {
        let angle = i as f64 * 0.37;
        let normal = if dim == 2 {
            [angle.cos(), angle.sin(), 0.0]
        } else {
            [angle.cos() * 0.6, angle.sin() * 0.6, 0.8]
        };
        s.contacts.push(Contact {
            id: format!("c{i}"),
            a: i,
            b: scene::Body::Grain(i + 1),
            point: [0.0; 3],
            normal,
            mu: Some(0.5),
        });
    }
    s
}

fn mean_sd(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, var.sqrt())
}

#[test]
fn stress_model_is_bias_plus_gaussian_times_value() {
    for dim in [2, 3] {
        let original = scene(dim, 4000);
        let noisy = perturb(
            std::slice::from_ref(&original),
            &PerturbConfig::original_study(11),
        )
        .unwrap();
        let mut ratios = Vec::new();
        for (a, b) in original.grains.iter().zip(&noisy[0].grains) {
            for k in 0..6 {
                if scene::sym::components(dim).contains(&k) {
                    ratios.push((b.stress[k] - a.stress[k]) / a.stress[k]);
                } else {
                    assert_eq!(b.stress[k], a.stress[k]);
                }
            }
            // Nothing else changes.
            assert_eq!(a.position, b.position);
            assert_eq!(a.acceleration, b.acceleration);
        }
        let (m, sd) = mean_sd(&ratios);
        let n = ratios.len() as f64;
        // Mean 0.15 within 4 standard errors, sd 0.1 within 5 %.
        assert!(
            (m - 0.15).abs() < 4.0 * 0.1 / n.sqrt(),
            "{dim}D mean factor {m}"
        );
        assert!((sd - 0.1).abs() < 0.005, "{dim}D sd {sd}");
        // Independent draws per component: neighbouring components uncorrelated.
        let pairs: Vec<f64> = ratios.windows(2).map(|w| (w[0] - m) * (w[1] - m)).collect();
        let corr = pairs.iter().sum::<f64>() / pairs.len() as f64 / (sd * sd);
        assert!(corr.abs() < 0.05, "{dim}D correlation {corr}");
        assert_eq!(noisy[0].contacts, original.contacts);
    }
}

#[test]
fn other_noises_have_the_requested_spread() {
    let original = scene(3, 3000);
    let config = PerturbConfig {
        position_noise: 1e-4,
        normal_noise_deg: 2.0,
        accel_noise: 0.5,
        seed: 3,
        ..Default::default()
    };
    let noisy = &perturb(std::slice::from_ref(&original), &config).unwrap()[0];
    let mut dx = Vec::new();
    let mut da = Vec::new();
    for (a, b) in original.grains.iter().zip(&noisy.grains) {
        assert_eq!(a.stress, b.stress);
        for k in 0..3 {
            dx.push(b.position[k] - a.position[k]);
            da.push(b.acceleration.unwrap()[k] - a.acceleration.unwrap()[k]);
        }
    }
    let (m, sd) = mean_sd(&dx);
    assert!(
        m.abs() < 1e-5 && (sd - 1e-4).abs() < 5e-6,
        "position {m} {sd}"
    );
    let (m, sd) = mean_sd(&da);
    assert!(
        m.abs() < 0.05 && (sd - 0.5).abs() < 0.025,
        "acceleration {m} {sd}"
    );
    // One Gaussian tilt angle per normal: the rms tilt is σ.
    let mut tilt = Vec::new();
    for (a, b) in original.contacts.iter().zip(&noisy.contacts) {
        assert!((scene::norm(b.normal) - 1.0).abs() < 1e-12);
        tilt.push(
            scene::dot(a.normal, b.normal)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees(),
        );
    }
    let rms = (tilt.iter().map(|t| t * t).sum::<f64>() / tilt.len() as f64).sqrt();
    assert!((rms - 2.0).abs() < 0.1, "normal tilt rms {rms}");
}

#[test]
fn dropping_contacts_and_determinism() {
    let original = scene(2, 5000);
    let config = PerturbConfig {
        drop_contacts: 0.2,
        stress_noise: 0.1,
        seed: 9,
        ..Default::default()
    };
    let a = perturb(std::slice::from_ref(&original), &config).unwrap();
    let b = perturb(std::slice::from_ref(&original), &config).unwrap();
    assert_eq!(a, b);
    let kept = a[0].contacts.len() as f64 / original.contacts.len() as f64;
    assert!(
        (kept - 0.8).abs() < 4.0 * (0.16f64 / 5000.0).sqrt(),
        "kept {kept}"
    );
    let other = perturb(
        std::slice::from_ref(&original),
        &PerturbConfig {
            seed: 10,
            ..config.clone()
        },
    )
    .unwrap();
    assert_ne!(a, other);
}

#[test]
fn bad_noise_values_are_errors() {
    let s = scene(2, 3);
    for bad in [
        PerturbConfig {
            drop_contacts: 1.5,
            ..Default::default()
        },
        PerturbConfig {
            stress_noise: -0.1,
            ..Default::default()
        },
        PerturbConfig {
            position_noise: f64::NAN,
            ..Default::default()
        },
    ] {
        assert!(perturb(std::slice::from_ref(&s), &bad).is_err());
    }
}
