//! PeGS / PeGS2 output (the photoelastic community's MATLAB pipeline,
//! Kollmer's PhotoElastic Grain Solver and its modular successor): the
//! `particle` struct array of contactDetect's `*_contacts.mat` or diskSolve's
//! `*_solved.mat` (PeGS 1.x: `particle` in PeGSDiskPrep's
//! `*_preprocessing.mat`, `pres` in PeGSDiskSolve's `*_solved.mat`),
//! optionally with particleDetect's `*_centers.txt`.
//!
//! PeGS's conventions, read from its source (PeGS2 `contactDetect.m`,
//! `diskSolve.m`, `stress_engine_original.m`, `adjacencyMatrix.m`; PeGS 1
//! `PeGSNeighbourFind.m`):
//! - `x`, `y`, `r`: MATLAB pixel coordinates, 1-based (the centre of the
//!   first pixel is at 1), `y` down the image rows. contactDetect rounds `r`
//!   to whole pixels; the centres file keeps the fitted radius, and is used
//!   for the radii (and checked against `x`, `y`) when given. `rm` = r · the
//!   run's metres per pixel.
//! - `neighbours(k)`: the id of the k-th contact's other disk (PeGS 1: its
//!   index), or a negative number for a wall. `betas(k)`: the direction from
//!   the centre to that contact, `atan2(Δy, Δx)` in pixel coordinates (y
//!   down); walls: 0 right, π left, π/2 the bottom of the image, −π/2 the top.
//! - `forces(k)`, `alphas(k)`: the fitted force on this disk at contact k,
//!   magnitude f [N, the unit of the fσ calibration] at angle α from the
//!   inward normal; normal part f cos α, tangential f sin α
//!   (adjacencyMatrix). From the fringe model (the chord of the force runs
//!   from the contact at β to the rim point at β + π − 2α) the force on the
//!   disk is, in pixel coordinates, F = −f (cos(β − α), sin(β − α)).
//! - Each contact between two disks is fitted twice, once in each disk's
//!   solve, and the two need not obey Newton's third law. The scene's force
//!   on `a` by `b` is the mean of `a`'s fit and minus `b`'s, and the
//!   disagreement is reported.
//!
//! Scene coordinates follow `detect` (docs/image.md): y up, x = (x − ½)/S,
//! y = (H + ½ − y)/S for an image H pixels high and S pixels per metre. S is
//! `--scale`, else r/rm from the file; H comes from the photograph, else the
//! lowest disk edge. Forces are divided by the disk thickness when given
//! (2D scenes hold forces per unit thickness).

use super::mat5::{self, Value};
use super::{ball_volume, sphere_contact, stress_from_forces, ImportedScene};
use crate::error::{Error, Result};
use crate::scene::{self, Body, Contact, Grain, Scene, Vec3};
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

#[derive(Debug, Clone, Default)]
pub struct Options {
    /// particleDetect's `*_centers.txt` (x, y, r, edge per disk, in the
    /// particle order), for the unrounded radii.
    pub centres: Option<PathBuf>,
    /// Pixels per metre; `None`: from the file's r/rm, else pixels.
    pub px_per_m: Option<f64>,
    /// Height of the photograph [px], for the y flip; `None`: the lowest disk
    /// edge, rounded up.
    pub image_height: Option<u32>,
    /// Disk thickness [m]: forces become forces per unit thickness.
    pub thickness: Option<f64>,
    pub gravity: Option<Vec3>,
}

/// How pixels became scene coordinates (for `image-frame.json` and notes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Conversion {
    pub px_per_m: f64,
    /// Where S came from: `--scale`, the file's rm, or none (1 px = 1 m).
    pub scale_source: ScaleSource,
    pub image_height: f64,
    pub height_given: bool,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ScaleSource {
    Given,
    File,
    Pixels,
}

/// One row of a centres file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Centre {
    pub line: usize,
    pub x: f64,
    pub y: f64,
    pub r: f64,
    pub edge: f64,
}

