//! 3D X-ray diffraction grain files (FitAllB / ImageD11 `.gff`) with a contact
//! list from tomography: the route to measured 3D data.
//!
//! The `.gff` is a whitespace-separated table whose column names are on the last
//! `#` line before the data (ImageD11 `columnfile`). FitAllB's columns
//! (`write_output.write_values`) and the frame of each:
//! - grain id: `grain_id`, `grainno` or `id` (else the 1-based row number);
//! - centroid `x y z` (sample frame) in the file's length unit (FitAllB: mm);
//! - volume: `grainvolume` in length unit³, unless a tomography grain table
//!   gives it;
//! - `U11 … U33`: orientation, crystal (xfab's Cartesian, x ∥ a*, z ∥ c) →
//!   sample, T_sample = U T_crystal Uᵀ;
//! - `eps11 eps22 eps33 eps23 eps13 eps12`: strain in the **crystal** frame;
//!   `eps11_s … eps12_s`: the same strain in the **sample** frame;
//! - `sig11 … sig12`: stress in the crystal frame, `sig11_s … sig12_s`: in the
//!   sample frame, in the file's stress unit (FitAllB: MPa), tension positive.
//!   The `_s` suffix is the sample frame, not a standard error: FitAllB writes
//!   the standard errors, under the same column names, to a separate
//!   `…_errors.gff` (`write_output.write_errors`), read with
//!   [`Options::errors`].
//!
//! The scene takes the sample-frame stress: `sig*_s`; else `sig*` rotated by U;
//! with [`Options::stiffness`], Hooke's law on the strain (`eps*_s`, else
//! `eps*`) through [`Stiffness::stress`]. Standard errors come from the errors
//! file's matching columns, propagated linearly (strain → stress, or crystal →
//! sample frame) assuming independent errors; a zero standard error (FitAllB's
//! mark for "not fitted") makes the grain's error unknown, with a warning.

//! The contact list (CSV, SI metres, in the same sample frame as the gff) has
//! columns `a,b,x,y,z,n_x,n_y,n_z` and optionally `id`; `b` may name a wall.
//! An optional tomography grain table (CSV, SI) `id,volume[,x,y,z]` overrides the
//! gff volume (and centroid) of the grains it lists. No forces: this is data to
//! infer them from.

pub use super::stiffness::Stiffness;
use super::stiffness::{self, Mat3};
use super::{csv_cell, csv_number, read_csv, ImportedScene};
use crate::error::{Error, Result};
use crate::scene::{self, Sym};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

#[derive(Debug, Clone)]
pub struct Options {
    /// Pa per stress unit of the gff (default 1e6: MPa).
    pub stress_unit: f64,
    /// Metres per length unit of the gff (default 1e-3: mm).
    pub length_unit: f64,
    /// Tomography grain table overriding volumes (and centroids).
    pub tomography_grains: Option<PathBuf>,
    /// Stress from strain by this crystal's Hooke's law (ignores sig columns).
    pub stiffness: Option<Stiffness>,
    /// FitAllB's `…_errors.gff`: standard errors under the value columns' names.
    pub errors: Option<PathBuf>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            stress_unit: 1e6,
            length_unit: 1e-3,
            tomography_grains: None,
            stiffness: None,
            errors: None,
        }
    }
}

/// FitAllB's tensor component suffixes and the [`Sym`] slot each fills.
const COMPONENTS: [(&str, usize); 6] = [
    ("11", scene::sym::XX),
    ("22", scene::sym::YY),
    ("33", scene::sym::ZZ),
    ("23", scene::sym::YZ),
    ("13", scene::sym::XZ),
    ("12", scene::sym::XY),
];

const ORIENTATION: [&str; 9] = [
    "U11", "U12", "U13", "U21", "U22", "U23", "U31", "U32", "U33",
];

/// Where a grain's sample-frame stress comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Source {
    /// `sig*_s` as written.
    SampleStress,
    /// `sig*` rotated by U.
    CrystalStress,
    /// Hooke's law on `eps*_s`.
    SampleStrain,
    /// Hooke's law on `eps*` rotated by U.
    CrystalStrain,
}

