//! `grainforce bench --scenes`: the speed/accuracy matrix on packings the user
//! gives (a sheared DEM box), with `-tolX` method variants and each stop's
//! distance to the tightest solve.

use grainforce::bench::{distances_to_tightest, preset, read_csv, split_tolerance};
mod common;
use common::run as grainforce;
use grainforce::scene::Vec3;
use std::path::{Path, PathBuf};

fn sheared_fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/regression/box3d_sheared")
}

#[test]
fn a_tolerance_suffix_sets_the_tolerance_and_nothing_else() {
    assert_eq!(split_tolerance("qs-tol1e-4"), Some(("qs", 1e-4)));
    assert_eq!(
        split_tolerance("tikhonov-coarse-tol0.01"),
        Some(("tikhonov-coarse", 0.01))
    );
    assert_eq!(split_tolerance("qs"), None);
    assert_eq!(
        split_tolerance("qs-tol2"),
        None,
        "a tolerance must lie in (0, 1)"
    );
    assert_eq!(split_tolerance("qs-tolx"), None);

    let tight = preset("qs-tol1e-6", 0.0).unwrap();
    let plain = preset("qs", 0.0).unwrap();
    assert_eq!(tight.tolerance, Some(1e-6));
    assert_eq!(plain.tolerance, None);
    assert_eq!(tight.solver, plain.solver, "the cascade is kept");
    assert_eq!(tight.method, plain.method);
    assert!(preset("qs-tol3", 0.0).is_err());
    let relative = preset("qs-tol1e-3-relative-nocheck", 0.0).unwrap();
    assert_eq!(relative.tolerance, Some(1e-3));
    assert_eq!(relative.uniqueness_limit, 0);
}

#[test]
fn distances_are_to_the_same_methods_tightest_stop() {
    let f = |x: f64| vec![[x, 1.0, 0.0], [0.0, 2.0, 0.0]];
    let (tight, loose, default, other) = (f(0.0), f(0.3), f(0.1), f(5.0));
    let cases: Vec<(&str, Option<&[Vec3]>)> = vec![
        ("qs", Some(&default)),
        ("qs-tol1e-2", Some(&loose)),
        ("qs-tol1e-8", Some(&tight)),
        ("ls", Some(&other)),
        ("tikhonov-tol1e-4", None),
    ];
    let d = distances_to_tightest(&cases);
    let norm = 5f64.sqrt();
    assert!((d[0].unwrap() - 0.1 / norm).abs() < 1e-15);
    assert!((d[1].unwrap() - 0.3 / norm).abs() < 1e-15);
    assert_eq!(d[2], Some(0.0));
    assert_eq!(d[3], None, "ls ran at no tolerance variant");
    assert_eq!(d[4], None, "a failed case has no distance");
}

#[test]
fn bench_on_a_given_sheared_packing_orders_its_stops() {
    let out = tempfile::tempdir().unwrap();
    let csv = out.path().join("cases.csv");
    let png = out.path().join("bench.png");
    let run = grainforce(&[
        "bench",
        "--quiet",
        "--scenes",
        sheared_fixture().to_str().unwrap(),
        "--noise",
        "stress",
        "--methods",
        "qs,qs-tol1e-2,qs-tol1e-6",
        "--csv",
        csv.to_str().unwrap(),
        "--plot",
        png.to_str().unwrap(),
    ]);
    assert!(run.0, "{}", run.1);
    let cases = read_csv(&csv).unwrap();
    assert_eq!(cases.len(), 3);
    let case = |m: &str| cases.iter().find(|c| c.method == m).unwrap();
    for c in &cases {
        assert!(c.ok(), "{:?}", c.error);
        assert_eq!((c.dim, c.grains), (3, 1000));
        // The packing's stresses carry eq. 2.16 noise: the answers lie about
        // 0.15 from the DEM's forces whatever the stop.
        assert!(
            (0.05..0.4).contains(&c.relerr),
            "{}: {}",
            c.method,
            c.relerr
        );
    }
    let tight = case("qs-tol1e-6").distance.unwrap();
    let default = case("qs").distance.unwrap();
    let loose = case("qs-tol1e-2").distance.unwrap();
    assert_eq!(tight, 0.0);
    assert!(
        loose > default && default > 0.0,
        "1e-2 stops farther from the optimum ({loose:.1e}) than the data's accuracy ({default:.1e})"
    );
    assert!(loose < 1e-2, "{loose}");
    // Three digits of relerr do not depend on the stop.
    assert!((case("qs").relerr - case("qs-tol1e-6").relerr).abs() < 5e-4);
    assert!(png.is_file());
    assert!(out.path().join("bench-distance.png").is_file());
}

#[test]
fn a_given_scene_without_exact_forces_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    for f in ["grains.csv", "contacts.csv", "walls.csv", "scene.json"] {
        let from = sheared_fixture().join(f);
        if from.is_file() {
            std::fs::copy(&from, dir.path().join(f)).unwrap();
        }
    }
    let run = grainforce(&[
        "bench",
        "--scenes",
        dir.path().to_str().unwrap(),
        "--methods",
        "ls",
    ]);
    let (ok, err) = run;
    assert!(!ok);
    assert!(
        err.contains("forces.csv") && err.contains(&*dir.path().to_string_lossy()),
        "{err}"
    );
    let both = grainforce(&[
        "bench",
        "--scenes",
        sheared_fixture().to_str().unwrap(),
        "--sizes",
        "1e3",
    ]);
    assert!(!both.0, "--scenes replaces --sizes");
    assert!(Path::new(&sheared_fixture()).join("forces.csv").is_file());
}

#[test]
fn a_failed_case_keeps_its_error_through_json_and_csv() {
    let failed = grainforce::bench::CaseResult::failed(3, 10, "stress", "qs", 1.5, "no".into());
    let json = serde_json::to_string(&failed).unwrap();
    let back: grainforce::bench::CaseResult = serde_json::from_str(&json).unwrap();
    assert!(back.relerr.is_nan() && back.coulomb_violation.is_nan());
    assert_eq!(back.error.as_deref(), Some("no"));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cases.csv");
    std::fs::write(&path, grainforce::bench::csv(&[failed]).unwrap()).unwrap();
    let rows = read_csv(&path).unwrap();
    assert!(rows[0].relerr.is_nan());
    assert_eq!(rows[0].error.as_deref(), Some("no"));
}
