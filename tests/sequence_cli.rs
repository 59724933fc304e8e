//! Long sequences on the command line: a failed frame is reported and the
//! others are written.

use std::path::Path;
use std::process::Command;

/// A disk on two supports ±30° from the vertical under a nearly horizontal
/// body force, one frame per μ: only friction (μ ≳ 1.4) can hold it, so a
/// frame with a small μ parses like the others but no force set balances it.
fn sideways_disks(dir: &Path, mus: &[f64]) {
    std::fs::create_dir_all(dir).unwrap();
    let r = (0.01 / std::f64::consts::PI).sqrt();
    let (s, c) = 30f64.to_radians().sin_cos();
    let mut grains = String::from("frame,id,x,y,volume,s_xx,s_yy,s_xy,mass\n");
    let mut contacts = String::from("frame,id,a,b,x,y,n_x,n_y,mu\n");
    for (k, mu) in mus.iter().enumerate() {
        grains.push_str(&format!("{k},1,0,0,0.01,0,0,0,0.1\n"));
        for (id, wall, side) in [("c1", "left", -1.0), ("c2", "right", 1.0)] {
            let n = [side * s, -c];
            contacts.push_str(&format!(
                "{k},{id},1,{wall},{},{},{},{},{mu}\n",
                r * n[0],
                r * n[1],
                n[0],
                n[1]
            ));
        }
    }
    std::fs::write(dir.join("grains.csv"), grains).unwrap();
    std::fs::write(dir.join("contacts.csv"), contacts).unwrap();
    std::fs::write(dir.join("scene.json"), r#"{"gravity": [-9.81, -1.0]}"#).unwrap();
}

fn infer(scene: &Path, args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .arg("infer")
        .arg(scene)
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn a_failed_frame_is_reported_and_the_others_are_written() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("disks");
    sideways_disks(&scene, &[2.0, 2.0, 1e-3, 2.0]);
    let out = tmp.path().join("forces.csv");
    let report = tmp.path().join("report.json");
    let run = infer(
        &scene,
        &[
            "-m",
            "qs",
            "-o",
            out.to_str().unwrap(),
            "--report",
            report.to_str().unwrap(),
            "-q",
        ],
    );
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(3), "{stderr}");
    assert!(
        stderr.contains("frame 2: failed") && stderr.contains("μ too small"),
        "{stderr}"
    );
    // The other three frames' forces, each balancing its disk.
    let forces = grainforce::scene::read_forces(&out).unwrap();
    let frames: Vec<i64> = forces.rows.iter().filter_map(|r| r.frame).collect();
    assert_eq!(frames, [0, 0, 1, 1, 3, 3]);
    for pair in forces.rows.chunks(2) {
        let total = [
            pair[0].force[0] + pair[1].force[0],
            pair[0].force[1] + pair[1].force[1],
        ];
        // Σ f = −m g with m = 0.1, g = (−9.81, −1).
        assert!((total[0] - 0.981).abs() < 1e-6 && (total[1] - 0.1).abs() < 1e-6, "{total:?}");
    }
    let entries: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(entries.len(), 4);
    assert_eq!(entries[2]["frame"], 2);
    assert!(entries[2]["error"].as_str().unwrap().contains("μ too small"));
    for k in [0, 1, 3] {
        assert_eq!(entries[k]["frame"], k as i64);
        assert!(entries[k].get("error").is_none() && entries[k]["stress_residual"].is_number());
    }

    // --stop-on-failure: the failure is the error, and nothing is written.
    let stopped = tmp.path().join("stopped.csv");
    let run = infer(
        &scene,
        &["-m", "qs", "-o", stopped.to_str().unwrap(), "--stop-on-failure", "-q"],
    );
    assert_eq!(run.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&run.stderr).contains("frame 2"));
    assert!(!stopped.exists());
}

#[test]
fn a_sequence_whose_frames_all_fail_is_an_error() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("disks");
    sideways_disks(&scene, &[1e-3, 1e-3]);
    let out = tmp.path().join("forces.csv");
    let run = infer(&scene, &["-m", "qs", "-o", out.to_str().unwrap(), "-q"]);
    assert_eq!(run.status.code(), Some(1));
    assert!(!out.exists());
}
