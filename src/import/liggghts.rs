//! LIGGGHTS: a `dump custom` of atoms plus a `dump local` of
//! `compute pair/gran/local` (checked on a LIGGGHTS 3.8.0 run,
//! `fixtures/import/liggghts/in.settle`).
//!
//! The local dump's columns are unnamed (`c_ID[1]` …); they follow the
//! keywords of the compute, in the order LIGGGHTS writes them, which is fixed
//! whatever the order in the command: pos (x_i y_i z_i x_j y_j z_j), vel (6),
//! id (id_i id_j periodic-flag), force (3, on i by j), force_normal (3),
//! force_tangential (3), torque (3), history (`--history N` values),
//! contactArea (1), delta (1), heatFlux (1). `contactPoint` (3, in LIGGGHTS
//! versions that have it) is read where it is listed in `keywords`; when
//! present it is the contact point, otherwise the point is the middle of the
//! overlap on the line of centres. `id` and `force` are required.
//!
//! Contact a = atom i, b = atom j, force on a by b = `force`. Atoms, 2D
//! detection, masses and accelerations (a = f/m from per-atom `fx fy fz`) are
//! handled as for LAMMPS ([`super::lammps`]); periodic boxes are refused.
//! Wall contacts (`compute wall/gran/local`, mesh walls only) are not read:
//! grains touching walls then lack those forces, and their stresses are
//! incomplete; the importer says so through [`ImportedScene::momentum_residual`].

use super::dump::paired_snapshots;
use super::lammps::{atoms_frame, AtomsFrame};
use super::{sphere_contact, stress_from_forces, ImportedScene};
use crate::error::{Error, Result};
use crate::scene::{Body, Contact, Vec3};
use std::collections::HashMap;
use std::path::Path;

#[derive(Debug, Clone, Default)]
pub struct Options {
    /// Keywords of `compute pair/gran/local`, in the order of the columns.
    /// `None`: `pos,id,force` for 12 columns, `id,force` for 6.
    pub keywords: Option<Vec<String>>,
    /// Number of history values (keyword `history`).
    pub history: usize,
    pub dim: Option<usize>,
    pub gravity: Option<Vec3>,
}

fn width(keyword: &str, history: usize) -> Option<usize> {
    Some(match keyword {
        "pos" | "vel" => 6,
        "id" | "force" | "force_normal" | "force_tangential" | "torque" | "contactPoint" => 3,
        "history" => history,
        "contactArea" | "delta" | "heatFlux" => 1,
        _ => return None,
    })
}

pub fn import(atoms: &Path, local: &Path, options: &Options) -> Result<ImportedScene> {
    let (dim, pairs) = paired_snapshots(atoms, local, options.dim)?;
    let sequence = pairs.len() > 1;
    let mut frames = Vec::new();
    let mut all_forces = Vec::new();
    for (af, lf) in &pairs {
        let n_cols = lf.columns.len();
        let keywords: Vec<String> = match &options.keywords {
            Some(k) => k.clone(),
            None => match n_cols {
                12 => vec!["pos".into(), "id".into(), "force".into()],
                6 => vec!["id".into(), "force".into()],
                _ => {
                    return Err(Error::data(
                        local,
                        Some(lf.header_line),
                        None,
                        format!(
                            "{n_cols} columns: name the compute's keywords with --keywords \
                             (e.g. pos,id,force,contactPoint)"
                        ),
                    ))
                }
            },
        };
        let mut offset: HashMap<&str, usize> = HashMap::new();
        let mut at = 0;
        for k in &keywords {
            let w = width(k, options.history).ok_or_else(|| {
                Error::Invalid(format!(
                    "unknown pair/gran/local keyword `{k}` (known: pos vel id force force_normal \
                     force_tangential torque history contactArea delta heatFlux contactPoint)"
                ))
            })?;
            offset.insert(k.as_str(), at);
            at += w;
        }
        if at != n_cols {
            return Err(Error::data(
                local,
                Some(lf.header_line),
                None,
                format!(
                    "the keywords {} make {at} columns, the dump has {n_cols}",
                    keywords.join(",")
                ),
            ));
        }
        let need = |k: &str| {
            offset.get(k).copied().ok_or_else(|| {
                Error::Invalid(format!("the pair/gran/local dump needs the `{k}` keyword"))
            })
        };
        let (id_at, force_at) = (need("id")?, need("force")?);
        let point_at = offset.get("contactPoint").copied();

        let AtomsFrame {
            mut scene, index, ..
        } = atoms_frame(atoms, af, dim)?;
        let mut forces = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for row in &lf.rows {
            let col = |k: usize| lf.columns[k].as_str();
            let mut ids = [0usize; 2];
            let mut raw = [0i64; 2];
            for s in 0..2 {
                let v = row.values[id_at + s];
                let found = (v.fract() == 0.0).then(|| index.get(&(v as i64))).flatten();
                let Some(&g) = found else {
                    return Err(Error::data(
                        local,
                        Some(row.line),
                        Some(col(id_at + s)),
                        format!(
                            "atom {v} is not in {} at timestep {}",
                            atoms.display(),
                            af.timestep
                        ),
                    ));
                };
                ids[s] = g;
                raw[s] = v as i64;
            }
            let [a, b] = ids;
            if a == b || !seen.insert((a.min(b), a.max(b))) {
                return Err(Error::data(
                    local,
                    Some(row.line),
                    Some(col(id_at)),
                    format!(
                        "the pair {}–{} is repeated or an atom with itself",
                        raw[0], raw[1]
                    ),
                ));
            }
            let mut f = [0.0; 3];
            f[..dim].copy_from_slice(&row.values[force_at..force_at + dim]);
            let (ga, gb) = (&scene.grains[a], &scene.grains[b]);
            let Some((mid, normal)) = sphere_contact(
                ga.position,
                ga.radius.unwrap_or(0.0),
                gb.position,
                gb.radius.unwrap_or(0.0),
            ) else {
                return Err(Error::data(
                    local,
                    Some(row.line),
                    Some(col(id_at)),
                    "the two atoms have the same centre",
                ));
            };
            let point = match point_at {
                Some(p) => {
                    let mut x = [0.0; 3];
                    x[..dim].copy_from_slice(&row.values[p..p + dim]);
                    x
                }
                None => mid,
            };
            scene.contacts.push(Contact {
                id: format!("{}-{}", raw[0], raw[1]),
                a,
                b: Body::Grain(b),
                point,
                normal,
                mu: None,
            });
            forces.push(f);
        }
        if let Some(g) = options.gravity {
            scene.settings.gravity = Some(g[..dim].to_vec());
        }
        scene.settings.description = Some(format!(
            "imported from LIGGGHTS dumps {} and {}",
            atoms.display(),
            local.display()
        ));
        if sequence {
            scene.frame = Some(af.timestep);
        }
        stress_from_forces(&mut scene, &forces);
        frames.push(scene);
        all_forces.push(forces);
    }
    Ok(ImportedScene {
        warnings: Vec::new(),
        frames,
        forces: Some(all_forces),
    })
}
