//! Isotropic linear elasticity in 2D: Hooke's law both ways, for plane stress
//! (thin disks) or plane strain (long cylinders). Tensors are (xx, yy, xy) with
//! tensorial shear strain ε_xy = ½(∂u_x/∂y + ∂u_y/∂x); tension positive.

use crate::error::{Error, Result};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlaneCondition {
    /// σ_zz = 0: thin disks, free faces.
    Stress,
    /// ε_zz = 0: long cylinders between rigid end plates.
    Strain,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Elasticity {
    /// Young's modulus E [Pa].
    pub youngs: f64,
    /// Poisson's ratio ν.
    pub poisson: f64,
    pub plane: PlaneCondition,
}

impl Elasticity {
    /// Checks the constants: E > 0, −1 < ν ≤ ½ (plane stress) or < ½ (plane
    /// strain, where ν = ½ makes the in-plane stiffness infinite).
    pub fn new(youngs: f64, poisson: f64, plane: PlaneCondition) -> Result<Self> {
        if !(youngs.is_finite() && youngs > 0.0) {
            return Err(Error::Invalid(format!(
                "Young's modulus must be a positive number of pascals, not {youngs}"
            )));
        }
        let upper_ok = match plane {
            PlaneCondition::Stress => poisson <= 0.5,
            PlaneCondition::Strain => poisson < 0.5,
        };
        if !(poisson.is_finite() && poisson > -1.0 && upper_ok) {
            let why = if plane == PlaneCondition::Strain && poisson >= 0.5 {
                " (an incompressible material in plane strain has no finite in-plane stiffness; use --plane-stress or ν < 0.5)"
            } else {
                ""
            };
            return Err(Error::Invalid(format!(
                "Poisson's ratio must lie in (−1, 0.5], not {poisson}{why}"
            )));
        }
        Ok(Elasticity {
            youngs,
            poisson,
            plane,
        })
    }

    /// Stress (xx, yy, xy) [Pa] from strain (xx, yy, xy).
    pub fn stress_from_strain(&self, e: [f64; 3]) -> [f64; 3] {
        let (young, nu) = (self.youngs, self.poisson);
        let shear = young / (1.0 + nu) * e[2];
        match self.plane {
            PlaneCondition::Stress => {
                let k = young / (1.0 - nu * nu);
                [k * (e[0] + nu * e[1]), k * (e[1] + nu * e[0]), shear]
            }
            PlaneCondition::Strain => {
                let k = young / ((1.0 + nu) * (1.0 - 2.0 * nu));
                [
                    k * ((1.0 - nu) * e[0] + nu * e[1]),
                    k * ((1.0 - nu) * e[1] + nu * e[0]),
                    shear,
                ]
            }
        }
    }

    /// Strain (xx, yy, xy) from stress (xx, yy, xy) [Pa].
    pub fn strain_from_stress(&self, s: [f64; 3]) -> [f64; 3] {
        let (young, nu) = (self.youngs, self.poisson);
        let shear = (1.0 + nu) / young * s[2];
        match self.plane {
            PlaneCondition::Stress => [
                (s[0] - nu * s[1]) / young,
                (s[1] - nu * s[0]) / young,
                shear,
            ],
            PlaneCondition::Strain => {
                let k = (1.0 + nu) / young;
                [
                    k * ((1.0 - nu) * s[0] - nu * s[1]),
                    k * ((1.0 - nu) * s[1] - nu * s[0]),
                    shear,
                ]
            }
        }
    }
}
