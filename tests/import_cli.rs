//! The command line end to end: import a LAMMPS run, compute its statistics,
//! export it for ParaView.

use std::path::Path;
use std::process::Command;

fn grainforce(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn import_stats_export() {
    let fx = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/import/lammps");
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    let (ok, out, err) = grainforce(&[
        "import",
        "lammps",
        &s(&fx.join("atoms.dump")),
        &s(&fx.join("pairs.dump")),
        "-o",
        &s(&scene),
        "--gravity",
        "0,-9.81,0",
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("2 frame(s), 80 grains"), "{out}");
    assert!(!err.contains("warning"), "{err}");
    // Without --gravity, the `fix gravity` of in.settle beside the dumps is read.
    let (ok, out, err) = grainforce(&[
        "import",
        "lammps",
        &s(&fx.join("atoms.dump")),
        &s(&fx.join("pairs.dump")),
        "-o",
        &s(&dir.path().join("script")),
    ]);
    assert!(ok && !err.contains("warning"), "{err}");
    assert!(
        out.contains("gravity 0,-9.81,0 from `fix gravity`"),
        "{out}"
    );
    // Without any gravity the importer warns: forces do not balance, and the
    // settled bed looks gravity-loaded.
    let alone = dir.path().join("alone");
    std::fs::create_dir(&alone).unwrap();
    for f in ["atoms.dump", "pairs.dump"] {
        std::fs::copy(fx.join(f), alone.join(f)).unwrap();
    }
    let (ok, _, err) = grainforce(&[
        "import",
        "lammps",
        &s(&alone.join("atoms.dump")),
        &s(&alone.join("pairs.dump")),
        "-o",
        &s(&dir.path().join("nog")),
    ]);
    assert!(ok && err.contains("do not balance"), "{err}");

    let forces = scene.join("forces.csv");
    let json = dir.path().join("stats.json");
    let csv = dir.path().join("stats.csv");
    let (ok, out, err) = grainforce(&[
        "stats",
        &s(&scene),
        &s(&forces),
        "--json",
        &s(&json),
        "--csv",
        &s(&csv),
    ]);
    assert!(ok, "{err}");
    assert!(
        out.contains("frame 100000") && out.contains("coordination Z"),
        "{out}"
    );
    let rows = std::fs::read_to_string(&csv).unwrap();
    assert_eq!(rows.lines().count(), 3);
    let parsed: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(parsed.as_array().unwrap().len(), 2);
    assert_eq!(parsed[0]["grains"], 40);

    let pvd = dir.path().join("vtk/run.pvd");
    let (ok, _, err) = grainforce(&["export", "vtk", &s(&scene), &s(&forces), "-o", &s(&pvd)]);
    assert!(ok, "{err}");
    assert!(dir.path().join("vtk/run_120000_contacts.vtp").exists());
    // A sequence needs a .pvd output.
    let (ok, _, err) = grainforce(&[
        "export",
        "vtk",
        &s(&scene),
        "-o",
        &s(&dir.path().join("x.vtp")),
    ]);
    assert!(!ok && err.contains(".pvd"), "{err}");
    // Bad input is located.
    let bad = dir.path().join("bad.dump");
    std::fs::write(&bad, "ITEM: TIMESTEP\nten\n").unwrap();
    let (ok, _, err) = grainforce(&[
        "import",
        "lammps",
        &s(&bad),
        &s(&fx.join("pairs.dump")),
        "-o",
        &s(&scene),
    ]);
    assert!(!ok && err.contains("bad.dump, line 2"), "{err}");
}
