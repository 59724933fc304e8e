//! Refining a candidate into a disk: its radius, the sub-pixel edge along
//! rays, the circle through it, and the judgement of support and contrast.

use super::circle_fit::{robust_circle_fit, solve3};
use super::options::{DetectOptions, Disk};
use crate::image::FloatImage;

/// A borrowed image plane with bilinear sampling: the whole image, or a
/// window of it whose first pixel is the image's pixel `origin`.
pub(crate) struct Plane<'a> {
    pub data: &'a [f32],
    pub w: usize,
    pub h: usize,
    pub origin: [f64; 2],
}

impl Plane<'_> {
    pub fn whole(image: &FloatImage) -> Plane<'_> {
        Plane {
            data: image.as_raw(),
            w: image.width() as usize,
            h: image.height() as usize,
            origin: [0.0, 0.0],
        }
    }

    /// Bilinear interpolation at image coordinates; `None` outside the pixel
    /// centres' hull.
    pub fn sample(&self, x: f64, y: f64) -> Option<f64> {
        let (x, y) = (x - self.origin[0], y - self.origin[1]);
        if !(x >= 0.0 && y >= 0.0 && x <= (self.w - 1) as f64 && y <= (self.h - 1) as f64) {
            return None;
        }
        let (x0, y0) = (
            (x.floor() as usize).min(self.w - 2),
            (y.floor() as usize).min(self.h - 2),
        );
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let at = |i: usize, j: usize| self.data[i * self.w + j] as f64;
        let top = at(y0, x0) * (1.0 - fx) + at(y0, x0 + 1) * fx;
        let bottom = at(y0 + 1, x0) * (1.0 - fx) + at(y0 + 1, x0 + 1) * fx;
        Some(top * (1.0 - fy) + bottom * fy)
    }
}

/// One ray's edge: its point and whether the image gradient there points
/// along the ray (as it does on a disk's boundary, and rarely on texture).
pub(crate) struct Edge {
    pub(crate) x: f64,
    pub(crate) y: f64,
    pub(crate) strength: f64,
    pub(crate) aligned: bool,
}

pub(crate) const STEP: f64 = 0.25;
/// Most narrow-window passes of [`refine`] with `settle_edges`, and the
/// move [px] (centre plus radius) below which the circle counts as settled.
const NARROW_PASSES: usize = 12;
const SETTLED_PX: f64 = 0.05;
/// Largest angle between the gradient and the ray at a boundary point: tan 25°.
pub(crate) const ALIGNMENT: f64 = 0.466;

/// Which edge of a ray's search window is the disk's outline.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum EdgePick {
    /// The strongest: a disk's outline against its surroundings.
    Strongest,
    /// The outermost of those at least [`OUTERMOST_SHARE`] of the strongest:
    /// in a picture of distances from the background nothing outside a
    /// disk is above the background but its neighbours, so the disk's
    /// outline is its last drop, however strong the fringe edges inside.
    Outermost,
}

/// An edge counts for [`EdgePick::Outermost`] at this share of the ray's
/// strongest: a dim outline beside a bright fringe band still counts,
/// noise does not (the circle fit drops edges under a quarter of the
/// median strength as well).
const OUTERMOST_SHARE: f64 = 0.25;

/// Most wide passes of [`EdgePick::Outermost`], and the move [px] at which
/// they stop: a circle found inside a disk along its fringes grows by
/// about the wide window a pass until it meets the outline.
const OUTERMOST_WIDE_PASSES: usize = 4;
const WIDE_SETTLED_PX: f64 = 0.5;

/// Refines a candidate centre into a disk, or rejects it.
pub(crate) fn refine(
    img: &Plane,
    centre: [f64; 2],
    hint: f64,
    sign: f64,
    sigma: f64,
    o: &DetectOptions,
) -> Option<Disk> {
    let r0 = radial_peak(img, centre, hint, sign, o)?;
    refine_from(img, centre, r0, sign, sigma, o, EdgePick::Strongest)
}

/// A disk refined again from its own circle, each ray's outline its
/// outermost edge ([`EdgePick::Outermost`]), judged as [`refine`] judges.
pub(crate) fn refine_outermost(
    img: &Plane,
    d: &Disk,
    sign: f64,
    sigma: f64,
    o: &DetectOptions,
) -> Option<Disk> {
    let r = d.r - sigma * sigma / (2.0 * d.r);
    refine_from(img, [d.x, d.y], r, sign, sigma, o, EdgePick::Outermost)
}

