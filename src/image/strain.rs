//! Grain stresses from images: DIC displacement field inside each grain →
//! average strain (affine fit) → Hooke's law → the scene's grain stresses.

use super::dic::{correlate_grain, DicOptions, GrainDic, Prepared};
use super::elastic::Elasticity;
use super::{FloatImage, PixelFrame};
use crate::error::{Error, Result};
use crate::scene::Scene;
use rayon::prelude::*;

#[derive(Debug, Clone)]
pub struct StrainOptions {
    pub elasticity: Elasticity,
    pub dic: DicOptions,
}

/// What was measured for one grain; strain and stress in scene axes (y up),
/// (xx, yy, xy), stress in Pa, tension positive.
#[derive(Debug, Clone)]
pub struct GrainStrain {
    pub id: String,
    pub strain: [f64; 3],
    pub stress: [f64; 3],
    pub dic: GrainDic,
}

#[derive(Debug, Clone, Default)]
pub struct StrainReport {
    pub grains: Vec<GrainStrain>,
}

/// Measures every grain's average strain between `reference` (unloaded) and
/// `deformed` (the scene's configuration) and writes the stress into the
/// scene's grains. Grains are located by the scene's positions and radii
/// through `frame`; each may have moved rigidly since the reference (up to the
/// search window).
pub fn measure_stresses(
    reference: &FloatImage,
    deformed: &FloatImage,
    scene: &mut Scene,
    frame: &PixelFrame,
    options: &StrainOptions,
) -> Result<StrainReport> {
    measure_stresses_with_progress(reference, deformed, scene, frame, options, &|| {})
}

/// As [`measure_stresses`], calling `progress` once per grain done (from any thread).
pub(crate) fn measure_stresses_with_progress(
    reference: &FloatImage,
    deformed: &FloatImage,
    scene: &mut Scene,
    frame: &PixelFrame,
    options: &StrainOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<StrainReport> {
    let reference = Prepared::new(reference);
    let deformed = Prepared::new(deformed);
    measure_prepared(&reference, &deformed, scene, frame, options, progress)
}

/// The same on images already prepared (a sequence reuses its reference).
pub fn measure_prepared(
    reference: &Prepared,
    deformed: &Prepared,
    scene: &mut Scene,
    frame: &PixelFrame,
    options: &StrainOptions,
    progress: &(dyn Fn() + Sync),
) -> Result<StrainReport> {
    options.dic.validate()?;
    frame.validate()?;
    if scene.dim != 2 {
        return Err(Error::Invalid(
            "strains from images are for 2D scenes (disks and cylinders)".into(),
        ));
    }
    if (reference.width, reference.height) != (deformed.width, deformed.height) {
        return Err(Error::Invalid(format!(
            "the reference image is {}×{} px but the deformed one {}×{} px",
            reference.width, reference.height, deformed.width, deformed.height
        )));
    }
    let s = frame.px_per_m;
    let results: Vec<Result<GrainStrain>> = scene
        .grains
        .par_iter()
        .map(|g| {
            let centre = frame.to_pixel([g.position[0], g.position[1]]);
            let radius = g.equivalent_radius(2) * s;
            let dic = correlate_grain(reference, deformed, centre, radius, &options.dic)
                .map_err(|e| Error::Invalid(format!("grain {}: {e}", g.id)))?;
            // Pixel y points down: the shear component changes sign.
            let strain = [dic.strain[0], dic.strain[1], -dic.strain[2]];
            let stress = options.elasticity.stress_from_strain(strain);
            progress();
            Ok(GrainStrain {
                id: g.id.clone(),
                strain,
                stress,
                dic,
            })
        })
        .collect();
    let mut report = StrainReport::default();
    for (g, r) in scene.grains.iter_mut().zip(results) {
        let r = r?;
        g.stress = [r.stress[0], r.stress[1], 0.0, r.stress[2], 0.0, 0.0];
        report.grains.push(r);
    }
    Ok(report)
}
