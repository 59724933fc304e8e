//! Measurement noise on scenes: eq. 2.16's stress error and the benchmark's
//! geometry error. It sits below `dem/` (whose `perturb` uses its constants)
//! and `bench/`, so the simulator does not depend on inference.

use crate::scene::{self, Scene};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Eq. 2.16's stress error: the modulus overestimated by this share...
pub const STRESS_BIAS: f64 = 0.15;
/// ...and this relative scatter (sd of a normal factor) per component.
pub const STRESS_SCATTER: f64 = 0.1;

/// Which measurement error a benchmark case carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Noise {
    /// Exact data.
    None,
    /// Eq. 2.16: every stress component s becomes s·(1 + 0.15 + N(0, 0.1)) —
    /// a 15 % modulus overestimate plus 10 % scatter.
    Stress,
    /// Geometry: centroids moved by N(0, 0.005 R), contact points by
    /// N(0, 0.01 R) per axis, normals turned by N(0, 0.01 rad) (R: the grain's
    /// radius); stresses unchanged.
    Geometry,
}

impl Noise {
    pub fn name(&self) -> &'static str {
        match self {
            Noise::None => "none",
            Noise::Stress => "stress",
            Noise::Geometry => "geometry",
        }
    }

    pub fn parse(s: &str) -> Option<Noise> {
        match s {
            "none" => Some(Noise::None),
            "stress" => Some(Noise::Stress),
            "geometry" => Some(Noise::Geometry),
            _ => None,
        }
    }
}

/// A copy of `scene` with the noise applied (deterministic in `seed`).
pub fn perturb(scene: &Scene, noise: Noise, seed: u64) -> Scene {
    let mut s = scene.clone();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let unit = Normal::new(0.0, 1.0).expect("unit normal distribution");
    let dim = s.dim;
    match noise {
        Noise::None => {}
        Noise::Stress => {
            for g in &mut s.grains {
                for &k in scene::sym::components(dim) {
                    g.stress[k] *= 1.0 + STRESS_BIAS + STRESS_SCATTER * unit.sample(&mut rng);
                }
            }
        }
        Noise::Geometry => {
            let radii: Vec<f64> = s.grains.iter().map(|g| g.equivalent_radius(dim)).collect();
            for (g, &r) in s.grains.iter_mut().zip(&radii) {
                for v in g.position.iter_mut().take(dim) {
                    *v += 0.005 * r * unit.sample(&mut rng);
                }
            }
            for c in &mut s.contacts {
                let r = radii[c.a];
                for v in c.point.iter_mut().take(dim) {
                    *v += 0.01 * r * unit.sample(&mut rng);
                }
                let mut n = c.normal;
                for v in n.iter_mut().take(dim) {
                    *v += 0.01 * unit.sample(&mut rng);
                }
                let l = scene::norm(n);
                c.normal = [n[0] / l, n[1] / l, n[2] / l];
            }
        }
    }
    s
}
