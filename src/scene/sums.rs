//! What each grain's contacts add up to: the one place that walks contacts
//! into per-grain sums (net force, moment, stress moment) and per-wall
//! totals, for importers, the generator, the DEM's checks and the exporters.

use super::{cross, sub, sym_outer, Body, Scene, Sym, Vec3};

/// The sums over one grain's contacts of a force set.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ContactSums {
    /// Σ f.
    pub force: Vec3,
    /// Σ r × f, r from the grain's centroid.
    pub moment: Vec3,
    /// Σ sym(r ⊗ f) = V σ̄ (tension positive).
    pub stress_moment: Sym,
}

/// Per grain, the sums of `forces` (forces[c] acts on `a`, −forces[c] on a
/// grain `b`).
pub fn contact_sums(scene: &Scene, forces: &[Vec3]) -> Vec<ContactSums> {
    let mut sums = vec![ContactSums::default(); scene.grains.len()];
    for (c, f) in scene.contacts.iter().zip(forces) {
        let mut add = |p: usize, f: Vec3| {
            let r = sub(c.point, scene.grains[p].position);
            let s = &mut sums[p];
            for k in 0..3 {
                s.force[k] += f[k];
            }
            let m = cross(r, f);
            for k in 0..3 {
                s.moment[k] += m[k];
            }
            let t = sym_outer(r, f);
            for k in 0..6 {
                s.stress_moment[k] += t[k];
            }
        };
        add(c.a, *f);
        if let Body::Grain(b) = c.b {
            add(b, f.map(|v| -v));
        }
    }
    sums
}

/// The total force each wall exerts on the grains (the sum of its contacts'
/// forces on `a`), skipping contacts without a force.
pub fn wall_totals(scene: &Scene, forces: &[Option<Vec3>]) -> Vec<Vec3> {
    let mut totals = vec![[0.0; 3]; scene.walls.len()];
    for (c, f) in scene.contacts.iter().zip(forces) {
        if let (Body::Wall(w), Some(f)) = (c.b, f) {
            for k in 0..3 {
                totals[w][k] += f[k];
            }
        }
    }
    totals
}

impl Scene {
    /// Sets every grain's stress to V σ = Σ sym(r ⊗ f) of `forces`.
    pub(crate) fn set_stresses_from(&mut self, forces: &[Vec3]) {
        let sums = contact_sums(self, forces);
        for (g, s) in self.grains.iter_mut().zip(sums) {
            g.stress = s.stress_moment.map(|v| v / g.volume);
        }
    }
}