/// The edges of one pass along rays from `c` within ±`half_window` of `r`,
/// and the circle fitted to them; `None` when too little of the circle is
/// in view or the fit fails.
fn edge_pass(
    img: &Plane,
    (c, r): ([f64; 2], f64),
    (sign, sigma): (f64, f64),
    half_window: f64,
    pick: EdgePick,
    o: &DetectOptions,
) -> Option<(Vec<Edge>, [f64; 3], usize, usize)> {
    let (edges, rays, visible_rays) = ray_edges(img, c, r, sign, half_window, sigma, pick);
    let seen = visible_rays > 0 && (visible_rays as f64) >= o.min_visible * rays as f64;
    let fit = seen.then(|| robust_circle_fit(&edges, c, r)).flatten()?;
    Some((edges, fit, rays, visible_rays))
}

/// [`refine`] from a circle (`centre`, `r0`).
fn refine_from(
    img: &Plane,
    centre: [f64; 2],
    r0: f64,
    sign: f64,
    sigma: f64,
    o: &DetectOptions,
    pick: EdgePick,
) -> Option<Disk> {
    let (mut c, mut r) = (centre, r0);
    // Wide search windows first (the candidate may be a few pixels off), then
    // narrower ones: the medium window judges support (wide enough that
    // texture and noise cannot look like a circle), the narrow ones place the
    // edge (close enough that texture inside the disk is not mistaken for it).
    // A narrow window moves the circle by at most about its width a pass;
    // with `settle_edges` the narrow passes repeat until the circle settles,
    // so a circle the wide pass left on a fringe edge inside a dim stretch
    // of outline creeps out to it pass by pass.
    let ray = (sign, sigma);
    let wide = 0.25 * r0 + 2.0 * sigma;
    let wide_passes = match pick {
        EdgePick::Strongest => 1,
        EdgePick::Outermost => OUTERMOST_WIDE_PASSES,
    };
    for _ in 0..wide_passes {
        let (_, fit, _, _) = edge_pass(img, (c, r), ray, wide, pick, o)?;
        let moved = (fit[0] - c[0]).hypot(fit[1] - c[1]) + (fit[2] - r).abs();
        (c, r) = ([fit[0], fit[1]], fit[2]);
        if moved < WIDE_SETTLED_PX {
            break;
        }
    }
    let judged = edge_pass(img, (c, r), ray, 2.0 * sigma + 2.0, pick, o)?;
    (c, r) = ([judged.1[0], judged.1[1]], judged.1[2]);
    let narrow = (1.5 * sigma).max(1.25);
    for pass in 0..NARROW_PASSES {
        // The first two narrow passes are required; later ones only improve.
        let Some((_, fit, _, _)) = edge_pass(img, (c, r), ray, narrow, pick, o) else {
            if pass < 2 {
                return None;
            }
            break;
        };
        let moved = (fit[0] - c[0]).hypot(fit[1] - c[1]) + (fit[2] - r).abs();
        (c, r) = ([fit[0], fit[1]], fit[2]);
        if pass >= 1 && (!o.settle_edges || moved < SETTLED_PX) {
            break;
        }
    }
    let (edges, fit, rays, visible_rays) = judged;
    // Support is judged with a fixed tolerance so noise cannot widen it.
    // Its pixel is the photograph's: an up-sampled picture's edges are no
    // sharper than the sensor made them.
    let tolerance = o.sensor_pixel + 0.02 * fit[2];
    let residuals: Vec<f64> = edges
        .iter()
        .filter(|e| e.aligned)
        .map(|e| ((e.x - fit[0]).powi(2) + (e.y - fit[1]).powi(2)).sqrt() - fit[2])
        .filter(|res| res.abs() <= tolerance)
        .collect();
    let support = residuals.len() as f64 / visible_rays as f64;
    let visible = visible_rays as f64 / rays as f64;
    if support < o.min_support_confirmed.min(o.min_support)
        || r < o.radius_min - 1.0
        || r > o.radius_max + 1.0
    {
        return None;
    }
    // The step across the edge, measured outside the smoothing's reach.
    let contrast = edge_contrast(img, c, r, sign, sigma);
    if contrast <= o.min_contrast.max(0.0) {
        return None;
    }
    if o.min_fill > 0.0 && interior_median(img, c, 0.8 * r).is_some_and(|m| sign * m < o.min_fill) {
        return None;
    }
    let rms = (residuals.iter().map(|v| v * v).sum::<f64>() / residuals.len() as f64).sqrt();
    // The smoothed edge of a disk peaks σ²/(2r) inside the true one.
    let r = r + sigma * sigma / (2.0 * r);
    Some(Disk {
        x: c[0],
        y: c[1],
        r,
        support,
        visible,
        contrast,
        rms,
    })
}

