//! LAMMPS granular runs: a `dump custom` of atoms plus a `dump local` of
//! `compute pair/local` contact data.
//!
//! Conventions (checked against a LAMMPS 7Jan2022 run, see
//! `fixtures/import/lammps/in.settle`):
//! - `compute pair/local fx fy fz` is the *normal* part of the force on atom i
//!   by atom j (for granular styles `single()` returns the normal force only);
//!   `p1 p2 p3` of `pair_style granular` / `gran/*` are the tangential part on
//!   i. The total force on i by j is their sum; i → contact `a`, j → `b`.
//! - `fix wall/gran … contacts` adds per-atom columns `f_ID[1..8]`: [1] = 1 when
//!   touching, [2..4] the force on the atom by the wall, [5..7] the contact
//!   point on the wall. Each such fix becomes one wall named by its fix ID (use
//!   one fix per wall to get separately named walls). The contact point is put
//!   one radius from the centre towards the wall, where LAMMPS applies the
//!   wall's tangential force (grain–grain: middle of the overlap, where
//!   `pair_style granular` applies it), so moments balance the dumped torques.
//! - Per-atom `fx fy fz` is the total force LAMMPS integrated (contacts, walls,
//!   gravity…), so the acceleration is f/m; `tqx tqy tqz` gives α = τ/I with
//!   LAMMPS's I = 0.4 m R².
//! - 2D runs (`dimension 2`, all z equal): volume = π R² per unit thickness, so
//!   stresses are force per length, consistent with the per-unit-thickness
//!   reading of forces that the scene format uses in 2D.
//! - Periodic boundaries are rejected: the scene format has no periodic images,
//!   and a contact across the boundary would get a wrong branch vector.
//! - Units are those of the LAMMPS run (`units si` gives SI, which the scene
//!   format expects).

use super::dump::{paired_snapshots, DumpFrame, DumpRow};
use super::{ball_volume, check_radius, sphere_contact, stress_from_forces, ImportedScene};
use crate::error::{Error, Result};
use crate::scene::{self, Body, Contact, Grain, Inertia, Scene, Vec3};
use std::collections::HashMap;
use std::path::Path;

/// Which `dump local` columns hold what.
#[derive(Debug, Clone, PartialEq)]
pub struct LocalColumns {
    pub i: String,
    pub j: String,
    /// Force on i by j (for granular pair/local: its normal part).
    pub force: [String; 3],
    /// Added to `force` when given (pair/local p1 p2 p3: the tangential part).
    pub tangential: Option<[String; 3]>,
}

impl LocalColumns {
    /// Parses `i=NAME,j=NAME,fx=NAME,fy=NAME,fz=NAME[,tx=NAME,ty=NAME,tz=NAME]`.
    pub fn parse(spec: &str) -> Result<LocalColumns> {
        let mut map: HashMap<&str, String> = HashMap::new();
        for part in spec.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let Some((key, value)) = part.split_once('=') else {
                return Err(Error::Invalid(format!(
                    "--columns: `{part}` should be KEY=COLUMN (keys: i j fx fy fz tx ty tz)"
                )));
            };
            let key = key.trim();
            if !["i", "j", "fx", "fy", "fz", "tx", "ty", "tz"].contains(&key) {
                return Err(Error::Invalid(format!(
                    "--columns: unknown key `{key}` (keys: i j fx fy fz tx ty tz)"
                )));
            }
            map.insert(key, value.trim().to_owned());
        }
        let get = |k: &str| {
            map.get(k)
                .cloned()
                .ok_or_else(|| Error::Invalid(format!("--columns: `{k}=COLUMN` is required")))
        };
        let tangential = if ["tx", "ty", "tz"].iter().any(|k| map.contains_key(k)) {
            Some([get("tx")?, get("ty")?, get("tz")?])
        } else {
            None
        };
        Ok(LocalColumns {
            i: get("i")?,
            j: get("j")?,
            force: [get("fx")?, get("fy")?, get("fz")?],
            tangential,
        })
    }

    /// The default layout: after an optional leading `index` column, the
    /// entries are i, j, fx, fy, fz and optionally p1, p2, p3 (tangential).
    fn default_for(frame: &DumpFrame, path: &Path) -> Result<LocalColumns> {
        let names: Vec<&String> = frame.columns.iter().filter(|c| *c != "index").collect();
        if names.len() != 5 && names.len() != 8 {
            return Err(Error::data(
                path,
                Some(frame.header_line),
                None,
                format!(
                    "cannot tell which of the {} entries are ids and forces; \
                     name them with --columns i=…,j=…,fx=…,fy=…,fz=…[,tx=…,ty=…,tz=…]",
                    names.len()
                ),
            ));
        }
        let s = |k: usize| names[k].clone();
        Ok(LocalColumns {
            i: s(0),
            j: s(1),
            force: [s(2), s(3), s(4)],
            tangential: (names.len() == 8).then(|| [s(5), s(6), s(7)]),
        })
    }
}

