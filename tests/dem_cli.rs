//! The `dem` and `perturb` verbs: they write what they say, and bad values
//! are reported as errors, never panics.

use std::process::Command;

fn grainforce(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(args)
        .output()
        .expect("run grainforce")
}

fn assert_clean_failure(args: &[&str], needle: &str) {
    let out = grainforce(args);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} should fail");
    assert!(!stderr.contains("panicked"), "{args:?} panicked: {stderr}");
    assert!(
        stderr.to_lowercase().contains(&needle.to_lowercase()),
        "{args:?}: expected `{needle}` in: {stderr}"
    );
}

#[test]
fn dem_writes_a_scene_and_perturb_copies_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let scene_dir = dir.path().join("oed");
    let s = scene_dir.to_str().unwrap();
    let out = grainforce(&[
        "dem",
        "oedometer",
        "-o",
        s,
        "--grains",
        "30",
        "--seed",
        "4",
        "--gate",
        "1e-8",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("30 grains") && stderr.contains("reached"),
        "{stderr}"
    );
    for f in [
        "grains.csv",
        "contacts.csv",
        "walls.csv",
        "scene.json",
        "forces.csv",
        "dem_report.json",
    ] {
        assert!(scene_dir.join(f).exists(), "{f} missing");
    }
    let noisy_dir = dir.path().join("noisy");
    let n = noisy_dir.to_str().unwrap();
    let out = grainforce(&[
        "perturb",
        s,
        "-o",
        n,
        "--stress-bias",
        "0.15",
        "--stress-noise",
        "0.1",
        "--seed",
        "2",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read(scene_dir.join("forces.csv")).unwrap(),
        std::fs::read(noisy_dir.join("forces.csv")).unwrap()
    );
    let a = grainforce::scene::read_scene(&scene_dir).unwrap();
    let b = grainforce::scene::read_scene(&noisy_dir).unwrap();
    assert_eq!(a.contacts, b.contacts);
    assert_ne!(a.grains[0].stress, b.grains[0].stress);
    // Thickness is recorded.
    let out = grainforce(&[
        "dem",
        "oedometer",
        "-o",
        s,
        "--grains",
        "10",
        "--thickness",
        "0.005",
        "--gate",
        "1e-3",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let again = grainforce::scene::read_scene(&scene_dir).unwrap();
    assert_eq!(again.settings.thickness, Some(0.005));
}

#[test]
fn bad_values_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let o = dir.path().join("x");
    let o = o.to_str().unwrap();
    assert_clean_failure(
        &["dem", "oedometer", "-o", o, "--grains", "0"],
        "at least 1",
    );
    assert_clean_failure(&["dem", "oedometer", "-o", o, "--gate", "2"], "gate");
    assert_clean_failure(&["dem", "oedometer", "-o", o, "--gate", "-1"], "gate");
    assert_clean_failure(&["dem", "oedometer", "-o", o, "--dim", "4"], "dim");
    assert_clean_failure(
        &["dem", "oedometer", "-o", o, "--thickness", "0"],
        "thickness",
    );
    assert_clean_failure(&["dem", "oedometer", "-o", o, "--mu", "-1"], "friction");
    assert_clean_failure(
        &[
            "dem",
            "oedometer",
            "-o",
            o,
            "--radius-min",
            "0.01",
            "--radius-max",
            "0.001",
        ],
        "radii",
    );
    assert_clean_failure(&["dem", "impact", "-o", o, "--dim", "3"], "two-dimensional");
    assert_clean_failure(
        &["dem", "impact", "-o", o, "--frames-every", "0"],
        "frames-every",
    );
    assert_clean_failure(
        &["dem", "impact", "-o", o, "--restitution", "0"],
        "restitution",
    );
    assert_clean_failure(&["dem", "nonsense", "-o", o], "invalid value");
    assert_clean_failure(
        &["dem", "oedometer", "-o", o, "--grains", "many"],
        "invalid value",
    );
    assert_clean_failure(&["perturb", "/nonexistent/scene", "-o", o], "not found");
    assert_clean_failure(
        &["perturb", o, "-o", o, "--drop-contacts", "1.5"],
        "drop-contacts",
    );
    assert_clean_failure(
        &["perturb", o, "-o", o, "--stress-noise", "-0.1"],
        "stress-noise",
    );
}

#[test]
fn help_documents_the_flags() {
    let out = grainforce(&["dem", "--help"]);
    let text = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--grains",
        "--seed",
        "--dim",
        "--gate",
        "--law",
        "--thickness",
        "--frames-every",
        "bed-impact",
    ] {
        assert!(text.contains(flag), "dem --help lacks {flag}");
    }
    let out = grainforce(&["perturb", "--help"]);
    let text = String::from_utf8_lossy(&out.stdout);
    for flag in [
        "--stress-bias",
        "--stress-noise",
        "--position-noise",
        "--normal-noise",
        "--accel-noise",
        "--drop-contacts",
        "forces.csv",
    ] {
        assert!(text.contains(flag), "perturb --help lacks {flag}");
    }
}
