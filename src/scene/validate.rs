//! [`Scene::validate`]: the checks the file readers make, for scenes built in
//! memory (from Rust, Python or an importer), so bad values give a clear
//! error that names the grain or contact instead of a panic further on.

use super::{Body, Inertia, Scene, Vec3};
use crate::error::{Error, Result};
use std::collections::HashSet;

fn finite(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl Scene {
    /// Checks dimensions, ids, indices and values; the first problem found
    /// is returned as [`Error::Invalid`] naming the grain, contact or wall.
    pub fn validate(&self) -> Result<()> {
        if !(self.dim == 2 || self.dim == 3) {
            return Err(Error::Invalid(format!(
                "the dimension must be 2 or 3, got {}",
                self.dim
            )));
        }
        let frame = match self.frame {
            Some(f) => format!("frame {f}: "),
            None => String::new(),
        };
        let bad = |what: String| Err(Error::Invalid(format!("{frame}{what}")));
        if self.grains.is_empty() {
            return bad("the scene has no grains".into());
        }
        let mut ids = HashSet::new();
        for g in &self.grains {
            let name = format!("grain `{}`", g.id);
            if !ids.insert(g.id.as_str()) {
                return bad(format!("{name} is listed twice"));
            }
            if !finite(&g.position) || (self.dim == 2 && g.position[2] != 0.0) {
                return bad(format!(
                    "{name}: the position must be finite (z = 0 in 2D), got {:?}",
                    g.position
                ));
            }
            if !(g.volume > 0.0 && g.volume.is_finite()) {
                return bad(format!(
                    "{name}: the volume must be positive, got {}",
                    g.volume
                ));
            }
            if !finite(&g.stress) {
                return bad(format!("{name}: the stress must be finite"));
            }
            if let Some(m) = g.mass.filter(|m| !(*m > 0.0 && m.is_finite())) {
                return bad(format!("{name}: the mass must be positive, got {m}"));
            }
            if let Some(r) = g.radius.filter(|r| !(*r > 0.0 && r.is_finite())) {
                return bad(format!("{name}: the radius must be positive, got {r}"));
            }
            let vectors: [(&str, Option<Vec3>); 2] = [
                ("acceleration", g.acceleration),
                ("angular acceleration", g.angular_acceleration),
            ];
            for (what, v) in vectors {
                if v.is_some_and(|v| !finite(&v)) {
                    return bad(format!("{name}: the {what} must be finite"));
                }
            }
            match g.inertia {
                Some(Inertia::Scalar(i)) if !(i > 0.0 && i.is_finite()) => {
                    return bad(format!("{name}: the inertia must be positive, got {i}"));
                }
                Some(Inertia::Tensor(t)) if !finite(&t) => {
                    return bad(format!("{name}: the inertia tensor must be finite"));
                }
                _ => {}
            }
            if let Some(sd) = &g.stress_sd {
                if sd.iter().any(|s| !(*s >= 0.0 && s.is_finite())) {
                    return bad(format!(
                        "{name}: stress standard errors must be finite and non-negative"
                    ));
                }
            }
        }
        let mut wall_names = HashSet::new();
        for w in &self.walls {
            if !wall_names.insert(w.name.as_str()) {
                return bad(format!("wall `{}` is listed twice", w.name));
            }
            if w.measured_force.is_some_and(|f| !finite(&f)) {
                return bad(format!(
                    "wall `{}`: the measured force must be finite",
                    w.name
                ));
            }
        }
        let mut contact_ids = HashSet::new();
        for c in &self.contacts {
            let name = format!("contact `{}`", c.id);
            if !contact_ids.insert(c.id.as_str()) {
                return bad(format!("{name} is listed twice"));
            }
            if c.a >= self.grains.len() {
                return bad(format!(
                    "{name}: grain index a = {} is out of range ({} grains)",
                    c.a,
                    self.grains.len()
                ));
            }
            match c.b {
                Body::Grain(b) if b >= self.grains.len() => {
                    return bad(format!(
                        "{name}: grain index b = {b} is out of range ({} grains)",
                        self.grains.len()
                    ));
                }
                Body::Grain(b) if b == c.a => {
                    return bad(format!("{name}: a contact of a grain with itself"));
                }
                Body::Wall(w) if w >= self.walls.len() => {
                    return bad(format!(
                        "{name}: wall index {w} is out of range ({} walls)",
                        self.walls.len()
                    ));
                }
                _ => {}
            }
            if !finite(&c.point) {
                return bad(format!("{name}: the contact point must be finite"));
            }
            let length = super::norm(c.normal);
            if !(length - 1.0).abs().le(&1e-2) || (self.dim == 2 && c.normal[2] != 0.0) {
                return bad(format!(
                    "{name}: the normal must be a unit vector (in the plane in 2D), got {:?}",
                    c.normal
                ));
            }
            if let Some(mu) = c.mu.filter(|m| !(*m >= 0.0 && m.is_finite())) {
                return bad(format!(
                    "{name}: the friction coefficient must be finite and non-negative, got {mu}"
                ));
            }
        }
        let s = &self.settings;
        if let Some(g) = &s.gravity {
            if g.len() < 2 || g.len() > 3 || !finite(g) {
                return bad("gravity must be 2 or 3 finite numbers".into());
            }
        }
        if let Some(mu) = s.mu.filter(|m| !(*m >= 0.0 && m.is_finite())) {
            return bad(format!(
                "the scene's friction coefficient must be finite and non-negative, got {mu}"
            ));
        }
        if let Some(t) = s.thickness.filter(|t| !(*t > 0.0 && t.is_finite())) {
            return bad(format!("the thickness must be positive, got {t}"));
        }
        Ok(())
    }
}
