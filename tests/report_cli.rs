//! `grainforce score` and `grainforce plot` end to end, through the binary.

use std::path::Path;
use std::process::{Command, Output};

fn grainforce(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(args)
        .output()
        .expect("run grainforce")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The value of the mandatory last line `relerr=<value>`.
fn last_line_relerr(out: &Output) -> f64 {
    let stdout = text(&out.stdout);
    let last = stdout.lines().last().expect("some output");
    let value = last
        .strip_prefix("relerr=")
        .unwrap_or_else(|| panic!("last line is `{last}`"));
    value
        .parse()
        .unwrap_or_else(|_| panic!("`{value}` is not a number"))
}

fn write(dir: &Path, name: &str, content: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, content).unwrap();
    p.to_str().unwrap().to_owned()
}

/// Three disks in a row on a floor; walls.csv measures the floor.
fn scene_dir(dir: &Path) -> String {
    let d = dir.join("scene");
    std::fs::create_dir_all(&d).unwrap();
    write(
        &d,
        "grains.csv",
        "id,x,y,volume,s_xx,s_yy,s_xy\n1,0,1,3.14159,0,0,0\n2,2,1,3.14159,0,0,0\n3,4,1,3.14159,0,0,0\n",
    );
    write(
        &d,
        "contacts.csv",
        "id,a,b,x,y,n_x,n_y\nc1,1,2,1,1,1,0\nc2,2,3,3,1,1,0\nw1,2,floor,2,0,0,-1\n",
    );
    write(&d, "walls.csv", "wall,f_x,f_y\nfloor,0,10\n");
    write(&d, "scene.json", "{\"mu\": 0.5}\n");
    d.to_str().unwrap().to_owned()
}

