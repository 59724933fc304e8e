//! Accelerations from centroid tracks, as the original experiments derived
//! them: a zero-phase low-pass FIR filter (windowed sinc, Hamming window) then
//! central differences — or a Savitzky–Golay fit — and the impulse check
//! (table 3.1): Δv from the integrated inferred contact forces vs Δv measured.

use crate::error::{Error, Result};
use crate::scene::{Body, Scene, Vec3};
use std::collections::BTreeMap;

#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum Smoother {
    /// Windowed-sinc low-pass with a Hamming window: `order` + 1 taps, cut-off
    /// as a fraction of the Nyquist frequency, applied without phase shift.
    Fir { order: usize, cutoff: f64 },
    /// Local least-squares polynomials of `degree` over `window` frames (odd).
    SavitzkyGolay { window: usize, degree: usize },
}

impl Smoother {
    /// Defaults from the frame rate: keep motion below fps/10 (cut-off 0.2 of
    /// Nyquist), 20th order — measured on the `impact` preset (see README).
    pub fn default_fir() -> Self {
        Smoother::Fir {
            order: 20,
            cutoff: 0.2,
        }
    }

    fn validate(&self) -> Result<()> {
        match *self {
            Smoother::Fir { order, cutoff } => {
                if order < 2 || order % 2 != 0 || !(cutoff > 0.0 && cutoff < 1.0) {
                    return Err(Error::Invalid(format!(
                        "FIR filter: order must be even and ≥ 2 and the cut-off in (0, 1) of Nyquist, got {order} and {cutoff}"
                    )));
                }
            }
            Smoother::SavitzkyGolay { window, degree } => {
                if window % 2 == 0 || degree < 2 || degree >= window {
                    return Err(Error::Invalid(format!(
                        "Savitzky–Golay: the window must be odd and larger than the degree (≥ 2), got {window} and {degree}"
                    )));
                }
            }
        }
        Ok(())
    }
}

/// Relative noise of m·a to state (`LambdaRule::Weights { momentum_sd }`) for
/// accelerations derived here from tracked positions. Measured on `impact`
/// with 0.1 % of a diameter position noise and exact stresses: 0.1 → relerr
/// 0.051, 0.3 → 0.038, 1 → 0.026; 0.3 also leaves room for noisy stresses.
/// Treating derived accelerations as exact is usually infeasible.
pub const DERIVED_ACCEL_SD: f64 = 0.3;

/// What happened while deriving accelerations.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct KinematicsReport {
    pub tracks: usize,
    /// Grains seen in too few consecutive frames to differentiate (acceleration set to zero).
    pub short_tracks: Vec<String>,
    /// Grains that appear or disappear during the sequence.
    pub partial_tracks: usize,
}

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
        return Err(Error::Invalid(format!("--fps must be positive, got {fps}")));
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
            "deriving accelerations needs consecutive frame numbers (equal time steps); select a range with --frames".into(),
        ));
    }
    Ok(())
}

/// Derivative of order `deriv` (1 or 2) of each component along a track, per frame.
fn differentiate(samples: &[Vec3], dt: f64, smoother: Smoother, deriv: usize) -> Vec<Vec3> {
    let n = samples.len();
    let mut out = vec![[0.0; 3]; n];
    for k in 0..3 {
        // Centred on the first sample: far from the origin, filtering raw
        // coordinates would add rounding of the offset's size.
        let origin = samples.first().map_or(0.0, |p| p[k]);
        let x: Vec<f64> = samples.iter().map(|p| p[k] - origin).collect();
        let d = match smoother {
            Smoother::Fir { order, cutoff } => {
                let smoothed = fir_zero_phase(&x, order, cutoff);
                finite_difference(&smoothed, dt, deriv)
            }
            Smoother::SavitzkyGolay { window, degree } => {
                savitzky_golay(&x, dt, window, degree, deriv)
            }
        };
        for (o, v) in out.iter_mut().zip(d) {
            o[k] = v;
        }
    }
    out
}

/// Low-pass windowed sinc (Hamming), applied as a centred (zero-phase)
/// convolution; ends are extended by odd reflection so a uniform motion
/// passes unchanged.
pub fn fir_zero_phase(x: &[f64], order: usize, cutoff: f64) -> Vec<f64> {
    let n = x.len();
    if n < 3 {
        return x.to_vec();
    }
    let m = order / 2;
    let taps: Vec<f64> = (0..=order)
        .map(|i| {
            let k = i as f64 - m as f64;
            let sinc = if k == 0.0 {
                cutoff
            } else {
                (std::f64::consts::PI * cutoff * k).sin() / (std::f64::consts::PI * k)
            };
            let w = 0.54 - 0.46 * (2.0 * std::f64::consts::PI * i as f64 / order as f64).cos();
            sinc * w
        })
        .collect();
    let sum: f64 = taps.iter().sum();
    let taps: Vec<f64> = taps.iter().map(|t| t / sum).collect();
    // Odd reflection: x(−j) = 2x(0) − x(j).
    let at = |i: isize| -> f64 {
        if i < 0 {
            let j = ((-i) as usize).min(n - 1);
            2.0 * x[0] - x[j]
        } else if i as usize >= n {
            let j = (2 * (n - 1)).saturating_sub(i as usize);
            2.0 * x[n - 1] - x[j]
        } else {
            x[i as usize]
        }
    };
    (0..n)
        .map(|i| {
            taps.iter()
                .enumerate()
                .map(|(j, t)| t * at(i as isize + j as isize - m as isize))
                .sum()
        })
        .collect()
}

