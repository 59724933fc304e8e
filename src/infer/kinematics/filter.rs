//! Track filters: zero-phase FIR, Savitzky–Golay and Whittaker smoothing,
//! the derivatives they give and the noise gain of those derivatives.

use crate::error::{Error, Result};
use crate::scene::Vec3;
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

    pub(super) fn validate(&self) -> Result<()> {
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

/// Derivative of order `deriv` (1 or 2) of each component along a track, per
/// frame. `known` (empty, or one entry per sample) holds accelerations known
/// exactly, which the Whittaker smoother keeps; the others ignore it.
pub(super) fn differentiate(
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
