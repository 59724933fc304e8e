//! Metrics on hand-made cases whose answers are known in closed form.

use grainforce::report::metrics::{self, relative_error, score, score_without_scene, Score};
use grainforce::scene::{self, Body, Contact, Grain, Scene, Vec3, Wall};
use std::path::Path;

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * b.abs().max(1.0)
}

/// A row of `n` touching unit-radius disks along x, one contact between each
/// neighbour pair (normal +x), friction μ = 0.5 scene-wide.
fn row_scene(n: usize) -> Scene {
    let mut s = Scene::new(2);
    for i in 0..n {
        s.grains.push(Grain::new(
            format!("g{i}"),
            [2.0 * i as f64, 0.0, 0.0],
            std::f64::consts::PI,
            [0.0; 6],
        ));
    }
    for i in 0..n - 1 {
        s.contacts.push(Contact {
            id: format!("c{i}"),
            a: i,
            b: Body::Grain(i + 1),
            point: [2.0 * i as f64 + 1.0, 0.0, 0.0],
            normal: [1.0, 0.0, 0.0],
            mu: None,
        });
    }
    s.settings.mu = Some(0.5);
    s
}

/// Compressive forces (n·f < 0) with some tangential part.
fn truth_forces(n: usize) -> Vec<Vec3> {
    (0..n)
        .map(|i| [-(10.0 + i as f64), 1.0 + 0.5 * i as f64, 0.0])
        .collect()
}

#[test]
fn scaled_truth_gives_the_scale_as_relative_error_in_every_part() {
    let s = row_scene(5);
    let truth = truth_forces(4);
    let inferred: Vec<Vec3> = truth.iter().map(|f| f.map(|x| 1.1 * x)).collect();
    assert!(close(relative_error(&truth, &inferred), 0.1, 1e-12));
    let sc = score(&s, &truth, &inferred).unwrap();
    assert!(close(sc.relerr(), 0.1, 1e-12), "{}", sc.relerr());
    assert!(close(sc.normal.unwrap().relative, 0.1, 1e-12));
    assert!(close(sc.tangential.unwrap().relative, 0.1, 1e-12));
    // Macroscopic stress is linear in the forces.
    let (si, st) = (sc.stress_inferred.unwrap(), sc.stress_truth.unwrap());
    assert!(close(si[0], 1.1 * st[0], 1e-12));
    assert!(
        st[0] < 0.0,
        "a compressed row must have σ_xx < 0 (tension positive)"
    );
}

#[test]
fn a_purely_tangential_error_shows_only_in_the_tangential_part() {
    let s = row_scene(3);
    let truth = truth_forces(2);
    // Change only the y component: tangential to normals along x.
    let mut inferred = truth.clone();
    inferred[0][1] += 0.3;
    inferred[1][1] -= 0.4;
    let sc = score(&s, &truth, &inferred).unwrap();
    let normal = sc.normal.unwrap();
    let tangential = sc.tangential.unwrap();
    assert_eq!(normal.absolute, 0.0);
    assert!(close(tangential.absolute, 0.5, 1e-12));
    let t_norm = (1.0f64 + 1.5 * 1.5).sqrt();
    assert!(close(tangential.relative, 0.5 / t_norm, 1e-12));
    let all = (10.0f64 * 10.0 + 1.0 + 11.0 * 11.0 + 1.5 * 1.5).sqrt();
    assert!(close(sc.relerr(), 0.5 / all, 1e-12));
}

#[test]
fn coulomb_violation_is_measured_against_the_mean_force() {
    let mut s = row_scene(3);
    // Contact c0: f_n = 10, |f_t| = 7 with μ = 0.5 → excess 2.
    // Contact c1 has its own μ = 0.8: f_n = 10, |f_t| = 6 → within the cone.
    s.contacts[1].mu = Some(0.8);
    let inferred = vec![[-10.0, 7.0, 0.0], [-10.0, -6.0, 0.0]];
    let sc = score(&s, &inferred, &inferred).unwrap();
    let mean = ((100.0f64 + 49.0).sqrt() + (100.0f64 + 36.0).sqrt()) / 2.0;
    let c = sc.coulomb.unwrap();
    assert!(close(c.relative, 2.0 / mean, 1e-12), "{}", c.relative);
    assert_eq!(c.contact.as_deref(), Some("c0"));
    assert_eq!(c.checked, 2);

    // Without any μ nothing is checked.
    s.settings.mu = None;
    s.contacts[1].mu = None;
    assert!(score(&s, &inferred, &inferred).unwrap().coulomb.is_none());
}

#[test]
fn tensile_contacts_are_counted() {
    let s = row_scene(5);
    let mut inferred = truth_forces(4);
    inferred[2][0] = 3.0; // n·f > 0: pulls
    inferred[3][0] = 1e-12; // within the tolerance: not tensile
    let sc = score(&s, &truth_forces(4), &inferred).unwrap();
    assert_eq!(sc.tensile_contacts, Some(1));
    assert!(close(sc.tensile_fraction().unwrap(), 0.25, 1e-15));
}