#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Layout of the local dump; `None` takes the default (see [`LocalColumns`]).
    pub columns: Option<LocalColumns>,
    /// Force the dimension; `None` detects it (2 when all z are equal).
    pub dim: Option<usize>,
    /// Gravity of the run, written to scene.json.
    pub gravity: Option<Vec3>,
}

/// One atoms snapshot as a scene, with the atom-id → grain index map.
pub(crate) struct AtomsFrame {
    pub scene: Scene,
    pub index: HashMap<i64, usize>,
    /// Wall contacts from `fix wall/gran … contacts`, with their forces.
    pub wall_contacts: Vec<(Contact, Vec3)>,
}

/// Detects the dimension from the first snapshot: 2 when there is no z column
/// or every z is the same.
pub(crate) fn detect_dim(frame: &DumpFrame) -> usize {
    let Some(z) = frame.column("z") else {
        return 2;
    };
    let (lo, hi) = frame
        .rows
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
            (lo.min(r.values[z]), hi.max(r.values[z]))
        });
    let scale = frame
        .rows
        .iter()
        .map(|r| r.values[z].abs())
        .fold(1e-300, f64::max);
    if hi - lo <= 1e-12 * scale.max(1e-300) || hi == lo {
        2
    } else {
        3
    }
}

fn atom_id(path: &Path, row: &DumpRow, col: usize, name: &str) -> Result<i64> {
    let v = row.values[col];
    if v.fract() != 0.0 {
        return Err(Error::data(
            path,
            Some(row.line),
            Some(name),
            format!("`{v}` is not an integer atom id"),
        ));
    }
    Ok(v as i64)
}

