//! The impulse check (table 3.1 of the method): Δv from the integrated
//! inferred contact forces against Δv measured from the tracks.

use super::{check_frames, estimate_position_sd, segments, tracks};
use crate::error::{Error, Result};
use crate::scene::{Body, Scene, Vec3};

/// How the impulse check compares velocities.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ImpulseOptions {
    /// Frames in each end window (odd, ≥ 3), at least. The velocity at either
    /// end of a track is the least-squares slope over its first / last
    /// `window` frames — or over the whole contact-free stretch at an end
    /// where the grain flies freely (up to half the track): its noise falls
    /// as window^(-3/2), whereas a velocity from two or three frames carries
    /// the position noise almost undamped.
    pub window: usize,
    /// Standard deviation of each tracked coordinate [m]; `None` estimates it
    /// from the tracks ([`estimate_position_sd`]).
    pub position_sd: Option<f64>,
    /// A grain moves when |Δv measured| ≥ `moving_factor` × the standard
    /// deviation of one measured Δv component.
    pub moving_factor: f64,
}

impl Default for ImpulseOptions {
    fn default() -> Self {
        ImpulseOptions {
            window: 21,
            position_sd: None,
            // Noise alone then moves the relative disagreement by at most
            // 10 % at two standard deviations.
            moving_factor: 20.0,
        }
    }
}

/// One grain's impulse check.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ImpulseRow {
    pub grain: String,
    /// Frame numbers of the first and last frame of the grain's track used.
    pub first_frame: i64,
    pub last_frame: i64,
    /// Frames in the start and end windows: `window`, or more where the grain
    /// touches nothing at that end of its track (free flight).
    pub start_window: usize,
    pub end_window: usize,
    /// Δv from the tracked positions: end-window slope minus start-window slope.
    pub measured: Vec3,
    /// The same two slopes of the trajectory integrated twice from
    /// (Σ inferred contact forces)/m + g.
    pub inferred: Vec3,
    /// Standard deviation of each measured Δv component caused by the position noise.
    pub measured_sd: f64,
    /// |Δv inferred − Δv measured| / |Δv measured|.
    pub disagreement: f64,
    /// |Δv inferred − Δv measured| / measured_sd: a few units (the norm of
    /// `dim` unit normals) is what noise in the tracks alone explains.
    pub gap_in_sd: f64,
    /// |Δv measured| ≥ moving_factor × measured_sd.
    pub moves: bool,
}

/// Table 3.1 of the method, per grain, with what is needed to judge it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ImpulseCheck {
    pub rows: Vec<ImpulseRow>,
    /// Position noise used for `measured_sd` [m].
    pub position_sd: f64,
    /// Whether `position_sd` was estimated from the tracks (else stated).
    pub position_sd_estimated: bool,
    pub options: ImpulseOptions,
    /// Grains whose longest contiguous track is shorter than window + 1 frames.
    pub skipped: Vec<String>,
}

impl ImpulseCheck {
    pub fn moving(&self) -> impl Iterator<Item = &ImpulseRow> {
        self.rows.iter().filter(|r| r.moves)
    }

    /// Largest relative disagreement among the moving grains (0 when none moves).
    pub fn worst_moving_disagreement(&self) -> f64 {
        self.moving().map(|r| r.disagreement).fold(0.0, f64::max)
    }
}

fn largest_odd_at_most(m: usize) -> usize {
    if m % 2 == 1 {
        m
    } else {
        m.saturating_sub(1)
    }
}

/// One frame's grains by id, with their net inferred contact force (on the
/// grain) and whether any contact touches them.
struct FrameLoads<'a> {
    index: std::collections::HashMap<&'a str, usize>,
    net: Vec<Vec3>,
    touched: Vec<bool>,
}

impl<'a> FrameLoads<'a> {
    fn new(frame: &'a Scene, forces: &[Option<Vec3>]) -> Self {
        let count = frame.grains.len();
        let index = frame
            .grains
            .iter()
            .enumerate()
            .map(|(p, g)| (g.id.as_str(), p))
            .collect();
        let (mut net, mut touched) = (vec![[0.0; 3]; count], vec![false; count]);
        for (c, fc) in frame.contacts.iter().zip(forces) {
            let b = match c.b {
                Body::Grain(b) if b < count => Some(b),
                _ => None,
            };
            for p in std::iter::once(c.a).filter(|&a| a < count).chain(b) {
                touched[p] = true;
            }
            let Some(f) = fc else { continue };
            for k in 0..3 {
                if c.a < count {
                    net[c.a][k] += f[k];
                }
                if let Some(b) = b {
                    net[b][k] -= f[k];
                }
            }
        }
        FrameLoads {
            index,
            net,
            touched,
        }
    }
}

/// Weights of the least-squares slope over `window` samples starting at
/// `start` of a series of length `n` (zero elsewhere), per unit time.
fn slope_weights(n: usize, start: usize, window: usize, dt: f64) -> Vec<f64> {
    let centre = (window - 1) as f64 / 2.0;
    let sum_sq: f64 = (0..window).map(|i| (i as f64 - centre).powi(2)).sum();
    let mut w = vec![0.0; n];
    for i in 0..window {
        w[start + i] = (i as f64 - centre) / (sum_sq * dt);
    }
    w
}

