//! YADE scenes exported by the recipe `fixtures/import/yade/grainforce_export.py`
//! (also in the README): `bodies.csv` and `interactions.csv`.
//!
//! Conventions (checked on a YADE 2023.02a run, `fixtures/import/yade/settle.py`,
//! and on YADE's source for the `Wall` case, `fixtures/import/yade/wall/`):
//! - spheres become grains (volume 4/3 π R³, or π R² per unit thickness when
//!   the run is a monolayer and `dim = 2`); any other body (Box, Facet, Wall…)
//!   becomes a wall named `<Kind><id>`, e.g. `Box4`;
//! - YADE applies −(normalForce + shearForce) to id1 and the opposite to id2,
//!   with `geom.normal` from id1 towards id2. So for a = id1, b = id2 the force
//!   on a by b is −(fn + fs) and the normal is YADE's; when id1 is a wall the
//!   pair is swapped (a = the sphere, normal reversed, force +(fn + fs));
//! - contact point: where YADE's ScGeom laws apply the force to the sphere,
//!   R − δ/2 from its centre along the normal (δ = `geom.penetrationDepth`;
//!   `Law2_*` add the torque (radius − δ/2) n × f). Between two spheres that is
//!   `geom.contactPoint` (middle of the overlap), and for Box and Facet too; for
//!   a `Wall` YADE's `contactPoint` is the centre projected on the plane, δ/2
//!   short of it. With the recipe's `depth` column every sphere–body contact
//!   is placed at R − δ/2; without it, `Wall` contacts get δ = R − |c − cp|;
//! - `O.forces.f/t` (contact force and torque, gravity excluded) give the
//!   acceleration a = f/m + g and α = τ/I with I = 0.4 m R²; g is
//!   `NewtonIntegrator.gravity` from the recipe's `gravity_*` columns, or
//!   `--gravity`, which overrides it (NewtonIntegrator adds g itself);
//! - when the torques are exported, each sphere's Σ r × f is checked against
//!   them and the disagreeing bodies are named in a warning (laws with rolling
//!   or twisting moments, or forces applied elsewhere, show up there);
//! - grain stresses are computed from the forces (V σ = Σ sym(r ⊗ f));
//! - periodic scenes are refused by the recipe.

use super::{
    ball_volume, check_radius, csv_cell, csv_number, read_csv, stress_from_forces, ImportedScene,
};
use crate::error::{Error, Result};
use crate::scene::{self, Body, Contact, Grain, Inertia, Scene, Vec3};
use std::collections::HashMap;
use std::path::Path;

#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Force the dimension; `None`: 2 when all sphere centres share one z.
    pub dim: Option<usize>,
    /// Gravity of the run (written to scene.json and used for a = f/m + g);
    /// overrides the export's `gravity_*` columns.
    pub gravity: Option<Vec3>,
}

enum Kind {
    Grain(usize),
    /// Wall name and YADE shape class.
    Wall(String, String),
}

/// Relative torque mismatch |Σ r × f − τ| / (mean |f| R) above which a body is
/// named in the warning (exports carry 17 significant digits).
const TORQUE_TOLERANCE: f64 = 1e-6;

/// An optional number: an empty cell is `None`.
fn optional_number(
    path: &Path,
    cols: &HashMap<String, usize>,
    r: &csv::StringRecord,
    line: usize,
    name: &str,
) -> Result<Option<f64>> {
    if !cols.contains_key(name) || csv_cell(path, cols, r, line, name)?.trim().is_empty() {
        return Ok(None);
    }
    csv_number(path, cols, r, line, name).map(Some)
}

