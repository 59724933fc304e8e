//! From the simulator's state to scenes in the data contract, and the checks
//! every written scene must pass.

use super::sim::System;
use crate::scene::{self, Body, Contact, Grain, Inertia, Scene, Settings, Vec3, Wall};

/// Builds one frame from the contacts recorded at the last force evaluation.
/// `dynamic` writes the integrator's accelerations; otherwise each grain gets
/// the residual a = Σf/m + g, α = Σ r × f / I of the recorded forces, so a
/// quasi-static frame balances to round-off whatever gate it was relaxed to.
/// `relabel` numbers contacts c0, c1, … in order instead of by their
/// persistent ids.
pub(crate) fn snapshot(
    sys: &System,
    settings: &Settings,
    frame: Option<i64>,
    dynamic: bool,
    relabel: bool,
) -> (Scene, Vec<Vec3>) {
    let dim = sys.dim;
    let mut s = Scene::new(dim);
    s.frame = frame;
    s.settings = settings.clone();
    let mut moments = vec![[0.0f64; 6]; sys.len()];
    let mut net = vec![[0.0f64; 3]; sys.len()];
    let mut torque = vec![[0.0f64; 3]; sys.len()];
    let mut forces = Vec::with_capacity(sys.records.len());
    for (k, rec) in sys.records.iter().enumerate() {
        let a = rec.a as usize;
        let ra = scene::sub(rec.point, sys.x[a]);
        add_sym(&mut moments[a], scene::sym_outer(ra, rec.force));
        add3(&mut net[a], rec.force);
        add3(&mut torque[a], scene::cross(ra, rec.force));
        let b = if rec.wall {
            Body::Wall(rec.b as usize)
        } else {
            let b = rec.b as usize;
            let rb = scene::sub(rec.point, sys.x[b]);
            let fb = [-rec.force[0], -rec.force[1], -rec.force[2]];
            add_sym(&mut moments[b], scene::sym_outer(rb, fb));
            add3(&mut net[b], fb);
            add3(&mut torque[b], scene::cross(rb, fb));
            Body::Grain(b)
        };
        let id = if relabel { k as u64 } else { rec.id - 1 };
        s.contacts.push(Contact {
            id: format!("c{id}"),
            a,
            b,
            point: rec.point,
            normal: rec.normal,
            mu: Some(rec.mu),
        });
        forces.push(rec.force);
    }
    for i in 0..sys.len() {
        let r = sys.radius[i];
        let volume = if dim == 2 {
            std::f64::consts::PI * r * r
        } else {
            4.0 / 3.0 * std::f64::consts::PI * r * r * r
        };
        let mut stress = moments[i];
        for x in &mut stress {
            *x /= volume;
        }
        let mut g = Grain::new(i.to_string(), sys.x[i], volume, stress);
        g.radius = Some(r);
        g.mass = Some(sys.mass[i]);
        g.inertia = Some(Inertia::Scalar(sys.inertia[i]));
        if dynamic {
            g.acceleration = Some(sys.a[i]);
            g.angular_acceleration = Some(sys.alpha[i]);
        } else {
            let m = sys.mass[i];
            g.acceleration = Some([0, 1, 2].map(|k| net[i][k] / m + sys.gravity[k]));
            let inv_i = 1.0 / sys.inertia[i];
            g.angular_acceleration = Some(torque[i].map(|t| t * inv_i));
        }
        s.grains.push(g);
    }
    for wall in &sys.walls {
        s.walls.push(Wall {
            name: wall.name.clone(),
            measured_force: Some(wall.force),
        });
    }
    (s, forces)
}

fn add_sym(acc: &mut [f64; 6], t: [f64; 6]) {
    for k in 0..6 {
        acc[k] += t[k];
    }
}

/// Per-grain balance of a scene with its forces.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BalanceResiduals {
    /// max over grains |Σ f − m (a − g)| / mean |f|.
    pub max_force: f64,
    /// max over grains |Σ r × f − I α| / (mean |f| · mean radius).
    pub max_moment: f64,
    /// Mean of the same two over grains.
    pub mean_force: f64,
    pub mean_moment: f64,
    pub mean_contact_force: f64,
}

/// How far each grain is from Σ f = m (a − g) and Σ r × f = I α, with r from
/// its centroid, relative to the mean contact force (and mean radius).
pub fn balance_residuals(s: &Scene, forces: &[Vec3]) -> BalanceResiduals {
    let n = s.grains.len();
    let sums = scene::contact_sums(s, forces);
    let total: f64 = forces.iter().map(|f| scene::norm(*f)).sum();
    let mean_f = if s.contacts.is_empty() {
        1.0
    } else {
        total / s.contacts.len() as f64
    };
    let mean_r = s
        .grains
        .iter()
        .map(|g| g.equivalent_radius(s.dim))
        .sum::<f64>()
        / n.max(1) as f64;
    let mut out = BalanceResiduals {
        mean_contact_force: mean_f,
        ..Default::default()
    };
    for (i, g) in s.grains.iter().enumerate() {
        let (target_f, target_m) = s.momentum_target(g);
        let rf = scene::norm(scene::sub(sums[i].force, target_f)) / mean_f;
        let rm = scene::norm(scene::sub(sums[i].moment, target_m)) / (mean_f * mean_r);
        out.max_force = out.max_force.max(rf);
        out.max_moment = out.max_moment.max(rm);
        out.mean_force += rf / n as f64;
        out.mean_moment += rm / n as f64;
    }
    out
}

fn add3(a: &mut Vec3, b: Vec3) {
    for k in 0..3 {
        a[k] += b[k];
    }
}

/// Largest |V σ − Σ sym(r ⊗ f)| over grains and components, relative to the
/// mean contact force times the mean radius.
pub fn stress_residual(s: &Scene, forces: &[Vec3]) -> f64 {
    let n = s.grains.len();
    let sums = scene::contact_sums(s, forces);
    let total: f64 = forces.iter().map(|f| scene::norm(*f)).sum();
    let mean_f = total / s.contacts.len().max(1) as f64;
    let mean_r = s
        .grains
        .iter()
        .map(|g| g.equivalent_radius(s.dim))
        .sum::<f64>()
        / n.max(1) as f64;
    let mut worst: f64 = 0.0;
    for (i, g) in s.grains.iter().enumerate() {
        for k in 0..6 {
            worst = worst.max((g.volume * g.stress[k] - sums[i].stress_moment[k]).abs());
        }
    }
    worst / (mean_f * mean_r).max(f64::MIN_POSITIVE)
}
