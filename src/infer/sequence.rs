//! A sequence made ready for frame-by-frame inference: the frame range,
//! accelerations derived from the tracks, the grains selected, and the
//! momentum rows weighted by the derived accelerations' noise. The CLI and
//! the Python package both run this, then [`super::infer_frames`].

use super::kinematics::{self, KinematicsReport, Smoother};
use super::{InferOptions, LambdaRule, Method};
use crate::error::{Error, Result};
use crate::scene::{self, Scene, Selection};

/// What to do with a sequence before inferring its frames.
#[derive(Debug, Clone)]
pub struct SequencePlan {
    /// Infer only the frames numbered in [lo, hi]. Accelerations are still
    /// derived from the whole tracks, so the range's ends are not a filter's.
    pub frame_range: Option<(f64, f64)>,
    /// Derive accelerations from the tracks even when the frames carry some
    /// (a dynamic sequence without any derives them anyway).
    pub derive_accelerations: bool,
    /// Frames per second; deriving accelerations needs it.
    pub fps: Option<f64>,
    pub smoother: Smoother,
    /// The grains to infer.
    pub selection: Selection,
    /// Whether the user stated the accelerations' noise; if not, derived
    /// accelerations weight the momentum rows frame by frame.
    pub acceleration_sd_given: bool,
}

/// The frames to infer, one option set each, and what deriving the
/// accelerations found (when it ran).
#[derive(Debug, Clone)]
pub struct PreparedSequence {
    pub frames: Vec<Scene>,
    pub options: Vec<InferOptions>,
    pub derived: Option<KinematicsReport>,
}

pub fn prepare(
    mut frames: Vec<Scene>,
    opts: &InferOptions,
    plan: &SequencePlan,
) -> Result<PreparedSequence> {
    let keep: Option<Vec<bool>> = match plan.frame_range {
        Some((lo, hi)) => {
            let keep: Vec<bool> = frames
                .iter()
                .map(|f| {
                    f.frame
                        .is_some_and(|k| (k as f64) >= lo && (k as f64) <= hi)
                })
                .collect();
            if !keep.contains(&true) {
                return Err(Error::Invalid(format!(
                    "no frame of the sequence lies in the range {lo}..{hi}"
                )));
            }
            Some(keep)
        }
        None => None,
    };
    let mut derived = None;
    let lacks_accelerations = frames.len() > 1 && !frames.iter().any(|f| f.has_accelerations());
    if plan.derive_accelerations || (lacks_accelerations && opts.method == Method::Dynamic) {
        let fps = plan.fps.ok_or_else(|| {
            Error::Invalid(
                "deriving accelerations from the tracks needs the frame rate (fps)".into(),
            )
        })?;
        derived = Some(kinematics::derive_accelerations(
            &mut frames,
            fps,
            plan.smoother,
        )?);
    }
    if let Some(keep) = &keep {
        let mut kept = keep.iter();
        frames.retain(|_| *kept.next().unwrap_or(&false));
        if let Some(k) = &mut derived {
            let mut kept = keep.iter();
            k.acceleration_sd.retain(|_| *kept.next().unwrap_or(&false));
        }
    }
    let mut options = Vec::with_capacity(frames.len());
    for frame in &frames {
        let mut o = opts.clone();
        if plan.selection != Selection::All {
            o.assemble.active = Some(scene::select_subassembly(frame, &plan.selection)?);
        }
        options.push(o);
    }
    if let (Some(k), false, LambdaRule::Weights { stress_sd, .. }, Method::Dynamic) = (
        &derived,
        plan.acceleration_sd_given,
        opts.dynamic.rule,
        opts.method,
    ) {
        kinematics::weight_derived_momentum(&frames, &mut options, k, stress_sd)?;
    }
    Ok(PreparedSequence {
        frames,
        options,
        derived,
    })
}

/// How far the frames of a sequence have got, passed to a progress callback
/// after each frame ends (inferred or failed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Progress {
    /// Frames ended so far, this one included.
    pub done: usize,
    pub total: usize,
    /// The frame that just ended (its number, when the scene has one).
    pub frame: Option<i64>,
    /// Frames failed so far.
    pub failed: usize,
}

/// A progress callback; called from the solving threads, one call at a
/// time, with `done` rising by one each call.
pub type ProgressFn<'a> = &'a (dyn Fn(Progress) + Sync);

/// Infers every frame of a sequence with the same options, frames in
/// parallel; the first failure (in frame order) is the error.
pub fn infer_sequence(
    frames: &[Scene],
    opts: &InferOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<Vec<super::Inference>> {
    let per_frame = vec![opts.clone(); frames.len()];
    infer_frames(frames, &per_frame, progress)
}

/// Infers frames in parallel, each with its own options; the first failure
/// (in frame order) is the error.
pub fn infer_frames(
    frames: &[Scene],
    opts: &[InferOptions],
    progress: Option<ProgressFn<'_>>,
) -> Result<Vec<super::Inference>> {
    use rayon::prelude::*;
    if frames.len() != opts.len() {
        return Err(Error::Invalid(
            "one set of options per frame is needed".into(),
        ));
    }
    let counts = std::sync::Mutex::new((0usize, 0usize));
    let results: Vec<Result<super::Inference>> = frames
        .par_iter()
        .zip(opts.par_iter())
        .map(|(scene, opts)| {
            let r = super::infer(scene, opts).map_err(|e| match scene.frame {
                Some(k) => Error::Solver(format!("frame {k}: {e}")),
                None => e,
            });
            if let Some(report) = progress {
                // Held while reporting, so calls come one at a time, in order.
                let mut counts = counts.lock().unwrap_or_else(|p| p.into_inner());
                counts.0 += 1;
                counts.1 += usize::from(r.is_err());
                report(Progress {
                    done: counts.0,
                    total: frames.len(),
                    frame: scene.frame,
                    failed: counts.1,
                });
            }
            r
        })
        .collect();
    results.into_iter().collect()
}
