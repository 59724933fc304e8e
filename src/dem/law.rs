//! Contact laws: linear spring–dashpot and Hertz–Mindlin, both with a
//! tangential history spring capped by Coulomb friction and no attractive
//! normal force.
//!
//! The normal dashpot is calibrated so that a binary collision ends with exactly
//! the configured coefficient of restitution *including* the clamp that forbids
//! attraction (the textbook formula ζ = −ln e/√(π² + ln² e) ignores it). For
//! both laws the rebound ratio depends only on the dimensionless damping
//! a = c/√(m* k) (c ∝ δ^{1/4} for Hertz), so a is found once by integrating
//! the dimensionless collision and bisecting.

use crate::scene::Vec3;

/// Which force–overlap law.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum ContactLaw {
    /// f_n = k_n δ + c_n δ̇, f_t = −k_t ξ (−c_t v_t).
    Linear,
    /// f_n = (4/3) E* √R* δ^{3/2} + c_n(δ) δ̇, tangential stiffness 8 G* √(R* δ).
    Hertz,
}

/// Mechanical parameters of one kind of contact, already per unit thickness in 2D.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interaction {
    pub law: ContactLaw,
    /// Linear: k_n [N/m]. Hertz: E* [Pa].
    pub normal: f64,
    /// Linear: k_t [N/m]. Hertz: G* [Pa].
    pub tangential: f64,
    /// Dimensionless normal damping a (see the module notes).
    pub damp_n: f64,
    /// Dimensionless tangential damping, same form with the tangential stiffness.
    pub damp_t: f64,
    pub mu: f64,
}

/// What one contact evaluation gives.
pub struct ContactForce {
    /// Normal force magnitude (≥ 0, repulsive).
    pub normal: f64,
    /// Tangential force on the first body.
    pub tangential: Vec3,
    /// Normal tangent stiffness dF/dδ (for the servo and diagnostics).
    pub stiffness: f64,
}

impl Interaction {
    /// A contact of this law: `normal`/`tangential` are k_n/k_t (linear) or
    /// E*/G* (Hertz), per unit thickness in 2D; the dashpot gives restitution
    /// `restitution`; `tangential_damping` scales it for the tangential dashpot.
    pub fn new(
        law: ContactLaw,
        normal: f64,
        tangential: f64,
        restitution: f64,
        tangential_damping: f64,
        mu: f64,
    ) -> Interaction {
        let damp_n = damping_for_restitution(law, restitution);
        Interaction {
            law,
            normal,
            tangential,
            damp_n,
            damp_t: tangential_damping * damp_n,
            mu,
        }
    }

    /// Force for overlap `delta` > 0, effective radius and mass, normal overlap
    /// rate `vn` (> 0 approaching), tangential relative velocity `vt` of the
    /// first body, normal `n`. The history `xi` (tangential displacement of the
    /// first body relative to the second) is advanced by `vt·dt` when `dt` > 0
    /// and frozen at the Coulomb cap when sliding.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn force(
        &self,
        delta: f64,
        rstar: f64,
        mstar: f64,
        vn: f64,
        vt: Vec3,
        n: Vec3,
        xi: &mut Vec3,
        dt: f64,
    ) -> ContactForce {
        let constants = self.pair_constants(rstar, mstar);
        self.force_with(delta, constants, vn, vt, n, xi, dt)
    }

    /// What [`Interaction::force_with`] needs of a pair besides its state:
    /// the normal and tangential dashpot coefficients (linear law, where they
    /// do not depend on the overlap) or R* and m* (Hertz). A neighbour list
    /// computes them once per pair instead of once per step.
    #[inline(always)]
    pub(crate) fn pair_constants(&self, rstar: f64, mstar: f64) -> [f64; 2] {
        match self.law {
            ContactLaw::Linear => [
                self.damp_n * (mstar * self.normal).sqrt(),
                self.tangential_dashpot(mstar, self.tangential),
            ],
            ContactLaw::Hertz => [rstar, mstar],
        }
    }

    #[inline(always)]
    fn tangential_dashpot(&self, mstar: f64, kt: f64) -> f64 {
        if self.damp_t > 0.0 {
            self.damp_t * (mstar * kt).sqrt()
        } else {
            0.0
        }
    }

    /// [`Interaction::force`] with the pair's [`Interaction::pair_constants`].
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn force_with(
        &self,
        delta: f64,
        constants: [f64; 2],
        vn: f64,
        vt: Vec3,
        n: Vec3,
        xi: &mut Vec3,
        dt: f64,
    ) -> ContactForce {
        let (spring, kn_tangent, cn, kt, ct) = match self.law {
            ContactLaw::Linear => (
                self.normal * delta,
                self.normal,
                constants[0],
                self.tangential,
                constants[1],
            ),
            ContactLaw::Hertz => {
                let [rstar, mstar] = constants;
                let s = (rstar * delta).sqrt();
                let k = 2.0 * self.normal * s;
                let kt = 8.0 * self.tangential * s;
                // (4/3) E* √(R*δ) is k_h δ^{1/2}: the dashpot ∝ √(m* k_h) δ^{1/4}.
                let damper_k = (4.0 / 3.0) * self.normal * s;
                (
                    (2.0 / 3.0) * k * delta,
                    k,
                    self.damp_n * (mstar * damper_k).sqrt(),
                    kt,
                    self.tangential_dashpot(mstar, kt),
                )
            }
        };
        let normal = (spring + cn * vn).max(0.0);

        // Keep the history in the current tangent plane. Projection only: it
        // never adds elastic energy (rescaling to the old length can pump
        // energy into a spinning grain and keep a packing from settling).
        let along = xi[0] * n[0] + xi[1] * n[1] + xi[2] * n[2];
        for k in 0..3 {
            xi[k] -= along * n[k];
        }
        for k in 0..3 {
            xi[k] += vt[k] * dt;
        }
        let mut ft = [
            -kt * xi[0] - ct * vt[0],
            -kt * xi[1] - ct * vt[1],
            -kt * xi[2] - ct * vt[2],
        ];
        let cap = self.mu * normal;
        let ft2 = norm2(ft);
        if ft2 > cap * cap {
            // Sliding: the force sits on the Coulomb cap and the spring is
            // frozen where it would produce exactly that force.
            if ft2 > 0.0 {
                let scale = cap / ft2.sqrt();
                for k in 0..3 {
                    ft[k] *= scale;
                }
            }
            if kt > 0.0 {
                for k in 0..3 {
                    xi[k] = -(ft[k] + ct * vt[k]) / kt;
                }
            }
        }
        ContactForce {
            normal,
            tangential: ft,
            stiffness: kn_tangent,
        }
    }

    /// Elastic energy stored in a contact (normal + tangential springs).
    pub fn energy(&self, delta: f64, rstar: f64, xi: Vec3) -> f64 {
        match self.law {
            ContactLaw::Linear => {
                0.5 * self.normal * delta * delta + 0.5 * self.tangential * norm2(xi)
            }
            ContactLaw::Hertz => {
                let s = (rstar * delta).sqrt();
                (8.0 / 15.0) * self.normal * s * delta * delta
                    + 0.5 * 8.0 * self.tangential * s * norm2(xi)
            }
        }
    }
}