/// Reads particleDetect's centres file: `x,y,r,edge` per line (commas or
/// blanks), MATLAB pixel coordinates.
pub fn read_centres(path: &Path) -> Result<Vec<Centre>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let cells: Vec<&str> = line
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|c| !c.is_empty())
            .collect();
        if cells.is_empty() {
            continue;
        }
        if cells.len() != 4 {
            let hint = if cells.len() == 6 {
                " (particleTrack's particle_positions.txt has frame,id,x,y,r,edge: give the \
                 frame's *_centers.txt, or only the .mat)"
            } else {
                ""
            };
            return Err(Error::data(
                path,
                Some(n),
                None,
                format!(
                    "expected 4 values `x,y,r,edge`, found {}{hint}",
                    cells.len()
                ),
            ));
        }
        let mut v = [0.0; 4];
        for (k, (cell, name)) in cells.iter().zip(["x", "y", "r", "edge"]).enumerate() {
            v[k] = match cell.parse::<f64>() {
                Ok(x) if x.is_finite() => x,
                _ => {
                    return Err(Error::data(
                        path,
                        Some(n),
                        Some(name),
                        format!("`{cell}` is not a finite number"),
                    ))
                }
            };
        }
        if v[2] <= 0.0 {
            return Err(Error::data(
                path,
                Some(n),
                Some("r"),
                format!("radius must be positive, got {}", v[2]),
            ));
        }
        rows.push(Centre {
            line: n,
            x: v[0],
            y: v[1],
            r: v[2],
            edge: v[3],
        });
    }
    Ok(rows)
}

/// A disk as read from the struct array, in pixels.
struct Disk {
    id: String,
    /// The id as a number, for neighbour look-ups.
    key: f64,
    x: f64,
    y: f64,
    r: f64,
    rm: Option<f64>,
    contacts: Vec<Touch>,
}

/// Contact k of a disk.
struct Touch {
    neighbour: f64,
    beta: f64,
    /// (f, α) when the disk was solved.
    force: Option<(f64, f64)>,
}

/// The names of the disks' struct array: `particle` (PeGS2, and PeGS 1.x's
/// PeGSDiskPrep `*_preprocessing.mat`), `pres` (PeGS 1.x's PeGSDiskSolve
/// `*_solved.mat`: the same fields plus `forces`, `alphas`, `fitError`,
/// `synthImg`).
const STRUCT_NAMES: [&str; 2] = ["particle", "pres"];

