//! Accelerations from tracks and the impulse check.

use grainforce::infer::kinematics::{
    derive_accelerations, fir_zero_phase, impulse_check, savitzky_golay, Smoother,
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

#[test]
fn impulse_of_a_constant_force() {
    // One grain pushed by a wall with a constant force: Δv = F T / m.
    let fps = 1000.0;
    let force = [0.3, -0.2, 0.0];
    let m = 0.1;
    let mut frames = track_frames(50, fps, |t| {
        [0.5 * force[0] / m * t * t, 0.5 * force[1] / m * t * t, 0.0]
    });
    for f in &mut frames {
        let w = f.wall_or_insert("pusher");
        f.contacts.push(grainforce::scene::Contact {
            id: "c".into(),
            a: 0,
            b: grainforce::scene::Body::Wall(w),
            point: [0.0; 3],
            normal: [-1.0, 0.0, 0.0],
            mu: None,
        });
    }
    let forces: Vec<Vec<Option<[f64; 3]>>> = frames.iter().map(|_| vec![Some(force)]).collect();
    let rows = impulse_check(
        &frames,
        &forces,
        fps,
        Smoother::SavitzkyGolay {
            window: 7,
            degree: 2,
        },
        [0.0; 3],
    )
    .unwrap();
    assert_eq!(rows.len(), 1);
    let t = 49.0 / fps;
    for k in 0..2 {
        let expected = force[k] / m * t;
        assert!((rows[0].inferred[k] - expected).abs() < 1e-9);
        assert!((rows[0].measured[k] - expected).abs() < 1e-6 * expected.abs().max(1.0));
    }
}
