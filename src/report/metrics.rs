//! How close inferred forces are to a ground truth, and how physical they are.
//!
//! Conventions: forces are in the scene's contact order, each the force on grain
//! `a` by `b`; the normal n points from `a` towards `b`, so a pushing contact has
//! n·f < 0 and its normal force is f_n = −n·f.
//!
//! Relative errors follow eq. 2.15, ‖f − f*‖ / ‖f*‖ over all components. When the
//! truth (or the part of it being compared) is zero the ratio is undefined; the
//! documented value is then 0 when the error is zero too and `+∞` otherwise — never
//! NaN. The absolute error and the truth's norm are always kept beside the ratio,
//! so a reader can see which case applies.

use crate::error::{Error, Result};
use crate::scene::{self, dot, norm, sub, Body, Scene, Sym, Vec3};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// A component is tensile when n·f exceeds this fraction of the mean |f|.
pub(crate) const TENSILE_TOLERANCE: f64 = 1e-6;

/// ‖f − f*‖ / ‖f*‖ (eq. 2.15) over all components; 0 when both are zero, `+∞` when
/// only the truth is zero. Pairs beyond the shorter slice are ignored: callers check
/// lengths (see [`score`]).
pub fn relative_error(truth: &[Vec3], inferred: &[Vec3]) -> f64 {
    let (error, truth_norm) = error_and_norm(truth, inferred);
    ratio(error, truth_norm)
}

fn error_and_norm(truth: &[Vec3], inferred: &[Vec3]) -> (f64, f64) {
    let mut error2 = 0.0;
    let mut truth2 = 0.0;
    for (t, f) in truth.iter().zip(inferred) {
        error2 += dot(sub(*f, *t), sub(*f, *t));
        truth2 += dot(*t, *t);
    }
    (error2.sqrt(), truth2.sqrt())
}

/// error / reference: 0 when both are zero, +∞ when only the reference is.
pub(crate) fn ratio(error: f64, reference: f64) -> f64 {
    if reference > 0.0 {
        error / reference
    } else if error == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}

/// Serialises ±∞ as a string: JSON has no infinity.
fn finite_or_text<S: serde::Serializer>(x: &f64, s: S) -> std::result::Result<S::Ok, S::Error> {
    if x.is_finite() {
        s.serialize_f64(*x)
    } else {
        s.serialize_str(&x.to_string())
    }
}

fn optional_finite_or_text<S: serde::Serializer>(
    x: &Option<f64>,
    s: S,
) -> std::result::Result<S::Ok, S::Error> {
    match x {
        Some(v) => finite_or_text(v, s),
        None => s.serialize_none(),
    }
}

/// An error and what it is relative to.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ErrorNorm {
    /// ‖f − f*‖ (of the part concerned).
    pub absolute: f64,
    /// ‖f*‖ (of the part concerned).
    pub truth_norm: f64,
    /// absolute / truth_norm, with the zero-truth convention of this module.
    #[serde(serialize_with = "finite_or_text")]
    pub relative: f64,
}

impl ErrorNorm {
    fn new(absolute: f64, truth_norm: f64) -> Self {
        ErrorNorm {
            absolute,
            truth_norm,
            relative: ratio(absolute, truth_norm),
        }
    }

    /// The error of several parts taken together (norms add in squares).
    fn combine(parts: impl Iterator<Item = ErrorNorm>) -> Self {
        let (mut a2, mut t2) = (0.0, 0.0);
        for p in parts {
            a2 += p.absolute * p.absolute;
            t2 += p.truth_norm * p.truth_norm;
        }
        ErrorNorm::new(a2.sqrt(), t2.sqrt())
    }
}

/// The worst friction violation of the inferred forces.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CoulombViolation {
    /// max (|f_t| − μ f_n)₊ over contacts with a μ, divided by the mean |f|.
    pub relative: f64,
    /// The contact where it happens (None when nothing is violated).
    pub contact: Option<String>,
    /// How many contacts had a μ to check.
    pub checked: usize,
}

/// Measured versus summed force of one wall.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct WallMismatch {
    pub wall: String,
    /// From walls.csv, when the wall is measured.
    pub measured: Option<Vec3>,
    /// Σ of the inferred forces of this wall's contacts (force on grains by the wall).
    pub inferred: Vec3,
    /// The same sum over the true forces.
    pub truth: Vec3,
    /// ‖measured − inferred‖ (None without a measurement).
    pub absolute: Option<f64>,
    /// absolute / ‖measured‖ with the module's zero convention.
    #[serde(serialize_with = "optional_finite_or_text")]
    pub relative: Option<f64>,
}