impl Source {
    /// Column prefix and suffix, e.g. ("sig", "_s").
    fn columns(self) -> (&'static str, &'static str) {
        match self {
            Source::SampleStress => ("sig", "_s"),
            Source::CrystalStress => ("sig", ""),
            Source::SampleStrain => ("eps", "_s"),
            Source::CrystalStrain => ("eps", ""),
        }
    }

    fn names(self) -> [String; 6] {
        let (p, s) = self.columns();
        COMPONENTS.map(|(c, _)| format!("{p}{c}{s}"))
    }

    fn needs_orientation(self) -> bool {
        self != Source::SampleStress
    }
}

struct Gff {
    columns: HashMap<String, usize>,
    header_line: usize,
    rows: Vec<(usize, Vec<String>)>,
}

fn read_gff(path: &Path) -> Result<Gff> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut header: Option<(usize, Vec<String>)> = None;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let t = line.trim();
        if t.is_empty() {
            continue;
        }
        if let Some(h) = t.strip_prefix('#') {
            if rows.is_empty() {
                // `# name = value` lines are parameters; the titles line has no `=`.
                if !h.contains('=') {
                    header = Some((n, h.split_whitespace().map(str::to_owned).collect()));
                }
            }
            continue;
        }
        let Some((_, names)) = &header else {
            return Err(Error::data(
                path,
                Some(n),
                None,
                "data before a `#` header line naming the columns",
            ));
        };
        let cells: Vec<String> = t.split_whitespace().map(str::to_owned).collect();
        if cells.len() != names.len() {
            return Err(Error::data(
                path,
                Some(n),
                None,
                format!(
                    "this row has {} values where the header names {} columns",
                    cells.len(),
                    names.len()
                ),
            ));
        }
        rows.push((n, cells));
    }
    let Some((header_line, names)) = header else {
        return Err(Error::data(
            path,
            None,
            None,
            "no `#` header line naming the columns",
        ));
    };
    let mut columns = HashMap::new();
    for (k, name) in names.iter().enumerate() {
        if columns.insert(name.clone(), k).is_some() {
            return Err(Error::data(
                path,
                Some(header_line),
                Some(name),
                "column appears twice in the header",
            ));
        }
    }
    Ok(Gff {
        columns,
        header_line,
        rows,
    })
}

impl Gff {
    fn has_any(&self, names: &[String]) -> bool {
        names.iter().any(|n| self.columns.contains_key(n))
    }

    fn symmetric(&self, path: &Path, line: usize, cells: &[String], source: Source) -> Result<Sym> {
        let mut t: Sym = [0.0; 6];
        for (name, (_, k)) in source.names().iter().zip(COMPONENTS) {
            t[k] = self.number(path, line, cells, name)?;
        }
        Ok(t)
    }

    /// U of a row; rows must hold a rotation (|UᵀU − I| ≤ 1e-4, FitAllB
    /// writes 12 decimals).
    fn orientation(&self, path: &Path, line: usize, cells: &[String]) -> Result<Mat3> {
        let mut u = [[0.0; 3]; 3];
        for (k, name) in ORIENTATION.iter().enumerate() {
            u[k / 3][k % 3] = self.number(path, line, cells, name)?;
        }
        let mut worst: f64 = 0.0;
        for i in 0..3 {
            for j in 0..3 {
                let d: f64 = (0..3).map(|k| u[k][i] * u[k][j]).sum();
                worst = worst.max((d - if i == j { 1.0 } else { 0.0 }).abs());
            }
        }
        let det = u[0][0] * (u[1][1] * u[2][2] - u[1][2] * u[2][1])
            - u[0][1] * (u[1][0] * u[2][2] - u[1][2] * u[2][0])
            + u[0][2] * (u[1][0] * u[2][1] - u[1][1] * u[2][0]);
        if worst > 1e-4 || det < 0.0 {
            return Err(Error::data(
                path,
                Some(line),
                Some("U11"),
                format!("U11…U33 is not a rotation (|UᵀU − I| = {worst:.1e}, det = {det:.4})"),
            ));
        }
        Ok(u)
    }

