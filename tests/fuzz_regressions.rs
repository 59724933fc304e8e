//! Replays the fuzz targets' inputs (see fuzz/) through the same readers in
//! stable `cargo test`: every input that once crashed, hung or ran away with
//! memory (fixtures/fuzz/<target>/) must now give Ok or a clean error, and the
//! hand-made seeds (fuzz/seeds/<target>/) must read, which checks the harness.

#[path = "../fuzz/readers.rs"]
mod readers;

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

type Reader = fn(&Path, &[u8]) -> grainforce::Result<()>;

fn files(folder: &str, target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(folder)
        .join(target);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries.map(|e| e.unwrap().path()).collect();
    files.sort();
    files
}

/// Runs `reader` on every file; returns the files that panicked, with the
/// answer of those that did not.
fn replay(reader: Reader, inputs: &[PathBuf]) -> Vec<(PathBuf, Option<grainforce::Result<()>>)> {
    inputs
        .iter()
        .map(|path| {
            let bytes = std::fs::read(path).unwrap();
            let dir = tempfile::tempdir().unwrap();
            let answer = catch_unwind(AssertUnwindSafe(|| reader(dir.path(), &bytes))).ok();
            (path.clone(), answer)
        })
        .collect()
}

fn check(target: &str, reader: Reader) {
    let crashes = files("fixtures/fuzz", target);
    let mut panicked = Vec::new();
    for (path, answer) in replay(reader, &crashes) {
        match answer {
            None => panicked.push(path),
            Some(Err(e)) => assert!(!e.to_string().is_empty(), "{}", path.display()),
            Some(Ok(())) => {}
        }
    }
    assert!(panicked.is_empty(), "{target}: panicked on {panicked:?}");

    let seeds = files("fuzz/seeds", target);
    assert!(
        !seeds.is_empty(),
        "{target}: no seeds in fuzz/seeds/{target}"
    );
    for (path, answer) in replay(reader, &seeds) {
        match answer {
            Some(Ok(())) => {}
            Some(Err(e)) => panic!("seed {} does not read: {e}", path.display()),
            None => panic!("seed {} panicked", path.display()),
        }
    }
}

#[test]
fn scene_inputs() {
    check("scene", readers::scene);
}

#[test]
fn lammps_inputs() {
    check("lammps", readers::lammps);
}

#[test]
fn liggghts_inputs() {
    check("liggghts", readers::liggghts);
}

#[test]
fn yade_inputs() {
    check("yade", readers::yade);
}

#[test]
fn gff_inputs() {
    check("gff", readers::gff);
}

#[test]
fn pegs_inputs() {
    check("pegs", readers::pegs);
}

#[test]
fn image_inputs() {
    check("image", readers::image);
}

#[test]
fn inputs_split_into_their_files() {
    let sep = std::str::from_utf8(readers::SEPARATOR).unwrap();
    let data = format!("a{sep}b{sep}c");
    let parts = readers::split(data.as_bytes(), 4);
    let want: [Option<&[u8]>; 4] = [Some(b"a"), Some(b"b"), Some(b"c"), None];
    assert_eq!(parts, want);
    // The last part keeps any further separators: nothing is dropped.
    let parts = readers::split(data.as_bytes(), 2);
    assert_eq!(parts[1], Some(format!("b{sep}c").as_bytes()));
}
