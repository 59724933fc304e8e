//! Accelerations from tracks and the impulse check.

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::infer::kinematics::{
    acceleration_noise_gain, derive_accelerations, fir_zero_phase, impulse_check, savitzky_golay,
    ImpulseOptions, Smoother,
};
use grainforce::scene::{Grain, Scene};

fn track_frames(n: usize, fps: f64, path: impl Fn(f64) -> [f64; 3]) -> Vec<Scene> {
    (0..n)
        .map(|k| {
            let mut s = Scene::new(2);
            s.frame = Some(k as i64);
            let mut g = Grain::new("7", path(k as f64 / fps), 1e-4, [0.0; 6]);
            g.mass = Some(0.1);
            s.grains.push(g);
            s
        })
        .collect()
}

#[test]
fn constant_acceleration_is_exact_inside_the_track() {
    let fps = 5000.0;
    let a = [-3.0, 9.0, 0.0];
    for smoother in [
        Smoother::default_fir(),
        Smoother::SavitzkyGolay {
            window: 11,
            degree: 3,
        },
        Smoother::Whittaker { cutoff: 0.15 },
    ] {
        let mut frames = track_frames(60, fps, |t| {
            [1e6 + 0.5 * a[0] * t * t, 0.2 * t + 0.5 * a[1] * t * t, 0.0]
        });
        derive_accelerations(&mut frames, fps, smoother).unwrap();
        // At 1e6 m a position is known to one ulp (1.2e-10 m); a second
        // difference amplifies that by 4/dt² — the limit of the data, not the method.
        let ulp = 1e6f64.next_up() - 1e6;
        let floor = 8.0 * ulp * fps * fps;
        for f in &frames[12..48] {
            let got = f.grains[0].acceleration.unwrap();
            assert!(
                (got[0] - a[0]).abs() <= floor,
                "{smoother:?}: {got:?} (floor {floor})"
            );
            assert!(
                (got[1] - a[1]).abs() <= 1e-9 * a[1].abs(),
                "{smoother:?}: {got:?}"
            );
        }
    }
}

#[test]
fn savitzky_golay_is_exact_for_cubics_everywhere() {
    let x: Vec<f64> = (0..30)
        .map(|i| {
            let t = i as f64 * 0.01;
            2.0 + t - 4.0 * t * t + 7.0 * t * t * t
        })
        .collect();
    let a = savitzky_golay(&x, 0.01, 9, 3, 2);
    for (i, v) in a.iter().enumerate() {
        let t = i as f64 * 0.01;
        assert!((v - (-8.0 + 42.0 * t)).abs() < 1e-8, "frame {i}: {v}");
    }
}

#[test]
fn fir_removes_noise_and_keeps_slow_motion() {
    let n = 400;
    let slow: Vec<f64> = (0..n).map(|i| (i as f64 * 0.02).sin()).collect();
    let noisy: Vec<f64> = slow
        .iter()
        .enumerate()
        .map(|(i, s)| s + 0.05 * if i % 2 == 0 { 1.0 } else { -1.0 })
        .collect();
    let f = fir_zero_phase(&noisy, 20, 0.2);
    let err = f[30..n - 30]
        .iter()
        .zip(&slow[30..n - 30])
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    // The Nyquist-frequency noise of amplitude 0.05 is cut to below 1 %.
    assert!(err < 5e-3, "max error {err}");
}

#[test]
fn grains_entering_and_leaving_are_handled() {
    let fps = 100.0;
    let mut frames = track_frames(20, fps, |t| [t * t, 0.0, 0.0]);
    // A second grain visible only in frames 5..=14, and one seen twice.
    for (k, f) in frames.iter_mut().enumerate() {
        if (5..15).contains(&k) {
            f.grains.push(Grain::new(
                "late",
                [0.0, (k as f64 / fps).powi(2), 0.0],
                1e-4,
                [0.0; 6],
            ));
        }
        if k == 3 || k == 4 {
            f.grains.push(Grain::new("blink", [0.0; 3], 1e-4, [0.0; 6]));
        }
    }
    let r = derive_accelerations(
        &mut frames,
        fps,
        Smoother::SavitzkyGolay {
            window: 5,
            degree: 2,
        },
    )
    .unwrap();
    assert_eq!(r.tracks, 3);
    assert_eq!(r.partial_tracks, 2);
    assert_eq!(r.short_tracks, vec!["blink".to_string()]);
    let late = frames[10].grains.iter().find(|g| g.id == "late").unwrap();
    assert!((late.acceleration.unwrap()[1] - 2.0).abs() < 1e-6);
}