/// Builds the grains (and wall contacts) of one atoms snapshot.
pub(crate) fn atoms_frame(path: &Path, frame: &DumpFrame, dim: usize) -> Result<AtomsFrame> {
    let axes = ["x", "y", "z"];
    for (k, axis) in axes.iter().enumerate().take(dim) {
        if frame.periodic[k] {
            return Err(Error::data(
                path,
                Some(frame.header_line.saturating_sub(4).max(1)),
                None,
                format!(
                    "the box is periodic in {}: periodic boundaries are not supported \
                     (the scene format has no periodic images); use fixed or shrink-wrapped \
                     boundaries (f, s or m) or walls",
                    axis
                ),
            ));
        }
    }
    let id_col = frame.require(path, "id")?;
    let pos: Vec<usize> = axes[..dim]
        .iter()
        .map(|a| frame.require(path, a))
        .collect::<Result<_>>()?;
    let (radius_col, radius_scale, radius_name) =
        match (frame.column("radius"), frame.column("diameter")) {
            (Some(c), _) => (c, 1.0, "radius"),
            (None, Some(c)) => (c, 0.5, "diameter"),
            _ => {
                frame.require(path, "radius")?;
                unreachable!()
            }
        };
    let mass_col = frame.column("mass");
    let force_cols: Option<Vec<usize>> =
        ["fx", "fy", "fz"].iter().map(|c| frame.column(c)).collect();
    let torque_cols: Option<Vec<usize>> = ["tqx", "tqy", "tqz"]
        .iter()
        .map(|c| frame.column(c))
        .collect();
    let walls = wall_fixes(frame);

    let mut scene = Scene::new(dim);
    let mut index = HashMap::new();
    let mut wall_contacts = Vec::new();
    for row in &frame.rows {
        let id = atom_id(path, row, id_col, "id")?;
        let mut p = [0.0; 3];
        for (k, &c) in pos.iter().enumerate() {
            p[k] = row.values[c];
        }
        let r = check_radius(
            path,
            row.line,
            radius_name,
            row.values[radius_col] * radius_scale,
        )?;
        let mut g = Grain::new(id.to_string(), p, ball_volume(dim, r), [0.0; 6]);
        g.radius = Some(r);
        if let Some(mc) = mass_col {
            let m = row.values[mc];
            if m <= 0.0 {
                return Err(Error::data(
                    path,
                    Some(row.line),
                    Some("mass"),
                    format!("mass must be positive, got {m}"),
                ));
            }
            g.mass = Some(m);
            if let Some(fc) = &force_cols {
                let mut a = [0.0; 3];
                for k in 0..dim {
                    a[k] = row.values[fc[k]] / m;
                }
                g.acceleration = Some(a);
            }
            if let Some(tc) = &torque_cols {
                let inertia = 0.4 * m * r * r;
                let mut alpha = [0.0; 3];
                for k in 0..3 {
                    alpha[k] = row.values[tc[k]] / inertia;
                }
                if dim == 2 {
                    alpha[0] = 0.0;
                    alpha[1] = 0.0;
                }
                g.inertia = Some(Inertia::Scalar(inertia));
                g.angular_acceleration = Some(alpha);
            }
        }
        let gi = scene.grains.len();
        if index.insert(id, gi).is_some() {
            return Err(Error::data(
                path,
                Some(row.line),
                Some("id"),
                format!("atom {id} appears twice in this snapshot"),
            ));
        }
        for (name, cols) in &walls {
            if row.values[cols[0]] == 0.0 {
                continue;
            }
            let mut f = [0.0; 3];
            let mut w = [0.0; 3];
            for k in 0..dim {
                f[k] = row.values[cols[1 + k]];
                w[k] = row.values[cols[4 + k]];
            }
            let d_vec = scene::sub(w, p);
            let d = scene::norm(d_vec);
            if d == 0.0 {
                return Err(Error::data(
                    path,
                    Some(row.line),
                    Some(&format!("f_{name}[5]")),
                    "the wall contact point is at the atom's centre",
                ));
            }
            let n = [d_vec[0] / d, d_vec[1] / d, d_vec[2] / d];
            // LAMMPS applies a wall's tangential force one radius from the
            // centre (checked on the fixture's torques), so the point goes there
            // and moments balance exactly.
            let arm = r;
            let wall = scene.wall_or_insert(name);
            wall_contacts.push((
                Contact {
                    id: format!("{id}-{name}"),
                    a: gi,
                    b: Body::Wall(wall),
                    point: [p[0] + arm * n[0], p[1] + arm * n[1], p[2] + arm * n[2]],
                    normal: n,
                    mu: None,
                },
                f,
            ));
        }
        scene.grains.push(g);
    }
    Ok(AtomsFrame {
        scene,
        index,
        wall_contacts,
    })
}

/// Fix IDs with the seven `f_ID[1..7]` columns of `fix wall/gran … contacts`.
fn wall_fixes(frame: &DumpFrame) -> Vec<(String, [usize; 7])> {
    let mut out = Vec::new();
    for c in &frame.columns {
        let Some(name) = c.strip_prefix("f_").and_then(|s| s.strip_suffix("[1]")) else {
            continue;
        };
        let cols: Option<Vec<usize>> = (1..=7)
            .map(|k| frame.column(&format!("f_{name}[{k}]")))
            .collect();
        if let Some(cols) = cols {
            out.push((name.to_owned(), cols.try_into().expect("seven columns")));
        }
    }
    out
}

