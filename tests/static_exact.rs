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

/// A 2×2×2 simple-cubic stack of spheres in a box of six frictionless walls.
fn cubic_stack(mu: f64) -> (Scene, Vec<[f64; 3]>) {
    let mut s = Scene::new(3);
    let r = 0.0006;
    for k in 0..2 {
        for j in 0..2 {
            for i in 0..2 {
                let id = format!("{}", s.grains.len());
                s.grains.push(grain(
                    &id,
                    [
                        r + 2.0 * r * i as f64,
                        r + 2.0 * r * j as f64,
                        r + 2.0 * r * k as f64,
                    ],
                    r,
                    3,
                ));
            }
        }
    }
    for a in 0..8 {
        for b in a + 1..8 {
            let d = grainforce::scene::norm(grainforce::scene::sub(
                s.grains[a].position,
                s.grains[b].position,
            ));
            if d < 2.0 * r * 1.0001 {
                touch(&mut s, a, b, Some(mu));
            }
        }
    }
    let names = [
        ("left", 0, -1.0),
        ("right", 0, 1.0),
        ("bottom", 1, -1.0),
        ("top", 1, 1.0),
        ("back", 2, -1.0),
        ("front", 2, 1.0),
    ];
    for a in 0..8 {
        let p = s.grains[a].position;
        for &(name, axis, sign) in &names {
            let low = p[axis] < 1.5 * r;
            if (sign < 0.0) == low {
                let mut n = [0.0; 3];
                n[axis] = sign;
                wall(&mut s, a, name, n, Some(0.0));
            }
        }
    }
    let guess = compressive_guess(&s, 70.0, 0.2);
    let forces = equilibrate(&s, &guess);
    assert!(admissible(&s, &forces), "{:?}", admissibility(&s, &forces));
    set_stresses(&mut s, &forces);
    (s, forces)
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