    fn require(&self, path: &Path, name: &str) -> Result<usize> {
        self.columns.get(name).copied().ok_or_else(|| {
            Error::data(
                path,
                Some(self.header_line),
                Some(name),
                format!("column `{name}` is missing from the header"),
            )
        })
    }

    fn number(&self, path: &Path, line: usize, cells: &[String], name: &str) -> Result<f64> {
        let s = &cells[self.require(path, name)?];
        match s.parse::<f64>() {
            Ok(x) if x.is_finite() => Ok(x),
            _ => Err(Error::data(
                path,
                Some(line),
                Some(name),
                format!("`{s}` is not a finite number"),
            )),
        }
    }
}

/// Imports a `.gff` grain file and a tomography contact list into one 3D scene.
pub fn import(gff_path: &Path, contacts_path: &Path, options: &Options) -> Result<ImportedScene> {
    if !(options.stress_unit > 0.0 && options.length_unit > 0.0) {
        return Err(Error::Invalid(
            "stress and length units must be positive".into(),
        ));
    }
    let gff = read_gff(gff_path)?;
    let id_col = ["grain_id", "grainno", "id"]
        .iter()
        .find_map(|c| gff.columns.get(*c).copied());
    let source = choose_source(&gff, gff_path, options.stiffness.is_some())?;
    let has_orientation = gff.has_any(&ORIENTATION.map(str::to_owned));
    if source.needs_orientation() {
        for name in ORIENTATION {
            gff.require(gff_path, name).map_err(|_| {
                Error::data(
                    gff_path,
                    Some(gff.header_line),
                    Some(name),
                    format!(
                        "column `{name}` is missing: `{}` are in the crystal frame (FitAllB's \
                         convention) and need U11…U33 to reach the sample frame",
                        source.names().join(" ")
                    ),
                )
            })?;
        }
    }
    // sig*_s should be sig* rotated by U; when it is not, the file follows
    // another convention (e.g. `_s` = standard error).
    let cross_check = source == Source::SampleStress
        && has_orientation
        && gff.has_any(&Source::CrystalStress.names());
    let errors = match &options.errors {
        Some(p) => Some(Errors::read(p)?),
        None => None,
    };
    let mut notes = Notes::default();
    let tomo = match &options.tomography_grains {
        Some(p) => Some((p.clone(), read_csv(p)?)),
        None => None,
    };
    let mut tomo_rows: HashMap<String, (usize, csv::StringRecord)> = HashMap::new();
    if let Some((p, (cols, rows))) = &tomo {
        for (line, r) in rows {
            let id = csv_cell(p, cols, r, *line, "id")?.to_owned();
            tomo_rows.insert(id, (*line, r.clone()));
        }
    }

    let mut s = scene::Scene::new(3);
    let mut index = HashMap::new();
    let l = options.length_unit;
    for (row_no, (line, cells)) in gff.rows.iter().enumerate() {
        let line = *line;
        let id = match id_col {
            Some(c) => cells[c].trim_end_matches(".0").to_owned(),
            None => (row_no + 1).to_string(),
        };
        let mut position = [0.0; 3];
        for (k, c) in ["x", "y", "z"].iter().enumerate() {
            position[k] = gff.number(gff_path, line, cells, c)? * l;
        }
        let u = if source.needs_orientation() || cross_check {
            Some(gff.orientation(gff_path, line, cells)?)
        } else {
            None
        };
        let values = gff.symmetric(gff_path, line, cells, source)?;
        if values.iter().all(|x| *x == 0.0) {
            notes.all_zero += 1;
        }
        // The linear map from the read columns to the sample-frame stress (Pa).
        let unit = options.stress_unit;
        let map = |v: &Sym| -> Sym {
            match (source, &u, &options.stiffness) {
                (Source::SampleStress, ..) => v.map(|x| x * unit),
                (Source::CrystalStress, Some(u), _) => crystal_to_sample(u, v).map(|x| x * unit),
                (Source::SampleStrain, Some(u), Some(c)) => c.stress(u, v),
                (Source::CrystalStrain, Some(u), Some(c)) => c.stress(u, &crystal_to_sample(u, v)),
                _ => unreachable!("orientation and stiffness checked above"),
            }
        };
        let stress = map(&values);
        if cross_check {
            let crystal = gff.symmetric(gff_path, line, cells, Source::CrystalStress)?;
            let rotated = crystal_to_sample(u.as_ref().expect("read for the check"), &crystal);
            let size = values
                .iter()
                .chain(&rotated)
                .fold(0.0_f64, |a, x| a.max(x.abs()));
            if values
                .iter()
                .zip(&rotated)
                .any(|(a, b)| (a - b).abs() > 1e-3 * size)
            {
                notes.inconsistent.push(line);
            }
        }
        let mut volume = None;
        if let Some((tline, record)) = tomo_rows.get(&id) {
            let (p, (cols, _)) = tomo.as_ref().expect("tomography table read");
            volume = Some((
                csv_number(p, cols, record, *tline, "volume")?,
                p.clone(),
                *tline,
            ));
            if cols.contains_key("x") {
                for (k, c) in ["x", "y", "z"].iter().enumerate() {
                    position[k] = csv_number(p, cols, record, *tline, c)?;
                }
            }
        }
        let (volume, vpath, vline, vcol) = match volume {
            Some((v, p, tl)) => (v, p, tl, "volume"),
            None => {
                if !gff.columns.contains_key("grainvolume") {
                    return Err(Error::data(
                        gff_path,
                        Some(line),
                        Some("grainvolume"),
                        format!(
                            "grain {id} has no volume: the gff has no `grainvolume` column \
                             and no tomography grain table lists it"
                        ),
                    ));
                }
                let v = gff.number(gff_path, line, cells, "grainvolume")? * l * l * l;
                (v, gff_path.to_owned(), line, "grainvolume")
            }
        };
        if volume <= 0.0 {
            return Err(Error::data(
                vpath,
                Some(vline),
                Some(vcol),
                format!("volume must be positive, got {volume}"),
            ));
        }
        let mut g = scene::Grain::new(id.clone(), position, volume, stress);
        if let Some(errors) = &errors {
            g.stress_sd = errors.stress_sd(&id, source, &map, options.stress_unit, &mut notes)?;
        }
        if index.insert(id.clone(), s.grains.len()).is_some() {
            return Err(Error::data(
                gff_path,
                Some(line),
                id_col.map(|_| "grain_id"),
                format!("duplicate grain id `{id}`"),
            ));
        }
        s.grains.push(g);
    }
    if s.grains.is_empty() {
        return Err(Error::data(gff_path, None, None, "no grains"));
    }

    read_contacts(&mut s, &index, gff_path, contacts_path)?;
    s.settings.description = Some(format!(
        "3DXRD grains from {} with tomography contacts from {}",
        gff_path.display(),
        contacts_path.display()
    ));
    let warnings = notes.warnings(gff_path, options.errors.as_deref(), source);
    Ok(ImportedScene {
        warnings,
        frames: vec![s],
        forces: None,
    })
}