/// Everything `grainforce score` reports for one frame (or, via [`Score::overall`],
/// for a whole sequence). Fields that need a scene are None without one.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Score {
    pub frame: Option<i64>,
    pub contacts: usize,
    /// eq. 2.15 over all components.
    pub error: ErrorNorm,
    /// Normal part n·f of each force.
    pub normal: Option<ErrorNorm>,
    /// Tangential part f − (n·f) n of each force.
    pub tangential: Option<ErrorNorm>,
    /// None when no contact has a friction coefficient.
    pub coulomb: Option<CoulombViolation>,
    /// Inferred contacts that pull (n·f > tolerance · mean |f|).
    pub tensile_contacts: Option<usize>,
    pub walls: Vec<WallMismatch>,
    /// Macroscopic stress (eq. 2.1) of the inferred and the true forces [Pa in 3D,
    /// N/m in 2D per unit thickness], tension positive; None without a scene or
    /// when the assembly has no volume.
    pub stress_inferred: Option<Sym>,
    pub stress_truth: Option<Sym>,
}

impl Score {
    /// eq. 2.15 as one number (see the module's zero convention).
    pub fn relerr(&self) -> f64 {
        self.error.relative
    }

    /// Fraction of tensile contacts, when known (0 for no contacts).
    pub fn tensile_fraction(&self) -> Option<f64> {
        self.tensile_contacts.map(|n| {
            if self.contacts == 0 {
                0.0
            } else {
                n as f64 / self.contacts as f64
            }
        })
    }

    /// The score of all frames together: errors over all stacked components, the
    /// worst Coulomb violation of any frame, tensile contacts summed. Walls and
    /// stress are per frame only.
    pub fn overall(frames: &[Score]) -> Score {
        let parts = |get: fn(&Score) -> Option<ErrorNorm>| -> Option<ErrorNorm> {
            let all: Option<Vec<ErrorNorm>> = frames.iter().map(get).collect();
            all.filter(|v| !v.is_empty())
                .map(|v| ErrorNorm::combine(v.into_iter()))
        };
        let coulomb = frames
            .iter()
            .filter_map(|s| s.coulomb.clone())
            .reduce(|worst, c| CoulombViolation {
                checked: worst.checked + c.checked,
                ..if c.relative > worst.relative {
                    c.clone()
                } else {
                    worst.clone()
                }
            });
        let tensile: Option<usize> = frames.iter().map(|s| s.tensile_contacts).sum();
        Score {
            frame: None,
            contacts: frames.iter().map(|s| s.contacts).sum(),
            error: ErrorNorm::combine(frames.iter().map(|s| s.error)),
            normal: parts(|s| s.normal),
            tangential: parts(|s| s.tangential),
            coulomb,
            tensile_contacts: if frames.is_empty() { None } else { tensile },
            walls: Vec::new(),
            stress_inferred: None,
            stress_truth: None,
        }
    }
}

fn check_lengths(scene: &Scene, forces: &[Vec3], what: &str) -> Result<()> {
    let n = scene.contacts.len();
    if forces.len() == n {
        return Ok(());
    }
    let detail = if forces.len() < n {
        format!("contact `{}` has none", scene.contacts[forces.len()].id)
    } else {
        "there are more forces than contacts".to_owned()
    };
    Err(Error::Invalid(format!(
        "{what} forces: {} values for the scene's {n} contacts; {detail}",
        forces.len()
    )))
}

