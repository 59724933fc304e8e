//! The command line end to end: import a LAMMPS run, compute its statistics,
//! export it for ParaView.

mod common;
use common::grainforce;
use std::path::Path;

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
    // "wrote …" goes to stderr; stdout holds only results (none here).
    assert!(out.is_empty(), "{out}");
    assert!(err.contains("2 frame(s), 80 grains"), "{err}");
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
        err.contains("note: gravity 0,-9.81,0 from `fix gravity`"),
        "{out}{err}"
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
        "--report",
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
    let (ok, out, err) = grainforce(&["export", "vtk", &s(&scene), &s(&forces), "-o", &s(&pvd)]);
    assert!(ok, "{err}");
    assert!(out.is_empty() && err.contains("wrote"), "{out}{err}");
    // The global -q silences "wrote …" and keeps the result.
    let quiet = dir.path().join("quiet/run.pvd");
    let (ok, out, err) = grainforce(&["-q", "export", "vtk", &s(&scene), "-o", &s(&quiet)]);
    assert!(ok && out.is_empty() && err.is_empty(), "{out}{err}");
    assert!(quiet.exists());
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

/// The importers' warnings reach the command line: YADE without gravity,
/// gff errors that were not fitted; --stiffness and --errors are wired.
#[test]
fn import_warnings_and_gff_options() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/import");
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_owned();
    let wall = root.join("yade/wall");
    let (ok, out, err) = grainforce(&[
        "import",
        "yade",
        &s(&wall.join("bodies.csv")),
        &s(&wall.join("interactions.csv")),
        "-o",
        &s(&dir.path().join("wall")),
    ]);
    assert!(
        ok && err.contains("27 grains") && !err.contains("warning"),
        "{out}{err}"
    );
    let json = std::fs::read_to_string(dir.path().join("wall/scene.json")).unwrap();
    assert!(json.contains("-9.81"), "gravity from the export: {json}");
    // The same bodies without the gravity columns.
    let text = std::fs::read_to_string(wall.join("bodies.csv")).unwrap();
    let cut: Vec<String> = text
        .lines()
        .map(|l| l.split(',').take(13).collect::<Vec<_>>().join(","))
        .collect();
    let bodies = dir.path().join("bodies.csv");
    std::fs::write(&bodies, cut.join("\n")).unwrap();
    let (ok, _, err) = grainforce(&[
        "import",
        "yade",
        &s(&bodies),
        &s(&wall.join("interactions.csv")),
        "-o",
        &s(&dir.path().join("nog")),
    ]);
    assert!(ok && err.contains("pass --gravity 0,0,-9.81"), "{err}");

    let strain = root.join("gff/strain");
    let (ok, _, err) = grainforce(&[
        "import",
        "gff",
        &s(&strain.join("quartz_strain.gff")),
        &s(&strain.join("contacts.csv")),
        "-o",
        &s(&dir.path().join("quartz")),
        "--stiffness",
        "quartz",
        "--errors",
        &s(&strain.join("quartz_strain_errors.gff")),
        "--tomography-grains",
        &s(&strain.join("tomo_grains.csv")),
    ]);
    assert!(ok && err.contains("10 grains"), "{err}");
    assert!(
        err.contains("warning: 1 grain(s) have a zero standard error"),
        "{err}"
    );
    let grains = std::fs::read_to_string(dir.path().join("quartz/grains.csv")).unwrap();
    assert!(grains.lines().next().unwrap().contains("sd_s_zz"));
    let (ok, _, err) = grainforce(&[
        "import",
        "gff",
        &s(&strain.join("quartz_strain.gff")),
        &s(&strain.join("contacts.csv")),
        "-o",
        &s(&dir.path().join("bad")),
        "--stiffness",
        "cubic:1,2",
    ]);
    assert!(!ok && err.contains("needs 3 constants"), "{err}");
    assert!(!dir.path().join("bad").exists());
}
