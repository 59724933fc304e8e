//! The joint time fit (`--time-fit joint`): all frames of a sequence at once,
//! against the raw tracks, forces smooth in time.

mod common;

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::dem::{simulate, DemConfig, DemRun, Preset};
use grainforce::infer::kinematics::{
    derive_accelerations, impulse_check, weight_derived_momentum, ImpulseOptions, Smoother,
};
use grainforce::infer::time_fit::{
    estimate_roughness, infer_time_fit, TimeFitOptions, ROUGHNESS_FACTOR,
};
use grainforce::infer::{infer_frames, ConeModel, InferOptions, Method};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{Body, Scene, Vec3};

const FPS: f64 = 5000.0;

fn dynamic() -> InferOptions {
    InferOptions {
        method: Method::Dynamic,
        ..InferOptions::default()
    }
}

fn impact(dim: usize) -> DemRun {
    simulate(&DemConfig::preset(Preset::Impact, dim).seed(1)).unwrap()
}

/// Relative error over all frames together (a contact left out counts as zero).
fn overall(truth: &[Vec<Vec3>], inferred: &[Vec<Option<Vec3>>]) -> f64 {
    let t: Vec<Vec3> = truth.iter().flatten().copied().collect();
    let f: Vec<Vec3> = inferred
        .iter()
        .flatten()
        .map(|f| f.unwrap_or([0.0; 3]))
        .collect();
    relative_error(&t, &f)
}

/// The frame-by-frame pipeline (FIR-derived accelerations, noise-aware weights).
fn frame_by_frame(noisy: &mut [Scene]) -> Vec<Vec<Option<Vec3>>> {
    let report = derive_accelerations(noisy, FPS, Smoother::default_fir()).unwrap();
    let mut per_frame = vec![dynamic(); noisy.len()];
    weight_derived_momentum(noisy, &mut per_frame, &report, 0.1).unwrap();
    infer_frames(noisy, &per_frame, None)
        .unwrap()
        .into_iter()
        .map(|r| r.forces)
        .collect()
}

#[test]
fn impact_from_noisy_tracks_beats_frame_by_frame() {
    // 0.1 % of a diameter of position noise, three draws: the joint fit is
    // more accurate than the frame-by-frame answer it starts from, and the
    // impulses of the moving grains follow the tracks (table 3.1).
    // Measured over twelve draws (examples/time_fit_draws): relerr
    // 0.018–0.022 against 0.030–0.035 frame by frame; impulse check 60/60
    // within 10 %, worst 1.4 % (frame by frame 59/60, worst 11.8 %).
    let run = impact(2);
    let diameter = 2.0 * run.frames[0].grains[0].radius.unwrap();
    let gravity = run.frames[0].gravity();
    let exact = impulse_check(
        &run.frames,
        &run.force_sets(),
        FPS,
        gravity,
        &ImpulseOptions::default(),
    )
    .unwrap();
    for seed in 1..=3 {
        let config = PerturbConfig {
            position_noise: 1e-3 * diameter,
            seed,
            ..Default::default()
        };
        let mut noisy = perturb(&run.frames, &config).unwrap();
        let start = frame_by_frame(&mut noisy);
        let fit =
            infer_time_fit(&noisy, &dynamic(), &TimeFitOptions::new(FPS), Some(&start)).unwrap();
        let (e_frames, e_joint) = (
            overall(&run.forces, &start),
            overall(&run.forces, &fit.forces),
        );
        eprintln!(
            "seed {seed}: relerr frame by frame {e_frames:.4}, joint {e_joint:.4}\n{}",
            fit.report
        );
        assert!(e_joint <= 0.03, "seed {seed}: joint relerr {e_joint}");
        assert!(
            e_joint < 0.8 * e_frames,
            "seed {seed}: {e_joint} vs {e_frames}"
        );
        assert!(fit.report.roughness_estimated && fit.report.position_sd_estimated);
        // Every contact of every frame has a force that meets Coulomb (to
        // round-off of the largest force).
        let largest = fit
            .forces
            .iter()
            .flatten()
            .flatten()
            .fold(0.0f64, |m, f| m.max(f[0].hypot(f[1])));
        for (frame, forces) in noisy.iter().zip(&fit.forces) {
            for (c, f) in frame.contacts.iter().zip(forces) {
                let f = f.expect("every contact is fitted");
                let fn_ = -(f[0] * c.normal[0] + f[1] * c.normal[1]);
                let ft = (f[0] + fn_ * c.normal[0]).hypot(f[1] + fn_ * c.normal[1]);
                assert!(fn_ >= -1e-12 * largest, "tension {fn_}");
                assert!(
                    ft <= c.mu.unwrap() * fn_ + 1e-12 * largest,
                    "{ft} > μ {fn_}"
                );
            }
        }
        let check = impulse_check(
            &noisy,
            &fit.forces,
            FPS,
            gravity,
            &ImpulseOptions::default(),
        )
        .unwrap();
        assert!(check.moving().count() >= 4);
        for (r, t) in check.rows.iter().zip(&exact.rows).filter(|(r, _)| r.moves) {
            assert!(r.disagreement <= 0.05, "seed {seed}: {r:?}");
            let off = (r.inferred[0] - t.measured[0]).hypot(r.inferred[1] - t.measured[1])
                / t.measured[0].hypot(t.measured[1]);
            assert!(
                off <= 0.05,
                "seed {seed}, grain {}: {off} off the noise-free Δv",
                r.grain
            );
        }
    }
}