#[test]
fn score_prints_relerr_last_and_checks_physics_with_a_scene() {
    let dir = tempfile::tempdir().unwrap();
    let truth = write(
        dir.path(),
        "truth.csv",
        "contact,f_x,f_y\nc1,-4,0\nc2,-2,1\nw1,0,10\n",
    );
    let inferred = write(
        dir.path(),
        "inferred.csv",
        "f_y,contact,f_x\n0,c1,-4.4\n1.1,c2,-2.2\n11,w1,0\n",
    );
    // Without a scene: the relative error only.
    let out = grainforce(&["score", &truth, &inferred]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!((last_line_relerr(&out) - 0.1).abs() < 1e-12);
    assert!(!text(&out.stdout).contains("tangential"));

    // With a scene and JSON.
    let scene = scene_dir(dir.path());
    let json = dir.path().join("score.json");
    let out = grainforce(&[
        "score",
        &truth,
        &inferred,
        "--scene",
        &scene,
        "--report",
        json.to_str().unwrap(),
    ]);
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!((last_line_relerr(&out) - 0.1).abs() < 1e-12);
    for expected in [
        "normal part",
        "tangential part",
        "Coulomb",
        "tensile contacts: 0 of 3",
        "floor",
        "macroscopic stress",
    ] {
        assert!(
            stdout.contains(expected),
            "missing `{expected}` in\n{stdout}"
        );
    }
    // Floor: measured 10, inferred 11 → 10 % mismatch.
    assert!(stdout.contains("10.0000% of measured"), "{stdout}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rel = report["overall"]["error"]["relative"].as_f64().unwrap();
    assert!((rel - 0.1).abs() < 1e-12);
    assert_eq!(report["overall"]["walls"][0]["wall"], "floor");
    // The old flag name still writes the same report, for old scripts.
    let old = dir.path().join("old.json");
    let out = grainforce(&[
        "score",
        &truth,
        &inferred,
        "--scene",
        &scene,
        "--json",
        old.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        std::fs::read_to_string(&old).unwrap(),
        std::fs::read_to_string(&json).unwrap()
    );
}

#[test]
fn score_names_a_missing_contact() {
    let dir = tempfile::tempdir().unwrap();
    let truth = write(
        dir.path(),
        "truth.csv",
        "contact,f_x,f_y\nc1,-4,0\nc2,-2,1\n",
    );
    let inferred = write(dir.path(), "inferred.csv", "contact,f_x,f_y\nc1,-4,0\n");
    let out = grainforce(&["score", &truth, &inferred]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(
        err.contains("`c2`") && err.contains("inferred.csv"),
        "{err}"
    );

    // Also when the scene has a contact that neither file covers.
    let scene = scene_dir(dir.path());
    let both = write(
        dir.path(),
        "both.csv",
        "contact,f_x,f_y\nc1,-4,0\nc2,-2,1\n",
    );
    let out = grainforce(&["score", &both, &both, "--scene", &scene]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("`w1`"), "{}", text(&out.stderr));
}

#[test]
fn score_refuses_an_all_zero_truth() {
    let dir = tempfile::tempdir().unwrap();
    let truth = write(dir.path(), "truth.csv", "contact,f_x,f_y\nc1,0,0\n");
    let inferred = write(dir.path(), "inferred.csv", "contact,f_x,f_y\nc1,1,0\n");
    let out = grainforce(&["score", &truth, &inferred]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("undefined"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn score_of_a_sequence_is_per_frame_and_overall() {
    let dir = tempfile::tempdir().unwrap();
    let truth = write(
        dir.path(),
        "truth.csv",
        "frame,contact,f_x,f_y\n0,c1,3,0\n1,c1,0,4\n",
    );
    let inferred = write(
        dir.path(),
        "inferred.csv",
        "frame,contact,f_x,f_y\n1,c1,0,1\n0,c1,3,4\n",
    );
    let out = grainforce(&["score", &truth, &inferred]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("all 2 frames together"), "{stdout}");
    // Frame 0: 4/3; frame 1: 3/4; overall √(16+9)/√(9+16) = 1.
    assert!(
        stdout.contains("1.3333e0") && stdout.contains("7.5000e-1"),
        "{stdout}"
    );
    assert!((last_line_relerr(&out) - 1.0).abs() < 1e-12);
}

fn png_size(path: &Path) -> (u32, u32) {
    let img = image::open(path).unwrap();
    (img.width(), img.height())
}

#[test]
fn plot_draws_forces_and_pareto_fronts() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene_dir(dir.path());
    let forces = write(
        dir.path(),
        "forces.csv",
        "contact,f_x,f_y\nc1,-4,0\nc2,-2,1\nw1,0,10\n",
    );
    let png = dir.path().join("chains.png");
    let out = grainforce(&[
        "plot",
        &scene,
        &forces,
        "-o",
        png.to_str().unwrap(),
        "--width",
        "400",
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(png_size(&png).0, 400);
    // "wrote …" is a status line on stderr; stdout is left for results.
    assert!(text(&out.stdout).is_empty(), "{}", text(&out.stdout));
    assert!(
        text(&out.stderr).starts_with("wrote "),
        "{}",
        text(&out.stderr)
    );

    let pareto = write(
        dir.path(),
        "pareto.csv",
        "lambda,stress_residual,momentum_residual,knee\n0.01,1,10,0\n0.1,2,3,1\n1,10,1,0\n",
    );
    let front = dir.path().join("front.png");
    let out = grainforce(&["plot", "--pareto", &pareto, "-o", front.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(png_size(&front).0 > 0);

    // Neither a scene nor --pareto: a clear error.
    let out = grainforce(&["plot", "-o", front.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("SCENE_DIR"),
        "{}",
        text(&out.stderr)
    );

    // A 2D scene cannot be projected on xz.
    let out = grainforce(&[
        "plot",
        &scene,
        &forces,
        "-o",
        png.to_str().unwrap(),
        "--plane",
        "xz",
    ]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("3D"), "{}", text(&out.stderr));

    // A frame that does not exist.
    let out = grainforce(&[
        "plot",
        &scene,
        &forces,
        "-o",
        png.to_str().unwrap(),
        "--frame",
        "3",
    ]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("--frame 3"),
        "{}",
        text(&out.stderr)
    );
}