/// The radius at which the mean outward intensity drop (signed by polarity)
/// peaks, near the radius the votes suggest (over the whole range when the
/// suggestion sits near either end, where its phase is ambiguous).
pub(crate) fn radial_peak(
    img: &Plane,
    c: [f64; 2],
    hint: f64,
    sign: f64,
    o: &DetectOptions,
) -> Option<f64> {
    let band = (0.25 * (o.radius_max - o.radius_min)).max(3.0);
    let (mut lo, mut hi) = (o.radius_min - 2.0, o.radius_max + 2.0);
    if hint - band > o.radius_min && hint + band < o.radius_max {
        (lo, hi) = (hint - band, hint + band);
    }
    let lo = lo.max(1.0);
    let n = ((hi - lo) / 0.5).ceil() as usize + 1;
    let rays = ((std::f64::consts::TAU * hi / 3.0).ceil() as usize).clamp(24, 720);
    let mut sum = vec![0.0; n];
    let mut count = vec![0usize; n];
    for k in 0..rays {
        let a = std::f64::consts::TAU * k as f64 / rays as f64;
        let (ca, sa) = (a.cos(), a.sin());
        for (b, (s, m)) in sum.iter_mut().zip(count.iter_mut()).enumerate() {
            let rho = lo + 0.5 * b as f64;
            let inner = img.sample(c[0] + (rho - 0.5) * ca, c[1] + (rho - 0.5) * sa);
            let outer = img.sample(c[0] + (rho + 0.5) * ca, c[1] + (rho + 0.5) * sa);
            if let (Some(i), Some(u)) = (inner, outer) {
                *s += sign * (i - u);
                *m += 1;
            }
        }
    }
    let need = (rays / 5).max(4);
    let profile: Vec<f64> = sum
        .iter()
        .zip(&count)
        .map(|(&s, &m)| {
            if m >= need {
                s / m as f64
            } else {
                f64::NEG_INFINITY
            }
        })
        .collect();
    let (best, &value) = profile
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    if value.is_nan() || value <= 0.0 {
        return None;
    }
    let offset = if best > 0 && best + 1 < n {
        parabola_vertex(profile[best - 1], value, profile[best + 1])
    } else {
        0.0
    };
    Some(lo + 0.5 * (best as f64 + offset))
}

/// Vertex offset (in steps) of the least-squares parabola through the samples
/// within `reach` of `best` (three samples at least), kept within the span.
pub(crate) fn parabola_fit(v: &[f64], best: usize, reach: usize) -> f64 {
    let lo = best.saturating_sub(reach);
    let hi = (best + reach).min(v.len() - 1);
    if hi - lo < 2 {
        return 0.0;
    }
    // Normal equations for v ≈ a + b t + c t², t relative to best.
    let mut m = [[0.0; 3]; 3];
    let mut rhs = [0.0; 3];
    for (k, &y) in v.iter().enumerate().take(hi + 1).skip(lo) {
        let t = k as f64 - best as f64;
        let basis = [1.0, t, t * t];
        for a in 0..3 {
            rhs[a] += basis[a] * y;
            for b in 0..3 {
                m[a][b] += basis[a] * basis[b];
            }
        }
    }
    match solve3(m, rhs) {
        Some([_, b, c]) if c < 0.0 => {
            (-b / (2.0 * c)).clamp(lo as f64 - best as f64, hi as f64 - best as f64)
        }
        _ => 0.0,
    }
}

/// Vertex offset (in steps, within ±½) of the parabola through three samples.
pub(crate) fn parabola_vertex(a: f64, b: f64, c: f64) -> f64 {
    let denominator = a - 2.0 * b + c;
    if !(a.is_finite() && c.is_finite()) || denominator >= 0.0 {
        return 0.0;
    }
    (0.5 * (a - c) / denominator).clamp(-0.5, 0.5)
}