/// A 3D sequence with known forces: sphere 1 rests on a frictional floor
/// (gravity −z), sphere 2 flies in and is pushed off it by a half-sine pulse
/// along the line of centres (frames 20–40 of 60 at `fps`); tracks integrated
/// with 200 substeps per frame, stresses V σ = Σ sym(r ⊗ f).
fn two_spheres_3d(fps: f64) -> (Vec<Scene>, Vec<Vec<Vec3>>) {
    use grainforce::scene::{sym_outer, Contact, Grain, Wall};
    let (radius, density, g): (f64, f64, f64) = (0.01, 2500.0, 9.81);
    let mass = 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3) * density;
    let volume = mass / density;
    let (t0, pulse, peak) = (20.0 / fps, 20.0 / fps, 40.0);
    let push = |t: f64| {
        if (t0..=t0 + pulse).contains(&t) {
            peak * (std::f64::consts::PI * (t - t0) / pulse).sin()
        } else {
            0.0
        }
    };
    let sub = |a: Vec3, b: Vec3| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let unit = |v: Vec3| {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / n, v[1] / n, v[2] / n]
    };
    let dir = unit([1.0, 0.5, 2.0]);
    let mut x = [[0.0, 0.0, radius], [0.0; 3]];
    for k in 0..3 {
        x[1][k] = x[0][k] + 2.0 * radius * dir[k];
    }
    let mut v = [[0.0; 3], [-0.05, -0.02, -0.1]];
    // Forces at time t: on 1 by the floor, on 1 by 2 (sphere 1 stays on the floor).
    let forces = |t: f64, x: &[Vec3; 2]| -> (Vec3, Vec3, Vec3) {
        let n = unit(sub(x[1], x[0]));
        let f = push(t);
        let on1 = [-f * n[0], -f * n[1], -f * n[2]];
        (n, [0.0, 0.0, mass * g + f * n[2]], on1)
    };
    let steps = 200;
    let h = 1.0 / (fps * steps as f64);
    let (mut frames, mut truth) = (Vec::new(), Vec::new());
    for frame in 0..60 {
        let t = frame as f64 / fps;
        let (n, floor, on1) = forces(t, &x);
        let mut scene = Scene::new(3);
        scene.frame = Some(frame);
        scene.settings.gravity = Some(vec![0.0, 0.0, -g]);
        scene.settings.mu = Some(0.5);
        scene.walls.push(Wall {
            name: "floor".into(),
            measured_force: None,
        });
        let mut stress = [[0.0; 6]; 2];
        let floor_point = [x[0][0], x[0][1], 0.0];
        let mut contacts = vec![(0usize, Body::Wall(0), floor_point, [0.0, 0.0, -1.0], floor)];
        if push(t) > 0.0 {
            let mid = [
                0.5 * (x[0][0] + x[1][0]),
                0.5 * (x[0][1] + x[1][1]),
                0.5 * (x[0][2] + x[1][2]),
            ];
            contacts.push((0, Body::Grain(1), mid, n, on1));
        }
        let mut truth_here = Vec::new();
        for (i, (a, b, point, normal, f)) in contacts.into_iter().enumerate() {
            let add = |s: &mut [f64; 6], r: Vec3, f: Vec3| {
                for (sk, ok) in s.iter_mut().zip(sym_outer(r, f)) {
                    *sk += ok / volume;
                }
            };
            add(&mut stress[a], sub(point, x[a]), f);
            if let Body::Grain(b) = b {
                add(&mut stress[b], sub(point, x[b]), [-f[0], -f[1], -f[2]]);
            }
            scene.contacts.push(Contact {
                id: format!("c{i}"),
                a,
                b,
                point,
                normal,
                mu: None,
            });
            truth_here.push(f);
        }
        for p in 0..2 {
            let mut grain = Grain::new((p + 1).to_string(), x[p], volume, stress[p]);
            grain.mass = Some(mass);
            grain.radius = Some(radius);
            scene.grains.push(grain);
        }
        frames.push(scene);
        truth.push(truth_here);
        // Velocity Verlet to the next frame (sphere 1 held on the floor).
        for s in 0..steps {
            let t = t + s as f64 * h;
            let acc = |t: f64, x: &[Vec3; 2]| {
                let (_, floor, on1) = forces(t, x);
                let mut a = [[0.0; 3]; 2];
                for k in 0..3 {
                    a[0][k] = (floor[k] + on1[k]) / mass;
                    a[1][k] = -on1[k] / mass;
                }
                a[0][2] -= g;
                a[1][2] -= g;
                a
            };
            let a0 = acc(t, &x);
            for p in 0..2 {
                for k in 0..3 {
                    x[p][k] += h * v[p][k] + 0.5 * h * h * a0[p][k];
                }
            }
            let a1 = acc(t + h, &x);
            for p in 0..2 {
                for k in 0..3 {
                    v[p][k] += 0.5 * h * (a0[p][k] + a1[p][k]);
                }
            }
        }
    }
    (frames, truth)
}