#[inline(always)]
fn norm2(v: Vec3) -> f64 {
    v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
}

/// Effective modulus E* of two bodies (an infinite modulus is rigid).
pub fn effective_young(e1: f64, nu1: f64, e2: f64, nu2: f64) -> f64 {
    let c = |e: f64, nu: f64| {
        if e.is_infinite() {
            0.0
        } else {
            (1.0 - nu * nu) / e
        }
    };
    1.0 / (c(e1, nu1) + c(e2, nu2))
}

/// Effective shear modulus G* of two bodies.
pub fn effective_shear(e1: f64, nu1: f64, e2: f64, nu2: f64) -> f64 {
    let c = |e: f64, nu: f64| {
        if e.is_infinite() {
            0.0
        } else {
            let g = e / (2.0 * (1.0 + nu));
            (2.0 - nu) / g
        }
    };
    1.0 / (c(e1, nu1) + c(e2, nu2))
}

/// Rebound ratio of the dimensionless collision x'' = −max(0, x^p + a x^q x'),
/// x(0) = 0, x'(0) = 1 (p = 1, q = 0 linear; p = 3/2, q = 1/4 Hertz).
fn rebound(law: ContactLaw, a: f64) -> f64 {
    let (p, q) = match law {
        ContactLaw::Linear => (1.0, 0.0),
        ContactLaw::Hertz => (1.5, 0.25),
    };
    let accel = |x: f64, v: f64| -> f64 {
        if x <= 0.0 {
            0.0
        } else {
            -(x.powf(p) + a * x.powf(q) * v).max(0.0)
        }
    };
    let h = 2e-4;
    let (mut x, mut v) = (0.0f64, 1.0f64);
    for _ in 0..200_000 {
        // RK4
        let (k1x, k1v) = (v, accel(x, v));
        let (k2x, k2v) = (
            v + 0.5 * h * k1v,
            accel(x + 0.5 * h * k1x, v + 0.5 * h * k1v),
        );
        let (k3x, k3v) = (
            v + 0.5 * h * k2v,
            accel(x + 0.5 * h * k2x, v + 0.5 * h * k2v),
        );
        let (k4x, k4v) = (v + h * k3v, accel(x + h * k3x, v + h * k3v));
        x += h / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x);
        v += h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
        if x <= 0.0 || (v < 0.0 && accel(x, v) == 0.0) {
            return -v;
        }
        if v.abs() < 1e-12 && accel(x, v).abs() < 1e-12 {
            return 0.0;
        }
    }
    (-v).max(0.0)
}

/// Dimensionless damping that gives restitution `e` (0 < e ≤ 1).
pub(crate) fn damping_for_restitution(law: ContactLaw, e: f64) -> f64 {
    if e >= 1.0 {
        return 0.0;
    }
    let (mut lo, mut hi) = (0.0f64, 1.0f64);
    while rebound(law, hi) > e && hi < 1e4 {
        hi *= 2.0;
    }
    for _ in 0..48 {
        let mid = 0.5 * (lo + hi);
        if rebound(law, mid) > e {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_calibration_close_to_textbook_without_clamp_effect_at_small_damping() {
        // For weak damping the clamp barely matters: a ≈ 2ζ with ζ from ln e.
        let e: f64 = 0.95;
        let zeta = -e.ln() / (std::f64::consts::PI.powi(2) + e.ln().powi(2)).sqrt();
        let a = damping_for_restitution(ContactLaw::Linear, e);
        assert!(
            (a - 2.0 * zeta).abs() / (2.0 * zeta) < 0.05,
            "{a} vs {}",
            2.0 * zeta
        );
        assert!((rebound(ContactLaw::Linear, a) - e).abs() < 1e-6);
        let ah = damping_for_restitution(ContactLaw::Hertz, 0.5);
        assert!((rebound(ContactLaw::Hertz, ah) - 0.5).abs() < 1e-6);
    }
}