/// Sub-pixel edge along each ray from the centre, searched within ±half_window
/// of the radius. Returns the edges, the number of rays and the number of rays
/// whose search window lies inside the image.
pub(crate) fn ray_edges(
    img: &Plane,
    c: [f64; 2],
    r: f64,
    sign: f64,
    half_window: f64,
    sigma: f64,
    pick: EdgePick,
) -> (Vec<Edge>, usize, usize) {
    let rays = ((std::f64::consts::TAU * r / 1.5).ceil() as usize).clamp(32, 1440);
    // Samples every STEP px; the derivative spans ±0.5 px (two samples each side).
    let lead = (0.5 / STEP) as usize;
    let n = (2.0 * half_window / STEP).ceil() as usize + 1 + 2 * lead;
    let start = r - half_window - 0.5;
    let mut edges = Vec::with_capacity(rays);
    let mut visible = 0;
    let mut samples = vec![0.0; n];
    for k in 0..rays {
        let a = std::f64::consts::TAU * k as f64 / rays as f64;
        let (ca, sa) = (a.cos(), a.sin());
        let mut inside = start > 0.0;
        for (m, s) in samples.iter_mut().enumerate() {
            let rho = start + STEP * m as f64;
            match img.sample(c[0] + rho * ca, c[1] + rho * sa) {
                Some(v) => *s = v,
                None => {
                    inside = false;
                    break;
                }
            }
        }
        if !inside {
            continue;
        }
        visible += 1;
        let derivative: Vec<f64> = (lead..n - lead)
            .map(|m| sign * (samples[m - lead] - samples[m + lead]))
            .collect();
        let Some((best, value)) = pick_edge(&derivative, pick) else {
            continue;
        };
        // The peak of a smoothed edge is about σ wide: fit the parabola over it.
        let reach = ((sigma / STEP).round() as usize).max(1);
        let offset = parabola_fit(&derivative, best, reach);
        let rho = start + STEP * (best as f64 + lead as f64 + offset);
        let (x, y) = (c[0] + rho * ca, c[1] + rho * sa);
        // Tangential derivative over the same 1 px span as the radial one.
        let aligned = match (
            img.sample(x - 0.5 * sa, y + 0.5 * ca),
            img.sample(x + 0.5 * sa, y - 0.5 * ca),
        ) {
            (Some(p), Some(q)) => (p - q).abs() <= ALIGNMENT * value,
            _ => false,
        };
        edges.push(Edge {
            x,
            y,
            strength: value,
            aligned,
        });
    }
    (edges, rays, visible)
}

/// The edge of one ray's derivative samples (index and value) that `pick`
/// asks for: a peak inside the window, `None` when it lies at either end
/// (the edge may be beyond the window) or nothing falls.
fn pick_edge(derivative: &[f64], pick: EdgePick) -> Option<(usize, f64)> {
    let (mut best, &strongest) = derivative
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    if pick == EdgePick::Outermost {
        // The outermost sample over the share, then up its peak.
        best = derivative
            .iter()
            .rposition(|&v| v >= OUTERMOST_SHARE * strongest)
            .unwrap_or(best);
        while best > 0 && derivative[best - 1] > derivative[best] {
            best -= 1;
        }
    }
    let value = derivative[best];
    (best > 0 && best + 1 < derivative.len() && value > 0.0).then_some((best, value))
}

/// The median intensity over a disk of radius `r` around `c` (a grid of
/// about 500 points); `None` when fewer than 16 of them lie in the image.
pub(crate) fn interior_median(img: &Plane, c: [f64; 2], r: f64) -> Option<f64> {
    let step = (r / 12.0).max(1.0);
    let n = (r / step).floor() as i64;
    let mut values = Vec::with_capacity(((2 * n + 1) * (2 * n + 1)) as usize);
    for i in -n..=n {
        for j in -n..=n {
            let (dx, dy) = (j as f64 * step, i as f64 * step);
            if dx.hypot(dy) <= r {
                values.extend(img.sample(c[0] + dx, c[1] + dy));
            }
        }
    }
    if values.len() < 16 {
        return None;
    }
    let k = values.len() / 2;
    Some(*values.select_nth_unstable_by(k, f64::total_cmp).1)
}

/// The intensity inside minus outside the circle, sampled beyond the
/// smoothing's reach and signed by the polarity: its 80th percentile over the
/// visible rays, since in a dense packing many rays end on a neighbour.
pub(crate) fn edge_contrast(img: &Plane, c: [f64; 2], r: f64, sign: f64, sigma: f64) -> f64 {
    let gap = 2.0 * sigma + 1.0;
    let rays = 64;
    let mut steps = Vec::with_capacity(rays);
    for k in 0..rays {
        let a = std::f64::consts::TAU * k as f64 / rays as f64;
        let (ca, sa) = (a.cos(), a.sin());
        let inner = img.sample(
            c[0] + (r - gap).max(0.0) * ca,
            c[1] + (r - gap).max(0.0) * sa,
        );
        let outer = img.sample(c[0] + (r + gap) * ca, c[1] + (r + gap) * sa);
        if let (Some(i), Some(u)) = (inner, outer) {
            steps.push(sign * (i - u));
        }
    }
    if steps.is_empty() {
        return 0.0;
    }
    let k = (steps.len() * 4 / 5).min(steps.len() - 1);
    *steps.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1
}