#[test]
fn wall_mismatch_from_a_walls_csv() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::write(
        d.join("grains.csv"),
        "id,x,y,volume,s_xx,s_yy,s_xy\n1,0,1,3.14159,0,0,0\n2,2,1,3.14159,0,0,0\n",
    )
    .unwrap();
    std::fs::write(
        d.join("contacts.csv"),
        "id,a,b,x,y,n_x,n_y\nk1,1,floor,0,0,0,-1\nk2,2,floor,2,0,0,-1\nk3,1,2,1,1,1,0\n",
    )
    .unwrap();
    std::fs::write(d.join("walls.csv"), "wall,f_x,f_y\nfloor,0,100\n").unwrap();
    let s = scene::read_scene(d).unwrap();
    let truth = vec![[0.0, 50.0, 0.0], [0.0, 50.0, 0.0], [-1.0, 0.0, 0.0]];
    let inferred = vec![[0.0, 40.0, 0.0], [3.0, 50.0, 0.0], [-1.0, 0.0, 0.0]];
    let sc = score(&s, &truth, &inferred).unwrap();
    assert_eq!(sc.walls.len(), 1);
    let w = &sc.walls[0];
    assert_eq!(w.wall, "floor");
    assert_eq!(w.measured, Some([0.0, 100.0, 0.0]));
    assert_eq!(w.inferred, [3.0, 90.0, 0.0]);
    assert_eq!(w.truth, [0.0, 100.0, 0.0]);
    assert!(close(w.absolute.unwrap(), 109f64.sqrt(), 1e-12)); // √(3² + 10²)
    assert!(close(w.relative.unwrap(), 109f64.sqrt() / 100.0, 1e-12));

    // An unmeasured wall is listed without a mismatch.
    let mut unmeasured = s.clone();
    unmeasured.walls = vec![Wall {
        name: "floor".into(),
        measured_force: None,
    }];
    let sc = score(&unmeasured, &truth, &inferred).unwrap();
    assert_eq!(sc.walls[0].absolute, None);
    assert_eq!(sc.walls[0].inferred, [3.0, 90.0, 0.0]);
}

#[test]
fn zero_truth_gives_documented_values_not_nan() {
    let zero = vec![[0.0; 3]; 3];
    let some = vec![[0.0, 1.0, 0.0]; 3];
    assert_eq!(relative_error(&zero, &zero), 0.0);
    assert_eq!(relative_error(&zero, &some), f64::INFINITY);
    let s = row_scene(4);
    let sc = score(&s, &zero, &some).unwrap();
    assert_eq!(sc.relerr(), f64::INFINITY);
    assert_eq!(sc.error.truth_norm, 0.0);
    assert!(close(sc.error.absolute, 3f64.sqrt(), 1e-12));
    // All-zero inferred forces: no NaN from the mean force in Coulomb or tension.
    let sc = score(&s, &some, &zero).unwrap();
    assert_eq!(sc.coulomb.as_ref().unwrap().relative, 0.0);
    assert_eq!(sc.tensile_contacts, Some(0));
    assert!(close(sc.relerr(), 1.0, 1e-12));
    // Empty scene.
    let empty = Scene::new(2);
    let sc = score(&empty, &[], &[]).unwrap();
    assert_eq!(sc.relerr(), 0.0);
    assert_eq!(sc.tensile_fraction(), Some(0.0));
}

#[test]
fn mismatched_lengths_name_the_contact_without_a_force() {
    let s = row_scene(4);
    let truth = truth_forces(3);
    let err = score(&s, &truth, &truth[..2]).unwrap_err().to_string();
    assert!(err.contains("`c2`"), "{err}");
    assert!(err.contains("inferred"), "{err}");
    let err = score(&s, &truth_forces(4), &truth).unwrap_err().to_string();
    assert!(err.contains("more forces than contacts"), "{err}");
}

#[test]
fn overall_score_stacks_frames() {
    let a = score_without_scene(Some(0), &[[3.0, 0.0, 0.0]], &[[3.0, 4.0, 0.0]]);
    let b = score_without_scene(Some(1), &[[0.0, 4.0, 0.0]], &[[0.0, 1.0, 0.0]]);
    let all = Score::overall(&[a, b]);
    // |error| = √(16 + 9) = 5, |truth| = √(9 + 16) = 5.
    assert!(close(all.relerr(), 1.0, 1e-12));
    assert_eq!(all.contacts, 2);
    assert!(all.normal.is_none() && all.tensile_contacts.is_none());
}

#[test]
fn pairing_names_the_missing_contact_and_the_file() {
    let row = |c: &str, frame, f: Vec3| scene::ForceRow {
        contact: c.into(),
        frame,
        force: f,
        sd: None,
    };
    let truth = scene::Forces {
        dim: 2,
        rows: vec![
            row("a", Some(1), [1.0, 0.0, 0.0]),
            row("b", Some(1), [2.0, 0.0, 0.0]),
        ],
    };
    let inferred = scene::Forces {
        dim: 2,
        rows: vec![
            row("b", Some(1), [2.5, 0.0, 0.0]),
            row("a", Some(1), [1.0, 0.0, 0.0]),
        ],
    };
    let (tp, ip) = (Path::new("truth.csv"), Path::new("inferred.csv"));
    let paired = metrics::pair_forces(&truth, tp, &inferred, ip).unwrap();
    assert_eq!(paired.len(), 1);
    assert_eq!(paired[0].contacts, vec!["a", "b"]);
    assert_eq!(paired[0].inferred[1], [2.5, 0.0, 0.0]);

    let mut short = inferred.clone();
    short.rows.remove(0);
    let err = metrics::pair_forces(&truth, tp, &short, ip)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("contact `b` of frame 1") && err.contains("inferred.csv"),
        "{err}"
    );

    let mut extra = inferred.clone();
    extra.rows.push(row("z", Some(1), [0.0; 3]));
    let err = metrics::pair_forces(&truth, tp, &extra, ip)
        .unwrap_err()
        .to_string();
    assert!(err.contains("`z`") && err.starts_with("truth.csv"), "{err}");

    let mut other_frame = inferred.clone();
    other_frame.rows[0].frame = Some(2);
    assert!(metrics::pair_forces(&truth, tp, &other_frame, ip).is_err());
}
