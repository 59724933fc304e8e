//! Importers: other tools' output converted into the scene contract
//! (`docs/scene-format.md`), with the true contact forces where the source has
//! them. One submodule per format; each returns an [`ImportedScene`].
//!
//! Conventions shared by all importers:
//! - contact `a`/`b` and the force are mapped so that the force is the one on
//!   grain `a` by `b` and the normal points from `a` towards `b`;
//! - when the source has forces but no stresses, each grain's stress is computed
//!   from them, V σ = Σ sym(r ⊗ f) with r = contact point − centroid, so that the
//!   written grains.csv and forces.csv agree exactly (see [`stress_from_forces`]);
//! - between two spheres the contact point is on the line of centres, in the
//!   middle of the overlap ([`sphere_contact`]).

pub mod dump;
pub mod gff;
pub mod imaged11;
pub mod labels;
pub mod lammps;
pub mod liggghts;
pub mod mat5;
pub mod pegs;
pub mod register;
pub mod stiffness;
pub mod yade;

use crate::error::{Error, Result};
use crate::scene::{self, Scene, Vec3};
use std::path::Path;

/// What an importer produces: the frames and, when the source has them, the
/// true forces per frame in contact order (force on grain `a` by `b`), plus
/// what the importer found doubtful in the source (printed by the CLI).
#[derive(Debug, Clone, PartialEq)]
pub struct ImportedScene {
    pub frames: Vec<Scene>,
    pub forces: Option<Vec<Vec<Vec3>>>,
    pub warnings: Vec<String>,
}

impl ImportedScene {
    /// Writes the scene folder (grains.csv, contacts.csv, scene.json…) and, when
    /// forces are known, `forces.csv` inside it.
    pub fn write(&self, dir: &Path) -> Result<()> {
        scene::write_sequence(dir, &self.frames)?;
        if let Some(forces) = &self.forces {
            let mut all = scene::Forces {
                dim: self.frames[0].dim,
                rows: Vec::new(),
            };
            for (frame, f) in self.frames.iter().zip(forces) {
                all.rows.extend(scene::Forces::from_scene(frame, f).rows);
            }
            scene::write_forces(&dir.join("forces.csv"), &all)?;
        }
        Ok(())
    }

    /// The largest momentum-balance residual |Σ f − m (a − g)| over all grains
    /// and frames, relative to the mean contact force magnitude; `None` without
    /// forces or masses. A large value means the source had loads the scene does
    /// not know about (gravity not given, other fixes).
    pub fn momentum_residual(&self) -> Option<f64> {
        let forces = self.forces.as_ref()?;
        let mut worst: Option<f64> = None;
        for (scene, f) in self.frames.iter().zip(forces) {
            let mean = f.iter().map(|x| scene::norm(*x)).sum::<f64>() / f.len().max(1) as f64;
            if mean == 0.0 {
                continue;
            }
            let net = net_forces(scene, f);
            for (g, n) in scene.grains.iter().zip(&net) {
                if g.mass.is_none() {
                    continue;
                }
                let (target, _) = scene.momentum_target(g);
                let r = scene::norm(scene::sub(*n, target)) / mean;
                worst = Some(worst.map_or(r, |w: f64| w.max(r)));
            }
        }
        worst
    }