/// Imports a LAMMPS run: `atoms` is the `dump custom` (id, x, y[, z], radius or
/// diameter, optional mass, fx fy fz, tqx tqy tqz and `f_ID[1..8]` of
/// `fix wall/gran … contacts`), `local` the `dump local` of pair/local data.
/// Snapshots are matched by timestep; a sequence gets the timestep as frame.
pub fn import(atoms: &Path, local: &Path, options: &Options) -> Result<ImportedScene> {
    let (dim, pairs) = paired_snapshots(atoms, local, options.dim)?;
    let sequence = pairs.len() > 1;
    let mut frames = Vec::new();
    let mut forces = Vec::new();
    for (af, lf) in &pairs {
        let AtomsFrame {
            mut scene,
            index,
            wall_contacts,
        } = atoms_frame(atoms, af, dim)?;
        let columns = match &options.columns {
            Some(c) => c.clone(),
            None => LocalColumns::default_for(lf, local)?,
        };
        let ci = lf.require(local, &columns.i)?;
        let cj = lf.require(local, &columns.j)?;
        let cf: Vec<usize> = columns
            .force
            .iter()
            .map(|c| lf.require(local, c))
            .collect::<Result<_>>()?;
        let ct: Option<Vec<usize>> = match &columns.tangential {
            Some(t) => Some(
                t.iter()
                    .map(|c| lf.require(local, c))
                    .collect::<Result<_>>()?,
            ),
            None => None,
        };
        let mut frame_forces = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for row in &lf.rows {
            let id_i = atom_id(local, row, ci, &columns.i)?;
            let id_j = atom_id(local, row, cj, &columns.j)?;
            let lookup = |id: i64, col: &str| {
                index.get(&id).copied().ok_or_else(|| {
                    Error::data(
                        local,
                        Some(row.line),
                        Some(col),
                        format!(
                            "atom {id} is not in {} at timestep {}",
                            atoms.display(),
                            af.timestep
                        ),
                    )
                })
            };
            let a = lookup(id_i, &columns.i)?;
            let b = lookup(id_j, &columns.j)?;
            let mut f = [0.0; 3];
            for k in 0..dim {
                f[k] = row.values[cf[k]] + ct.as_ref().map_or(0.0, |t| row.values[t[k]]);
            }
            let (ga, gb) = (&scene.grains[a], &scene.grains[b]);
            let (ra, rb) = (ga.radius.unwrap_or(0.0), gb.radius.unwrap_or(0.0));
            let gap = scene::norm(scene::sub(gb.position, ga.position)) - ra - rb;
            if gap >= 0.0 && f.iter().all(|&x| x == 0.0) {
                continue; // a neighbour pair, not a contact
            }
            if !seen.insert((a.min(b), a.max(b))) {
                return Err(Error::data(
                    local,
                    Some(row.line),
                    Some(&columns.i),
                    format!("the pair {id_i}–{id_j} is listed twice"),
                ));
            }
            let Some((point, normal)) = sphere_contact(ga.position, ra, gb.position, rb) else {
                return Err(Error::data(
                    local,
                    Some(row.line),
                    Some(&columns.i),
                    format!("atoms {id_i} and {id_j} have the same centre"),
                ));
            };
            scene.contacts.push(Contact {
                id: format!("{id_i}-{id_j}"),
                a,
                b: Body::Grain(b),
                point,
                normal,
                mu: None,
            });
            frame_forces.push(f);
        }
        for (c, f) in wall_contacts {
            scene.contacts.push(c);
            frame_forces.push(f);
        }
        if let Some(g) = options.gravity {
            scene.settings.gravity = Some(g[..dim].to_vec());
        }
        scene.settings.description = Some(format!(
            "imported from LAMMPS dumps {} and {} (timestep {})",
            atoms.display(),
            local.display(),
            af.timestep
        ));
        if sequence {
            scene.frame = Some(af.timestep);
        }
        stress_from_forces(&mut scene, &frame_forces);
        frames.push(scene);
        forces.push(frame_forces);
    }
    if sequence {
        // scene.json is shared by all frames: keep a description that fits them all.
        let d = format!(
            "imported from LAMMPS dumps {} and {} ({} snapshots)",
            atoms.display(),
            local.display(),
            frames.len()
        );
        for s in &mut frames {
            s.settings.description = Some(d.clone());
        }
    }
    Ok(ImportedScene {
        warnings: Vec::new(),
        frames,
        forces: Some(forces),
    })
}

