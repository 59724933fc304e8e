//! Exact data → exact forces: hand-built 2D and 3D scenes recovered by `qs`.

mod common;
use common::*;
use grainforce::infer::{infer, InferOptions, Method};
use grainforce::scene::Scene;

fn recover(scene: &Scene, method: Method) -> (Vec<[f64; 3]>, grainforce::infer::InferenceReport) {
    let opts = InferOptions {
        method,
        ..InferOptions::default()
    };
    let r = infer(scene, &opts).expect("inference");
    (r.forces_or_zero(), r.report)
}

#[test]
fn two_disks_between_walls() {
    let mut s = Scene::new(2);
    let r = 0.01;
    s.grains.push(grain("1", [0.0, r, 0.0], r, 2));
    s.grains.push(grain("2", [0.0, 3.0 * r, 0.0], r, 2));
    wall(&mut s, 0, "bottom", [0.0, -1.0, 0.0], Some(0.5));
    touch(&mut s, 0, 1, Some(0.5));
    wall(&mut s, 1, "top", [0.0, 1.0, 0.0], Some(0.5));
    let p = 250.0;
    let truth = vec![[0.0, p, 0.0], [0.0, -p, 0.0], [0.0, -p, 0.0]];
    set_stresses(&mut s, &truth);
    // Compressed grains have negative (tension-positive) vertical stress.
    assert!(s.grains[0].stress[1] < 0.0);
    let (f, report) = recover(&s, Method::Qs);
    let e = relerr(&truth, &f);
    assert!(e <= 1e-8, "relerr {e}\n{report}");
}

#[test]
fn triangular_packing_frictionless_walls() {
    let (s, truth) = lattice_2d(4, 3, 0.5);
    let (f, report) = recover(&s, Method::Qs);
    let e = relerr(&truth, &f);
    assert!(e <= 1e-8, "relerr {e}\n{report}");
}

#[test]
fn simple_cubic_stack_3d() {
    let (s, truth) = cubic_stack(0.5);
    assert_eq!(s.contacts.len(), 12 + 24);
    let (f, report) = recover(&s, Method::Qs);
    let e = relerr(&truth, &f);
    eprintln!("3D cubic stack: relerr {e:.2e}");
    assert!(e <= 1e-8, "relerr {e}\n{report}");
}

#[test]
fn flipping_a_contact_negates_its_force() {
    let (s, truth) = lattice_2d(3, 3, 0.5);
    let mut flipped = s.clone();
    let k = flipped
        .contacts
        .iter()
        .position(|c| matches!(c.b, grainforce::scene::Body::Grain(_)))
        .unwrap();
    let c = &mut flipped.contacts[k];
    let grainforce::scene::Body::Grain(b) = c.b else {
        unreachable!()
    };
    c.b = grainforce::scene::Body::Grain(c.a);
    c.a = b;
    c.normal = [-c.normal[0], -c.normal[1], -c.normal[2]];
    let (f, _) = recover(&flipped, Method::Qs);
    for k2 in 0..3 {
        assert!((f[k][k2] + truth[k][k2]).abs() <= 1e-8 * 100.0);
    }
    // Compressive: the force on `a` points against the normal from a to b.
    let n = flipped.contacts[k].normal;
    assert!(grainforce::scene::dot(f[k], n) < 0.0);
}

#[test]
fn unknowns_match_what_the_scene_requires() {
    let (s, _) = lattice_2d(3, 3, 0.5);
    let r = infer(&s, &InferOptions::default()).unwrap();
    let walls = s.contacts.iter().filter(|c| c.mu == Some(0.0)).count();
    let grain_contacts = s.contacts.len() - walls;
    // Frictionless wall contacts have one unknown, frictional 2D contacts two.
    assert_eq!(r.report.unknowns, walls + 2 * grain_contacts);
}