/// Scores inferred forces against the truth on a scene (forces in contact order).
/// Errors when either slice does not match the scene's contacts, naming the first
/// contact without a value.
pub fn score(scene: &Scene, truth: &[Vec3], inferred: &[Vec3]) -> Result<Score> {
    check_lengths(scene, truth, "true")?;
    check_lengths(scene, inferred, "inferred")?;
    let (error, truth_norm) = error_and_norm(truth, inferred);

    // Normal and tangential parts.
    let (mut n_err2, mut n_truth2, mut t_err2, mut t_truth2) = (0.0, 0.0, 0.0, 0.0);
    for ((c, t), f) in scene.contacts.iter().zip(truth).zip(inferred) {
        let (tn, tt) = split(c.normal, *t);
        let (fn_, ft) = split(c.normal, *f);
        n_err2 += (fn_ - tn).powi(2);
        n_truth2 += tn * tn;
        t_err2 += dot(sub(ft, tt), sub(ft, tt));
        t_truth2 += dot(tt, tt);
    }

    let mean_force = if inferred.is_empty() {
        0.0
    } else {
        inferred.iter().map(|f| norm(*f)).sum::<f64>() / inferred.len() as f64
    };

    // Coulomb: (|f_t| − μ f_n)₊ with f_n = −n·f.
    let mut coulomb: Option<CoulombViolation> = None;
    for (c, f) in scene.contacts.iter().zip(inferred) {
        let Some(mu) = scene.contact_mu(c) else {
            continue;
        };
        let (normal, tangential) = split(c.normal, *f);
        let excess = (norm(tangential) - mu * (-normal)).max(0.0);
        let relative = if mean_force > 0.0 {
            excess / mean_force
        } else {
            0.0
        };
        let entry = coulomb.get_or_insert(CoulombViolation {
            relative: 0.0,
            contact: None,
            checked: 0,
        });
        entry.checked += 1;
        if relative > entry.relative {
            entry.relative = relative;
            entry.contact = Some(c.id.clone());
        }
    }

    let tensile = scene
        .contacts
        .iter()
        .zip(inferred)
        .filter(|(c, f)| dot(c.normal, **f) > TENSILE_TOLERANCE * mean_force)
        .count();

    let walls = scene
        .walls
        .iter()
        .enumerate()
        .map(|(w, wall)| {
            let mut inferred_sum = [0.0; 3];
            let mut truth_sum = [0.0; 3];
            for ((c, t), f) in scene.contacts.iter().zip(truth).zip(inferred) {
                if c.b == Body::Wall(w) {
                    for k in 0..3 {
                        inferred_sum[k] += f[k];
                        truth_sum[k] += t[k];
                    }
                }
            }
            let absolute = wall.measured_force.map(|m| norm(sub(m, inferred_sum)));
            let relative = wall
                .measured_force
                .zip(absolute)
                .map(|(m, a)| ratio(a, norm(m)));
            WallMismatch {
                wall: wall.name.clone(),
                measured: wall.measured_force,
                inferred: inferred_sum,
                truth: truth_sum,
                absolute,
                relative,
            }
        })
        .collect();

    let volume = scene::assembly_volume(scene);
    let stress = |forces: &[Vec3]| {
        (volume > 0.0 && volume.is_finite())
            .then(|| scene::macroscopic_stress(scene, forces, volume))
    };

    Ok(Score {
        frame: scene.frame,
        contacts: scene.contacts.len(),
        error: ErrorNorm::new(error, truth_norm),
        normal: Some(ErrorNorm::new(n_err2.sqrt(), n_truth2.sqrt())),
        tangential: Some(ErrorNorm::new(t_err2.sqrt(), t_truth2.sqrt())),
        coulomb,
        tensile_contacts: Some(tensile),
        walls,
        stress_inferred: stress(inferred),
        stress_truth: stress(truth),
    })
}

/// (n·f, f − (n·f) n).
fn split(n: Vec3, f: Vec3) -> (f64, Vec3) {
    let fn_ = dot(n, f);
    (
        fn_,
        [f[0] - fn_ * n[0], f[1] - fn_ * n[1], f[2] - fn_ * n[2]],
    )
}

/// The score that needs no scene: the relative error only.
pub fn score_without_scene(frame: Option<i64>, truth: &[Vec3], inferred: &[Vec3]) -> Score {
    let (error, truth_norm) = error_and_norm(truth, inferred);
    Score {
        frame,
        contacts: truth.len().min(inferred.len()),
        error: ErrorNorm::new(error, truth_norm),
        normal: None,
        tangential: None,
        coulomb: None,
        tensile_contacts: None,
        walls: Vec::new(),
        stress_inferred: None,
        stress_truth: None,
    }
}

/// The true and inferred forces of one frame, paired by contact id.
#[derive(Debug, Clone, PartialEq)]
pub struct PairedFrame {
    pub frame: Option<i64>,
    pub contacts: Vec<String>,
    pub truth: Vec<Vec3>,
    pub inferred: Vec<Vec3>,
}