/// Reads a tomography contact list (`a,b,x,y,z,n_x,n_y,n_z[,id]`, SI) into
/// `s`, whose grains `index` names; `b` may name a wall.
pub(crate) fn read_contacts(
    s: &mut scene::Scene,
    index: &HashMap<String, usize>,
    gff_path: &Path,
    contacts_path: &Path,
) -> Result<()> {
    let (cols, rows) = read_csv(contacts_path)?;
    let cp = contacts_path;
    for (n, (line, r)) in rows.iter().enumerate() {
        let line = *line;
        let a_name = csv_cell(cp, &cols, r, line, "a")?;
        let Some(&a) = index.get(a_name) else {
            return Err(Error::data(
                cp,
                Some(line),
                Some("a"),
                format!("grain `{a_name}` is not in {}", gff_path.display()),
            ));
        };
        let b_name = csv_cell(cp, &cols, r, line, "b")?;
        let b = match index.get(b_name) {
            Some(&b) if b == a => {
                return Err(Error::data(
                    cp,
                    Some(line),
                    Some("b"),
                    "a contact of a grain with itself",
                ))
            }
            Some(&b) => scene::Body::Grain(b),
            None if b_name.parse::<f64>().is_err() => scene::Body::Wall(s.wall_or_insert(b_name)),
            None => {
                return Err(Error::data(
                    cp,
                    Some(line),
                    Some("b"),
                    format!(
                        "grain `{b_name}` is not in {} (walls have names)",
                        gff_path.display()
                    ),
                ))
            }
        };
        let mut point = [0.0; 3];
        let mut normal = [0.0; 3];
        for k in 0..3 {
            point[k] = csv_number(cp, &cols, r, line, ["x", "y", "z"][k])?;
            normal[k] = csv_number(cp, &cols, r, line, ["n_x", "n_y", "n_z"][k])?;
        }
        let len = scene::norm(normal);
        if (len - 1.0).abs() > 1e-2 {
            return Err(Error::data(
                cp,
                Some(line),
                Some("n_x"),
                format!("the normal is not a unit vector (its length is {len})"),
            ));
        }
        normal.iter_mut().for_each(|x| *x /= len);
        let id = match cols.get("id") {
            Some(_) => csv_cell(cp, &cols, r, line, "id")?.to_owned(),
            None => (n + 1).to_string(),
        };
        s.contacts.push(scene::Contact {
            id,
            a,
            b,
            point,
            normal,
            mu: None,
        });
    }
    Ok(())
}