/// The export's gravity: every row of the `gravity_*` columns holds the same
/// vector (empty when the run had no NewtonIntegrator).
fn gravity_from_export(
    bodies: &Path,
    cols: &HashMap<String, usize>,
    rows: &[(usize, csv::StringRecord)],
) -> Result<Option<Vec3>> {
    let mut found: Option<Vec3> = None;
    for (line, r) in rows {
        let mut g = [0.0; 3];
        let mut empty = false;
        for (k, name) in ["gravity_x", "gravity_y", "gravity_z"].iter().enumerate() {
            match optional_number(bodies, cols, r, *line, name)? {
                Some(x) => g[k] = x,
                None => empty = true,
            }
        }
        if empty {
            continue;
        }
        match found {
            Some(f) if f != g => {
                return Err(Error::data(
                    bodies,
                    Some(*line),
                    Some("gravity_x"),
                    "gravity differs from the rows above (it is one vector per run)",
                ))
            }
            _ => found = Some(g),
        }
    }
    Ok(found)
}

pub fn import(bodies: &Path, interactions: &Path, options: &Options) -> Result<ImportedScene> {
    let (cols, rows) = read_csv(bodies)?;
    // First pass: spheres' z, to detect the dimension.
    let mut sphere_z = Vec::new();
    for (line, r) in &rows {
        if csv_cell(bodies, &cols, r, *line, "kind")? == "Sphere" {
            sphere_z.push(csv_number(bodies, &cols, r, *line, "z")?);
        }
    }
    let dim = match options.dim {
        Some(d @ (2 | 3)) => d,
        Some(d) => return Err(Error::Invalid(format!("dimension must be 2 or 3, not {d}"))),
        None => {
            let same = sphere_z.windows(2).all(|w| w[0] == w[1]);
            if same {
                2
            } else {
                3
            }
        }
    };
    let gravity = match options.gravity {
        Some(g) => Some(g),
        None => gravity_from_export(bodies, &cols, &rows)?,
    };
    let g = gravity.unwrap_or([0.0; 3]);
    let has_f = cols.contains_key("f_x");
    let has_t = cols.contains_key("t_x");
    let mut scene = Scene::new(dim);
    let mut kinds: HashMap<String, Kind> = HashMap::new();
    // O.forces.t per grain, for the moment check.
    let mut torques: Vec<Option<Vec3>> = Vec::new();
    for (line, r) in &rows {
        let line = *line;
        let id = csv_cell(bodies, &cols, r, line, "id")?.to_owned();
        let kind = csv_cell(bodies, &cols, r, line, "kind")?;
        let entry = if kind == "Sphere" {
            let mut p = [0.0; 3];
            for k in 0..dim {
                p[k] = csv_number(bodies, &cols, r, line, ["x", "y", "z"][k])?;
            }
            let radius = check_radius(
                bodies,
                line,
                "radius",
                csv_number(bodies, &cols, r, line, "radius")?,
            )?;
            let mut grain = Grain::new(id.clone(), p, ball_volume(dim, radius), [0.0; 6]);
            grain.radius = Some(radius);
            let mut torque = None;
            if has_t {
                let mut t = [0.0; 3];
                for (k, name) in ["t_x", "t_y", "t_z"].iter().enumerate() {
                    t[k] = csv_number(bodies, &cols, r, line, name)?;
                }
                torque = Some(t);
            }
            torques.push(torque);
            if cols.contains_key("mass") {
                let m = csv_number(bodies, &cols, r, line, "mass")?;
                if m <= 0.0 {
                    return Err(Error::data(
                        bodies,
                        Some(line),
                        Some("mass"),
                        format!("mass must be positive, got {m}"),
                    ));
                }
                grain.mass = Some(m);
                if has_f {
                    let mut a = [0.0; 3];
                    for k in 0..dim {
                        a[k] = csv_number(bodies, &cols, r, line, ["f_x", "f_y", "f_z"][k])? / m
                            + g[k];
                    }
                    grain.acceleration = Some(a);
                }
                if let Some(t) = torque {
                    let inertia = 0.4 * m * radius * radius;
                    let mut alpha = [0.0; 3];
                    for k in 0..3 {
                        if dim == 3 || k == 2 {
                            alpha[k] = t[k] / inertia;
                        }
                    }
                    grain.inertia = Some(Inertia::Scalar(inertia));
                    grain.angular_acceleration = Some(alpha);
                }
            }
            scene.grains.push(grain);
            Kind::Grain(scene.grains.len() - 1)
        } else {
            Kind::Wall(format!("{kind}{id}"), kind.to_owned())
        };
        if kinds.insert(id.clone(), entry).is_some() {
            return Err(Error::data(
                bodies,
                Some(line),
                Some("id"),
                format!("body {id} is listed twice"),
            ));
        }
    }

    let (icols, irows) = read_csv(interactions)?;
    let ip = interactions;
    let vector = |r: &csv::StringRecord, line: usize, prefix: &str| -> Result<Vec3> {
        let mut v = [0.0; 3];
        for k in 0..3 {
            v[k] = csv_number(
                ip,
                &icols,
                r,
                line,
                &format!("{prefix}{}", ["x", "y", "z"][k]),
            )?;
        }
        Ok(v)
    };
    let mut forces = Vec::new();
    for (line, r) in &irows {
        let line = *line;
        let id1 = csv_cell(ip, &icols, r, line, "id1")?;
        let id2 = csv_cell(ip, &icols, r, line, "id2")?;
        let body = |id: &str, col: &str| {
            kinds.get(id).ok_or_else(|| {
                Error::data(
                    ip,
                    Some(line),
                    Some(col),
                    format!("body {id} is not in {}", bodies.display()),
                )
            })
        };
        let (k1, k2) = (body(id1, "id1")?, body(id2, "id2")?);
        let point = vector(r, line, "cp_")?;
        let normal = vector(r, line, "n_")?;
        let fn_ = vector(r, line, "fn_")?;
        let fs = vector(r, line, "fs_")?;
        let total = [fn_[0] + fs[0], fn_[1] + fs[1], fn_[2] + fs[2]];
        let len = scene::norm(normal);
        if (len - 1.0).abs() > 1e-2 {
            return Err(Error::data(
                ip,
                Some(line),
                Some("n_x"),
                format!("the normal is not a unit vector (its length is {len})"),
            ));
        }
        let (a, b, sign, wall_first, wall_kind) = match (k1, k2) {
            (Kind::Grain(a), Kind::Grain(b)) => (*a, Body::Grain(*b), -1.0, false, None),
            (Kind::Grain(a), Kind::Wall(w, kind)) => (
                *a,
                Body::Wall(scene.wall_or_insert(w)),
                -1.0,
                false,
                Some(kind),
            ),
            (Kind::Wall(w, kind), Kind::Grain(a)) => (
                *a,
                Body::Wall(scene.wall_or_insert(w)),
                1.0,
                true,
                Some(kind),
            ),
            (Kind::Wall(..), Kind::Wall(..)) => continue, // wall–wall: no grain involved
        };
        let n_sign = if wall_first { -1.0 } else { 1.0 };
        let depth = optional_number(ip, &icols, r, line, "depth")?;
        let point = match wall_kind {
            Some(kind) => {
                let grain = &scene.grains[a];
                let centre = grain.position;
                let radius = grain.radius.expect("spheres have radii");
                // δ from the export, else from a Wall's projected point.
                let depth = depth.or_else(|| {
                    (kind == "Wall").then(|| {
                        let mut c = centre;
                        if dim == 2 {
                            c[2] = point[2];
                        }
                        radius - scene::norm(scene::sub(point, c))
                    })
                });
                match depth {
                    Some(delta) => {
                        // Normal from the sphere towards the body.
                        let arm = (radius - 0.5 * delta) * n_sign / len;
                        let mut p = [0.0; 3];
                        for k in 0..3 {
                            p[k] = centre[k] + arm * normal[k];
                        }
                        if dim == 2 {
                            p[2] = point[2];
                        }
                        p
                    }
                    None => point,
                }
            }
            None => point,
        };
        let mut contact = Contact {
            id: if wall_first {
                format!("{id2}-{id1}")
            } else {
                format!("{id1}-{id2}")
            },
            a,
            b,
            point,
            normal: normal.map(|x| n_sign * x / len),
            mu: None,
        };
        let mut f = total.map(|x| sign * x);
        if dim == 2 {
            contact.point[2] = 0.0;
            contact.normal[2] = 0.0;
            f[2] = 0.0;
        }
        scene.contacts.push(contact);
        forces.push(f);
    }
    if let Some(gv) = gravity {
        scene.settings.gravity = Some(gv[..dim].to_vec());
    }
    let mut warnings = Vec::new();
    if let Some(w) = torque_warning(&scene, &forces, &torques, bodies) {
        warnings.push(w);
    }
    scene.settings.description = Some(format!(
        "imported from YADE export {} and {}",
        bodies.display(),
        interactions.display()
    ));
    stress_from_forces(&mut scene, &forces);
    Ok(ImportedScene {
        frames: vec![scene],
        forces: Some(vec![forces]),
        warnings,
    })
}

