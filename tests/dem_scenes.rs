//! Every scene the DEM writes reads back and is self-consistent: stresses
//! equal Σ sym(r ⊗ f), quasi-static grains balance to the gate, dynamic
//! frames balance Σ f = m (a − g) and Σ r × f = I α to round-off; runs are
//! reproducible by seed.

use grainforce::dem::{self, balance_residuals, stress_residual, DemConfig, Preset};
use grainforce::scene::{self, Body};

fn read_back(run: &dem::DemRun) -> (tempfile::TempDir, Vec<scene::Scene>, Vec<Vec<[f64; 3]>>) {
    let dir = tempfile::tempdir().unwrap();
    dem::write_run(dir.path(), run).unwrap();
    let frames = scene::read_sequence(dir.path()).unwrap();
    let truth = scene::read_forces(&dir.path().join("forces.csv")).unwrap();
    let forces = frames
        .iter()
        .map(|s| truth.for_scene(s, &dir.path().join("forces.csv")).unwrap())
        .collect();
    (dir, frames, forces)
}

/// Contract checks shared by all scenes.
fn check_contract(s: &scene::Scene, forces: &[[f64; 3]]) {
    for (c, f) in s.contacts.iter().zip(forces) {
        // Cohesionless and within the Coulomb cone.
        let fn_ = scene::dot(*f, c.normal);
        assert!(fn_ <= 1e-12 * scene::norm(*f), "contact {} pulls", c.id);
        let ft = scene::norm([
            f[0] - fn_ * c.normal[0],
            f[1] - fn_ * c.normal[1],
            f[2] - fn_ * c.normal[2],
        ]);
        let mu = c.mu.expect("every contact has mu");
        assert!(
            ft <= mu * (-fn_) * (1.0 + 1e-9) + 1e-12,
            "contact {} outside its cone",
            c.id
        );
        // The contact point lies on the line of centres / the normal from the centroid.
        let a = &s.grains[c.a];
        let r = scene::sub(c.point, a.position);
        let cr = scene::cross(r, c.normal);
        assert!(
            scene::norm(cr) < 1e-9 * scene::norm(r),
            "contact {} point off the line of centres",
            c.id
        );
        assert!(scene::dot(r, c.normal) > 0.0);
        if let Body::Grain(b) = c.b {
            let d = scene::sub(s.grains[b].position, a.position);
            assert!(scene::norm(scene::cross(d, c.normal)) < 1e-9 * scene::norm(d));
        }
    }
    assert!(stress_residual(s, forces) < 1e-12, "V σ ≠ Σ sym(r ⊗ f)");
}

fn oedometer(dim: usize, seed: u64) -> dem::DemRun {
    let c = DemConfig::preset(Preset::Oedometer, dim)
        .seed(seed)
        .gate(1e-10)
        .grains(if dim == 2 { 58 } else { 40 });
    dem::simulate(&c).unwrap()
}