#[test]
fn exact_tracks_recover_the_forces_in_2d_and_3d() {
    // Noise-free tracks and stresses: only the integrator (trapezoidal in
    // the sampled forces, against the finer steps of the data) and the prior
    // differ.
    let run = impact(2);
    let sphere_fps = 10_000.0;
    let (spheres, sphere_forces) = two_spheres_3d(sphere_fps);
    for (dim, frames, truth, fps) in [
        (2, &run.frames, &run.forces, FPS),
        (3, &spheres, &sphere_forces, sphere_fps),
    ] {
        let known: Vec<Vec<Option<Vec3>>> = truth
            .iter()
            .map(|f| f.iter().map(|&x| Some(x)).collect())
            .collect();
        let mut fit = TimeFitOptions::new(fps);
        fit.stress_sd = 0.01;
        fit.roughness = Some(ROUGHNESS_FACTOR * estimate_roughness(frames, &known).unwrap());
        let out = infer_time_fit(frames, &dynamic(), &fit, None).unwrap();
        let e = overall(truth, &out.forces);
        eprintln!("{dim}D exact tracks: relerr {e:.2e}\n{}", out.report);
        assert!(e <= 0.01, "{dim}D: relerr {e}");
        assert!(!out.report.roughness_estimated);
        // The noise-free 3D tracks (σ_x at its floor, 1e-7 m) go through the
        // tenfold loosening on the kept analysis; its answer is the one scored.
        let loosened = out
            .report
            .warnings
            .iter()
            .any(|w| w.contains("position sd raised"));
        assert_eq!(loosened, dim == 3, "{}", out.report);
    }
}

#[test]
fn contact_orientation_may_change_between_frames() {
    // Storing a contact as (b, a) with the opposite normal in some frames
    // describes the same physics: the fit follows the pair, not the order.
    let run = impact(2);
    let mut fit = TimeFitOptions::new(FPS);
    fit.roughness = Some(200.0);
    let reference = infer_time_fit(&run.frames, &dynamic(), &fit, None).unwrap();
    let mut swapped = run.frames.clone();
    let mut flipped = Vec::new();
    for (k, frame) in swapped.iter_mut().enumerate().filter(|(k, _)| k % 2 == 1) {
        for (i, c) in frame.contacts.iter_mut().enumerate() {
            if let Body::Grain(b) = c.b {
                (c.a, c.b) = (b, Body::Grain(c.a));
                c.normal = [-c.normal[0], -c.normal[1], -c.normal[2]];
                flipped.push((k, i));
            }
        }
    }
    assert!(!flipped.is_empty());
    let out = infer_time_fit(&swapped, &dynamic(), &fit, None).unwrap();
    for (k, (a, b)) in reference.forces.iter().zip(&out.forces).enumerate() {
        for (i, (fa, fb)) in a.iter().zip(b).enumerate() {
            let (fa, fb) = (fa.unwrap(), fb.unwrap());
            let sign = if flipped.contains(&(k, i)) { -1.0 } else { 1.0 };
            let gap = (fa[0] - sign * fb[0]).hypot(fa[1] - sign * fb[1]);
            assert!(
                gap <= 1e-6 * (1.0 + fa[0].hypot(fa[1])),
                "frame {k} contact {i}: {fa:?} vs {fb:?}"
            );
        }
    }
}