/// Table 3.1 of the method. For each grain, over its longest contiguous
/// track: the velocity change between its start and end windows (`window`
/// frames, widened over a contact-free stretch at that end) measured from the
/// positions (least-squares slopes), against the same
/// slopes of the trajectory obtained by integrating (Σ inferred contact
/// forces)/m + g twice. Applying one linear operator to both sides makes them
/// estimate the same quantity whatever the window, so only the errors of the
/// data and of the inferred forces remain; the measured side's noise
/// sd follows exactly from the position noise.
pub fn impulse_check(
    frames: &[Scene],
    forces: &[Vec<Option<Vec3>>],
    fps: f64,
    gravity: Vec3,
    options: &ImpulseOptions,
) -> Result<ImpulseCheck> {
    check_frames(frames, fps)?;
    let window = options.window;
    if window < 3 || window % 2 == 0 {
        return Err(Error::Invalid(format!(
            "impulse check: the end window must be odd and ≥ 3 frames, got {window}"
        )));
    }
    if !(options.moving_factor >= 0.0 && options.moving_factor.is_finite()) {
        return Err(Error::Invalid(format!(
            "impulse check: the moving factor must be ≥ 0, got {}",
            options.moving_factor
        )));
    }
    if let Some(sd) = options.position_sd {
        if !(sd >= 0.0 && sd.is_finite()) {
            return Err(Error::Invalid(format!(
                "impulse check: the position noise must be ≥ 0, got {sd}"
            )));
        }
    }
    if forces.len() != frames.len() {
        return Err(Error::Invalid("one force set per frame is needed".into()));
    }
    let (position_sd, position_sd_estimated) = match options.position_sd {
        Some(sd) => (sd, false),
        None => (estimate_position_sd(frames), true),
    };
    let dt = 1.0 / fps;
    let dim = frames[0].dim;
    // Each frame's contacts are visited once, not once per grain.
    let loads: Vec<FrameLoads> = frames
        .iter()
        .zip(forces)
        .map(|(f, fk)| FrameLoads::new(f, fk))
        .collect();
    let mut rows = Vec::new();
    let mut skipped = Vec::new();
    for (id, track) in tracks(frames) {
        let Some(seg) = segments(&track).into_iter().max_by_key(|s| s.len()) else {
            continue;
        };
        let n = seg.len();
        if n < window + 1 {
            skipped.push(id);
            continue;
        }
        let mut accel = Vec::with_capacity(n);
        let mut mass = None;
        let mut touches = Vec::with_capacity(n);
        for &(k, _) in seg {
            let load = &loads[k];
            let p = load.index[id.as_str()];
            mass = frames[k].grains[p].mass.or(mass);
            accel.push(load.net[p]);
            touches.push(load.touched[p]);
        }
        let Some(m) = mass else {
            skipped.push(id);
            continue;
        };
        for a in &mut accel {
            for k in 0..3 {
                a[k] = a[k] / m + gravity[k];
            }
        }
        // Integrated with the acceleration linear between frames (exact for
        // piecewise-linear a): v trapezoidal, x with dt²(a₀/3 + a₁/6).
        let mut integrated = vec![[0.0; 3]; n];
        let mut v = [0.0; 3];
        for i in 1..n {
            let (a0, a1) = (accel[i - 1], accel[i]);
            for k in 0..3 {
                integrated[i][k] =
                    integrated[i - 1][k] + v[k] * dt + dt * dt * (a0[k] / 3.0 + a1[k] / 6.0);
                v[k] += 0.5 * dt * (a0[k] + a1[k]);
            }
        }
        // Where the grain touches nothing at an end of its track, it flies
        // freely: the track there is a parabola under gravity, whose
        // least-squares slope is the velocity at the window's centre, so that
        // end's window covers the whole contact-free stretch (quieter, and
        // the inferred side is exactly g there). Capped at half the track.
        let free_start = touches.iter().take_while(|&&t| !t).count();
        let free_end = touches.iter().rev().take_while(|&&t| !t).count();
        let widen = |free: usize| window.max(largest_odd_at_most(free.min(n / 2)));
        let (start_window, end_window) = (widen(free_start), widen(free_end));
        let begin = slope_weights(n, 0, start_window, dt);
        let end = slope_weights(n, n - end_window, end_window, dt);
        let weights: Vec<f64> = end.iter().zip(&begin).map(|(e, b)| e - b).collect();
        let apply = |x: &dyn Fn(usize, usize) -> f64| -> Vec3 {
            let mut out = [0.0; 3];
            for (k, o) in out.iter_mut().enumerate().take(dim) {
                // Relative to the first sample, so a far origin adds no rounding.
                *o = weights
                    .iter()
                    .enumerate()
                    .map(|(i, w)| w * (x(i, k) - x(0, k)))
                    .sum();
            }
            out
        };
        let measured = apply(&|i, k| seg[i].1[k]);
        let inferred = apply(&|i, k| integrated[i][k]);
        let measured_sd = position_sd * weights.iter().map(|w| w * w).sum::<f64>().sqrt();
        let norm = crate::scene::norm;
        let ratio = crate::report::metrics::ratio;
        let gap = norm([
            inferred[0] - measured[0],
            inferred[1] - measured[1],
            inferred[2] - measured[2],
        ]);
        let size = norm(measured);
        let disagreement = ratio(gap, size);
        rows.push(ImpulseRow {
            grain: id,
            first_frame: frames[seg[0].0].frame.unwrap_or(seg[0].0 as i64),
            last_frame: frames[seg[n - 1].0].frame.unwrap_or(seg[n - 1].0 as i64),
            start_window,
            end_window,
            measured,
            inferred,
            measured_sd,
            disagreement,
            gap_in_sd: ratio(gap, measured_sd),
            moves: size > 0.0 && size >= options.moving_factor * measured_sd,
        });
    }
    Ok(ImpulseCheck {
        rows,
        position_sd,
        position_sd_estimated,
        options: *options,
        skipped,
    })
}