#[test]
fn gaps_in_frame_numbers_are_an_error() {
    let mut frames = track_frames(10, 100.0, |t| [t, 0.0, 0.0]);
    frames[5].frame = Some(50);
    frames[6..]
        .iter_mut()
        .enumerate()
        .for_each(|(i, f)| f.frame = Some(51 + i as i64));
    assert!(derive_accelerations(&mut frames, 100.0, Smoother::default_fir()).is_err());
    assert!(derive_accelerations(
        &mut track_frames(5, 0.0, |t| [t, 0.0, 0.0]),
        0.0,
        Smoother::default_fir()
    )
    .is_err());
}

/// Per frame, the force of each contact.
type FrameForces = Vec<Vec<Option<[f64; 3]>>>;

/// One grain pushed by a wall with `force(t)` (mass 0.1, no gravity), its
/// track integrated exactly for piecewise-constant force between frames.
fn pushed_grain(
    n: usize,
    fps: f64,
    force: impl Fn(usize) -> [f64; 3],
) -> (Vec<Scene>, FrameForces) {
    let m = 0.1;
    let dt = 1.0 / fps;
    let (mut x, mut v) = ([0.0; 3], [0.02, -0.01, 0.0]);
    let mut frames = Vec::new();
    let mut forces = Vec::new();
    for k in 0..n {
        let f = force(k);
        let mut s = Scene::new(2);
        s.frame = Some(k as i64);
        let mut g = Grain::new("7", x, 1e-4, [0.0; 6]);
        g.mass = Some(m);
        s.grains.push(g);
        let w = s.wall_or_insert("pusher");
        s.contacts.push(grainforce::scene::Contact {
            id: "c".into(),
            a: 0,
            b: grainforce::scene::Body::Wall(w),
            point: [0.0; 3],
            normal: [-1.0, 0.0, 0.0],
            mu: None,
        });
        frames.push(s);
        forces.push(vec![Some(f)]);
        // Exact for a force linear between frames: the check's own rule.
        let f1 = force(k + 1);
        for i in 0..2 {
            x[i] += v[i] * dt + dt * dt * (f[i] / 3.0 + f1[i] / 6.0) / m;
            v[i] += 0.5 * dt * (f[i] + f1[i]) / m;
        }
    }
    (frames, forces)
}

/// A 4 ms half-sine push of 14 N along (3, 4)/5 in the middle of a
/// 100-frame track: Δv = 0.36 m/s.
fn pulse(k: usize) -> [f64; 3] {
    let t = k as f64;
    let f = if (40.0..=60.0).contains(&t) {
        14.0 * (std::f64::consts::PI * (t - 40.0) / 20.0).sin()
    } else {
        0.0
    };
    [0.6 * f, 0.8 * f, 0.0]
}

#[test]
fn impulse_of_a_constant_force() {
    // Constant force: both sides are the slope difference of a parabola, F/m
    // times the time between the window centres.
    let fps = 1000.0;
    let force = [0.3, -0.2, 0.0];
    let (frames, forces) = pushed_grain(50, fps, |_| force);
    let options = ImpulseOptions {
        window: 7,
        ..Default::default()
    };
    let check = impulse_check(&frames, &forces, fps, [0.0; 3], &options).unwrap();
    assert_eq!(check.rows.len(), 1);
    let r = &check.rows[0];
    assert_eq!((r.first_frame, r.last_frame), (0, 49));
    let t = (50.0 - 7.0) / fps;
    for k in 0..2 {
        let expected = force[k] / 0.1 * t;
        assert!((r.inferred[k] - expected).abs() < 1e-9, "{r:?}");
        assert!((r.measured[k] - expected).abs() < 1e-9, "{r:?}");
    }
    assert!(r.moves && r.disagreement < 1e-8, "{r:?}");
}

