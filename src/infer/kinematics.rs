//! Accelerations from centroid tracks, as the original experiments derived
//! them: a zero-phase low-pass FIR filter (windowed sinc, Hamming window) then
//! central differences — or a Savitzky–Golay fit — and the impulse check
//! (table 3.1): Δv from the integrated inferred contact forces vs Δv measured,
//! with the measured side's noise.

use super::{InferOptions, LambdaRule};
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
    /// Penalised least squares (Whittaker–Henderson): the track closest to
    /// the samples under a third-difference roughness penalty whose gain is
    /// ½ at `cutoff` of Nyquist, as the FIR's. Where a grain touches nothing
    /// and the scene states gravity, its acceleration is known and the fit
    /// holds it there, so free flights pin the velocities on either side of
    /// a collision and no smoothing leaks out of the contact frames.
    Whittaker { cutoff: f64 },
}

impl Smoother {
    /// Defaults from the frame rate: keep motion below 0.075 fps (cut-off
    /// 0.15 of Nyquist), 20th order — measured on the `impact` preset at
    /// 5000 frames/s with 0.1 % of a diameter position noise (see README):
    /// 0.2 passes more noise, 0.1 smears the impacts.
    pub fn default_fir() -> Self {
        Smoother::Fir {
            order: 20,
            cutoff: 0.15,
        }
    }

    /// Frames on either side of a sample that its derivative depends on.
    fn reach(&self) -> usize {
        match *self {
            Smoother::Fir { order, .. } => order / 2 + 1,
            Smoother::SavitzkyGolay { window, .. } => window / 2,
            // The equivalent kernel decays as exp(−|k|/λ^(1/6)) roughly.
            Smoother::Whittaker { cutoff } => {
                (8.0 * whittaker_lambda(cutoff).powf(1.0 / 6.0)).ceil() as usize
            }
        }
    }

