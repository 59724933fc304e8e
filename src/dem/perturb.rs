//! Measurement noise on scenes. The stress model is exactly the original
//! study's (eq. 2.16): every stress component b becomes b + (bias + N(0, sd))·b,
//! one normal draw per component.

use crate::error::{Error, Result};
use crate::scene::{self, Scene};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

/// Which noise to add; all zero means none.
#[derive(Debug, Clone, PartialEq)]
pub struct PerturbConfig {
    /// Systematic relative stress error (0.15 in the original study).
    pub stress_bias: f64,
    /// Standard deviation of the random relative stress error (0.1 there).
    pub stress_noise: f64,
    /// Standard deviation of each centroid coordinate [m].
    pub position_noise: f64,
    /// Standard deviation of the tilt of each contact normal [degrees].
    pub normal_noise_deg: f64,
    /// Standard deviation of each acceleration component [m/s²].
    pub accel_noise: f64,
    /// Probability that a contact is missed (removed from contacts.csv).
    pub drop_contacts: f64,
    pub seed: u64,
}

impl Default for PerturbConfig {
    fn default() -> Self {
        PerturbConfig {
            stress_bias: 0.0,
            stress_noise: 0.0,
            position_noise: 0.0,
            normal_noise_deg: 0.0,
            accel_noise: 0.0,
            drop_contacts: 0.0,
            seed: 1,
        }
    }
}

impl PerturbConfig {
    /// The original study's model: b ← b + (0.15 + N(0, 0.1))·b.
    pub fn original_study(seed: u64) -> Self {
        PerturbConfig {
            stress_bias: crate::scene::noise::STRESS_BIAS,
            stress_noise: crate::scene::noise::STRESS_SCATTER,
            seed,
            ..Default::default()
        }
    }

    /// Checks every field; the error names it (in backticks).
    pub fn validate(&self) -> Result<()> {
        let finite = [
            ("`stress_bias`", self.stress_bias),
            ("`stress_noise`", self.stress_noise),
            ("`position_noise`", self.position_noise),
            ("`normal_noise_deg`", self.normal_noise_deg),
            ("`accel_noise`", self.accel_noise),
        ];
        for (name, v) in finite {
            if !v.is_finite() {
                return Err(Error::Invalid(format!("{name} must be finite (got {v})")));
            }
        }
        for (name, v) in &finite[1..] {
            if *v < 0.0 {
                return Err(Error::Invalid(format!(
                    "{name} is a standard deviation and cannot be negative (got {v})"
                )));
            }
        }
        if !(0.0..=1.0).contains(&self.drop_contacts) {
            return Err(Error::Invalid(format!(
                "`drop_contacts` is a probability in [0, 1] (got {})",
                self.drop_contacts
            )));
        }
        Ok(())
    }
}

/// Returns noisy copies of the frames (same ids; dropped contacts removed).
pub fn perturb(frames: &[Scene], config: &PerturbConfig) -> Result<Vec<Scene>> {
    config.validate()?;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    let mut normal = move || -> f64 { StandardNormal.sample(&mut rng) };
    let mut uniform_rng = ChaCha8Rng::seed_from_u64(config.seed ^ 0x9e37_79b9_7f4a_7c15);
    let mut out = Vec::with_capacity(frames.len());
    for frame in frames {
        let mut s = frame.clone();
        let dim = s.dim;
        for g in &mut s.grains {
            if config.stress_bias != 0.0 || config.stress_noise != 0.0 {
                for &k in scene::sym::components(dim) {
                    let factor = config.stress_bias + config.stress_noise * normal();
                    g.stress[k] += factor * g.stress[k];
                }
            }
            if config.position_noise > 0.0 {
                for k in 0..dim {
                    g.position[k] += config.position_noise * normal();
                }
            }
            if config.accel_noise > 0.0 {
                if let Some(a) = &mut g.acceleration {
                    for x in a.iter_mut().take(dim) {
                        *x += config.accel_noise * normal();
                    }
                }
            }
        }
        if config.normal_noise_deg > 0.0 {
            let sd = config.normal_noise_deg.to_radians();
            for c in &mut s.contacts {
                let n = c.normal;
                let theta = sd * normal();
                c.normal = if dim == 2 {
                    let (sn, cs) = theta.sin_cos();
                    [cs * n[0] - sn * n[1], sn * n[0] + cs * n[1], 0.0]
                } else {
                    // Tilt towards a uniformly random tangent direction.
                    let (t1, t2) = scene::tangents(3, n);
                    let phi = 2.0 * std::f64::consts::PI * rand::Rng::gen::<f64>(&mut uniform_rng);
                    let (sp, cp) = phi.sin_cos();
                    let t = [
                        cp * t1[0] + sp * t2[0],
                        cp * t1[1] + sp * t2[1],
                        cp * t1[2] + sp * t2[2],
                    ];
                    let (st, ct) = theta.sin_cos();
                    [
                        ct * n[0] + st * t[0],
                        ct * n[1] + st * t[1],
                        ct * n[2] + st * t[2],
                    ]
                };
            }
        }
        if config.drop_contacts > 0.0 {
            let p = config.drop_contacts;
            s.contacts
                .retain(|_| rand::Rng::gen::<f64>(&mut uniform_rng) >= p);
        }
        out.push(s);
    }
    Ok(out)
}