/// Pairs the rows of two forces.csv files by (frame, contact), in the truth file's
/// order, frames ascending. A contact present in one file but not the other is an
/// error naming it, its frame and the file that lacks it.
pub fn pair_forces(
    truth: &scene::Forces,
    truth_path: &Path,
    inferred: &scene::Forces,
    inferred_path: &Path,
) -> Result<Vec<PairedFrame>> {
    if truth.dim != inferred.dim {
        return Err(Error::Invalid(format!(
            "{} holds {}D forces but {} holds {}D forces",
            truth_path.display(),
            truth.dim,
            inferred_path.display(),
            inferred.dim
        )));
    }
    let framed = |f: &scene::Forces| f.rows.iter().any(|r| r.frame.is_some());
    if framed(truth) != framed(inferred) {
        let (with, without) = if framed(truth) {
            (truth_path, inferred_path)
        } else {
            (inferred_path, truth_path)
        };
        return Err(Error::data(
            without,
            Some(1),
            Some("frame"),
            format!(
                "{} has a `frame` column but this file has none",
                with.display()
            ),
        ));
    }
    let inferred_map: HashMap<(Option<i64>, &str), Vec3> = inferred
        .rows
        .iter()
        .map(|r| ((r.frame, r.contact.as_str()), r.force))
        .collect();
    let truth_keys: std::collections::HashSet<(Option<i64>, &str)> = truth
        .rows
        .iter()
        .map(|r| (r.frame, r.contact.as_str()))
        .collect();
    let describe = |frame: Option<i64>, contact: &str| match frame {
        Some(k) => format!("contact `{contact}` of frame {k}"),
        None => format!("contact `{contact}`"),
    };
    if let Some(r) = inferred
        .rows
        .iter()
        .find(|r| !truth_keys.contains(&(r.frame, r.contact.as_str())))
    {
        return Err(Error::data(
            truth_path,
            None,
            Some("contact"),
            format!(
                "{} (in {}) has no true force here",
                describe(r.frame, &r.contact),
                inferred_path.display()
            ),
        ));
    }
    let mut frames: BTreeMap<Option<i64>, PairedFrame> = BTreeMap::new();
    for r in &truth.rows {
        let Some(f) = inferred_map.get(&(r.frame, r.contact.as_str())) else {
            return Err(Error::data(
                inferred_path,
                None,
                Some("contact"),
                format!(
                    "{} (in {}) has no inferred force here",
                    describe(r.frame, &r.contact),
                    truth_path.display()
                ),
            ));
        };
        let entry = frames.entry(r.frame).or_insert_with(|| PairedFrame {
            frame: r.frame,
            contacts: Vec::new(),
            truth: Vec::new(),
            inferred: Vec::new(),
        });
        entry.contacts.push(r.contact.clone());
        entry.truth.push(r.force);
        entry.inferred.push(*f);
    }
    Ok(frames.into_values().collect())
}

/// Reorders a paired frame into a scene's contact order. Contacts of the scene
/// missing from the pair, or paired contacts the scene lacks, are errors naming
/// the contact.
pub fn in_scene_order(
    scene: &Scene,
    paired: &PairedFrame,
    scene_dir: &Path,
) -> Result<(Vec<Vec3>, Vec<Vec3>)> {
    let index: HashMap<&str, usize> = paired
        .contacts
        .iter()
        .enumerate()
        .map(|(i, c)| (c.as_str(), i))
        .collect();
    let frame_text = |f: Option<i64>| f.map(|k| format!(" of frame {k}")).unwrap_or_default();
    let mut truth = Vec::with_capacity(scene.contacts.len());
    let mut inferred = Vec::with_capacity(scene.contacts.len());
    for c in &scene.contacts {
        let Some(&i) = index.get(c.id.as_str()) else {
            return Err(Error::Invalid(format!(
                "contact `{}`{} of the scene {} has no force in the forces files",
                c.id,
                frame_text(scene.frame),
                scene_dir.display()
            )));
        };
        truth.push(paired.truth[i]);
        inferred.push(paired.inferred[i]);
    }
    if paired.contacts.len() != scene.contacts.len() {
        let known: std::collections::HashSet<&str> =
            scene.contacts.iter().map(|c| c.id.as_str()).collect();
        let extra = paired
            .contacts
            .iter()
            .find(|c| !known.contains(c.as_str()))
            .map(String::as_str)
            .unwrap_or("?");
        return Err(Error::Invalid(format!(
            "contact `{extra}`{} of the forces files is not in the scene {}",
            frame_text(paired.frame),
            scene_dir.display()
        )));
    }
    Ok((truth, inferred))
}
