//! Sub-assemblies for local inference (§2.4.3 of the method): the equations of
//! the chosen grains only, with every contact that touches one of them.

use super::Scene;
use crate::error::{Error, Result};

/// Which grains' equations to solve.
#[derive(Debug, Clone, PartialEq)]
pub enum Selection {
    All,
    /// Grain ids.
    Grains(Vec<String>),
    /// Axis-aligned box on centroids: [min, max] per axis (2 or 3 axes).
    Region(Vec<(f64, f64)>),
}

/// A mask over the scene's grains: true where the grain's equations are kept.
pub fn select_subassembly(scene: &Scene, selection: &Selection) -> Result<Vec<bool>> {
    match selection {
        Selection::All => Ok(vec![true; scene.grains.len()]),
        Selection::Grains(ids) => {
            let mut mask = vec![false; scene.grains.len()];
            for id in ids {
                let i = scene
                    .grains
                    .iter()
                    .position(|g| &g.id == id)
                    .ok_or_else(|| {
                        Error::Invalid(format!("`grains`: no grain `{id}` in the scene"))
                    })?;
                mask[i] = true;
            }
            Ok(mask)
        }
        Selection::Region(bounds) => {
            if bounds.len() != scene.dim {
                return Err(Error::Invalid(format!(
                    "`region` needs {} bounds (min,max per axis) for a {}D scene",
                    2 * scene.dim,
                    scene.dim
                )));
            }
            let mask: Vec<bool> = scene
                .grains
                .iter()
                .map(|g| {
                    bounds
                        .iter()
                        .enumerate()
                        .all(|(k, &(lo, hi))| g.position[k] >= lo && g.position[k] <= hi)
                })
                .collect();
            if !mask.iter().any(|&m| m) {
                return Err(Error::Invalid("`region` contains no grain centroid".into()));
            }
            Ok(mask)
        }
    }
}