/// Per grain with an exported torque: |Σ r × f − τ| relative to the mean
/// |f|·R over all contacts (in 2D only the z component is compared).
pub fn torque_mismatch(
    scene: &Scene,
    forces: &[Vec3],
    torques: &[Option<Vec3>],
) -> Vec<Option<f64>> {
    let mut moments = vec![[0.0; 3]; scene.grains.len()];
    let mut scale = 0.0;
    for (c, f) in scene.contacts.iter().zip(forces) {
        let t = scene::cross(scene::sub(c.point, scene.grains[c.a].position), *f);
        (0..3).for_each(|k| moments[c.a][k] += t[k]);
        scale += scene::norm(*f) * scene.grains[c.a].radius.unwrap_or(0.0);
        if let Body::Grain(b) = c.b {
            let t = scene::cross(scene::sub(c.point, scene.grains[b].position), *f);
            (0..3).for_each(|k| moments[b][k] -= t[k]);
        }
    }
    let scale = scale / forces.len().max(1) as f64;
    moments
        .iter()
        .zip(torques)
        .map(|(m, t)| {
            let t = (*t)?;
            let mut d = scene::sub(*m, t);
            if scene.dim == 2 {
                d[0] = 0.0;
                d[1] = 0.0;
            }
            Some(if scale > 0.0 {
                scene::norm(d) / scale
            } else {
                scene::norm(d)
            })
        })
        .collect()
}