/// Reads the disks' struct array with the field checks PeGS's format
/// implies; errors name the file and `particle(n).field` (1-based, as
/// MATLAB; `pres(n).field` in a PeGS 1.x solved file).
fn read_particles(path: &Path) -> Result<Vec<Disk>> {
    let variables = mat5::read(path)?;
    let Some(var) = STRUCT_NAMES
        .iter()
        .find_map(|&name| variables.iter().find(|v| v.name == name))
    else {
        let names: Vec<&str> = variables.iter().map(|v| v.name.as_str()).collect();
        return Err(Error::data(
            path,
            None,
            None,
            format!(
                "no variable `particle` or `pres` (PeGS's struct array of disks); the file holds: {}",
                if names.is_empty() {
                    "nothing".to_owned()
                } else {
                    names.join(", ")
                }
            ),
        ));
    };
    let particle = &var.value;
    let name = var.name.as_str();
    let Value::Struct { fields, .. } = particle else {
        return Err(Error::data(
            path,
            None,
            None,
            format!("`{name}` is {}, not a struct array", particle.describe()),
        ));
    };
    let bad = |message: String| Error::data(path, None, None, message);
    for needed in ["x", "y", "r"] {
        if !fields.iter().any(|f| f == needed) {
            return Err(bad(format!(
                "`{name}` has no field `{needed}` (fields: {})",
                fields.join(", ")
            )));
        }
    }
    let has = |f: &str| fields.iter().any(|x| x == f);
    let has_contacts = has("neighbours") && has("betas");
    if has("neighbours") != has("betas") {
        return Err(bad(format!(
            "`{name}` has `{}` but not `{}`: each contact needs both",
            if has("neighbours") {
                "neighbours"
            } else {
                "betas"
            },
            if has("neighbours") {
                "betas"
            } else {
                "neighbours"
            }
        )));
    }
    let n = particle.len();
    let mut disks = Vec::with_capacity(n);
    for i in 0..n {
        let at = |f: &str| format!("{name}({}).{f}", i + 1);
        let get = |f: &str| particle.field(i, f);
        let scalar = |f: &str| -> Result<f64> {
            let v = get(f).ok_or_else(|| bad(format!("{} is missing", at(f))))?;
            match v.numbers().as_deref() {
                Some(&[x]) if x.is_finite() => Ok(x),
                Some(&[x]) => Err(bad(format!("{} is {x}, not a finite number", at(f)))),
                _ => Err(bad(format!(
                    "{} should be one number, found {}",
                    at(f),
                    v.describe()
                ))),
            }
        };
        let list = |f: &str| -> Result<Vec<f64>> {
            let Some(v) = get(f) else {
                return Ok(Vec::new());
            };
            let Some(x) = v.numbers() else {
                return Err(bad(format!(
                    "{} should be numbers, found {}",
                    at(f),
                    v.describe()
                )));
            };
            if let Some(k) = x.iter().position(|x| !x.is_finite()) {
                return Err(bad(format!(
                    "{}({}) is {}, not a finite number",
                    at(f),
                    k + 1,
                    x[k]
                )));
            }
            Ok(x)
        };
        let (x, y, r) = (scalar("x")?, scalar("y")?, scalar("r")?);
        if r <= 0.0 {
            return Err(bad(format!("{} must be positive, got {r}", at("r"))));
        }
        let key = if has("id") {
            scalar("id")?
        } else {
            (i + 1) as f64
        };
        let rm = if has("rm") {
            Some(scalar("rm")?).filter(|v| *v > 0.0)
        } else {
            None
        };
        let mut contacts = Vec::new();
        if has_contacts {
            let neighbours = list("neighbours")?;
            let betas = list("betas")?;
            if betas.len() != neighbours.len() {
                return Err(bad(format!(
                    "{} has {} values but {} has {}",
                    at("betas"),
                    betas.len(),
                    at("neighbours"),
                    neighbours.len()
                )));
            }
            if has("z") {
                let z = scalar("z")?;
                if z != neighbours.len() as f64 {
                    return Err(bad(format!(
                        "{} = {z} but {} lists {} contacts",
                        at("z"),
                        at("neighbours"),
                        neighbours.len()
                    )));
                }
            }
            let forces = list("forces")?;
            let alphas = list("alphas")?;
            let solved = !forces.is_empty() || !alphas.is_empty();
            if solved && (forces.len() != neighbours.len() || alphas.len() != neighbours.len()) {
                return Err(bad(format!(
                    "{} lists {} contacts but {} has {} values and {} has {}",
                    at("neighbours"),
                    neighbours.len(),
                    at("forces"),
                    forces.len(),
                    at("alphas"),
                    alphas.len()
                )));
            }
            for (k, (&neighbour, &beta)) in neighbours.iter().zip(&betas).enumerate() {
                if neighbour == 0.0 || neighbour.fract() != 0.0 {
                    return Err(bad(format!(
                        "{}({}) = {neighbour} is neither a particle id nor a wall (negative)",
                        at("neighbours"),
                        k + 1
                    )));
                }
                contacts.push(Touch {
                    neighbour,
                    beta,
                    force: solved.then(|| (forces[k], alphas[k])),
                });
            }
        }
        disks.push(Disk {
            id: number_id(key),
            key,
            x,
            y,
            r,
            rm,
            contacts,
        });
    }
    Ok(disks)
}

/// "12" for 12.0; other numbers as written by Rust.
fn number_id(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{}", x as i64)
    } else {
        format!("{x}")
    }
}

/// Wall name from PeGS's wall contact angle (pixel frame, y down).
fn wall_name(beta: f64, code: f64) -> String {
    let named = [
        (0.0, "right"),
        (std::f64::consts::FRAC_PI_2, "bottom"),
        (std::f64::consts::PI, "left"),
        (-std::f64::consts::FRAC_PI_2, "top"),
    ];
    for (angle, name) in named {
        let d = (beta - angle).rem_euclid(std::f64::consts::TAU);
        if d.min(std::f64::consts::TAU - d) < 1e-6 {
            return name.to_owned();
        }
    }
    format!("wall{}", number_id(code))
}

/// Unit vector of pixel-frame angle β in the scene frame (y up).
fn direction(beta: f64) -> Vec3 {
    [beta.cos(), -beta.sin(), 0.0]
}

/// PeGS's force on the disk, in the scene frame, per unit thickness.
fn force_on_disk(f: f64, alpha: f64, beta: f64, thickness: f64) -> Vec3 {
    let t = beta - alpha;
    [-f * t.cos() / thickness, f * t.sin() / thickness, 0.0]
}