#[test]
fn bad_requests_are_clear_errors() {
    let run = impact(2);
    let fit = TimeFitOptions {
        roughness: Some(100.0),
        ..TimeFitOptions::new(FPS)
    };
    let err = |frames: &[Scene], opts: &InferOptions, fit: &TimeFitOptions| {
        infer_time_fit(frames, opts, fit, None)
            .unwrap_err()
            .to_string()
    };
    let e = err(&run.frames[..2], &dynamic(), &fit);
    assert!(e.contains("at least 3 frames"), "{e}");
    let e = err(
        &run.frames,
        &dynamic(),
        &TimeFitOptions {
            stress_sd: 0.0,
            ..fit
        },
    );
    assert!(e.contains("`stress_sd`"), "{e}");
    let e = err(
        &run.frames,
        &dynamic(),
        &TimeFitOptions {
            roughness: None,
            ..fit
        },
    );
    assert!(e.contains("`roughness`"), "{e}");
    let e = err(
        &run.frames,
        &dynamic(),
        &TimeFitOptions {
            roughness: Some(-1.0),
            ..fit
        },
    );
    assert!(e.contains("roughness"), "{e}");
    let e = err(&run.frames, &dynamic(), &TimeFitOptions { fps: 0.0, ..fit });
    assert!(e.contains("frame rate"), "{e}");
    let pyramid = InferOptions {
        cone: ConeModel::Pyramid(8),
        ..dynamic()
    };
    let e = err(&run.frames, &pyramid, &fit);
    assert!(e.contains("exact cones"), "{e}");
    // A loaded grain without mass cannot be integrated: named, not a panic.
    let mut massless = run.frames.clone();
    let id = massless[0].grains[2].id.clone();
    for frame in &mut massless {
        frame.grains[2].mass = None;
    }
    let e = err(&massless, &dynamic(), &fit);
    assert!(
        e.contains(&format!("grain {id}")) && e.contains("mass"),
        "{e}"
    );
}

#[test]
fn cli_joint_time_fit() {
    let case = common::noisy_impact_on_disk(4);
    let (run, dir) = (&case.run, &case.dir);
    let (forces, report) = (dir.path().join("f.csv"), dir.path().join("r.json"));
    let infer = |extra: &[&str]| {
        let mut args = vec!["--time-fit", "joint", "-o", forces.to_str().unwrap()];
        args.extend(["--report", report.to_str().unwrap()]);
        args.extend(extra);
        case.infer_from_tracks(&args)
    };
    let out = infer(&["--method", "dynamic"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(stderr.contains("time fit: 141 frames"), "{stderr}");
    let written = grainforce::scene::read_forces(&forces).unwrap();
    let mut inferred: Vec<Vec<Option<Vec3>>> = run
        .frames
        .iter()
        .map(|f| vec![None; f.contacts.len()])
        .collect();
    for row in &written.rows {
        let k = row.frame.unwrap() as usize;
        let i = run.frames[k]
            .contacts
            .iter()
            .position(|c| c.id == row.contact)
            .unwrap();
        inferred[k][i] = Some(row.force);
    }
    let e = overall(&run.forces, &inferred);
    assert!(e <= 0.03, "relerr {e}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(json["time_fit"]["frames"], 141);
    assert_eq!(json["frame_by_frame"].as_array().unwrap().len(), 141);
    // Only with --method dynamic; nothing written on refusal.
    std::fs::remove_file(&forces).unwrap();
    std::fs::remove_file(&report).unwrap();
    for (extra, message) in [
        (&["--method", "qs"][..], "--method dynamic"),
        (&["--method", "dynamic", "--roughness", "-1"], "--roughness"),
        (&["--method", "dynamic", "--stress-sd", "0"], "--stress-sd"),
        (
            &["--method", "dynamic", "--uncertainty", "3"],
            "--uncertainty",
        ),
    ] {
        let out = infer(extra);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && stderr.contains(message),
            "{extra:?}: {stderr}"
        );
        assert!(!forces.exists() && !report.exists());
    }
}
