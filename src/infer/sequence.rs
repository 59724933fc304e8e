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
    /// Infer only the frames numbered in [lo, hi]. Accelerations are derived
    /// from the tracks around them ([`read`] reads the filter's margin), so
    /// the range's ends are not a filter's.
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
    /// Standard deviation of each tracked coordinate [m], which weights the
    /// derived accelerations; `None` estimates it from the tracks read.
    pub position_sd: Option<f64>,
}

impl SequencePlan {
    /// Whether accelerations may be derived: asked for, or a dynamic
    /// sequence whose grains.csv has no acceleration columns.
    fn may_derive(&self, opts: &InferOptions, acceleration_columns: bool) -> bool {
        self.derive_accelerations || (opts.method == Method::Dynamic && !acceleration_columns)
    }

    /// Whether the momentum weights use the position noise estimated from
    /// the tracks (which then must be all of them).
    fn weighs_by_estimated_noise(&self, opts: &InferOptions) -> bool {
        !self.acceleration_sd_given
            && self.position_sd.is_none()
            && opts.method == Method::Dynamic
            && matches!(opts.dynamic.rule, LambdaRule::Weights { .. })
    }
}

/// Which frames [`read`] read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadScope {
    /// The frame numbers read, `None` for all.
    pub frames: Option<(i64, i64)>,
    /// Why a frame range still read the whole sequence.
    pub whole_because: Option<&'static str>,
}