#[test]
fn measured_impulse_noise_is_as_stated() {
    // 200 noisy copies of a pushed grain: the measured Δv scatters around the
    // exact one with the stated sd, and the noise is estimated from the tracks.
    let fps = 5000.0;
    let (exact, forces) = pushed_grain(100, fps, pulse);
    let options = ImpulseOptions::default();
    let truth = impulse_check(&exact, &forces, fps, [0.0; 3], &options).unwrap();
    let truth = &truth.rows[0];
    assert!(truth.disagreement < 1e-9, "{truth:?}");
    let noise = 2e-5;
    let (mut sum_sq, mut count, mut sd_estimates) = (0.0, 0, Vec::new());
    for seed in 0..200 {
        let config = PerturbConfig {
            position_noise: noise,
            seed,
            ..Default::default()
        };
        let noisy = perturb(&exact, &config).unwrap();
        let check = impulse_check(&noisy, &forces, fps, [0.0; 3], &options).unwrap();
        let r = &check.rows[0];
        for k in 0..2 {
            sum_sq += ((r.measured[k] - truth.measured[k]) / r.measured_sd).powi(2);
            count += 1;
        }
        sd_estimates.push(check.position_sd / noise);
        // The inferred side uses the true forces: only the tracks are noisy.
        assert_eq!(r.inferred, truth.inferred);
    }
    let z_rms = (sum_sq / count as f64).sqrt();
    // With the noise as estimated from each track (a 100-frame track gives
    // ±8 % on σ) the z-scores still have unit spread within sampling error.
    assert!((z_rms - 1.0).abs() < 0.1, "rms z {z_rms}");
    let mean_ratio = sd_estimates.iter().sum::<f64>() / sd_estimates.len() as f64;
    eprintln!("measured Δv: rms z {z_rms:.3}, estimated σ / true σ {mean_ratio:.3}");
    assert!(
        (mean_ratio - 1.0).abs() < 0.05,
        "estimated σ / true σ {mean_ratio}"
    );
}

#[test]
fn impulse_check_flags_wrong_forces_and_resting_grains() {
    let fps = 5000.0;
    let (exact, forces) = pushed_grain(100, fps, pulse);
    let noisy = perturb(
        &exact,
        &PerturbConfig {
            position_noise: 2e-5,
            seed: 9,
            ..Default::default()
        },
    )
    .unwrap();
    let options = ImpulseOptions {
        position_sd: Some(2e-5),
        ..Default::default()
    };
    let right = impulse_check(&noisy, &forces, fps, [0.0; 3], &options).unwrap();
    let r = &right.rows[0];
    // Δv = 0.36 m/s against an sd of 0.005 m/s: the grain moves, and the
    // correct forces agree within noise.
    assert!(
        r.moves && r.disagreement < 0.05 && r.gap_in_sd < 4.0,
        "{r:?}"
    );
    assert!(!right.position_sd_estimated);
    // Forces 20 % too small are a real disagreement, far outside the noise.
    let weak: FrameForces = forces
        .iter()
        .map(|fs| fs.iter().map(|f| f.map(|f| f.map(|x| 0.8 * x))).collect())
        .collect();
    let wrong = impulse_check(&noisy, &weak, fps, [0.0; 3], &options).unwrap();
    let w = &wrong.rows[0];
    eprintln!("right forces: {r:?}\nforces × 0.8: {w:?}");
    assert!(w.disagreement > 0.15 && w.gap_in_sd > 10.0, "{w:?}");
    // A grain at rest does not move: its Δv is noise.
    let (still, zero) = pushed_grain(100, fps, |_| [0.0; 3]);
    let still: Vec<Scene> = still
        .into_iter()
        .map(|mut s| {
            s.grains[0].position = [0.0; 3];
            s
        })
        .collect();
    let still = perturb(
        &still,
        &PerturbConfig {
            position_noise: 2e-5,
            seed: 4,
            ..Default::default()
        },
    )
    .unwrap();
    let rest = impulse_check(&still, &zero, fps, [0.0; 3], &options).unwrap();
    assert!(!rest.rows[0].moves, "{:?}", rest.rows[0]);
    assert_eq!(rest.moving().count(), 0);
    assert_eq!(rest.worst_moving_disagreement(), 0.0);
}

