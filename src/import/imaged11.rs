//! ImageD11 grain maps (`.map` / `.ubi` text files, as
//! `ImageD11.grain.write_grain_file` writes them, or HDF5 grain files, as
//! `ImageD11.grain.write_grain_file_h5` writes them) to grain stresses.
//!
//! An HDF5 grain file holds a group per phase (`/<phase>/<i>/`, `i` = 0, 1, …)
//! with datasets `ubi` (3 × 3) and `translation` (3, µm); it keeps the UBIs'
//! full precision where a `.map` has 9 digits.
//!
//! A file is blank-line-separated blocks: optional `#translation: x y z`
//! (µm, sample frame), other `#key value` lines (`#npks`, `#name`, …, skipped),
//! then `#UBI:` and three rows of three numbers: the real-space lattice
//! vectors a, b, c (Å) as rows, in the sample frame.
//!
//! Conventions (each decides the answer by tens of MPa; docs/field.md):
//! - B0 is the Busing–Levy B of the unstrained cell (`--cell`), as
//!   `ImageD11.unitcell` builds it: crystal frame x ∥ a*, z ∥ c;
//! - deformation gradient F = UBIᵀ B0ᵀ (`ImageD11.finite_strain`);
//! - polar decomposition F = R S = V R; the strain is Biot's, S − I in the
//!   crystal frame (ImageD11's `eps_grain`, Seth–Hill m = ½; its
//!   `EpsSigSolver` defaults to Green–Lagrange, m = 1);
//! - Hooke's law in the crystal frame with engineering shears (Voigt factor
//!   2), then rotated to the sample frame by the polar R, not by the
//!   Busing–Levy U (σ_sample = R σ_crystal Rᵀ);
//! - trigonal constants given in the IEEE axes (x ∥ a) are turned 30° about c
//!   into the x ∥ a* frame ([`Stiffness`] does this).

use super::stiffness::{self, Mat3, Stiffness};
use super::ImportedScene;
use crate::error::{Error, Result};
use crate::scene::{self, Sym};
use std::collections::HashMap;
use std::path::Path;

/// One grain of a map.
#[derive(Debug, Clone, PartialEq)]
pub struct MapGrain {
    /// The block's 0-based number (ImageD11's HDF5 grain files name grains so).
    pub index: usize,
    /// Rows: a, b, c in the sample frame [Å].
    pub ubi: Mat3,
    /// µm, sample frame.
    pub translation: Option<[f64; 3]>,
    /// Where it was read (for messages).
    pub source: GrainSource,
}

/// Where a grain was read in its file.
#[derive(Debug, Clone, PartialEq)]
pub enum GrainSource {
    /// The line of `#UBI:` in a `.map`.
    Line(usize),
    /// The grain's group in an HDF5 file (`/quartz/3`).
    Group(String),
}

impl MapGrain {
    /// An error about this grain's UBI or translation (`field`: `ubi` or
    /// `translation`), located by line or by HDF5 dataset.
    fn error(&self, path: &Path, field: &str, message: impl Into<String>) -> Error {
        match &self.source {
            GrainSource::Line(n) => {
                let column = if field == "ubi" {
                    "UBI"
                } else {
                    "#translation"
                };
                Error::data(path, Some(*n), Some(column), message)
            }
            GrainSource::Group(g) => {
                Error::data(path, None, Some(&format!("{g}/{field}")), message)
            }
        }
    }
}

/// The HDF5 file signature.
const HDF5_SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// Whether the file is HDF5: its signature at byte 0, or after a user block
/// (at 512, 1024, 2048, … as the format allows).
fn is_hdf5(path: &Path) -> bool {
    use std::io::{Read, Seek, SeekFrom};
    let Ok(mut file) = std::fs::File::open(path) else {
        return false;
    };
    let len = file.metadata().map_or(0, |m| m.len());
    let mut offset = 0u64;
    while offset + 8 <= len {
        let mut head = [0u8; 8];
        let read = file
            .seek(SeekFrom::Start(offset))
            .and_then(|_| file.read_exact(&mut head));
        if read.is_err() {
            return false;
        }
        if &head == HDF5_SIGNATURE {
            return true;
        }
        offset = if offset == 0 { 512 } else { 2 * offset };
    }
    false
}

