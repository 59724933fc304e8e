//! The readers under fuzzing, shared by the fuzz targets and by
//! `tests/fuzz_regressions.rs` (which replays the saved crashing inputs in
//! stable `cargo test`). One fuzz input holds all the files a reader needs,
//! separated by [`SEPARATOR`]; they are written into a folder so the readers run
//! on real paths, exactly as the CLI calls them.

use grainforce::import::{gff, lammps, liggghts, pegs, yade};
use grainforce::{image, scene, Result};
use std::path::Path;

/// Between two files of one input. Short, so mutations keep or make it easily.
pub const SEPARATOR: &[u8] = b"\n@@@@\n";

/// Splits `data` into at most `n` parts; missing parts are `None`.
pub fn split(data: &[u8], n: usize) -> Vec<Option<&[u8]>> {
    let mut parts = Vec::with_capacity(n);
    let mut rest = data;
    while parts.len() + 1 < n {
        match rest.windows(SEPARATOR.len()).position(|w| w == SEPARATOR) {
            Some(at) => {
                parts.push(Some(&rest[..at]));
                rest = &rest[at + SEPARATOR.len()..];
            }
            None => break,
        }
    }
    parts.push(Some(rest));
    parts.resize(n, None);
    parts
}

/// Writes each present part to its file name in `dir` and removes the files of
/// absent parts (the folder is reused between inputs).
fn write_parts(dir: &Path, names: &[&str], data: &[u8]) {
    for (name, part) in names.iter().zip(split(data, names.len())) {
        let path = dir.join(name);
        match part {
            Some(bytes) => std::fs::write(&path, bytes).expect("write fuzz input"),
            None => {
                let _ = std::fs::remove_file(&path);
            }
        }
    }
}

/// Files of a scene input, in order (walls.csv and forces.csv may be absent).
pub const SCENE_FILES: [&str; 5] = [
    "scene.json",
    "grains.csv",
    "contacts.csv",
    "walls.csv",
    "forces.csv",
];

/// Scene folder reader, then forces.csv against the scene read.
pub fn scene(dir: &Path, data: &[u8]) -> Result<()> {
    write_parts(dir, &SCENE_FILES, data);
    let frames = scene::read_sequence(dir);
    let forces_path = dir.join("forces.csv");
    if forces_path.exists() {
        let forces = scene::read_forces(&forces_path)?;
        if let Ok(frames) = &frames {
            if let [one] = frames.as_slice() {
                forces.for_scene(one, &forces_path)?;
            }
        }
    }
    frames.map(drop)
}

pub fn lammps(dir: &Path, data: &[u8]) -> Result<()> {
    write_parts(dir, &["atoms.dump", "pairs.dump"], data);
    let options = lammps::Options::default();
    lammps::import(&dir.join("atoms.dump"), &dir.join("pairs.dump"), &options).map(drop)
}

pub fn liggghts(dir: &Path, data: &[u8]) -> Result<()> {
    write_parts(dir, &["atoms.dump", "pairs.dump"], data);
    let options = liggghts::Options::default();
    liggghts::import(&dir.join("atoms.dump"), &dir.join("pairs.dump"), &options).map(drop)
}

pub fn yade(dir: &Path, data: &[u8]) -> Result<()> {
    write_parts(dir, &["bodies.csv", "interactions.csv"], data);
    let options = yade::Options::default();
    yade::import(
        &dir.join("bodies.csv"),
        &dir.join("interactions.csv"),
        &options,
    )
    .map(drop)
}

/// The gff importer, with the tomography grain table when a third part exists.
pub fn gff(dir: &Path, data: &[u8]) -> Result<()> {
    write_parts(
        dir,
        &["grains.gff", "contacts.csv", "tomo_grains.csv"],
        data,
    );
    let tomography = dir.join("tomo_grains.csv");
    let options = gff::Options {
        tomography_grains: tomography.exists().then_some(tomography),
        ..gff::Options::default()
    };
    gff::import(&dir.join("grains.gff"), &dir.join("contacts.csv"), &options).map(drop)
}

/// The PeGS importer: a particle .mat, with the centres file when a second
/// part exists.
pub fn pegs(dir: &Path, data: &[u8]) -> Result<()> {
    write_parts(dir, &["particle.mat", "centers.txt"], data);
    let centres = dir.join("centers.txt");
    let options = pegs::Options {
        centres: centres.exists().then_some(centres),
        ..pegs::Options::default()
    };
    pegs::import(&dir.join("particle.mat"), &options).map(drop)
}

/// The image loader; the format is guessed from the bytes, as for any file.
pub fn image(dir: &Path, data: &[u8]) -> Result<()> {
    let path = dir.join("image.png");
    std::fs::write(&path, data).expect("write fuzz input");
    image::io::load_gray(&path).map(drop)
}