#[test]
fn impulse_check_rejects_bad_options_and_skips_short_tracks() {
    let fps = 1000.0;
    let (frames, forces) = pushed_grain(30, fps, |_| [0.1, 0.0, 0.0]);
    for window in [0, 2, 4] {
        let options = ImpulseOptions {
            window,
            ..Default::default()
        };
        let err = impulse_check(&frames, &forces, fps, [0.0; 3], &options).unwrap_err();
        assert!(err.to_string().contains("window"), "{err}");
    }
    let options = ImpulseOptions {
        position_sd: Some(-1.0),
        ..Default::default()
    };
    assert!(impulse_check(&frames, &forces, fps, [0.0; 3], &options).is_err());
    // Unequal time steps are named, not integrated over.
    let mut gappy = frames.clone();
    gappy[20..]
        .iter_mut()
        .for_each(|f| f.frame = Some(f.frame.unwrap() + 5));
    let err = impulse_check(&gappy, &forces, fps, [0.0; 3], &Default::default()).unwrap_err();
    assert!(err.to_string().contains("impulse check"), "{err}");
    // 30 frames cannot hold two disjoint-enough 31-frame windows.
    let options = ImpulseOptions {
        window: 31,
        ..Default::default()
    };
    let check = impulse_check(&frames, &forces, fps, [0.0; 3], &options).unwrap();
    assert!(check.rows.is_empty());
    assert_eq!(check.skipped, vec!["7".to_string()]);
}

#[test]
fn stated_acceleration_noise_matches_noisy_tracks() {
    // White position noise of sd σ on a still grain: the derived acceleration's
    // sd per frame is the stated gain × σ, larger at the track's ends.
    let (fps, n, sigma, draws) = (5000.0, 80, 1e-5, 400);
    for smoother in [
        Smoother::default_fir(),
        Smoother::SavitzkyGolay {
            window: 11,
            degree: 3,
        },
        Smoother::Whittaker { cutoff: 0.15 },
    ] {
        let gain = acceleration_noise_gain(n, 1.0 / fps, smoother).unwrap();
        // The shortcut for long tracks gives what the full computation gives.
        let long = acceleration_noise_gain(300, 1.0 / fps, smoother).unwrap();
        assert!((long[150] - gain[40]).abs() <= 1e-9 * gain[40]);
        assert!((long[299] - gain[79]).abs() <= 1e-9 * gain[79]);
        let edge = gain[..6].iter().copied().fold(0.0, f64::max);
        assert!(edge > 1.3 * gain[40], "{smoother:?}: {gain:?}");
        let still = track_frames(n, fps, |_| [0.3, 0.2, 0.0]);
        let (mut sum_sq, mut ratios) = (vec![0.0; n], 0.0);
        for seed in 0..draws {
            let config = PerturbConfig {
                position_noise: sigma,
                seed,
                ..Default::default()
            };
            let mut frames = perturb(&still, &config).unwrap();
            let report = derive_accelerations(&mut frames, fps, smoother).unwrap();
            assert_eq!(report.acceleration_sd.len(), n);
            // Stated from the position noise estimated on this one track.
            ratios += report.acceleration_sd[40] / (sigma * gain[40]) / draws as f64;
            for (s, f) in sum_sq.iter_mut().zip(&frames) {
                *s += f.grains[0].acceleration.unwrap()[0].powi(2);
            }
        }
        assert!((0.95..1.05).contains(&ratios), "{smoother:?}: {ratios}");
        // 400 draws: the sample sd is within ±10 % at 3 sd (≈ 3.5 % each).
        for k in [0, 1, 5, 40, 79] {
            let measured = (sum_sq[k] / draws as f64).sqrt();
            let stated = sigma * gain[k];
            assert!(
                (measured / stated - 1.0).abs() < 0.1,
                "{smoother:?} frame {k}: measured {measured}, stated {stated}"
            );
        }
    }
}