/// Reads a grain file: HDF5 (by its signature) or a `.map`/`.ubi` text file.
/// `phase` names the HDF5 group; without it a file with one group is read.
pub fn read_grains(path: &Path, phase: Option<&str>) -> Result<Vec<MapGrain>> {
    if is_hdf5(path) {
        read_h5(path, phase)
    } else if let Some(phase) = phase {
        Err(Error::Invalid(format!(
            "--phase {phase} names a group of an HDF5 grain file; {} is a text grain map",
            path.display()
        )))
    } else {
        read_map(path)
    }
}

/// Reads an ImageD11 HDF5 grain file (`/<phase>/<i>/{ubi, translation}`).
pub fn read_h5(path: &Path, phase: Option<&str>) -> Result<Vec<MapGrain>> {
    let bad = |at: Option<&str>, message: String| Error::data(path, None, at, message);
    let file = hdf5_reader::Hdf5File::open(path)
        .map_err(|e| bad(None, format!("not a readable HDF5 file: {e}")))?;
    let root = file
        .root_group()
        .map_err(|e| bad(Some("/"), e.to_string()))?;
    let (groups, _) = root
        .member_names()
        .map_err(|e| bad(Some("/"), e.to_string()))?;
    let phase = match phase {
        Some(p) if groups.iter().any(|g| g == p) => p.to_owned(),
        Some(p) => {
            return Err(bad(
                None,
                format!("no group `{p}`; its groups: {}", groups.join(", ")),
            ))
        }
        None if groups.len() == 1 => groups[0].clone(),
        None => {
            return Err(bad(
                None,
                format!(
                    "{} groups ({}): name the phase with --phase",
                    groups.len(),
                    groups.join(", ")
                ),
            ))
        }
    };
    let at = format!("/{phase}");
    let group = file.group(&at).map_err(|e| bad(Some(&at), e.to_string()))?;
    let (names, _) = group
        .member_names()
        .map_err(|e| bad(Some(&at), e.to_string()))?;
    // ImageD11 names the grains 0, 1, … and reads them in that order.
    let mut numbered = Vec::with_capacity(names.len());
    for name in names {
        let i: usize = name.parse().map_err(|_| {
            bad(
                Some(&format!("{at}/{name}")),
                "a grain group is named by its number".into(),
            )
        })?;
        numbered.push((i, name));
    }
    numbered.sort();
    if numbered.is_empty() {
        return Err(bad(Some(&at), "no grains".into()));
    }
    let read = |dataset: &str, out: &mut [f64]| -> Result<()> {
        let d = file
            .dataset(dataset)
            .map_err(|e| bad(Some(dataset), e.to_string()))?;
        let len: u64 = d.shape().iter().product();
        if len as usize != out.len() {
            return Err(bad(
                Some(dataset),
                format!("{} values, expected {}", len, out.len()),
            ));
        }
        d.read_into(out)
            .map_err(|e| bad(Some(dataset), e.to_string()))?;
        if out.iter().any(|x| !x.is_finite()) {
            return Err(bad(Some(dataset), "a value is not finite".into()));
        }
        Ok(())
    };
    let mut grains = Vec::with_capacity(numbered.len());
    for (index, name) in numbered {
        let g = format!("{at}/{name}");
        let mut ubi = [0.0; 9];
        read(&format!("{g}/ubi"), &mut ubi)?;
        let members = file
            .group(&g)
            .and_then(|grp| grp.member_names())
            .map_err(|e| bad(Some(&g), e.to_string()))?;
        let translation = if members.1.iter().any(|d| d == "translation") {
            let mut t = [0.0; 3];
            read(&format!("{g}/translation"), &mut t)?;
            Some(t)
        } else {
            None
        };
        grains.push(MapGrain {
            index,
            ubi: [
                [ubi[0], ubi[1], ubi[2]],
                [ubi[3], ubi[4], ubi[5]],
                [ubi[6], ubi[7], ubi[8]],
            ],
            translation,
            source: GrainSource::Group(g),
        });
    }
    Ok(grains)
}

