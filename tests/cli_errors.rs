//! Bad input: a clear message naming file, line and column, a non-zero exit,
//! and no output file.

mod common;
use std::path::Path;
use std::process::Command;

fn write_good_scene(dir: &Path) {
    let (s, _) = common::lattice_2d(3, 2, 0.5);
    grainforce::scene::write_scene(dir, &s).unwrap();
}

/// Runs `grainforce infer` on a scene whose `file` had `from` replaced by `to`.
fn infer_with(file: &str, edit: impl Fn(String) -> String) -> (String, bool) {
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    write_good_scene(&scene);
    let path = scene.join(file);
    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, edit(text)).unwrap();
    let out = dir.path().join("forces.csv");
    let result = Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .arg("infer")
        .arg(&scene)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(!result.status.success(), "bad input was accepted");
    assert!(
        !out.exists(),
        "an output file was written despite the error"
    );
    let leftovers: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers.len(), 1, "stray files: {leftovers:?}");
    (
        String::from_utf8_lossy(&result.stderr).into_owned(),
        result.status.success(),
    )
}

fn replace_cell(text: String, line: usize, column: &str, value: &str) -> String {
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    let header: Vec<&str> = lines[0].split(',').collect();
    let k = header.iter().position(|h| *h == column).unwrap();
    let mut cells: Vec<String> = lines[line - 1].split(',').map(str::to_owned).collect();
    cells[k] = value.to_owned();
    lines[line - 1] = cells.join(",");
    lines.join("\n") + "\n"
}

fn assert_names(msg: &str, parts: &[&str]) {
    for p in parts {
        assert!(msg.contains(p), "message does not name `{p}`: {msg}");
    }
}

#[test]
fn good_scene_succeeds() {
    let dir = tempfile::tempdir().unwrap();
    write_good_scene(dir.path());
    let out = dir.path().join("f.csv");
    let r = Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args([
            "infer",
            dir.path().to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    assert!(out.exists());
}

#[test]
fn missing_file() {
    let dir = tempfile::tempdir().unwrap();
    write_good_scene(dir.path());
    std::fs::remove_file(dir.path().join("contacts.csv")).unwrap();
    let out = dir.path().join("f.csv");
    let r = Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args([
            "infer",
            dir.path().to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(!out.exists());
    assert_names(&String::from_utf8_lossy(&r.stderr), &["contacts.csv"]);
}

#[test]
fn missing_column() {
    let (msg, _) = infer_with("grains.csv", |t| t.replacen("volume", "vol", 1));
    assert_names(&msg, &["grains.csv", "line 1", "`volume`"]);
}

#[test]
fn non_numeric_value() {
    let (msg, _) = infer_with("grains.csv", |t| replace_cell(t, 3, "x", "abc"));
    assert_names(&msg, &["grains.csv", "line 3", "`x`", "abc"]);
}

#[test]
fn nan_value() {
    let (msg, _) = infer_with("contacts.csv", |t| replace_cell(t, 4, "n_y", "NaN"));
    assert_names(&msg, &["contacts.csv", "line 4", "`n_y`"]);
}

#[test]
fn duplicate_grain_id() {
    let (msg, _) = infer_with("grains.csv", |t| replace_cell(t, 3, "id", "0"));
    assert_names(&msg, &["grains.csv", "line 3", "`id`", "duplicate"]);
}

#[test]
fn unknown_grain_in_contact() {
    let (msg, _) = infer_with("contacts.csv", |t| replace_cell(t, 2, "b", "999"));
    assert_names(&msg, &["contacts.csv", "line 2", "`b`", "999"]);
    let (msg, _) = infer_with("contacts.csv", |t| replace_cell(t, 2, "a", "top"));
    assert_names(&msg, &["contacts.csv", "line 2", "`a`", "top"]);
}

#[test]
fn zero_normal() {
    let (msg, _) = infer_with("contacts.csv", |t| {
        replace_cell(replace_cell(t, 3, "n_x", "0"), 3, "n_y", "0")
    });
    assert_names(&msg, &["contacts.csv", "line 3", "normal"]);
}

#[test]
fn zero_volume() {
    let (msg, _) = infer_with("grains.csv", |t| replace_cell(t, 2, "volume", "0"));
    assert_names(&msg, &["grains.csv", "line 2", "`volume`"]);
}

#[test]
fn wrong_number_of_fields() {
    let (msg, _) = infer_with("grains.csv", |t| {
        let mut lines: Vec<String> = t.lines().map(str::to_owned).collect();
        lines[2].push_str(",7");
        lines.join("\n") + "\n"
    });
    assert_names(&msg, &["grains.csv", "line 3"]);
}

#[test]
fn bad_flag_values() {
    let dir = tempfile::tempdir().unwrap();
    write_good_scene(dir.path());
    let out = dir.path().join("f.csv");
    for args in [["--mu", "-1"], ["--lambda", "nan"], ["--gravity", "1,x"]] {
        let r = Command::new(env!("CARGO_BIN_EXE_grainforce"))
            .args([
                "infer",
                dir.path().to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
            ])
            .args(args)
            .output()
            .unwrap();
        assert!(!r.status.success(), "{args:?} accepted");
        assert!(!out.exists());
        assert!(
            String::from_utf8_lossy(&r.stderr).contains(args[0]),
            "{args:?}"
        );
    }
}

#[test]
fn a_late_failure_leaves_no_output_at_all() {
    // --pareto needs --method dynamic: the run fails after inference, and
    // neither the forces nor the report of that failed run may remain.
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("scene");
    write_good_scene(&scene);
    let (out, report, front) = (
        dir.path().join("f.csv"),
        dir.path().join("r.json"),
        dir.path().join("p.csv"),
    );
    let r = Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .arg("infer")
        .arg(&scene)
        .args([
            "-o",
            out.to_str().unwrap(),
            "--report",
            report.to_str().unwrap(),
        ])
        .args(["--pareto", front.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!r.status.success());
    assert!(String::from_utf8_lossy(&r.stderr).contains("--pareto"));
    for p in [&out, &report, &front] {
        assert!(!p.exists(), "{} was written by a failed run", p.display());
    }
}
