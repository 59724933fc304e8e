//! One inference run, as `grainforce infer` and the Python package make it:
//! read → prepare the sequence → solve the frames → joint time fit →
//! uncertainty → impulse check → the Pareto front → the report. Front ends
//! turn their arguments into an [`InferConfig`], call [`run`] and write or
//! return what it gives.

use super::config::{InferConfig, TimeFitChoice};
use super::dynamic::Front;
use super::kinematics::{self, ImpulseCheck, KinematicsReport};
use super::sequence::{self, FrameOutcome, OnFrameFailure, Progress};
use super::time_fit::{self, TimeFitReport};
use super::uncertainty::{frames_uncertainty, NoiseEstimate, Uncertainty, UncertaintyOptions};
use super::{InferOptions, Inference, InferenceReport};
use crate::error::{Error, Result};
use crate::scene::{ForceRow, Forces, Scene, Vec3};
use std::path::Path;

/// What a run infers: a scene (or sequence) folder, read as far as the
/// configuration needs, or frames in memory.
#[derive(Debug, Clone, Copy)]
pub enum Source<'a> {
    Folder(&'a Path),
    Frames(&'a [Scene]),
}

/// What a run tells its caller while it works.
#[derive(Debug, Clone, Copy)]
pub enum Event<'a> {
    /// A remark worth showing (fields of the configuration in backticks,
    /// see [`super::config::spell_fields`]).
    Note(&'a str),
    /// Accelerations were derived from the tracks (before any frame is solved).
    Derived(&'a KinematicsReport),
    /// A frame of the sequence ended.
    Frame(Progress),
}

/// A run's callback; called from the solving threads, one call at a time.
pub type EventFn<'a> = &'a (dyn Fn(Event<'_>) + Sync);

/// Everything a run found.
#[derive(Debug)]
pub struct Run {
    /// The frames inferred (those that failed are in `failures`).
    pub frames: Vec<Scene>,
    /// Each inferred frame's solver options.
    pub per_frame: Vec<InferOptions>,
    /// Each inferred frame's forces and report; after a joint time fit the
    /// forces are the fit's and the reports the frame-by-frame start's.
    pub results: Vec<Inference>,
    /// Frame number and error of each failed frame.
    pub failures: Vec<(i64, String)>,
    /// Every frame in order: `None` when inferred, else its failure.
    pub entries: Vec<Option<(i64, String)>>,
    /// Whether the source was one frame (a static scene).
    pub single_frame: bool,
    /// What deriving accelerations from the tracks found, when it ran.
    pub derived: Option<KinematicsReport>,
    pub time_fit: Option<TimeFitReport>,
    /// Per inferred frame, with `uncertainty` draws.
    pub uncertainty: Option<Vec<Uncertainty>>,
    /// With `impulse`, when every frame was inferred.
    pub impulse: Option<ImpulseCheck>,
}

impl Run {
    /// The forces.csv table: every inferred contact of every frame, with
    /// standard deviations after `uncertainty`.
    pub fn forces(&self) -> Forces {
        let mut rows = Vec::new();
        for (i, (frame, result)) in self.frames.iter().zip(&self.results).enumerate() {
            for (c, f) in result.forces.iter().enumerate() {
                if let Some(f) = f {
                    rows.push(ForceRow {
                        contact: frame.contacts[c].id.clone(),
                        frame: frame.frame,
                        force: *f,
                        // A contact every draw left out has no spread: zero.
                        sd: self
                            .uncertainty
                            .as_ref()
                            .map(|u| u[i].sd[c].unwrap_or([0.0; 3])),
                    });
                }
            }
        }
        Forces {
            dim: self.frames.first().map_or(2, |f| f.dim),
            rows,
        }
    }

    /// The first frame's Pareto front (dynamic and soft with `pareto` or
    /// the knee rule).
    pub fn pareto(&self) -> Option<&Front> {
        self.results.first().and_then(|r| r.report.pareto.as_ref())
    }

    /// The report as `infer --report` writes it: one frame's report; a
    /// sequence's list (a failed frame `{"frame", "error"}`); or, after a
    /// joint time fit, `{"time_fit", "frame_by_frame"}`.
    pub fn report_json(&self) -> serde_json::Value {
        let reports: Vec<&InferenceReport> = self.results.iter().map(|r| &r.report).collect();
        let value = if let Some(fit) = &self.time_fit {
            // The frames' reports describe the frame-by-frame start.
            serde_json::to_value(serde_json::json!({
                "time_fit": fit,
                "frame_by_frame": reports,
            }))
        } else if self.single_frame {
            serde_json::to_value(reports[0])
        } else {
            serde_json::to_value(sequence::sequence_report(&self.entries, &reports))
        };
        value.unwrap_or(serde_json::Value::Null)
    }

    /// The report in one shape for one frame or many: `frames` (a list,
    /// one entry per frame, a failed one `{"frame", "error"}`), and
    /// `time_fit`, `uncertainty`, `impulse`, `accelerations` (what deriving
    /// them found), each `null` when not run.
    pub fn report_uniform(&self) -> serde_json::Value {
        let reports: Vec<&InferenceReport> = self.results.iter().map(|r| &r.report).collect();
        let uncertainty: Option<Vec<serde_json::Value>> = self.uncertainty.as_ref().map(|u| {
            u.iter()
                .map(|u| {
                    serde_json::json!({
                        "draws": u.draws,
                        "failed_draws": u.failed_draws,
                        "noise_level": u.noise_level,
                        "estimated": u.estimated,
                        "time": u.time,
                    })
                })
                .collect()
        });
        let impulse = self.impulse.as_ref().map(|c| {
            serde_json::json!({
                "grains": c.rows.len(),
                "skipped": c.skipped,
                "position_sd": c.position_sd,
                "position_sd_estimated": c.position_sd_estimated,
                "moving": c.moving().count(),
                "worst_moving_disagreement": c.worst_moving_disagreement(),
            })
        });
        serde_json::json!({
            "frames": sequence::sequence_report(&self.entries, &reports),
            "time_fit": self.time_fit,
            "uncertainty": uncertainty,
            "impulse": impulse,
            "accelerations": self.derived,
        })
    }
}

/// Runs an inference as the configuration asks (checked first, see
/// [`InferConfig::validate`]). A failed frame of a sequence ends the run
/// only with `stop_on_failure` or when no frame was inferred; the others
/// are in [`Run::failures`].
pub fn run(source: Source<'_>, config: &InferConfig, events: Option<EventFn<'_>>) -> Result<Run> {
    config.validate()?;
    let note = |text: &str| {
        if let Some(events) = events {
            events(Event::Note(text));
        }
    };
    let (opts, _) = config.options()?;
    let plan = config.sequence_plan()?;
    let frames = match source {
        Source::Frames(frames) => {
            if frames.is_empty() {
                return Err(Error::Invalid("no frame to infer".into()));
            }
            frames.to_vec()
        }
        Source::Folder(dir) => {
            let (frames, scope) = sequence::read(dir, &opts, &plan)?;
            if let Some(reason) = scope.whole_because {
                note(&format!(
                    "`frames` reads every frame: {reason} (`position_sd` or `accel_sd`)"
                ));
            }
            frames
        }
    };
    let prepared = sequence::prepare(frames, &opts, &plan)?;
    if let (Some(k), Some(events)) = (&prepared.derived, events) {
        events(Event::Derived(k));
    }
    let sequence::PreparedSequence {
        frames,
        options: per_frame,
        derived,
    } = prepared;
    let single_frame = frames.len() == 1;
    let outcomes = if single_frame {
        vec![FrameOutcome::Inferred(Box::new(super::infer(
            &frames[0],
            &per_frame[0],
        )?))]
    } else {
        let on_failure = if config.stop_on_failure {
            OnFrameFailure::Stop
        } else {
            OnFrameFailure::Continue
        };
        let advance = |p: Progress| {
            if let Some(events) = events {
                events(Event::Frame(p));
            }
        };
        sequence::solve_frames(&frames, &per_frame, on_failure, Some(&advance))?
    };
    let sequence::Solved {
        frames,
        per_frame,
        mut results,
        failures,
        entries,
    } = sequence::split_outcomes(config.stop_on_failure, frames, per_frame, outcomes)?;
    let time_fit = match (config.time_fit, config.fps) {
        (TimeFitChoice::Joint, Some(fps)) => {
            if !failures.is_empty() {
                return Err(Error::Invalid(format!(
                    "`time_fit` = joint fits every frame at once, and {} frames failed: {}",
                    failures.len(),
                    failures
                        .iter()
                        .map(|(k, e)| format!("frame {k}: {e}"))
                        .collect::<Vec<_>>()
                        .join("; ")
                )));
            }
            let fit = joint_time_fit(config, &opts, fps, &frames, &results)?;
            for (result, forces) in results.iter_mut().zip(fit.forces) {
                result.forces = forces;
            }
            Some(fit.report)
        }
        _ => None,
    };
    let uncertainty = match config.uncertainty {
        Some(draws) => {
            let options = UncertaintyOptions {
                draws: draws as usize,
                seed: config.uncertainty_seed as u64,
                noise: match config.noise_level {
                    Some(s) => NoiseEstimate::Relative(s),
                    None => NoiseEstimate::FromResidual,
                },
            };
            Some(frames_uncertainty(&frames, &per_frame, &results, &options)?)
        }
        None => None,
    };
    let impulse = match (config.impulse, config.fps) {
        // It integrates every frame's forces.
        (true, Some(fps)) if failures.is_empty() => {
            let gravity = opts.assemble.gravity.unwrap_or_else(|| frames[0].gravity());
            let forces: Vec<Vec<Option<Vec3>>> = results.iter().map(|r| r.forces.clone()).collect();
            let options = kinematics::ImpulseOptions {
                window: config.impulse_window,
                position_sd: config.position_sd,
                ..Default::default()
            };
            Some(kinematics::impulse_check(
                &frames, &forces, fps, gravity, &options,
            )?)
        }
        _ => None,
    };
    Ok(Run {
        frames,
        per_frame,
        results,
        failures,
        entries,
        single_frame,
        derived,
        time_fit,
        uncertainty,
        impulse,
    })
}

/// The joint time fit, started from the frame-by-frame answer.
fn joint_time_fit(
    config: &InferConfig,
    opts: &InferOptions,
    fps: f64,
    frames: &[Scene],
    results: &[Inference],
) -> Result<time_fit::TimeFit> {
    let fit = time_fit::TimeFitOptions {
        fps,
        position_sd: config.position_sd,
        stress_sd: config.stress_sd,
        roughness: config.roughness,
    };
    let frame_by_frame: Vec<Vec<Option<Vec3>>> = results.iter().map(|r| r.forces.clone()).collect();
    time_fit::infer_time_fit(frames, opts, &fit, Some(&frame_by_frame))
}

/// The impulse check as CSV (the columns `infer --impulse` documents).
pub fn impulse_csv(check: &ImpulseCheck, dim: usize) -> String {
    let axes = &["x", "y", "z"][..dim];
    let mut text = String::from("grain,first_frame,last_frame,start_window,end_window");
    for a in axes {
        text.push_str(&format!(",dv_{a}_measured,dv_{a}_inferred"));
    }
    text.push_str(",dv_sd,disagreement,gap_in_sd,moves\n");
    for r in &check.rows {
        text.push_str(&format!(
            "{},{},{},{},{}",
            r.grain, r.first_frame, r.last_frame, r.start_window, r.end_window
        ));
        for k in 0..dim {
            text.push_str(&format!(",{},{}", r.measured[k], r.inferred[k]));
        }
        text.push_str(&format!(
            ",{},{},{},{}\n",
            r.measured_sd,
            r.disagreement,
            r.gap_in_sd,
            u8::from(r.moves)
        ));
    }
    text
}

/// A one-line summary of the impulse check.
pub fn impulse_summary(check: &ImpulseCheck) -> String {
    let moving: Vec<f64> = check.moving().map(|r| r.disagreement).collect();
    format!(
        "impulse check: {} grains ({} skipped, tracks shorter than {} frames), position sd {:.3e} m ({}), {} move (|Δv| ≥ {} sd); worst disagreement of a moving grain {:.1} %",
        check.rows.len(),
        check.skipped.len(),
        check.options.window + 1,
        check.position_sd,
        if check.position_sd_estimated {
            "estimated from the tracks"
        } else {
            "stated"
        },
        moving.len(),
        check.options.moving_factor,
        100.0 * check.worst_moving_disagreement()
    )
}

/// A one-line summary of a frame's bootstrap.
pub fn uncertainty_summary(u: &Uncertainty) -> String {
    format!(
        "uncertainty {} draws ({} failed), stress noise {:.3} ({}), {:.3} s",
        u.draws,
        u.failed_draws,
        u.noise_level,
        if u.estimated {
            "from the residual"
        } else {
            "stated"
        },
        u.time
    )
}
