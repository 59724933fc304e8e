//! Accelerations derived from the tracks of a sequence, what happened while
//! deriving them, and the momentum weights they call for.

use super::filter::{acceleration_noise_gain, differentiate, Smoother};
use super::{check_frames, estimate_position_sd, segments, tracks};
use crate::error::{Error, Result};
use crate::infer::{InferOptions, LambdaRule};
use crate::scene::{Body, Scene, Vec3};
use std::collections::BTreeMap;

/// Accelerations derived here are inferred with a stated noise of this many
/// times the position noise propagated through the filter
/// ([`KinematicsReport::acceleration_sd`]): the rest covers the filter's
/// smoothing of impacts. Measured on `impact` (0.1 % of a diameter position
/// noise, twelve draws; relerr, moving grain-draws within 10 % of the
/// measured Δv, worst, with 21-frame end windows): 1 → 0.037–0.043, 57/60, 0.12; 1.5 → 0.033–0.038,
/// 59/60, 0.13; 2 → 0.030–0.035, 59/60, 0.14 (all within 9.1 % of the
/// noise-free Δv); 3 → 0.027–0.031, 58/60, 0.16.
pub const DERIVED_ACCEL_NOISE_FACTOR: f64 = 2.0;

/// What happened while deriving accelerations.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct KinematicsReport {
    pub tracks: usize,
    /// Grains seen in too few consecutive frames to differentiate (acceleration set to zero).
    pub short_tracks: Vec<String>,
    /// Grains that appear or disappear during the sequence.
    pub partial_tracks: usize,
    /// Position noise estimated from the tracks [m] ([`estimate_position_sd`]).
    pub position_sd: f64,
    /// Per frame: rms over its tracked grains of the derived acceleration's
    /// noise sd [m/s²], the position noise propagated through the filter and
    /// the difference — largest near the ends of tracks.
    pub acceleration_sd: Vec<f64>,
}

/// Fills every grain's centroid acceleration from its track. Frames must be
/// consecutive and sorted; grains are matched by id. Infer with the noise
/// this reports ([`weight_derived_momentum`]), not with exact momentum.
pub fn derive_accelerations(
    frames: &mut [Scene],
    fps: f64,
    smoother: Smoother,
) -> Result<KinematicsReport> {
    derive_accelerations_with_noise(frames, fps, smoother, None)
}