#[test]
fn oedometer_2d_and_3d_pass_the_gate_and_read_back_consistent() {
    for dim in [2, 3] {
        let run = oedometer(dim, 1);
        let r = &run.report;
        eprintln!(
            "oedometer {dim}D: {} contacts, {} steps, unbalanced {:.2e}, moment {:.2e}, max residual {:.2e}/{:.2e}, {:.1} s",
            r.contacts, r.steps, r.unbalanced_ratio, r.moment_ratio, r.max_momentum_residual, r.max_moment_residual, r.seconds
        );
        assert!(r.passed, "{dim}D gate not reached: {r:?}");
        assert!(r.unbalanced_ratio < 1e-10 && r.moment_ratio < 1e-10);
        let (_dir, frames, forces) = read_back(&run);
        assert_eq!(frames.len(), 1);
        let s = &frames[0];
        assert_eq!(s.dim, dim);
        assert_eq!(s.contacts.len(), r.contacts);
        // Quasi-static frames carry each grain's residual acceleration, so
        // the files balance to round-off whatever the gate.
        assert!(s.frame.is_none() && s.has_accelerations());
        check_contract(s, &forces[0]);
        let b = balance_residuals(s, &forces[0]);
        assert!(b.max_force < 1e-12 && b.max_moment < 1e-12, "{b:?}");
        // Without them: Σ f = 0 and Σ r × f = 0 per grain, to the gate.
        let mut at_rest = s.clone();
        for g in &mut at_rest.grains {
            g.acceleration = None;
            g.angular_acceleration = None;
        }
        let b = balance_residuals(&at_rest, &forces[0]);
        assert!(b.mean_force < 1e-10 && b.mean_moment < 1e-10, "{b:?}");
        assert!(b.max_force < 1e-8 && b.max_moment < 1e-8, "{b:?}");
        // The top wall carries the target stress (within the servo tolerance);
        // the walls are frictionless and their loads are what the contacts carry.
        let top = s.wall_index("top").unwrap();
        let load: f64 = s
            .contacts
            .iter()
            .zip(&forces[0])
            .filter(|(c, _)| c.b == Body::Wall(top))
            .map(|(_, f)| f[1])
            .sum();
        let measured = s.walls[top].measured_force.unwrap();
        assert!((load - measured[1]).abs() < 1e-9 * load.abs());
        let stress = r.wall_stress.iter().find(|(n, _)| n == "top").unwrap().1;
        assert!(
            (stress - r.target_stress).abs() < 0.05 * r.target_stress,
            "top stress {stress}"
        );
        for (c, f) in s.contacts.iter().zip(&forces[0]) {
            if let Body::Wall(_) = c.b {
                assert_eq!(c.mu, Some(0.0));
                assert!(scene::norm(scene::cross(*f, c.normal)) < 1e-12 * scene::norm(*f));
            }
        }
        // Ids as the contract asks.
        assert_eq!(s.grains[0].id, "0");
        assert!(s
            .contacts
            .iter()
            .enumerate()
            .all(|(k, c)| c.id == format!("c{k}")));
        assert!(s
            .grains
            .iter()
            .all(|g| g.mass.is_some() && g.radius.is_some() && g.inertia.is_some()));
        // Compressed grains: negative mean stress.
        let mean: f64 = s.grains.iter().map(|g| g.stress[0] + g.stress[1]).sum();
        assert!(mean < 0.0);
    }
}

#[test]
fn same_seed_same_scene_other_seed_other_scene() {
    let a = oedometer(2, 5);
    let b = oedometer(2, 5);
    assert_eq!(a.frames, b.frames);
    assert_eq!(a.forces, b.forces);
    let c = oedometer(2, 6);
    assert_ne!(
        a.frames[0].grains[0].position,
        c.frames[0].grains[0].position
    );
}

#[test]
fn box_2d_is_isotropically_loaded_and_balanced() {
    let c = DemConfig::preset(Preset::Box, 2).grains(120).gate(1e-9);
    let run = dem::simulate(&c).unwrap();
    assert!(run.report.passed, "{:?}", run.report);
    let (_dir, frames, forces) = read_back(&run);
    check_contract(&frames[0], &forces[0]);
    let b = balance_residuals(&frames[0], &forces[0]);
    assert!(b.mean_force < 1e-9, "{b:?}");
    for (name, stress) in &run.report.wall_stress {
        assert!(
            (stress - c.pressure).abs() < 0.05 * c.pressure,
            "wall {name} at {stress} Pa for {} Pa",
            c.pressure
        );
    }
}