/// Which columns give the stress (see the module documentation).
fn choose_source(gff: &Gff, path: &Path, with_stiffness: bool) -> Result<Source> {
    let has = |s: Source| gff.has_any(&s.names());
    let missing = |s: Source, why: &str| {
        let name = &s.names()[0];
        Error::data(
            path,
            Some(gff.header_line),
            Some(name),
            format!("column `{name}` is missing from the header: {why}"),
        )
    };
    if with_stiffness {
        return if has(Source::SampleStrain) {
            Ok(Source::SampleStrain)
        } else if has(Source::CrystalStrain) {
            Ok(Source::CrystalStrain)
        } else {
            Err(missing(
                Source::CrystalStrain,
                "--stiffness needs strains (eps11… crystal frame or eps11_s… sample frame)",
            ))
        };
    }
    if has(Source::SampleStress) {
        Ok(Source::SampleStress)
    } else if has(Source::CrystalStress) {
        Ok(Source::CrystalStress)
    } else if has(Source::CrystalStrain) || has(Source::SampleStrain) {
        Err(missing(
            Source::SampleStress,
            "the file has strains but no stresses; give the crystal's stiffness with \
             --stiffness SPEC (e.g. quartz, zirconium, cubic:C11,C12,C44) to compute them",
        ))
    } else {
        Err(missing(
            Source::SampleStress,
            "no stress (sig11_s… sample frame, sig11… crystal frame) or strain (eps11…) columns",
        ))
    }
}

/// U T Uᵀ of a crystal-frame [`Sym`].
fn crystal_to_sample(u: &Mat3, t: &Sym) -> Sym {
    stiffness::from_tensor(&stiffness::rotate_out_of(u, &stiffness::tensor(t)))
}

/// What the import noticed, for the warnings.
#[derive(Default)]
struct Notes {
    all_zero: usize,
    inconsistent: Vec<usize>,
    zero_sd_grains: usize,
    zero_sd_columns: usize,
    not_in_errors: usize,
}