/// [`derive_accelerations`] with the position noise stated (`Some`) rather
/// than estimated from these frames' tracks.
pub fn derive_accelerations_with_noise(
    frames: &mut [Scene],
    fps: f64,
    smoother: Smoother,
    position_sd: Option<f64>,
) -> Result<KinematicsReport> {
    check_frames(frames, fps)?;
    smoother.validate()?;
    let dt = 1.0 / fps;
    let mut report = KinematicsReport::default();
    let all = tracks(frames);
    report.tracks = all.len();
    let touched: Vec<std::collections::HashSet<String>> = frames
        .iter()
        .map(|f| {
            let mut ids = std::collections::HashSet::new();
            for c in &f.contacts {
                for p in std::iter::once(c.a).chain(match c.b {
                    Body::Grain(b) => Some(b),
                    _ => None,
                }) {
                    if let Some(g) = f.grains.get(p) {
                        ids.insert(g.id.clone());
                    }
                }
            }
            ids
        })
        .collect();
    report.position_sd = match position_sd {
        Some(sd) if sd >= 0.0 && sd.is_finite() => sd,
        Some(sd) => {
            return Err(Error::Invalid(format!(
                "the position noise must be finite and ≥ 0, got {sd}"
            )))
        }
        None => estimate_position_sd(frames),
    };
    let mut gain_sq = vec![(0.0, 0usize); frames.len()];
    let mut gains: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    let mut accel: Vec<BTreeMap<String, Vec3>> = vec![BTreeMap::new(); frames.len()];
    for (id, track) in &all {
        if track.len() < frames.len() {
            report.partial_tracks += 1;
        }
        for seg in segments(track) {
            if seg.len() < 3 {
                report.short_tracks.push(id.clone());
                for &(k, _) in seg {
                    accel[k].insert(id.clone(), [0.0; 3]);
                }
                continue;
            }
            let positions: Vec<Vec3> = seg.iter().map(|s| s.1).collect();
            // A grain that touches nothing accelerates with gravity exactly —
            // when the scene states gravity; else nothing is assumed.
            let known: Vec<Option<Vec3>> = seg
                .iter()
                .map(|&(k, _)| {
                    let declared = frames[k].settings.gravity.is_some();
                    (declared && !touched[k].contains(id.as_str())).then(|| frames[k].gravity())
                })
                .collect();
            let a = differentiate(&positions, dt, smoother, 2, &known)?;
            // Tracks of one length share their gain: computed once.
            let gain = match gains.entry(seg.len()) {
                std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                std::collections::btree_map::Entry::Vacant(e) => {
                    e.insert(acceleration_noise_gain(seg.len(), dt, smoother)?)
                }
            };
            let holds = matches!(smoother, Smoother::Whittaker { .. });
            for (((&(k, _), a), &g), known) in seg.iter().zip(a).zip(gain.iter()).zip(&known) {
                accel[k].insert(id.clone(), a);
                // Held accelerations carry no noise, and such a grain has no
                // contact to weigh in that frame.
                if !(holds && known.is_some()) {
                    gain_sq[k].0 += g * g;
                    gain_sq[k].1 += 1;
                }
            }
        }
    }
    report.acceleration_sd = gain_sq
        .iter()
        .map(|&(sq, n)| {
            if n > 0 {
                report.position_sd * (sq / n as f64).sqrt()
            } else {
                0.0
            }
        })
        .collect();
    for (frame, acc) in frames.iter_mut().zip(accel) {
        let dim = frame.dim;
        for g in &mut frame.grains {
            let mut a = acc.get(&g.id).copied().unwrap_or([0.0; 3]);
            if dim == 2 {
                a[2] = 0.0;
            }
            g.acceleration = Some(a);
        }
    }
    Ok(report)
}

/// Sets each frame's momentum weight for accelerations derived by
/// [`derive_accelerations`]: `LambdaRule::Weights` with the stresses'
/// relative noise `stress_sd` and, for m·a, the absolute acceleration noise
/// [`DERIVED_ACCEL_NOISE_FACTOR`] × `report.acceleration_sd` of that frame.
/// Per frame, because the noise is larger near the ends of tracks and its
/// size relative to m·a varies from impact to rest; a weight relative to each
/// frame's m·a would trust the noise of grains at rest.
pub fn weight_derived_momentum(
    frames: &[Scene],
    options: &mut [InferOptions],
    report: &KinematicsReport,
    stress_sd: f64,
) -> Result<()> {
    if options.len() != frames.len() || report.acceleration_sd.len() != frames.len() {
        return Err(Error::Invalid(
            "one set of options and one acceleration noise per frame are needed".into(),
        ));
    }
    for ((frame, o), &sigma_a) in frames.iter().zip(options).zip(&report.acceleration_sd) {
        // The assembly infer() builds for a soft momentum weight.
        let mut assemble = o.assemble.clone();
        assemble.prune_single_contacts = false;
        assemble.single_system = false;
        let assembly = crate::assemble::assemble(frame, &assemble)?;
        let (sum, count) = assembly
            .systems
            .iter()
            .flat_map(|s| &s.grains)
            .filter_map(|&p| frame.grains[p].mass)
            .fold((0.0, 0usize), |(s, n), m| (s + m * m, n + 1));
        let scale = crate::infer::dynamic::momentum_row_scale(&assembly);
        let momentum_sd = if count > 0 && scale > 0.0 {
            let mass = (sum / count as f64).sqrt();
            let sigma_row = DERIVED_ACCEL_NOISE_FACTOR * sigma_a * mass / assembly.scales.force;
            // Noise-free tracks still carry the filter's smoothing: never exact.
            (sigma_row / scale).max(MIN_DERIVED_MOMENTUM_SD)
        } else {
            1.0
        };
        o.dynamic.rule = LambdaRule::Weights {
            stress_sd,
            momentum_sd,
        };
    }
    Ok(())
}

/// Floor of the relative momentum noise of derived accelerations.
const MIN_DERIVED_MOMENTUM_SD: f64 = 0.01;