/// Reads the frames of a sequence folder that the plan needs: with a frame
/// range, only those frames, and, when accelerations are derived from the
/// tracks, the smoother's margin on either side
/// ([`Smoother::margin`](kinematics::Smoother::margin)) — so [`prepare`]
/// gives the range the forces a read of every frame gives it. The whole
/// sequence is read when the derivation needs every frame: the Whittaker
/// smoother, or momentum weights from a position noise estimated from the
/// tracks.
pub fn read(
    dir: &std::path::Path,
    opts: &InferOptions,
    plan: &SequencePlan,
) -> Result<(Vec<Scene>, ReadScope)> {
    let whole = |because| -> Result<(Vec<Scene>, ReadScope)> {
        Ok((
            scene::read_sequence(dir)?,
            ReadScope {
                frames: None,
                whole_because: because,
            },
        ))
    };
    let Some((lo, hi)) = plan.frame_range else {
        return whole(None);
    };
    // Frame numbers are integers: the range's integer ends (clamped, as
    // no sequence holds 2^62 frames).
    let limit = (1i64 << 62) as f64;
    let (first, last) = (
        lo.ceil().clamp(-limit, limit) as i64,
        hi.floor().clamp(-limit, limit) as i64,
    );
    if first > last {
        return Err(Error::Invalid(format!(
            "{}: no frame of the sequence lies in the range {lo}..{hi}",
            dir.display()
        )));
    }
    let mut derive = plan.may_derive(opts, scene::sequence_has_acceleration_columns(dir)?);
    loop {
        let margin = if derive {
            if plan.weighs_by_estimated_noise(opts) {
                return whole(Some(
                    "the momentum weights use the position noise estimated from every track; stating the noise lets a block read only its frames",
                ));
            }
            match plan.smoother.margin() {
                Some(m) => m as i64,
                None => return whole(Some("the Whittaker smoother fits each whole track")),
            }
        } else {
            0
        };
        let frames = scene::read_sequence_frames(dir, first - margin, last + margin)?;
        // Acceleration columns with empty cells: derived after all.
        if !derive && plan.may_derive(opts, frames.iter().any(Scene::has_accelerations)) {
            derive = true;
            continue;
        }
        return Ok((
            frames,
            ReadScope {
                frames: Some((first - margin, last + margin)),
                whole_because: None,
            },
        ));
    }
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
        derived = Some(kinematics::derive_accelerations_with_noise(
            &mut frames,
            fps,
            plan.smoother,
            plan.position_sd,
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

/// What to do with the other frames when one fails.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OnFrameFailure {
    /// Infer every other frame; the failed ones are reported.
    #[default]
    Continue,
    /// Start no further frame (those already running finish).
    Stop,
}

/// One frame's end.
#[derive(Debug)]
pub enum FrameOutcome {
    Inferred(Box<super::Inference>),
    /// The frame's error (its message names the frame).
    Failed(Error),
    /// Not started: an earlier failure stopped the run ([`OnFrameFailure::Stop`]).
    NotRun,
}

impl FrameOutcome {
    pub fn inference(&self) -> Option<&super::Inference> {
        match self {
            FrameOutcome::Inferred(r) => Some(r),
            _ => None,
        }
    }
}

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
/// (in frame order) is the error. [`solve_frames`] reports each frame's
/// outcome instead.
pub fn infer_frames(
    frames: &[Scene],
    opts: &[InferOptions],
    progress: Option<ProgressFn<'_>>,
) -> Result<Vec<super::Inference>> {
    let outcomes = solve_frames(frames, opts, OnFrameFailure::Stop, progress)?;
    let mut results = Vec::with_capacity(outcomes.len());
    let mut not_run = false;
    for outcome in outcomes {
        match outcome {
            FrameOutcome::Inferred(r) => results.push(*r),
            FrameOutcome::Failed(e) => return Err(e),
            FrameOutcome::NotRun => not_run = true,
        }
    }
    if not_run {
        // Only a failure stops frames, and it was returned above.
        return Err(Error::Solver(
            "frames were left out without a failure".into(),
        ));
    }
    Ok(results)
}

/// Infers frames in parallel, each with its own options, and returns each
/// frame's outcome in frame order: a frame that fails does not stop the
/// others unless `on_failure` says so.
pub fn solve_frames(
    frames: &[Scene],
    opts: &[InferOptions],
    on_failure: OnFrameFailure,
    progress: Option<ProgressFn<'_>>,
) -> Result<Vec<FrameOutcome>> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    if frames.len() != opts.len() {
        return Err(Error::Invalid(
            "one set of options per frame is needed".into(),
        ));
    }
    let stopped = AtomicBool::new(false);
    let counts = std::sync::Mutex::new((0usize, 0usize));
    Ok(frames
        .par_iter()
        .zip(opts.par_iter())
        .map(|(scene, opts)| {
            if stopped.load(Ordering::Relaxed) {
                return FrameOutcome::NotRun;
            }
            let outcome = match super::infer(scene, opts) {
                Ok(r) => FrameOutcome::Inferred(Box::new(r)),
                Err(e) => {
                    if on_failure == OnFrameFailure::Stop {
                        stopped.store(true, Ordering::Relaxed);
                    }
                    FrameOutcome::Failed(match scene.frame {
                        Some(k) => in_frame(e, k),
                        None => e,
                    })
                }
            };
            if let Some(report) = progress {
                // Held while reporting, so calls come one at a time, in order.
                let mut counts = counts.lock().unwrap_or_else(|p| p.into_inner());
                counts.0 += 1;
                counts.1 += usize::from(matches!(outcome, FrameOutcome::Failed(_)));
                report(Progress {
                    done: counts.0,
                    total: frames.len(),
                    frame: scene.frame,
                    failed: counts.1,
                });
            }
            outcome
        })
        .collect())
}

/// The error with the frame's number in front, of the same kind.
fn in_frame(error: Error, frame: i64) -> Error {
    match error {
        Error::Invalid(m) => Error::Invalid(format!("frame {frame}: {m}")),
        Error::Infeasible(m) => Error::Infeasible(format!("frame {frame}: {m}")),
        Error::Solver(m) => Error::Solver(format!("frame {frame}: {m}")),
        other => Error::Solver(format!("frame {frame}: {other}")),
    }
}

/// The frames that were inferred, with their options and results, and the
/// failed ones.
pub struct Solved {
    pub frames: Vec<Scene>,
    pub per_frame: Vec<InferOptions>,
    pub results: Vec<super::Inference>,
    /// Frame number and error of each failed frame.
    pub failures: Vec<(i64, String)>,
    /// Every frame in order: `None` when inferred, else its failure.
    pub entries: Vec<Option<(i64, String)>>,
}

/// An entry of a sequence's JSON report.
#[derive(serde::Serialize)]
#[serde(untagged)]
pub enum ReportEntry<'a> {
    Inferred(&'a super::InferenceReport),
    Failed { frame: i64, error: &'a str },
}

/// A sequence's JSON report: one entry per frame in frame order, a failed
/// frame's `{"frame": k, "error": "…"}`.
pub fn sequence_report<'a>(
    entries: &'a [Option<(i64, String)>],
    reports: &[&'a super::InferenceReport],
) -> Vec<ReportEntry<'a>> {
    let mut reports = reports.iter();
    entries
        .iter()
        .filter_map(|entry| match entry {
            Some((frame, error)) => Some(ReportEntry::Failed {
                frame: *frame,
                error,
            }),
            None => reports.next().map(|r| ReportEntry::Inferred(r)),
        })
        .collect()
}

/// Sorts the frames' outcomes; an error when the run must stop (a failure
/// under `--stop-on-failure`, or no frame inferred).
pub fn split_outcomes(
    stop_on_failure: bool,
    frames: Vec<Scene>,
    per_frame: Vec<InferOptions>,
    outcomes: Vec<FrameOutcome>,
) -> Result<Solved> {
    let mut solved = Solved {
        frames: Vec::new(),
        per_frame: Vec::new(),
        results: Vec::new(),
        failures: Vec::new(),
        entries: Vec::new(),
    };
    let mut first_error = None;
    for ((frame, opts), outcome) in frames.into_iter().zip(per_frame).zip(outcomes) {
        match outcome {
            FrameOutcome::Inferred(r) => {
                solved.frames.push(frame);
                solved.per_frame.push(opts);
                solved.results.push(*r);
                solved.entries.push(None);
            }
            FrameOutcome::Failed(e) => {
                let failure = (frame.frame.unwrap_or_default(), e.to_string());
                solved.failures.push(failure.clone());
                solved.entries.push(Some(failure));
                first_error.get_or_insert(e);
            }
            FrameOutcome::NotRun => {}
        }
    }
    match first_error {
        Some(e) if stop_on_failure || solved.results.is_empty() => Err(e),
        _ => Ok(solved),
    }
}