fn finite_difference(x: &[f64], dt: f64, deriv: usize) -> Vec<f64> {
    let n = x.len();
    (0..n)
        .map(|i| {
            // Central differences inside, the nearest interior stencil at the ends.
            let c = i.clamp(1, n - 2);
            if deriv == 1 {
                if i == c {
                    (x[c + 1] - x[c - 1]) / (2.0 * dt)
                } else if i == 0 {
                    (x[1] - x[0]) / dt
                } else {
                    (x[n - 1] - x[n - 2]) / dt
                }
            } else {
                (x[c + 1] - 2.0 * x[c] + x[c - 1]) / (dt * dt)
            }
        })
        .collect()
}

/// Savitzky–Golay derivative: at each sample, a least-squares polynomial over
/// the window (shifted inside the track at its ends), differentiated there.
pub fn savitzky_golay(x: &[f64], dt: f64, window: usize, degree: usize, deriv: usize) -> Vec<f64> {
    let n = x.len();
    let w = window.min(n);
    let p = degree.min(w.saturating_sub(1));
    if p < deriv {
        return vec![0.0; n];
    }
    (0..n)
        .map(|i| {
            let start = i.saturating_sub(w / 2).min(n - w);
            let a = nalgebra::DMatrix::from_fn(w, p + 1, |r, c| {
                ((start + r) as f64 - i as f64).powi(c as i32)
            });
            let b = nalgebra::DVector::from_iterator(w, x[start..start + w].iter().copied());
            let coef = a
                .svd(true, true)
                .solve(&b, 1e-12)
                .unwrap_or_else(|_| nalgebra::DVector::zeros(p + 1));
            // d^k/dt^k of Σ c_j (t/dt)^j at t = 0.
            let factorial: f64 = (1..=deriv).map(|v| v as f64).product();
            coef[deriv] * factorial / dt.powi(deriv as i32)
        })
        .collect()
}

/// Fills every grain's centroid acceleration from its track. Frames must be
/// consecutive and sorted; grains are matched by id. Infer with
/// [`DERIVED_ACCEL_SD`] as the acceleration noise, not as exact momentum.
pub fn derive_accelerations(
    frames: &mut [Scene],
    fps: f64,
    smoother: Smoother,
) -> Result<KinematicsReport> {
    check_frames(frames, fps)?;
    smoother.validate()?;
    let dt = 1.0 / fps;
    let mut report = KinematicsReport::default();
    let all = tracks(frames);
    report.tracks = all.len();
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
            let a = differentiate(&positions, dt, smoother, 2);
            for (&(k, _), a) in seg.iter().zip(a) {
                accel[k].insert(id.clone(), a);
            }
        }
    }
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

/// One grain's impulse check.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ImpulseRow {
    pub grain: String,
    /// Δv from the tracked positions (smoothed), first to last frame.
    pub measured: Vec3,
    /// Δv = (1/m) ∫ (Σ contact forces + m g) dt from the inferred forces.
    pub inferred: Vec3,
}

/// Table 3.1 of the method: for each grain present in every frame, Δv from
/// the time integral (trapezoid) of its inferred net force vs Δv from its track.
pub fn impulse_check(
    frames: &[Scene],
    forces: &[Vec<Option<Vec3>>],
    fps: f64,
    smoother: Smoother,
    gravity: Vec3,
) -> Result<Vec<ImpulseRow>> {
    check_frames(frames, fps)?;
    smoother.validate()?;
    if forces.len() != frames.len() {
        return Err(Error::Invalid("one force set per frame is needed".into()));
    }
    let dt = 1.0 / fps;
    let mut rows = Vec::new();
    for (id, track) in tracks(frames) {
        if track.len() != frames.len() || track.len() < 3 {
            continue;
        }
        let mut net = Vec::with_capacity(frames.len());
        let mut mass = None;
        for (f, fs) in frames.iter().zip(forces) {
            let p = f.grains.iter().position(|g| g.id == id).unwrap_or(0);
            mass = f.grains[p].mass.or(mass);
            let mut sum = [0.0; 3];
            for (c, fc) in f.contacts.iter().zip(fs) {
                let Some(fc) = fc else { continue };
                let sign = if c.a == p {
                    1.0
                } else if c.b == Body::Grain(p) {
                    -1.0
                } else {
                    continue;
                };
                for k in 0..3 {
                    sum[k] += sign * fc[k];
                }
            }
            net.push(sum);
        }
        let Some(m) = mass else { continue };
        let mut inferred = [0.0; 3];
        for w in net.windows(2) {
            for k in 0..3 {
                inferred[k] += 0.5 * (w[0][k] + w[1][k]) * dt / m;
            }
        }
        let duration = dt * (frames.len() - 1) as f64;
        for k in 0..3 {
            inferred[k] += gravity[k] * duration;
        }
        let positions: Vec<Vec3> = track.iter().map(|s| s.1).collect();
        let v = differentiate(&positions, dt, smoother, 1);
        let (first, last) = (v[0], v[v.len() - 1]);
        rows.push(ImpulseRow {
            grain: id,
            measured: [last[0] - first[0], last[1] - first[1], last[2] - first[2]],
            inferred,
        });
    }
    Ok(rows)
}
