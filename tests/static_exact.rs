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