fn torque_warning(
    scene: &Scene,
    forces: &[Vec3],
    torques: &[Option<Vec3>],
    bodies: &Path,
) -> Option<String> {
    let mismatch = torque_mismatch(scene, forces, torques);
    let bad: Vec<(&str, f64)> = scene
        .grains
        .iter()
        .zip(&mismatch)
        .filter_map(|(g, m)| {
            m.filter(|m| *m > TORQUE_TOLERANCE)
                .map(|m| (g.id.as_str(), m))
        })
        .collect();
    if bad.is_empty() {
        return None;
    }
    let worst = bad.iter().map(|b| b.1).fold(0.0, f64::max);
    let mut names: Vec<&str> = bad.iter().take(12).map(|b| b.0).collect();
    let more = bad.len().saturating_sub(names.len());
    let more = if more > 0 {
        format!(" and {more} more")
    } else {
        String::new()
    };
    names.sort();
    Some(format!(
        "on {} sphere(s) the contact moments Σ r × f differ from YADE's torques (t_* of {}) by up \
         to {:.2e} of the mean |f|·R: bodies {}{}. The contact law applies moments or forces \
         elsewhere than grainforce assumes (R − depth/2 from the centre); export `depth` with the \
         recipe, or expect `qs` to miss these forces",
        bad.len(),
        bodies.display(),
        worst,
        names.join(", "),
        more
    ))
}