/// Imports one PeGS `particle` file (one image) as a 2D scene, with PeGS's
/// forces as the reference forces when the file was solved.
pub fn import(mat: &Path, options: &Options) -> Result<(ImportedScene, Conversion)> {
    let mut disks = read_particles(mat)?;
    if disks.is_empty() {
        return Err(Error::data(mat, None, None, "the file holds no disks"));
    }
    // Before the centres file replaces the rounded radii rm was made from.
    let in_file = file_scale(&disks);
    if let Some(path) = &options.centres {
        let centres = read_centres(path)?;
        if centres.len() != disks.len() {
            return Err(Error::data(
                path,
                None,
                None,
                format!(
                    "{} disks, but {} holds {}: give the centres file of the same image",
                    centres.len(),
                    mat.display(),
                    disks.len()
                ),
            ));
        }
        for (k, (d, c)) in disks.iter_mut().zip(&centres).enumerate() {
            let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(1.0);
            // contactDetect rounds r; PeGS 1 keeps it.
            if !close(d.x, c.x) || !close(d.y, c.y) || (d.r - c.r).abs() > 0.5 + 1e-9 {
                return Err(Error::data(
                    path,
                    Some(c.line),
                    None,
                    format!(
                        "disk ({}, {}, r {}) is not particle({}) of {} at ({}, {}, r {}): give the \
                         centres file of the same image",
                        c.x,
                        c.y,
                        c.r,
                        k + 1,
                        mat.display(),
                        d.x,
                        d.y,
                        d.r
                    ),
                ));
            }
            d.r = c.r;
        }
    }
    let mut warnings = Vec::new();
    let (s, scale_source) = match options.px_per_m {
        Some(s) if s > 0.0 && s.is_finite() => (s, ScaleSource::Given),
        Some(s) => return Err(Error::Invalid(format!("--scale must be positive, got {s}"))),
        None => match in_file {
            FileScale::Agreed(s) => (s, ScaleSource::File),
            FileScale::Absent => (1.0, ScaleSource::Pixels),
            FileScale::Disagree(lo, hi) => {
                warnings.push(format!(
                    "r/rm differs between disks ({lo:.6}..{hi:.6} px/m), so the file gives no one \
                     scale: lengths are in pixels (1 px = 1 m); give --scale"
                ));
                (1.0, ScaleSource::Pixels)
            }
        },
    };
    let thickness = match options.thickness {
        Some(t) if t > 0.0 && t.is_finite() => t,
        Some(t) => {
            return Err(Error::Invalid(format!(
                "--thickness must be positive, got {t}"
            )))
        }
        None => 1.0,
    };
    let (height, height_given) = match options.image_height {
        Some(h) => (h as f64, true),
        None => (
            disks.iter().map(|d| d.y + d.r).fold(0.0, f64::max).ceil(),
            false,
        ),
    };
    let position = |d: &Disk| [(d.x - 0.5) / s, (height + 0.5 - d.y) / s, 0.0];

    let mut scene = Scene::new(2);
    let mut index: HashMap<u64, usize> = HashMap::new();
    for (i, d) in disks.iter().enumerate() {
        let r = d.r / s;
        let mut g = Grain::new(d.id.clone(), position(d), ball_volume(2, r), [0.0; 6]);
        g.radius = Some(r);
        scene.grains.push(g);
        if index.insert(d.key.to_bits(), i).is_some() {
            return Err(Error::data(
                mat,
                None,
                None,
                format!("particle({}).id = {} is used twice", i + 1, d.id),
            ));
        }
    }
    let (targets, by_index) = resolve_neighbours(&disks, &index);
    if by_index {
        warnings.push(
            "`neighbours` are read as particle indices (PeGS 1's convention), not ids: as ids \
             some do not exist or do not lie in the direction `betas` gives"
                .to_owned(),
        );
    }
    // Each pair of disks is one contact, whichever disk lists it first.
    let mut pairs: HashMap<(usize, usize), usize> = HashMap::new();
    // Per contact: force on a from a's fit, force on a from b's fit (−F_b).
    let mut sides: Vec<[Option<Vec3>; 2]> = Vec::new();
    let mut walls_seen: HashSet<(usize, String)> = HashSet::new();
    let mut solved_any = false;
    let mut bent = 0usize;
    for (i, d) in disks.iter().enumerate() {
        for (k, t) in d.contacts.iter().enumerate() {
            let force = t
                .force
                .map(|(f, alpha)| force_on_disk(f, alpha, t.beta, thickness));
            solved_any |= force.is_some();
            let at = format!("particle({}).neighbours({})", i + 1, k + 1);
            if t.neighbour < 0.0 {
                let name = wall_name(t.beta, t.neighbour);
                if !walls_seen.insert((i, name.clone())) {
                    return Err(Error::data(
                        mat,
                        None,
                        None,
                        format!("{at}: disk {} touches wall `{name}` twice", d.id),
                    ));
                }
                let n = direction(t.beta);
                let c = position(d);
                let r = d.r / s;
                let wall = scene.wall_or_insert(&name);
                scene.contacts.push(Contact {
                    id: format!("{}-{name}", d.id),
                    a: i,
                    b: Body::Wall(wall),
                    point: [c[0] + r * n[0], c[1] + r * n[1], 0.0],
                    normal: n,
                    mu: None,
                });
                sides.push([force, None]);
                continue;
            }
            let Some(j) = targets[i][k] else {
                return Err(Error::data(
                    mat,
                    None,
                    None,
                    format!(
                        "{at} = {} is not the id of any particle",
                        number_id(t.neighbour)
                    ),
                ));
            };
            if j == i {
                return Err(Error::data(
                    mat,
                    None,
                    None,
                    format!("{at}: disk {} lists itself as its neighbour", d.id),
                ));
            }
            let key = (i.min(j), i.max(j));
            let side = usize::from(i != key.0);
            let c = match pairs.get(&key) {
                Some(&c) => c,
                None => {
                    let (a, b) = (&scene.grains[key.0], &scene.grains[key.1]);
                    let (point, normal) = sphere_contact(
                        a.position,
                        a.radius.unwrap_or(0.0),
                        b.position,
                        b.radius.unwrap_or(0.0),
                    )
                    .ok_or_else(|| {
                        Error::data(
                            mat,
                            None,
                            None,
                            format!(
                                "{at}: disks {} and {} have the same centre",
                                d.id, disks[j].id
                            ),
                        )
                    })?;
                    scene.contacts.push(Contact {
                        id: format!("{}-{}", disks[key.0].id, disks[key.1].id),
                        a: key.0,
                        b: Body::Grain(key.1),
                        point,
                        normal,
                        mu: None,
                    });
                    sides.push([None, None]);
                    pairs.insert(key, scene.contacts.len() - 1);
                    scene.contacts.len() - 1
                }
            };
            // β should point along the line of centres, from this disk.
            let towards = scene::sub(scene.grains[j].position, scene.grains[i].position);
            let dir = direction(t.beta);
            let cos = scene::dot(towards, dir) / scene::norm(towards).max(f64::MIN_POSITIVE);
            if cos < BETA_TOLERANCE.cos() {
                bent += 1;
            }
            if sides[c][side].is_some() {
                return Err(Error::data(
                    mat,
                    None,
                    None,
                    format!("{at}: disk {} lists disk {} twice", d.id, disks[j].id),
                ));
            }
            // Both sides stored as the force on `a`; NaN marks "listed, not solved".
            sides[c][side] = Some(match force {
                Some(f) if side == 1 => f.map(|x| -x),
                Some(f) => f,
                None => [f64::NAN; 3],
            });
        }
    }
    if bent > 0 {
        warnings.push(format!(
            "{bent} contact angle(s) `betas` differ from the line of centres by more than 0.01 \
             rad: are `neighbours` ids of another numbering?"
        ));
    }
    let mut one_sided = 0usize;
    let mut mismatch = Vec::new();
    let forces: Option<Vec<Vec3>> = if solved_any {
        let mut out = Vec::with_capacity(sides.len());
        let mut missing = Vec::new();
        for (c, [fa, fb]) in sides.iter().enumerate() {
            let known = |f: &Option<Vec3>| f.filter(|v| v.iter().all(|x| x.is_finite()));
            let is_wall = matches!(scene.contacts[c].b, Body::Wall(_));
            match (known(fa), known(fb)) {
                (Some(x), Some(y)) => {
                    let scale = 0.5 * (scene::norm(x) + scene::norm(y));
                    if scale > 0.0 {
                        mismatch.push(scene::norm(scene::sub(x, y)) / scale);
                    }
                    out.push([0.5 * (x[0] + y[0]), 0.5 * (x[1] + y[1]), 0.0]);
                }
                (Some(x), None) | (None, Some(x)) => {
                    if !is_wall {
                        one_sided += 1;
                    }
                    out.push(x);
                }
                (None, None) => missing.push(scene.contacts[c].id.clone()),
            }
        }
        if missing.is_empty() {
            Some(out)
        } else {
            warnings.push(format!(
                "{} contact(s) have no fitted force on either disk (e.g. {}): no reference \
                 forces written",
                missing.len(),
                missing[0]
            ));
            None
        }
    } else {
        None
    };
    if one_sided > 0 {
        warnings.push(format!(
            "{one_sided} contact(s) between disks have a fitted force on one disk only; that one \
             is used"
        ));
    }
    if !mismatch.is_empty() {
        mismatch.sort_by(f64::total_cmp);
        let median = mismatch[mismatch.len() / 2];
        let worst = mismatch[mismatch.len() - 1];
        if worst > 1e-6 {
            warnings.push(format!(
                "PeGS fits each disk on its own: the two fits of a contact differ by {:.1} % of \
                 the force (median), {:.1} % at worst; the reference force is their mean",
                100.0 * median,
                100.0 * worst
            ));
        }
    }
    if !solved_any {
        warnings.push(
            "no fitted forces (`forces`, `alphas`) in the file — contactDetect's output, not \
             diskSolve's: the grain stresses are zero; measure them with `grainforce strain`"
                .to_owned(),
        );
    }
    if let Some(f) = &forces {
        stress_from_forces(&mut scene, f);
    }
    if options.thickness.is_some() {
        scene.settings.thickness = Some(thickness);
    }
    if let Some(g) = options.gravity {
        scene.settings.gravity = Some(g[..2].to_vec());
    }
    scene.settings.description = Some(format!(
        "imported from PeGS {}{}",
        mat.display(),
        options
            .centres
            .as_ref()
            .map(|c| format!(" and {}", c.display()))
            .unwrap_or_default()
    ));
    Ok((
        ImportedScene {
            frames: vec![scene],
            forces: forces.map(|f| vec![f]),
            warnings,
        },
        Conversion {
            px_per_m: s,
            scale_source,
            image_height: height,
            height_given,
        },
    ))
}

