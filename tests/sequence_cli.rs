//! Long sequences on the command line: a failed frame is reported and the
//! others are written; `--frames A..B` reads only the frames it needs and
//! gives them the forces one run over every frame gives them.

mod common;

use grainforce::infer::kinematics::Smoother;
use grainforce::infer::sequence::{self, SequencePlan};
use grainforce::infer::{InferOptions, Method};
use grainforce::scene::Selection;
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
        stderr.contains("not written: infeasible: frame 2:") && stderr.contains("μ too small"),
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
        assert!(
            (total[0] - 0.981).abs() < 1e-6 && (total[1] - 0.1).abs() < 1e-6,
            "{total:?}"
        );
    }
    let entries: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    assert_eq!(entries.len(), 4);
    assert_eq!(entries[2]["frame"], 2);
    assert!(entries[2]["error"]
        .as_str()
        .unwrap()
        .contains("μ too small"));
    for k in [0, 1, 3] {
        assert_eq!(entries[k]["frame"], k as i64);
        assert!(entries[k].get("error").is_none() && entries[k]["stress_residual"].is_number());
    }

    // --stop-on-failure: the failure is the error, and nothing is written.
    let stopped = tmp.path().join("stopped.csv");
    let run = infer(
        &scene,
        &[
            "-m",
            "qs",
            "-o",
            stopped.to_str().unwrap(),
            "--stop-on-failure",
            "-q",
        ],
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

/// The lines of a forces.csv whose frame (first column) lies in first..=last.
/// The 2D impact preset simulated (optionally cut short) and written as a sequence.
fn impact_sequence(dir: &Path, seed: u64, duration: Option<f64>) -> grainforce::dem::DemRun {
    let mut config =
        grainforce::dem::DemConfig::preset(grainforce::dem::Preset::Impact, 2).seed(seed);
    if let Some(d) = duration {
        config = config.duration(d);
    }
    let run = grainforce::dem::simulate(&config).unwrap();
    grainforce::scene::write_sequence(dir, &run.frames).unwrap();
    run
}

fn rows_of_frames(text: &str, first: i64, last: i64) -> Vec<&str> {
    text.lines()
        .skip(1)
        .filter(|l| {
            let k: i64 = l.split(',').next().unwrap().parse().unwrap();
            (first..=last).contains(&k)
        })
        .collect()
}

#[test]
fn a_frame_range_reads_its_frames_and_gets_one_runs_forces() {
    // Accelerations in grains.csv (DEM): a range reads exactly its frames.
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("impact");
    let run = impact_sequence(&scene, 1, Some(0.004));
    let (first, last) = (
        run.frames[0].frame.unwrap(),
        run.frames.last().unwrap().frame.unwrap(),
    );
    let cut = (first + last) / 2;
    let opts = InferOptions {
        method: Method::Dynamic,
        ..Default::default()
    };
    let plan = SequencePlan {
        frame_range: Some((cut as f64, last as f64)),
        derive_accelerations: false,
        fps: None,
        smoother: Smoother::default_fir(),
        selection: Selection::All,
        acceleration_sd_given: false,
        position_sd: None,
    };
    let (frames, scope) = sequence::read(&scene, &opts, &plan).unwrap();
    assert_eq!(scope.frames, Some((cut, last)));
    let numbers: Vec<i64> = frames.iter().filter_map(|f| f.frame).collect();
    assert_eq!(numbers, (cut..=last).collect::<Vec<_>>());

    let whole = tmp.path().join("whole.csv");
    let part = tmp.path().join("part.csv");
    let range = format!("{cut}..{last}");
    for (out, extra) in [(&whole, vec![]), (&part, vec!["--frames", range.as_str()])] {
        let mut args = vec!["-m", "dynamic", "-q", "-o", out.to_str().unwrap()];
        args.extend(extra);
        let done = infer(&scene, &args);
        assert!(
            done.status.success(),
            "{}",
            String::from_utf8_lossy(&done.stderr)
        );
    }
    let (whole, part) = (
        std::fs::read_to_string(whole).unwrap(),
        std::fs::read_to_string(part).unwrap(),
    );
    assert_eq!(part.lines().next(), whole.lines().next());
    let expected = rows_of_frames(&whole, cut, last);
    assert!(!expected.is_empty());
    assert_eq!(rows_of_frames(&part, i64::MIN, i64::MAX), expected);
}

#[test]
fn derived_accelerations_at_a_range_boundary_are_one_runs() {
    let case = common::noisy_impact_on_disk(3);
    let diameter = 2.0 * case.run.frames[0].grains[0].radius.unwrap();
    let position_sd = (1e-3 * diameter).to_string();
    let first = case.noisy[0].frame.unwrap();
    let last = case.noisy.last().unwrap().frame.unwrap();
    // A boundary where the ball is near the disk (a busy stretch of the tracks).
    let cut = first + (last - first) / 2;
    for (smoother, extra) in [("fir", &[][..]), ("savgol", &["--savgol-window", "15"][..])] {
        let common = |out: &Path| -> Vec<String> {
            let mut a: Vec<String> = [
                "-m",
                "dynamic",
                "-q",
                "--smoother",
                smoother,
                "--position-sd",
            ]
            .iter()
            .map(|s| s.to_string())
            .collect();
            a.push(position_sd.clone());
            a.extend(extra.iter().map(|s| s.to_string()));
            a.extend(["-o".to_string(), out.to_str().unwrap().to_string()]);
            a
        };
        let whole = case.dir.path().join(format!("whole-{smoother}.csv"));
        let done = case.infer_from_tracks(
            &common(&whole)
                .iter()
                .map(String::as_str)
                .collect::<Vec<_>>(),
        );
        assert!(
            done.status.success(),
            "{}",
            String::from_utf8_lossy(&done.stderr)
        );
        let whole = std::fs::read_to_string(whole).unwrap();
        for (a, b) in [(first, first + 3), (cut - 4, cut), (cut + 1, cut + 6)] {
            let part = case.dir.path().join(format!("part-{smoother}-{a}.csv"));
            let mut args = common(&part);
            args.extend(["--frames".to_string(), format!("{a}..{b}")]);
            let done = case.infer_from_tracks(&args.iter().map(String::as_str).collect::<Vec<_>>());
            assert!(
                done.status.success(),
                "{}",
                String::from_utf8_lossy(&done.stderr)
            );
            let part = std::fs::read_to_string(part).unwrap();
            let expected = rows_of_frames(&whole, a, b);
            assert!(!expected.is_empty());
            assert_eq!(
                rows_of_frames(&part, i64::MIN, i64::MAX),
                expected,
                "{smoother} {a}..{b}"
            );
        }
    }

    // The range reads its frames and the smoother's margin only, unless the
    // weights need the noise estimated from every track.
    let opts = InferOptions {
        method: Method::Dynamic,
        ..Default::default()
    };
    let mut plan = SequencePlan {
        frame_range: Some((cut as f64, (cut + 5) as f64)),
        derive_accelerations: true,
        fps: Some(case.fps),
        smoother: Smoother::default_fir(),
        selection: Selection::All,
        acceleration_sd_given: false,
        position_sd: Some(1e-3 * diameter),
    };
    let margin = Smoother::default_fir().margin().unwrap() as i64;
    let (frames, scope) = sequence::read(&case.scene, &opts, &plan).unwrap();
    assert_eq!(scope.frames, Some((cut - margin, cut + 5 + margin)));
    assert_eq!(frames.len() as i64, 6 + 2 * margin);
    // The margin matters: the block's accelerations are the whole run's to
    // the bit with it, and not without it.
    let accelerations = |frames: Vec<grainforce::scene::Scene>| -> Vec<Option<[f64; 3]>> {
        let prepared = sequence::prepare(frames, &opts, &plan).unwrap();
        prepared.frames[0]
            .grains
            .iter()
            .map(|g| g.acceleration)
            .collect()
    };
    let from_block = accelerations(frames);
    let from_all = accelerations(grainforce::scene::read_sequence(&case.scene).unwrap());
    let unpadded =
        accelerations(grainforce::scene::read_sequence_frames(&case.scene, cut, cut + 5).unwrap());
    assert_eq!(from_block, from_all);
    assert_ne!(unpadded, from_all);
    plan.position_sd = None;
    let (frames, scope) = sequence::read(&case.scene, &opts, &plan).unwrap();
    assert!(scope.frames.is_none() && scope.whole_because.is_some());
    assert_eq!(frames.len(), case.noisy.len());
}

/// A report with its timings (which differ from run to run) removed.
fn without_timings(mut value: serde_json::Value) -> serde_json::Value {
    match &mut value {
        serde_json::Value::Object(map) => {
            map.retain(|k, _| !(k == "time" || k.ends_with("_time")));
            for v in map.values_mut() {
                *v = without_timings(v.take());
            }
        }
        serde_json::Value::Array(items) => {
            for v in items {
                *v = without_timings(v.take());
            }
        }
        _ => {}
    }
    value
}

/// `infer` over the whole sequence and over blocks, then `merge` of the
/// blocks' forces and reports: the forces byte for byte, the reports entry
/// for entry (timings aside) and in the same layout.
fn merged_blocks_are_one_run(scene: &Path, work: &Path, args: &[&str], blocks: &[(i64, i64)]) {
    let run = |out: &str, report: &str, extra: &[&str]| {
        let mut all: Vec<&str> = args.to_vec();
        all.extend(["-q", "-o", out, "--report", report]);
        all.extend(extra);
        let done = infer(scene, &all);
        assert!(
            matches!(done.status.code(), Some(0 | 3)),
            "{}",
            String::from_utf8_lossy(&done.stderr)
        );
        done.status.code()
    };
    let path = |name: String| work.join(name).to_str().unwrap().to_owned();
    let whole_status = run(&path("whole.csv".into()), &path("whole.json".into()), &[]);
    let mut statuses = Vec::new();
    // Listed backwards: merge orders the blocks by frame.
    for (k, (a, b)) in blocks.iter().enumerate().rev() {
        let range = format!("{a}..{b}");
        statuses.push(run(
            &path(format!("forces-{k}.csv")),
            &path(format!("report-{k}.json")),
            &["--frames", &range],
        ));
    }
    assert_eq!(statuses.contains(&Some(3)), whole_status == Some(3));
    for (kind, whole) in [
        ("forces-{}.csv", "whole.csv"),
        ("report-{}.json", "whole.json"),
    ] {
        let out = path(format!("merged-{whole}"));
        let mut args = vec!["merge".to_string(), out.clone()];
        args.extend(
            (0..blocks.len())
                .rev()
                .map(|k| path(kind.replace("{}", &k.to_string()))),
        );
        let done = Command::new(env!("CARGO_BIN_EXE_grainforce"))
            .args(&args)
            .output()
            .unwrap();
        assert!(
            done.status.success(),
            "{}",
            String::from_utf8_lossy(&done.stderr)
        );
        let (merged, whole) = (
            std::fs::read_to_string(&out).unwrap(),
            std::fs::read_to_string(path(whole.into())).unwrap(),
        );
        if whole.starts_with('[') {
            let parse = |t: &str| without_timings(serde_json::from_str(t).unwrap());
            assert_eq!(parse(&merged), parse(&whole));
            // The same text, timings aside.
            let untimed = |t: &str| -> Vec<String> {
                t.lines()
                    .filter(|l| !l.contains("time\""))
                    .map(str::to_owned)
                    .collect()
            };
            assert_eq!(untimed(&merged), untimed(&whole));
        } else {
            assert_eq!(merged, whole);
        }
    }
}

#[test]
fn merged_blocks_give_one_runs_files() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("impact");
    let run = impact_sequence(&scene, 2, None);
    let (first, last) = (
        run.frames[0].frame.unwrap(),
        run.frames.last().unwrap().frame.unwrap(),
    );
    let cut = (first + last) / 2;
    // The middle block is one frame (its report a single object).
    let blocks = [(first, cut - 1), (cut, cut), (cut + 1, last)];
    merged_blocks_are_one_run(&scene, tmp.path(), &["-m", "dynamic"], &blocks);

    // With a failed frame (2): its block exits 3, and the merge still lists it.
    let disks = tmp.path().join("disks");
    sideways_disks(&disks, &[2.0, 2.0, 1e-3, 2.0, 2.0]);
    let work = tmp.path().join("disk-runs");
    std::fs::create_dir(&work).unwrap();
    merged_blocks_are_one_run(&disks, &work, &["-m", "qs"], &[(0, 1), (2, 4)]);

    // Blocks that overlap do not merge.
    let out = tmp.path().join("bad.csv");
    let done = Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .arg("merge")
        .arg(&out)
        .arg(tmp.path().join("forces-0.csv"))
        .arg(tmp.path().join("whole.csv"))
        .output()
        .unwrap();
    assert!(!done.status.success());
    assert!(String::from_utf8_lossy(&done.stderr).contains("both hold frame"));
    assert!(!out.exists());
}