    /// When no gravity is known (scene.json has none) but the contacts carry a
    /// uniform load per unit mass, the way a bed resting under gravity does:
    /// returns that load u (≈ −g). Each grain's net contact force per unit mass
    /// c = Σ f / m is compared with the component-wise median u over all grains
    /// with a mass; the scene "looks gravity-loaded" when |u| > 0 and at least
    /// 90 % of those grains (and at least 3) are within 25 % of |u| of it.
    pub fn gravity_like_load(&self) -> Option<Vec3> {
        let forces = self.forces.as_ref()?;
        if self.frames.iter().any(|f| f.settings.gravity.is_some()) {
            return None;
        }
        let mut per_mass = Vec::new();
        for (scene, f) in self.frames.iter().zip(forces) {
            for (g, n) in scene.grains.iter().zip(net_forces(scene, f)) {
                if let Some(m) = g.mass {
                    per_mass.push(n.map(|x| x / m));
                }
            }
        }
        if per_mass.len() < 3 {
            return None;
        }
        let mut u = [0.0; 3];
        for (k, uk) in u.iter_mut().enumerate() {
            let mut column: Vec<f64> = per_mass.iter().map(|c| c[k]).collect();
            column.sort_by(f64::total_cmp);
            *uk = column[column.len() / 2];
        }
        let size = scene::norm(u);
        if !(size > 0.0 && size.is_finite()) {
            return None;
        }
        let close = per_mass
            .iter()
            .filter(|c| scene::norm(scene::sub(**c, u)) <= 0.25 * size)
            .count();
        (close as f64 >= 0.9 * per_mass.len() as f64).then_some(u)
    }
}

/// The warning for [`ImportedScene::gravity_like_load`]: what it saw and what
/// to pass.
pub fn gravity_like_warning(u: Vec3, dim: usize) -> String {
    // Rounded for the command line; `+ 0.0` turns −0 into 0.
    let g: Vec<String> = u[..dim]
        .iter()
        .map(|x| format!("{}", (-x * 1e4).round() / 1e4 + 0.0))
        .collect();
    format!(
        "no gravity was given, but the contacts push every grain with about the same force per \
         unit mass (|Σf|/m ≈ {:.4}), as in a bed resting under gravity: the accelerations are then \
         off by g. If the run had gravity, pass --gravity {}",
        scene::norm(u),
        g.join(",")
    )
}

/// Net contact force on each grain (walls receive nothing here).
pub fn net_forces(scene: &Scene, forces: &[Vec3]) -> Vec<Vec3> {
    scene::contact_sums(scene, forces)
        .iter()
        .map(|s| s.force)
        .collect()
}

/// Sets every grain's stress from the contact forces: V σ = Σ sym(r ⊗ f), with
/// r from the grain's centroid to the contact point and f the force on that
/// grain (−f for grain `b`). Tension positive: a grain squeezed from both sides
/// gets negative normal stress.
pub fn stress_from_forces(scene: &mut Scene, forces: &[Vec3]) {
    scene.set_stresses_from(forces);
}

/// Contact point and unit normal (from `a` towards `b`) of two overlapping
/// spheres/disks: on the line of centres, in the middle of the overlap
/// δ = R_a + R_b − d, i.e. at distance R_a − δ/2 from a's centre. Coincident
/// centres have no normal and give `None`.
pub fn sphere_contact(pa: Vec3, ra: f64, pb: Vec3, rb: f64) -> Option<(Vec3, Vec3)> {
    let d_vec = scene::sub(pb, pa);
    let d = scene::norm(d_vec);
    if d == 0.0 || !d.is_finite() {
        return None;
    }
    let n = [d_vec[0] / d, d_vec[1] / d, d_vec[2] / d];
    let overlap = ra + rb - d;
    let arm = ra - 0.5 * overlap;
    Some((
        [pa[0] + arm * n[0], pa[1] + arm * n[1], pa[2] + arm * n[2]],
        n,
    ))
}

/// Volume of a grain of radius r: π r² per unit thickness in 2D, 4/3 π r³ in 3D.
pub(crate) fn ball_volume(dim: usize, r: f64) -> f64 {
    if dim == 2 {
        std::f64::consts::PI * r * r
    } else {
        4.0 / 3.0 * std::f64::consts::PI * r * r * r
    }
}

/// A positive, finite radius or a located error.
pub(crate) fn check_radius(path: &Path, line: usize, column: &str, r: f64) -> Result<f64> {
    if r > 0.0 && r.is_finite() {
        Ok(r)
    } else {
        Err(Error::data(
            path,
            Some(line),
            Some(column),
            format!("radius must be positive, got {r}"),
        ))
    }
}

// CSV inputs are read exactly like scene tables.
pub(crate) use crate::scene::{csv_cell, csv_number, read_csv};