fn check_dynamic(run: &dem::DemRun, gravity: bool) {
    let (_dir, frames, forces) = read_back(run);
    assert_eq!(frames.len(), run.frames.len());
    assert!(frames.len() > 5);
    let mut busy = 0;
    for (k, (s, f)) in frames.iter().zip(&forces).enumerate() {
        assert_eq!(s.frame, Some(k as i64));
        assert!(s.has_accelerations());
        assert_eq!(s.gravity()[1] != 0.0, gravity);
        check_contract(s, f);
        if s.contacts.is_empty() {
            continue;
        }
        busy += 1;
        // Kinematic accelerations: Σ f = m (a − g) and Σ r × f = I α to round-off.
        let b = balance_residuals(s, f);
        assert!(
            b.max_force < 1e-9 && b.max_moment < 1e-9,
            "frame {k}: {b:?}"
        );
    }
    assert!(busy > 3);
    // Something actually happened: some grain accelerates far beyond gravity.
    let peak = frames
        .iter()
        .flat_map(|s| s.grains.iter())
        .map(|g| scene::norm(g.acceleration.unwrap()))
        .fold(0.0, f64::max);
    assert!(peak > 50.0, "peak acceleration {peak}");
}

#[test]
fn impact_frames_balance_momentum_to_round_off() {
    let c = DemConfig::preset(Preset::Impact, 2).duration(0.01);
    // The library reports progress through the callback, in order; the run is
    // the same as without one.
    let mut events = Vec::new();
    let run = dem::simulate_with_progress(&c, &mut |p| events.push(p.clone())).unwrap();
    assert!(matches!(
        events[0],
        dem::DemProgress::Built {
            grains: 6,
            dim: 2,
            ..
        }
    ));
    assert!(events[1..]
        .iter()
        .any(|e| matches!(e, dem::DemProgress::Relaxing { .. })));
    let frames: Vec<u64> = events
        .iter()
        .filter_map(|e| match e {
            dem::DemProgress::Frame { frame, total, .. } => Some(*frame).filter(|_| *total == 50),
            _ => None,
        })
        .collect();
    assert_eq!(frames, [20, 40]);
    assert_eq!(run.frames, dem::simulate(&c).unwrap().frames);
    assert_eq!(run.frames.len(), 51);
    assert!(run.report.max_momentum_residual < 1e-9);
    let impactor = run.frames[20].wall_index("impactor").unwrap();
    assert!(run.frames[20]
        .contacts
        .iter()
        .any(|c| c.b == Body::Wall(impactor)));
    check_dynamic(&run, true);
}

#[test]
fn bed_impact_small_frames_balance_momentum_to_round_off() {
    let c = DemConfig::preset(Preset::BedImpact, 2)
        .grains(60)
        .duration(0.004);
    let run = dem::simulate(&c).unwrap();
    assert!(run.report.passed, "{:?}", run.report);
    check_dynamic(&run, true);
}

#[test]
fn hertz_and_polydisperse_variants_run() {
    let mut c = DemConfig::preset(Preset::Oedometer, 2)
        .law(dem::ContactLaw::Hertz)
        .grains(30)
        .gate(1e-8);
    c.sizes = dem::SizeDistribution::InverseSquare {
        min: 1.5e-3,
        max: 4e-3,
    };
    let run = dem::simulate(&c).unwrap();
    assert!(run.report.passed, "{:?}", run.report);
    check_contract(&run.frames[0], &run.forces[0]);
    let radii: Vec<f64> = run.frames[0]
        .grains
        .iter()
        .map(|g| g.radius.unwrap())
        .collect();
    assert!(radii.iter().all(|&r| (1.5e-3..=4e-3).contains(&r)));
}

#[test]
fn invalid_configurations_are_errors() {
    let base = DemConfig::preset(Preset::Oedometer, 2);
    for bad in [
        base.clone().grains(0),
        base.clone().gate(0.0),
        base.clone().gate(1.5),
        base.clone().thickness(-1.0),
        DemConfig::preset(Preset::Oedometer, 4),
        DemConfig::preset(Preset::Impact, 3),
        DemConfig::preset(Preset::Impact, 2).frames_every(0),
    ] {
        assert!(dem::simulate(&bad).is_err());
    }
}
