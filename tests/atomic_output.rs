//! A run killed at any moment leaves each output file whole: the old file or
//! a complete new one, never a truncated one (outputs are written to a
//! temporary file in the same folder and renamed). It catches writers that
//! open their output before the work is done, which a kill then truncates.

use grainforce::bench::{generate, PackingSpec};
use grainforce::scene::write_scene;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

const OLD: &str = "contact,f_x,f_y\nold,1,2\n";

fn infer(dir: &Path, out: &Path) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(["infer", "-q"])
        .arg(dir)
        .arg("-o")
        .arg(out)
        .arg("--plot")
        .arg(out.with_extension("png"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// The forces file is the old one, or complete: a header and one row per
/// contact, the last line ended.
fn whole(out: &Path, contacts: usize) -> bool {
    let text = std::fs::read_to_string(out).unwrap();
    text == OLD || (text.ends_with('\n') && text.lines().count() == contacts + 1)
}

#[test]
fn killed_runs_leave_old_or_complete_files() {
    let tmp = tempfile::tempdir().unwrap();
    let scene_dir = tmp.path().join("scene");
    let packing = generate(&PackingSpec::new(2, 8_000)).unwrap();
    write_scene(&scene_dir, &packing.scene).unwrap();
    let contacts = packing.scene.contacts.len();
    let out = tmp.path().join("forces.csv");

    let clock = Instant::now();
    let status = infer(&scene_dir, &out).wait().unwrap();
    let full = clock.elapsed();
    assert!(status.success());
    assert!(whole(&out, contacts));

    // Kills spread over the run, denser at its end where the files are written.
    let mut killed_running = 0;
    for share in [0.2, 0.4, 0.6, 0.8, 0.9, 0.95, 0.98, 0.99, 1.0] {
        std::fs::write(&out, OLD).unwrap();
        let mut child = infer(&scene_dir, &out);
        std::thread::sleep(full.mul_f64(share));
        if child.try_wait().unwrap().is_none() {
            killed_running += 1;
        }
        let _ = child.kill();
        child.wait().unwrap();
        assert!(
            whole(&out, contacts),
            "killed at {share} of the run: a torn forces.csv"
        );
    }
    assert!(
        killed_running >= 3,
        "only {killed_running} runs were killed while running"
    );
}