/// Gravity set by `fix ID GROUP gravity MAG STYLE ARGS` in a LAMMPS (or
/// LIGGGHTS) input script: the sum of the `gravity` fixes on group `all` still
/// defined at the end of the script (`unfix` removes one). Styles `vector x y
/// z`, `chute angle` and `spherical phi theta` are read as LAMMPS's
/// `FixGravity::set_acceleration` does (in 2D, per `dimension 2`, the vector's z
/// is dropped before normalising). A variable magnitude or direction, or a fix
/// on another group, is not read and is reported in the returned notes.
/// `None` when the script has no readable gravity fix.
pub fn gravity_from_script(path: &Path) -> Result<(Option<Vec3>, Vec<String>)> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut dim = 3;
    let mut fixes: Vec<(String, Vec3)> = Vec::new();
    let mut notes = Vec::new();
    let mut joined = String::new();
    let mut start = 0;
    for (i, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("").trim_end();
        if joined.is_empty() {
            start = i + 1;
        }
        if let Some(head) = line.strip_suffix('&') {
            joined.push_str(head);
            joined.push(' ');
            continue;
        }
        joined.push_str(line);
        let words: Vec<String> = joined.split_whitespace().map(str::to_owned).collect();
        joined.clear();
        let number = |k: usize| -> Result<Option<f64>> {
            let Some(w) = words.get(k) else {
                return Err(Error::data(
                    path,
                    Some(start),
                    None,
                    "fix gravity: too few arguments",
                ));
            };
            if w.starts_with("v_") {
                return Ok(None);
            }
            w.parse::<f64>().map(Some).map_err(|_| {
                Error::data(
                    path,
                    Some(start),
                    None,
                    format!("fix gravity: `{w}` is not a number"),
                )
            })
        };
        match words.first().map(String::as_str) {
            Some("dimension") if words.get(1).map(String::as_str) == Some("2") => dim = 2,
            Some("unfix") => {
                if let Some(id) = words.get(1) {
                    fixes.retain(|(f, _)| f != id);
                }
            }
            Some("fix") if words.get(3).map(String::as_str) == Some("gravity") => {
                let id = words[1].clone();
                if words[2] != "all" {
                    notes.push(format!(
                        "{}, line {start}: fix {id} applies gravity to group `{}` only; not used",
                        path.display(),
                        words[2]
                    ));
                    continue;
                }
                let style = words.get(5).map(String::as_str).unwrap_or("");
                let values: Vec<Option<f64>> = match style {
                    "vector" => [4, 6, 7, 8]
                        .into_iter()
                        .map(number)
                        .collect::<Result<_>>()?,
                    "chute" => [4, 6].into_iter().map(number).collect::<Result<_>>()?,
                    "spherical" => [4, 6, 7].into_iter().map(number).collect::<Result<_>>()?,
                    _ => {
                        notes.push(format!(
                            "{}, line {start}: fix {id} gravity style `{style}` is not read",
                            path.display()
                        ));
                        continue;
                    }
                };
                let Some(values) = values.into_iter().collect::<Option<Vec<f64>>>() else {
                    notes.push(format!(
                        "{}, line {start}: fix {id} gravity uses a variable; not read",
                        path.display()
                    ));
                    continue;
                };
                let magnitude = values[0];
                let (theta, phi) = match style {
                    "chute" => (180.0 - values[1], 0.0),
                    "spherical" => (values[2], values[1]),
                    _ => (0.0, 0.0),
                };
                let direction = if style == "vector" {
                    let mut d = [values[1], values[2], values[3]];
                    if dim == 2 {
                        d[2] = 0.0;
                    }
                    let len = scene::norm(d);
                    if len == 0.0 {
                        return Err(Error::data(
                            path,
                            Some(start),
                            None,
                            "fix gravity: zero direction vector",
                        ));
                    }
                    d.map(|x| x / len)
                } else {
                    let (t, p) = (theta.to_radians(), phi.to_radians());
                    if dim == 3 {
                        [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
                    } else {
                        [t.sin(), t.cos(), 0.0]
                    }
                };
                fixes.retain(|(f, _)| *f != id);
                fixes.push((id, direction.map(|x| magnitude * x)));
            }
            _ => {}
        }
    }
    if fixes.is_empty() {
        return Ok((None, notes));
    }
    let mut g = [0.0; 3];
    for (_, v) in &fixes {
        (0..3).for_each(|k| g[k] += v[k]);
    }
    Ok((Some(g), notes))
}