#[test]
fn impulse_windows_widen_over_free_flight() {
    // The pulse with the wall touching only while it pushes (frames 40–60):
    // each end window widens over the contact-free stretch (40 and 39 frames,
    // taken odd), which the same slopes on both sides keep exact and which
    // quiets the measured side by (21/39)^1.5.
    let fps = 5000.0;
    let (mut frames, mut forces) = pushed_grain(100, fps, pulse);
    for (k, (frame, f)) in frames.iter_mut().zip(&mut forces).enumerate() {
        if !(40..=60).contains(&k) {
            frame.contacts.clear();
            f.clear();
        }
    }
    let options = ImpulseOptions {
        position_sd: Some(2e-5),
        ..Default::default()
    };
    let check = impulse_check(&frames, &forces, fps, [0.0; 3], &options).unwrap();
    let r = &check.rows[0];
    assert_eq!((r.start_window, r.end_window), (39, 39), "{r:?}");
    assert!(r.disagreement < 1e-9, "{r:?}");
    // The whole pulse lies between the windows: Δv is its full impulse / m
    // (trapezoidal, the track's own rule), 0.36 m/s.
    let impulse: f64 = (40..=60)
        .map(|k| pulse(k)[0].hypot(pulse(k)[1]))
        .sum::<f64>()
        / fps;
    let size = r.measured[0].hypot(r.measured[1]);
    assert!(
        (size - impulse / 0.1).abs() < 1e-9,
        "{size} vs {}",
        impulse / 0.1
    );
    let (touching, _) = pushed_grain(100, fps, pulse);
    let fixed = impulse_check(&touching, &forces_all(&touching), fps, [0.0; 3], &options).unwrap();
    let f = &fixed.rows[0];
    assert_eq!((f.start_window, f.end_window), (21, 21));
    let ratio = r.measured_sd / f.measured_sd;
    assert!((ratio - (21.0f64 / 39.0).powf(1.5)).abs() < 0.02, "{ratio}");
}

/// No force at any contact.
fn forces_all(frames: &[Scene]) -> FrameForces {
    frames
        .iter()
        .map(|f| vec![Some([0.0; 3]); f.contacts.len()])
        .collect()
}

#[test]
fn whittaker_holds_free_flight_at_gravity() {
    // A noisy ballistic track, gravity stated, no contact: the Whittaker fit
    // returns gravity at every frame; the FIR passes the noise on.
    let (fps, n, g) = (5000.0, 90, [0.0, -9.81, 0.0]);
    let mut frames = track_frames(n, fps, |t| {
        [2e3 + 0.4 * t, 1.5 + 0.3 * t + 0.5 * g[1] * t * t, 0.0]
    });
    for f in &mut frames {
        f.settings.gravity = Some(vec![g[0], g[1]]);
    }
    let config = PerturbConfig {
        position_noise: 2e-5,
        seed: 3,
        ..Default::default()
    };
    let noisy = perturb(&frames, &config).unwrap();
    let worst = |smoother: Smoother| {
        let mut f = noisy.clone();
        derive_accelerations(&mut f, fps, smoother).unwrap();
        f.iter()
            .map(|s| {
                let a = s.grains[0].acceleration.unwrap();
                (a[0] - g[0]).hypot(a[1] - g[1])
            })
            .fold(0.0, f64::max)
    };
    // Across the cut-off range (λ from ~0.3 to ~1e10) the hold stays exact.
    for cutoff in [0.01, 0.15, 0.95] {
        let held = worst(Smoother::Whittaker { cutoff });
        assert!(
            held <= 1e-6 * 9.81,
            "cut-off {cutoff}: held free flight deviates by {held} m/s²"
        );
    }
    let fir = worst(Smoother::default_fir());
    assert!(fir > 1.0, "the FIR should carry the noise: {fir}");
    // Without stated gravity nothing is held: the noise shows again.
    let mut f = noisy.clone();
    for s in &mut f {
        s.settings.gravity = None;
    }
    derive_accelerations(&mut f, fps, Smoother::Whittaker { cutoff: 0.15 }).unwrap();
    let free = f
        .iter()
        .map(|s| {
            let a = s.grains[0].acceleration.unwrap();
            (a[0] - g[0]).hypot(a[1] - g[1])
        })
        .fold(0.0, f64::max);
    assert!(free > 1.0, "unstated gravity must not be assumed: {free}");
}
