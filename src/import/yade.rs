//! YADE scenes exported by the recipe `fixtures/import/yade/grainforce_export.py`
//! (also in the README): `bodies.csv` and `interactions.csv`.
//!
//! Conventions (checked on a YADE 2023.02a run, `fixtures/import/yade/settle.py`):
//! - spheres become grains (volume 4/3 π R³, or π R² per unit thickness when
//!   the run is a monolayer and `dim = 2`); any other body (Box, Facet, Wall…)
//!   becomes a wall named `<Kind><id>`, e.g. `Box4`;
//! - YADE applies −(normalForce + shearForce) to id1 and the opposite to id2,
//!   with `geom.normal` from id1 towards id2. So for a = id1, b = id2 the force
//!   on a by b is −(fn + fs) and the normal is YADE's; when id1 is a wall the
//!   pair is swapped (a = the sphere, normal reversed, force +(fn + fs));
//! - the contact point is YADE's `geom.contactPoint` (for ScGeom the middle of
//!   the overlap);
//! - `O.forces.f/t` (contact force and torque, gravity excluded) give the
//!   acceleration a = f/m + g and α = τ/I with I = 0.4 m R², where g is the
//!   gravity given to the importer (YADE's NewtonIntegrator adds it itself);
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
    /// Gravity of the run (written to scene.json and used for a = f/m + g).
    pub gravity: Option<Vec3>,
}

enum Kind {
    Grain(usize),
    Wall(String),
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
    let g = options.gravity.unwrap_or([0.0; 3]);
    let has_f = cols.contains_key("f_x");
    let has_t = cols.contains_key("t_x");
    let mut scene = Scene::new(dim);
    let mut kinds: HashMap<String, Kind> = HashMap::new();
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
                if has_t {
                    let inertia = 0.4 * m * radius * radius;
                    let mut alpha = [0.0; 3];
                    for k in 0..3 {
                        if dim == 3 || k == 2 {
                            alpha[k] =
                                csv_number(bodies, &cols, r, line, ["t_x", "t_y", "t_z"][k])?
                                    / inertia;
                        }
                    }
                    grain.inertia = Some(Inertia::Scalar(inertia));
                    grain.angular_acceleration = Some(alpha);
                }
            }
            scene.grains.push(grain);
            Kind::Grain(scene.grains.len() - 1)
        } else {
            Kind::Wall(format!("{kind}{id}"))
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
        let (a, b, sign, wall_first) = match (k1, k2) {
            (Kind::Grain(a), Kind::Grain(b)) => (*a, Body::Grain(*b), -1.0, false),
            (Kind::Grain(a), Kind::Wall(w)) => {
                (*a, Body::Wall(scene.wall_or_insert(w)), -1.0, false)
            }
            (Kind::Wall(w), Kind::Grain(a)) => (*a, Body::Wall(scene.wall_or_insert(w)), 1.0, true),
            (Kind::Wall(_), Kind::Wall(_)) => continue, // wall–wall: no grain involved
        };
        let n_sign = if wall_first { -1.0 } else { 1.0 };
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
    if let Some(gv) = options.gravity {
        scene.settings.gravity = Some(gv[..dim].to_vec());
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
    })
}