    /// Frames on either side of a block that deriving its accelerations
    /// reads: a derivative's reach, and twice the noise gain's (which
    /// depends on where a track ends) — so the block's accelerations and
    /// noise are those of the whole tracks. `None` for Whittaker, a fit
    /// over each whole track.
    pub fn margin(&self) -> Option<usize> {
        match self {
            Smoother::Whittaker { .. } => None,
            _ => Some(2 * (self.reach() + 1) + 1),
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
            Smoother::Whittaker { cutoff } => {
                if !(cutoff > 0.0 && cutoff < 1.0) {
                    return Err(Error::Invalid(format!(
                        "Whittaker smoother: the cut-off must be in (0, 1) of Nyquist, got {cutoff}"
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
            "deriving accelerations and the impulse check need consecutive frame numbers (equal time steps); select a range with --frames".into(),
        ));
    }
    Ok(())
}

/// Derivative of order `deriv` (1 or 2) of each component along a track, per
/// frame. `known` (empty, or one entry per sample) holds accelerations known
/// exactly, which the Whittaker smoother keeps; the others ignore it.
fn differentiate(
    samples: &[Vec3],
    dt: f64,
    smoother: Smoother,
    deriv: usize,
    known: &[Option<Vec3>],
) -> Result<Vec<Vec3>> {
    // Per axis. The FIR and Savitzky–Golay derivatives centre each output on
    // a sample near it (far from the origin, filtering raw coordinates would
    // add rounding of the offset's size), so an output depends on the
    // samples within its reach only: a block of frames read with its margin
    // gets the bits of the whole track.
    let per_axis = |points: &[Vec3], series: &dyn Fn(&[f64]) -> Vec<f64>| {
        let mut out = vec![[0.0; 3]; points.len()];
        for k in 0..3 {
            let x: Vec<f64> = points.iter().map(|p| p[k]).collect();
            for (o, v) in out.iter_mut().zip(series(&x)) {
                o[k] = v;
            }
        }
        out
    };
    Ok(match smoother {
        Smoother::Fir { order, cutoff } => {
            per_axis(samples, &|x| fir_derivative(x, dt, order, cutoff, deriv))
        }
        Smoother::SavitzkyGolay { window, degree } => {
            per_axis(samples, &|x| savitzky_golay(x, dt, window, degree, deriv))
        }
        // The fit holds all three axes together (one analysis), over the
        // whole track, centred on its first sample.
        Smoother::Whittaker { cutoff } => {
            per_axis(&whittaker_fit(samples, dt, cutoff, known)?, &|x| {
                let origin = x.first().copied().unwrap_or(0.0);
                let centred: Vec<f64> = x.iter().map(|v| v - origin).collect();
                finite_difference(&centred, dt, deriv)
            })
        }
    })
}

/// Roughness weight λ of the Whittaker smoother: its gain
/// 1 / (1 + λ (2 sin(ω/2))⁶) is ½ at ω = π·cutoff.
fn whittaker_lambda(cutoff: f64) -> f64 {
    let s = 2.0 * (0.5 * std::f64::consts::PI * cutoff).sin();
    1.0 / s.powi(6)
}

/// Relative KKT residual a Whittaker fit must reach.
const WHITTAKER_KKT_TOL: f64 = 1e-8;

/// Positions x̂ minimising Σ (x̂ − x)² + λ Σ (Δ³x̂)², with the second
/// difference equal to a·dt² where the acceleration a is known: an
/// equality-constrained least squares (exact holds, so no penalty weight to
/// fight λ, which spans 0.3 … 1e9 over the cut-off range). Coordinates are
/// taken relative to the first sample and scaled to order one, so offsets
/// and units don't matter; the result is in the samples' coordinates.
fn whittaker_fit(
    samples: &[Vec3],
    dt: f64,
    cutoff: f64,
    known: &[Option<Vec3>],
) -> Result<Vec<Vec3>> {
    let n = samples.len();
    if n < 4 {
        return Ok(samples.to_vec());
    }
    let origin = samples[0];
    let scale = samples
        .iter()
        .flat_map(|p| (0..3).map(move |k| (p[k] - origin[k]).abs()))
        .fold(0.0f64, f64::max);
    let scale = if scale > 0.0 { scale } else { 1.0 };
    // Held second differences by centre (the ends on the nearest interior
    // stencil, as `finite_difference` does); one row per centre.
    let mut held: BTreeMap<usize, Vec3> = BTreeMap::new();
    for (i, a) in known.iter().enumerate() {
        if let Some(a) = a {
            held.insert(i.clamp(1, n - 2), a.map(|v| v * dt * dt / scale));
        }
    }
    let mut smoother = Whittaker::new(n, cutoff, held.keys().copied())?;
    let mut out = samples.to_vec();
    for k in 0..3 {
        let data: Vec<f64> = samples.iter().map(|p| (p[k] - origin[k]) / scale).collect();
        let targets: Vec<f64> = held.values().map(|t| t[k]).collect();
        for (o, x) in out.iter_mut().zip(smoother.smooth(&data, &targets)?) {
            o[k] = origin[k] + scale * x;
        }
    }
    Ok(out)
}

/// The Whittaker smoother of one track length and set of held centres,
/// analysed once and applied to any number of series.
struct Whittaker {
    fit: crate::solver::Triplets,
    hold: crate::solver::Triplets,
    ls: crate::solver::sparse_ls::EqualityLeastSquares,
}

impl Whittaker {
    /// Rows [I; √λ Δ³] and, per held centre c, x[c−1] − 2x[c] + x[c+1]
    /// (centres in 1..n−1, distinct); n ≥ 4.
    fn new(n: usize, cutoff: f64, centres: impl Iterator<Item = usize>) -> Result<Self> {
        use crate::solver::{sparse_ls::EqualityLeastSquares, Triplets};
        let root_lambda = whittaker_lambda(cutoff).sqrt();
        let mut fit = Triplets::new(2 * n - 3, n);
        for i in 0..n {
            fit.push(i, i, 1.0);
        }
        for i in 0..n - 3 {
            for (o, c) in [-1.0, 3.0, -3.0, 1.0].into_iter().enumerate() {
                fit.push(n + i, i + o, root_lambda * c);
            }
        }
        let centres: Vec<usize> = centres.collect();
        let mut hold = Triplets::new(centres.len(), n);
        for (r, &c) in centres.iter().enumerate() {
            for (o, v) in [1.0, -2.0, 1.0].into_iter().enumerate() {
                hold.push(r, c - 1 + o, v);
            }
        }
        let ls = EqualityLeastSquares::new(&fit, &hold)?;
        Ok(Whittaker { fit, hold, ls })
    }

    /// The smoothed series of `data`, with the held second differences at `targets`.
    fn smooth(&mut self, data: &[f64], targets: &[f64]) -> Result<Vec<f64>> {
        let mut rhs = vec![0.0; self.fit.nrows];
        rhs[..data.len()].copy_from_slice(data);
        let solution = self.ls.solve(&self.fit, &self.hold, &rhs, targets, 0.0)?;
        // Tracked positions are known to ~1e-4 of a track's extent at best,
        // so 1e-8 is far below the data; λ ~ 1e9 (cut-off 0.01) stops near
        // 3e-9, short of the solver's own 1e-10-level tolerance.
        if !(solution.converged || solution.kkt_residual <= WHITTAKER_KKT_TOL) {
            return Err(Error::Solver(format!(
                "Whittaker fit of a {}-frame track did not converge (KKT residual {:e})",
                data.len(),
                solution.kkt_residual
            )));
        }
        Ok(solution.x)
    }
}

/// Standard deviation of the derived acceleration at each of `n` consecutive
/// samples per unit standard deviation of white position noise: the filter
/// and difference are linear, so it is the norm of each output's weights.
/// It is largest at the ends of a track, where the filter has fewer neighbours.
pub fn acceleration_noise_gain(n: usize, dt: f64, smoother: Smoother) -> Result<Vec<f64>> {
    smoother.validate()?;
    // Samples out of the stencil's reach of both ends share one gain, so a
    // long track is computed on a short one (cost independent of n).
    let reach = smoother.reach() + 1;
    let short = n.min(2 * reach + 1);
    let mut sum_sq = vec![0.0; short];
    // One analysis for all unit responses (holds play no part in the gain).
    let mut whittaker = match smoother {
        Smoother::Whittaker { cutoff } if short >= 4 => {
            Some(Whittaker::new(short, cutoff, std::iter::empty())?)
        }
        _ => None,
    };
    let mut unit = vec![[0.0; 3]; short];
    for j in 0..short {
        unit[j][0] = 1.0;
        let response: Vec<f64> = match &mut whittaker {
            Some(w) => {
                let column: Vec<f64> = unit.iter().map(|u| u[0]).collect();
                finite_difference(&w.smooth(&column, &[])?, dt, 2)
            }
            None => differentiate(&unit, dt, smoother, 2, &[])?
                .iter()
                .map(|r| r[0])
                .collect(),
        };
        unit[j][0] = 0.0;
        for (s, r) in sum_sq.iter_mut().zip(&response) {
            *s += r * r;
        }
    }
    Ok((0..n)
        .map(|i| {
            let k = if i < reach {
                i
            } else if i + reach >= n {
                i + short - n
            } else {
                reach
            };
            sum_sq[k].sqrt()
        })
        .collect())
}

/// Low-pass windowed sinc (Hamming), applied as a centred (zero-phase)
/// convolution; ends are extended by odd reflection so a uniform motion
/// passes unchanged.
pub fn fir_zero_phase(x: &[f64], order: usize, cutoff: f64) -> Vec<f64> {
    let n = x.len();
    if n < 3 {
        return x.to_vec();
    }
    let taps = fir_taps(order, cutoff);
    (0..n).map(|i| fir_at(x, &taps, i, 0.0)).collect()
}

/// Derivative of order `deriv` of the zero-phase FIR-filtered series, by
/// the differences of [`finite_difference`]; each output's filtered values
/// are taken relative to the sample at its stencil's centre.
fn fir_derivative(x: &[f64], dt: f64, order: usize, cutoff: f64, deriv: usize) -> Vec<f64> {
    let n = x.len();
    if n < 3 {
        return finite_difference(x, dt, deriv);
    }
    let taps = fir_taps(order, cutoff);
    (0..n)
        .map(|i| {
            let c = i.clamp(1, n - 2);
            let y = |j: usize| fir_at(x, &taps, j, x[c]);
            if deriv == 1 {
                if i == c {
                    (y(c + 1) - y(c - 1)) / (2.0 * dt)
                } else if i == 0 {
                    (y(1) - y(0)) / dt
                } else {
                    (y(n - 1) - y(n - 2)) / dt
                }
            } else {
                (y(c + 1) - 2.0 * y(c) + y(c - 1)) / (dt * dt)
            }
        })
        .collect()
}

/// The normalised taps of the windowed-sinc low-pass (`order` + 1).
fn fir_taps(order: usize, cutoff: f64) -> Vec<f64> {
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
    taps.iter().map(|t| t / sum).collect()
}

/// The filtered value at sample `i` (n ≥ 3) of x − `origin`; the ends are
/// extended by odd reflection, x(−j) = 2x(0) − x(j).
fn fir_at(x: &[f64], taps: &[f64], i: usize, origin: f64) -> f64 {
    let n = x.len();
    let m = (taps.len() / 2) as isize;
    let at = |i: isize| -> f64 {
        if i < 0 {
            let j = ((-i) as usize).min(n - 1);
            2.0 * (x[0] - origin) - (x[j] - origin)
        } else if i as usize >= n {
            let j = (2 * (n - 1)).saturating_sub(i as usize);
            2.0 * (x[n - 1] - origin) - (x[j] - origin)
        } else {
            x[i as usize] - origin
        }
    };
    taps.iter()
        .enumerate()
        .map(|(j, t)| t * at(i as isize + j as isize - m))
        .sum()
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
            // Relative to the sample itself (see `differentiate`); the
            // constant term takes it back.
            let b =
                nalgebra::DVector::from_iterator(w, x[start..start + w].iter().map(|v| v - x[i]));
            let coef = a
                .svd(true, true)
                .solve(&b, 1e-12)
                .unwrap_or_else(|_| nalgebra::DVector::zeros(p + 1));
            // d^k/dt^k of Σ c_j (t/dt)^j at t = 0.
            let factorial: f64 = (1..=deriv).map(|v| v as f64).product();
            let offset = if deriv == 0 { x[i] } else { 0.0 };
            offset + coef[deriv] * factorial / dt.powi(deriv as i32)
        })
        .collect()
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
        let scale = super::dynamic::momentum_row_scale(&assembly);
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
