//! 3D X-ray diffraction grain files (FitAllB / ImageD11 `.gff`) with a contact
//! list from tomography: the route to measured 3D data.
//!
//! The `.gff` is a whitespace-separated table whose column names are on the last
//! `#` line before the data (ImageD11 `columnfile`). Columns used:
//! - grain id: `grain_id`, `grainno` or `id` (else the 1-based row number);
//! - centroid `x y z` in the file's length unit (ImageD11/FitAllB: mm);
//! - volume: `grainvolume` in length unit³, unless a tomography grain table
//!   gives it;
//! - stress `sig11 sig22 sig33 sig23 sig13 sig12` → s_xx s_yy s_zz s_yz s_xz
//!   s_xy, in the file's stress unit (FitAllB: MPa), tension positive as in
//!   FitAllB (stress from strain by Hooke's law, expansion positive);
//! - standard errors `sig11_s … sig12_s`, when present, → `sd_s_*` columns of
//!   grains.csv ([`crate::scene::Grain::stress_sd`]) so inference can weight
//!   rows by them.
//!
//! The contact list (CSV, SI metres, in the same sample frame as the gff) has
//! columns `a,b,x,y,z,n_x,n_y,n_z` and optionally `id`; `b` may name a wall.
//! An optional tomography grain table (CSV, SI) `id,volume[,x,y,z]` overrides the
//! gff volume (and centroid) of the grains it lists. No forces: this is data to
//! infer them from.

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
}

impl Default for Options {
    fn default() -> Self {
        Options {
            stress_unit: 1e6,
            length_unit: 1e-3,
            tomography_grains: None,
        }
    }
}

/// gff stress columns and the [`Sym`] slot each fills.
const STRESS: [(&str, usize); 6] = [
    ("sig11", scene::sym::XX),
    ("sig22", scene::sym::YY),
    ("sig33", scene::sym::ZZ),
    ("sig23", scene::sym::YZ),
    ("sig13", scene::sym::XZ),
    ("sig12", scene::sym::XY),
];

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
    let has_sd = STRESS
        .iter()
        .any(|(c, _)| gff.columns.contains_key(&format!("{c}_s")));
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
        let mut stress: Sym = [0.0; 6];
        for (c, k) in STRESS {
            stress[k] = gff.number(gff_path, line, cells, c)? * options.stress_unit;
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
        if has_sd {
            let mut sd: Sym = [0.0; 6];
            for (c, k) in STRESS {
                let x = gff.number(gff_path, line, cells, &format!("{c}_s"))?;
                if x < 0.0 {
                    return Err(Error::data(
                        gff_path,
                        Some(line),
                        Some(&format!("{c}_s")),
                        "a standard error cannot be negative",
                    ));
                }
                sd[k] = x * options.stress_unit;
            }
            g.stress_sd = Some(sd);
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
    s.settings.description = Some(format!(
        "3DXRD grains from {} with tomography contacts from {}",
        gff_path.display(),
        contacts_path.display()
    ));
    Ok(ImportedScene {
        warnings: Vec::new(),
        frames: vec![s],
        forces: None,
    })
}
