//! What every formulation's solve reads, and the pieces each builds its
//! conic problems from.

use super::{ConeModel, FactorCache, InferOptions};
use crate::assemble::{Assembly, Friction, System};
use crate::scene::Scene;
use crate::solver::cascade::Pattern;
use crate::solver::Cone;

/// One frame's solve: the scene, its assembly (the stress rows possibly
/// reweighted by the noise model), the options and the factorisations kept
/// across the solves of a λ search or sweep.
#[derive(Clone, Copy)]
pub(crate) struct Context<'a> {
    pub scene: &'a Scene,
    pub assembly: &'a Assembly,
    pub opts: &'a InferOptions,
    pub factors: &'a FactorCache,
}

/// What the cascade's sparse stages need of a cluster: its contacts' unknowns.
pub(crate) fn pattern(system: &System) -> Pattern {
    Pattern {
        dim: system.dim,
        contact_blocks: system.contact_blocks(),
    }
}

/// The cones of a system's unknowns under the chosen friction and cone model.
pub fn cones(system: &System, cone_model: ConeModel) -> Vec<Cone> {
    system
        .unknowns
        .iter()
        .map(|u| {
            let o = u.offset;
            match (u.friction, system.dim) {
                (Friction::Coulomb(mu), 2) => Cone::Wedge {
                    normal: o,
                    tangent: o + 1,
                    mu,
                },
                (Friction::Coulomb(mu), _) => match cone_model {
                    ConeModel::Exact => Cone::Circular {
                        normal: o,
                        t1: o + 1,
                        t2: o + 2,
                        mu,
                    },
                    ConeModel::Pyramid(facets) => Cone::Pyramid {
                        normal: o,
                        t1: o + 1,
                        t2: o + 2,
                        mu,
                        facets,
                    },
                },
                _ => Cone::NonNegative { normal: o },
            }
        })
        .collect()
}