/// Reads a `.map`/`.ubi` grain file.
pub fn read_map(path: &Path) -> Result<Vec<MapGrain>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut grains = Vec::new();
    let mut translation = None;
    let mut rows: Vec<[f64; 3]> = Vec::new();
    let mut ubi_line = None;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let t = line.trim();
        if t.is_empty() {
            continue;
        }
        if let Some(rest) = t.strip_prefix("#translation:") {
            let v = three_numbers(rest).ok_or_else(|| {
                Error::data(
                    path,
                    Some(n),
                    Some("#translation"),
                    "expected three numbers (µm)",
                )
            })?;
            translation = Some(v);
            continue;
        }
        if t.starts_with("#UBI") {
            ubi_line = Some(n);
            rows.clear();
            continue;
        }
        if t.starts_with('#') {
            continue;
        }
        let Some(start) = ubi_line else {
            return Err(Error::data(
                path,
                Some(n),
                None,
                "numbers before a `#UBI:` line",
            ));
        };
        let v = three_numbers(t).ok_or_else(|| {
            Error::data(
                path,
                Some(n),
                Some("UBI"),
                "a UBI row is three finite numbers",
            )
        })?;
        rows.push(v);
        if rows.len() == 3 {
            grains.push(MapGrain {
                index: grains.len(),
                ubi: [rows[0], rows[1], rows[2]],
                translation: translation.take(),
                source: GrainSource::Line(start),
            });
            rows.clear();
            ubi_line = None;
        }
    }
    if let Some(start) = ubi_line {
        return Err(Error::data(
            path,
            Some(start),
            Some("UBI"),
            format!("the UBI has {} rows, not 3", rows.len()),
        ));
    }
    if grains.is_empty() {
        return Err(Error::data(path, None, None, "no `#UBI:` block"));
    }
    Ok(grains)
}

/// Busing–Levy B of a cell a, b, c [Å], α, β, γ [degrees] (x ∥ a*, z ∥ c), as
/// `ImageD11.unitcell.unitcell(cell).B`.
pub fn b_matrix(cell: [f64; 6]) -> Result<Mat3> {
    let [a, b, c, al, be, ga] = cell;
    if !(cell.iter().all(|x| x.is_finite()) && a > 0.0 && b > 0.0 && c > 0.0) {
        return Err(Error::Invalid(format!(
            "--cell {cell:?}: lengths must be positive"
        )));
    }
    let (ca, cb, cg) = (
        al.to_radians().cos(),
        be.to_radians().cos(),
        ga.to_radians().cos(),
    );
    let g = nalgebra::Matrix3::new(
        a * a,
        a * b * cg,
        a * c * cb,
        a * b * cg,
        b * b,
        b * c * ca,
        a * c * cb,
        b * c * ca,
        c * c,
    );
    let gi = g
        .try_inverse()
        .filter(|m| m.iter().all(|x| x.is_finite()))
        .ok_or_else(|| Error::Invalid(format!("--cell {cell:?} is degenerate")))?;
    let (astar, bstar, cstar) = (gi[(0, 0)].sqrt(), gi[(1, 1)].sqrt(), gi[(2, 2)].sqrt());
    let cos_gs = gi[(0, 1)] / astar / bstar;
    let cos_bs = gi[(0, 2)] / astar / cstar;
    let sin = |c: f64| (1.0 - c * c).max(0.0).sqrt();
    Ok([
        [astar, bstar * cos_gs, cstar * cos_bs],
        [0.0, bstar * sin(cos_gs), -cstar * sin(cos_bs) * ca],
        [0.0, 0.0, 1.0 / c],
    ])
}

fn to_na(m: &Mat3) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::from_fn(|i, j| m[i][j])
}

fn from_na(m: &nalgebra::Matrix3<f64>) -> Mat3 {
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = m[(i, j)];
        }
    }
    out
}

/// What a grain's UBI gives: the polar rotation R (crystal → sample) and the
/// Biot strain in the sample frame, V − I (= R (S − I) Rᵀ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GrainStrain {
    pub rotation: Mat3,
    pub strain_sample: Sym,
}

