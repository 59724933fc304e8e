//! Accelerations from centroid tracks, as the original experiments derived
//! them: a zero-phase low-pass FIR filter (windowed sinc, Hamming window) then
//! central differences — or a Savitzky–Golay fit — and the impulse check
//! (table 3.1): Δv from the integrated inferred contact forces vs Δv measured,
//! with the measured side's noise.
//!
//! Layout: `filter` (the smoothers and their noise gain), `derive`
//! (accelerations of a sequence and the momentum weights they call for),
//! `impulse` (the impulse check); the track helpers shared by both live here.

mod derive;
mod filter;
mod impulse;

pub use derive::{
    derive_accelerations, derive_accelerations_with_noise, weight_derived_momentum,
    KinematicsReport, DERIVED_ACCEL_NOISE_FACTOR,
};
pub use filter::{acceleration_noise_gain, fir_zero_phase, savitzky_golay, Smoother};
pub use impulse::{impulse_check, ImpulseCheck, ImpulseOptions, ImpulseRow};

use crate::error::{Error, Result};
use crate::scene::{Scene, Vec3};
use std::collections::BTreeMap;

/// Positions of each grain id by frame index (frames must be sorted by number).
fn tracks(frames: &[Scene]) -> BTreeMap<String, Vec<(usize, Vec3)>> {
    let mut t: BTreeMap<String, Vec<(usize, Vec3)>> = BTreeMap::new();
    for (k, f) in frames.iter().enumerate() {
        for g in &f.grains {
            t.entry(g.id.clone()).or_default().push((k, g.position));
        }
    }
    t
}

/// Contiguous runs of frame indices.
fn segments(track: &[(usize, Vec3)]) -> Vec<&[(usize, Vec3)]> {
    let mut out = Vec::new();
    let mut start = 0;
    for i in 1..=track.len() {
        if i == track.len() || track[i].0 != track[i - 1].0 + 1 {
            out.push(&track[start..i]);
            start = i;
        }
    }
    out
}

fn check_frames(frames: &[Scene], fps: f64) -> Result<()> {
    if !(fps > 0.0 && fps.is_finite()) {
        return Err(Error::Invalid(format!("`fps` must be positive, got {fps}")));
    }
    if frames.windows(2).any(|w| w[0].frame >= w[1].frame) {
        return Err(Error::Invalid(
            "frames must have increasing frame numbers".into(),
        ));
    }
    if frames
        .windows(2)
        .any(|w| w[1].frame.unwrap_or(0) - w[0].frame.unwrap_or(0) != 1)
    {
        return Err(Error::Invalid(
            "deriving accelerations and the impulse check need consecutive frame numbers (equal time steps); select a range with `frames`".into(),
        ));
    }
    Ok(())
}

/// Robust estimate of the position noise from the tracks: the median absolute
/// fourth difference over all grains and axes. For white noise of sd σ a
/// fourth difference has sd √70·σ; smooth motion contributes ~ x⁗·dt⁴, far
/// less, and the median ignores the few frames of a violent impact.
pub fn estimate_position_sd(frames: &[Scene]) -> f64 {
    let dim = frames.first().map_or(3, |f| f.dim);
    let mut diffs = Vec::new();
    for track in tracks(frames).values() {
        for seg in segments(track) {
            for w in seg.windows(5) {
                for k in 0..dim {
                    let x = |i: usize| w[i].1[k];
                    diffs.push((x(0) - 4.0 * x(1) + 6.0 * x(2) - 4.0 * x(3) + x(4)).abs());
                }
            }
        }
    }
    if diffs.is_empty() {
        return 0.0;
    }
    let mid = diffs.len() / 2;
    let median = *diffs.select_nth_unstable_by(mid, f64::total_cmp).1;
    // Median of |N(0, s)| is 0.6745 s.
    median / 0.674_489_75 / 70f64.sqrt()
}