#[test]
fn a_frame_range_of_files_not_sorted_by_frame_reads_the_same_scenes() {
    let tmp = tempfile::tempdir().unwrap();
    let sorted = tmp.path().join("sorted");
    let run = impact_sequence(&sorted, 1, Some(0.004));
    // The same rows, frames in reverse order (each frame's rows in order).
    let shuffled = tmp.path().join("shuffled");
    std::fs::create_dir(&shuffled).unwrap();
    for entry in std::fs::read_dir(&sorted).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        if path.extension().is_some_and(|e| e == "csv") && text.starts_with("frame,") {
            let mut lines = text.lines();
            let header = lines.next().unwrap();
            let mut rows: Vec<&str> = lines.collect();
            rows.sort_by_key(|l| -l.split(',').next().unwrap().parse::<i64>().unwrap());
            std::fs::write(
                shuffled.join(name),
                format!("{header}\n{}\n", rows.join("\n")),
            )
            .unwrap();
        } else {
            std::fs::write(shuffled.join(name), text).unwrap();
        }
    }
    let first = run.frames[0].frame.unwrap();
    let (a, b) = (first + 3, first + 9);
    let expected: Vec<_> = grainforce::scene::read_sequence(&sorted)
        .unwrap()
        .into_iter()
        .filter(|f| (a..=b).contains(&f.frame.unwrap()))
        .collect();
    assert_eq!(expected.len(), 7);
    for dir in [&sorted, &shuffled] {
        assert_eq!(
            grainforce::scene::read_sequence_frames(dir, a, b).unwrap(),
            expected
        );
    }
    let none = grainforce::scene::read_sequence_frames(&shuffled, 10_000, 10_010);
    assert!(none
        .unwrap_err()
        .to_string()
        .contains("no frame of the sequence lies in the range"));
}