/// The polar decomposition of F = UBIᵀ B0ᵀ; `None` when F is singular or
/// left-handed.
pub fn grain_strain(ubi: &Mat3, b0: &Mat3) -> Option<GrainStrain> {
    let f = to_na(ubi).transpose() * to_na(b0).transpose();
    let det = f.determinant();
    if det.is_nan() || det <= 0.0 {
        return None;
    }
    let svd = f.svd(true, true);
    let (w, vt) = (svd.u?, svd.v_t?);
    let r = w * vt;
    let v = w * nalgebra::Matrix3::from_diagonal(&svd.singular_values) * w.transpose();
    let e = v - nalgebra::Matrix3::identity();
    // Symmetrised: V is symmetric up to round-off.
    let e = (e + e.transpose()) * 0.5;
    Some(GrainStrain {
        rotation: from_na(&r),
        strain_sample: stiffness::from_tensor(&from_na(&e)),
    })
}

#[derive(Debug, Clone)]
pub struct Options {
    /// Unstrained cell a, b, c [Å], α, β, γ [degrees].
    pub cell: [f64; 6],
    pub stiffness: Stiffness,
    /// Volume of every grain [m³] when no tomography table gives it.
    pub grain_volume: Option<f64>,
    /// The group (phase) of an HDF5 grain file; needed when it has several.
    pub phase: Option<String>,
}

/// Sample-frame stress [Pa] of each grain of a map, in file order.
pub fn stresses(path: &Path, grains: &[MapGrain], options: &Options) -> Result<Vec<Sym>> {
    let b0 = b_matrix(options.cell)?;
    grains
        .iter()
        .map(|g| {
            let s = grain_strain(&g.ubi, &b0).ok_or_else(|| {
                g.error(path, "ubi", "the UBI is singular or left-handed (det ≤ 0)")
            })?;
            Ok(options.stiffness.stress(&s.rotation, &s.strain_sample))
        })
        .collect()
}

/// Imports a grain map (and optionally a tomography contact list) into a 3D
/// scene: positions from `#translation` (µm → m), stresses from the UBIs.
/// `map` is a `.map`/`.ubi` text file or an HDF5 grain file.
pub fn import(map: &Path, contacts: Option<&Path>, options: &Options) -> Result<ImportedScene> {
    let grains = read_grains(map, options.phase.as_deref())?;
    let sigma = stresses(map, &grains, options)?;
    let volume =
        match options.grain_volume {
            Some(v) if v > 0.0 && v.is_finite() => v,
            Some(v) => {
                return Err(Error::Invalid(format!(
                    "--grain-volume must be positive, got {v}"
                )))
            }
            None => return Err(Error::Invalid(
                "an ImageD11 map has no grain volumes: give --grain-volume (m³), or attach the \
                 stresses to a label volume's grains with `import labels … --stresses`"
                    .into(),
            )),
        };
    let mut s = scene::Scene::new(3);
    let mut index = HashMap::new();
    for (g, stress) in grains.iter().zip(sigma) {
        let Some(t) = g.translation else {
            return Err(g.error(
                map,
                "translation",
                format!(
                    "grain {} has no translation: its position is unknown",
                    g.index
                ),
            ));
        };
        let id = g.index.to_string();
        index.insert(id.clone(), s.grains.len());
        s.grains
            .push(scene::Grain::new(id, t.map(|x| x * 1e-6), volume, stress));
    }
    if let Some(c) = contacts {
        super::gff::read_contacts(&mut s, &index, map, c)?;
    }
    s.settings.description = Some(format!(
        "ImageD11 grains from {} (Biot strain, {} stiffness)",
        map.display(),
        options.stiffness.label
    ));
    s.validate()?;
    Ok(ImportedScene {
        frames: vec![s],
        forces: None,
        warnings: Vec::new(),
    })
}

/// Exactly three finite numbers separated by white space.
fn three_numbers(text: &str) -> Option<[f64; 3]> {
    let mut words = text.split_whitespace();
    let mut v = [0.0; 3];
    for x in &mut v {
        *x = words.next()?.parse().ok().filter(|x: &f64| x.is_finite())?;
    }
    words.next().is_none().then_some(v)
}