impl Notes {
    fn warnings(&self, gff: &Path, errors: Option<&Path>, source: Source) -> Vec<String> {
        let mut w = Vec::new();
        if self.all_zero > 0 {
            w.push(format!(
                "{} grain(s) of {} have all of {} equal to 0: FitAllB writes zeros where it did \
                 not refine the strain, and their stress is read as 0",
                self.all_zero,
                gff.display(),
                source.names().join(" ")
            ));
        }
        if !self.inconsistent.is_empty() {
            w.push(format!(
                "in {} grain(s) of {} (first on line {}) sig*_s is not sig* rotated by U, as \
                 FitAllB writes it; sig*_s was read as the sample-frame stress",
                self.inconsistent.len(),
                gff.display(),
                self.inconsistent[0]
            ));
        }
        let errors = errors.map(|p| p.display().to_string()).unwrap_or_default();
        if self.zero_sd_grains > 0 {
            w.push(format!(
                "{} grain(s) have a zero standard error in {} column(s) of {}: FitAllB writes 0 \
                 where it did not fit the errors, so their errors are unknown (no sd_s_* in \
                 grains.csv for them)",
                self.zero_sd_grains, self.zero_sd_columns, errors
            ));
        }
        if self.not_in_errors > 0 {
            w.push(format!(
                "{} grain(s) are not in {}: their errors are unknown",
                self.not_in_errors, errors
            ));
        }
        w
    }
}

/// FitAllB's `…_errors.gff`, rows by grain id.
struct Errors {
    path: PathBuf,
    gff: Gff,
    rows: HashMap<String, usize>,
}

impl Errors {
    fn read(path: &Path) -> Result<Errors> {
        let gff = read_gff(path)?;
        let id_col = ["grain_id", "grainno", "id"]
            .iter()
            .find_map(|c| gff.columns.get(*c).copied());
        let mut rows = HashMap::new();
        for (n, (_, cells)) in gff.rows.iter().enumerate() {
            let id = match id_col {
                Some(c) => cells[c].trim_end_matches(".0").to_owned(),
                None => (n + 1).to_string(),
            };
            rows.insert(id, n);
        }
        Ok(Errors {
            path: path.to_owned(),
            gff,
            rows,
        })
    }

    /// Standard errors of the sample-frame stress of grain `id`, propagated
    /// through the linear `map` (columns read → stress) as independent errors:
    /// var σ_i = Σ_k (∂σ_i/∂x_k)² sd_k². `None` when unknown (zero or absent).
    fn stress_sd(
        &self,
        id: &str,
        source: Source,
        map: &dyn Fn(&Sym) -> Sym,
        stress_unit: f64,
        notes: &mut Notes,
    ) -> Result<Option<Sym>> {
        let Some(&row) = self.rows.get(id) else {
            notes.not_in_errors += 1;
            return Ok(None);
        };
        let (line, cells) = &self.gff.rows[row];
        // FitAllB rotates the stress covariance itself: prefer its sig*_s.
        let as_written = |v: &Sym| v.map(|x| x * stress_unit);
        let (columns, map): (Source, &dyn Fn(&Sym) -> Sym) =
            if source == Source::CrystalStress && self.gff.has_any(&Source::SampleStress.names()) {
                (Source::SampleStress, &as_written)
            } else {
                (source, map)
            };
        let sd = self.gff.symmetric(&self.path, *line, cells, columns)?;
        for (name, (_, k)) in columns.names().iter().zip(COMPONENTS) {
            if sd[k] < 0.0 {
                return Err(Error::data(
                    &self.path,
                    Some(*line),
                    Some(name),
                    "a standard error cannot be negative",
                ));
            }
        }
        let zeros = sd.iter().filter(|x| **x == 0.0).count();
        if zeros > 0 {
            notes.zero_sd_grains += 1;
            notes.zero_sd_columns += zeros;
            return Ok(None);
        }
        let mut var = [0.0; 6];
        for k in 0..6 {
            let mut unit = [0.0; 6];
            unit[k] = 1.0;
            let column = map(&unit);
            for i in 0..6 {
                var[i] += (column[i] * sd[k]).powi(2);
            }
        }
        Ok(Some(var.map(f64::sqrt)))
    }
}