/// The disk each contact names: PeGS2 writes the neighbour's `id`, PeGS 1
/// its index in the struct array (the same unless tracked). Ids are taken
/// unless they leave a contact unresolved or off the direction `betas` gives
/// while indices resolve them all. Returns the targets and whether indices
/// were used.
fn resolve_neighbours(
    disks: &[Disk],
    ids: &HashMap<u64, usize>,
) -> (Vec<Vec<Option<usize>>>, bool) {
    let targets = |by_index: bool| -> (Vec<Vec<Option<usize>>>, bool) {
        let mut all_fit = true;
        let out = disks
            .iter()
            .enumerate()
            .map(|(i, d)| {
                d.contacts
                    .iter()
                    .map(|t| {
                        if t.neighbour < 0.0 {
                            return None;
                        }
                        let j = if by_index {
                            let k = t.neighbour as usize;
                            (k >= 1 && k <= disks.len()).then(|| k - 1)
                        } else {
                            ids.get(&t.neighbour.to_bits()).copied()
                        };
                        let fits = j.is_some_and(|j| {
                            let (dx, dy) = (disks[j].x - d.x, disks[j].y - d.y);
                            let off = (dy.atan2(dx) - t.beta).rem_euclid(std::f64::consts::TAU);
                            j != i && off.min(std::f64::consts::TAU - off) < BETA_TOLERANCE
                        });
                        all_fit &= fits;
                        j
                    })
                    .collect()
            })
            .collect();
        (out, all_fit)
    };
    let (by_id, ids_fit) = targets(false);
    if !ids_fit {
        let (by_index, indices_fit) = targets(true);
        if indices_fit {
            return (by_index, true);
        }
    }
    (by_id, false)
}

/// Largest angle [rad] between `betas` and the line of centres.
const BETA_TOLERANCE: f64 = 0.01;

enum FileScale {
    Agreed(f64),
    Absent,
    Disagree(f64, f64),
}

/// S = r/rm when every disk with an `rm` gives the same (PeGS stores
/// rm = r · metersperpixel with the rounded r).
fn file_scale(disks: &[Disk]) -> FileScale {
    let ratios: Vec<f64> = disks
        .iter()
        .filter_map(|d| d.rm.map(|rm| d.r / rm))
        .collect();
    if ratios.is_empty() {
        return FileScale::Absent;
    }
    let lo = ratios.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = ratios.iter().copied().fold(0.0, f64::max);
    if hi - lo <= 1e-9 * hi {
        FileScale::Agreed(ratios[0])
    } else {
        FileScale::Disagree(lo, hi)
    }
}
