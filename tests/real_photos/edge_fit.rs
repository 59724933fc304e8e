//! An independent check of disk centres on real photographs: each disk's
//! outline fitted to sub-pixel edge points, with no template and no vote
//! (`benches/edge_fit.py` does the same in Python). The edge picture is the
//! colour distance from the background colour, as `detect --channel auto`
//! reads it; along 360 rays from a starting centre the outline is where the
//! distance falls, going outward, half-way from the disk's level (its median
//! over 0.75–0.9 R on that ray) to the level outside (1.15–1.3 R). A ray
//! counts only when the disk stands clear of the background, the outside is
//! below 0.4 of the disk and nothing beyond 1.15 R rises half-way back (no
//! neighbour, wall or paint there).

use grainforce::image::FloatImage;
use nalgebra::{Matrix3, Vector3};

/// Bilinear sample; coordinates outside the image are clamped to its edge.
fn sample(image: &FloatImage, x: f64, y: f64) -> f64 {
    let (w, h) = (image.width() as f64, image.height() as f64);
    let (x, y) = (x.clamp(0.0, w - 1.0), y.clamp(0.0, h - 1.0));
    let (x0, y0) = (
        x.floor().min(w - 2.0).max(0.0),
        y.floor().min(h - 2.0).max(0.0),
    );
    let (fx, fy) = (x - x0, y - y0);
    let v = |i: f64, j: f64| image.get_pixel(i as u32, j as u32)[0] as f64;
    let top = v(x0, y0) * (1.0 - fx) + v(x0 + 1.0, y0) * fx;
    let bottom = v(x0, y0 + 1.0) * (1.0 - fx) + v(x0 + 1.0, y0 + 1.0) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// Least squares on rows `(j, r)`: the normal equations of Σ (j·p − r)².
fn least_squares(rows: impl Iterator<Item = ([f64; 3], f64)>) -> Option<[f64; 3]> {
    let (mut a, mut b) = (Matrix3::<f64>::zeros(), Vector3::<f64>::zeros());
    for (j, r) in rows {
        let j = Vector3::from(j);
        a += j * j.transpose();
        b += j * r;
    }
    a.lu().solve(&b).map(Into::into)
}

/// Circle through the points: algebraic (Kåsa), then Gauss–Newton on the
/// distances. Returns (x, y, r).
fn fit_circle(points: &[[f64; 2]]) -> Option<[f64; 3]> {
    let p = least_squares(
        points
            .iter()
            .map(|q| ([2.0 * q[0], 2.0 * q[1], 1.0], q[0] * q[0] + q[1] * q[1])),
    )?;
    let mut c = [p[0], p[1], (p[2] + p[0] * p[0] + p[1] * p[1]).sqrt()];
    for _ in 0..20 {
        let step = least_squares(points.iter().map(|q| {
            let (dx, dy) = (q[0] - c[0], q[1] - c[1]);
            let rho = dx.hypot(dy);
            ([dx / rho, dy / rho, 1.0], rho - c[2])
        }))?;
        for k in 0..3 {
            c[k] += step[k];
        }
        if step.iter().all(|s| s.abs() < 1e-7) {
            break;
        }
    }
    c.iter().all(|v| v.is_finite()).then_some(c)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// The outline point of one ray at angle `t` from (x0, y0), or `None` when
/// the ray does not end in background.
fn ray_edge(
    distance: &FloatImage,
    empty: f64,
    (x0, y0, r0): (f64, f64, f64),
    t: f64,
) -> Option<f64> {
    let step = 0.25;
    let rho: Vec<f64> = (0..)
        .map(|k| 0.6 * r0 + step * k as f64)
        .take_while(|&r| r < 1.35 * r0)
        .collect();
    let p: Vec<f64> = rho
        .iter()
        .map(|r| sample(distance, x0 + r * t.cos(), y0 + r * t.sin()))
        .collect();
    let within = |lo: f64, hi: f64| -> Vec<f64> {
        rho.iter()
            .zip(&p)
            .filter(|(r, _)| **r >= lo * r0 && **r <= hi * r0)
            .map(|(_, v)| *v)
            .collect()
    };
    let inside = median(&mut within(0.75, 0.9));
    let mut beyond = within(1.15, 1.3);
    let outside = median(&mut beyond);
    let half = 0.5 * (inside + outside);
    if inside < 2.0 * empty || outside > 0.4 * inside || beyond.iter().any(|&v| v >= half) {
        return None;
    }
    let i = (0..p.len() - 1).rfind(|&i| p[i] >= half && rho[i] < 1.15 * r0)?;
    let f = (p[i] - half) / (p[i] - p[i + 1]).max(1e-9);
    Some(rho[i] + f * step)
}

/// The disk's outline fitted near (x0, y0, r0): centre, radius and rms
/// residual [px]; `None` when fewer than 40 rays over more than half the
/// circumference show it, or the fit wanders off (centre moved > 0.2 r0,
/// radius > 15 %). Points more than 3 median deviations off are dropped, twice.
pub fn edge_fit(
    distance: &FloatImage,
    background_level: f64,
    (x0, y0, r0): (f64, f64, f64),
) -> Option<[f64; 4]> {
    let empty = (2.5 * background_level).max(0.04);
    let mut points: Vec<([f64; 2], f64)> = (0..360)
        .filter_map(|k| {
            let t = std::f64::consts::TAU * k as f64 / 360.0;
            let r = ray_edge(distance, empty, (x0, y0, r0), t)?;
            Some(([x0 + r * t.cos(), y0 + r * t.sin()], t))
        })
        .collect();
    let residuals = |pts: &[([f64; 2], f64)], c: [f64; 3]| -> Vec<f64> {
        pts.iter()
            .map(|(q, _)| (q[0] - c[0]).hypot(q[1] - c[1]) - c[2])
            .collect()
    };
    for _ in 0..3 {
        if points.len() < 40 {
            return None;
        }
        let xy: Vec<[f64; 2]> = points.iter().map(|p| p.0).collect();
        let c = fit_circle(&xy)?;
        let res = residuals(&points, c);
        let mid = median(&mut res.clone());
        let mad = median(&mut res.iter().map(|r| (r - mid).abs()).collect::<Vec<_>>()) + 1e-9;
        points = points
            .into_iter()
            .zip(&res)
            .filter(|(_, r)| (*r - mid).abs() <= 3.0 * 1.4826 * mad)
            .map(|(p, _)| p)
            .collect();
    }
    let mut angles: Vec<f64> = points.iter().map(|p| p.1).collect();
    angles.sort_by(f64::total_cmp);
    let widest = angles
        .windows(2)
        .map(|w| w[1] - w[0])
        .chain(
            angles
                .first()
                .zip(angles.last())
                .map(|(a, b)| a + std::f64::consts::TAU - b),
        )
        .fold(0.0, f64::max);
    if points.len() < 40 || widest > std::f64::consts::PI {
        return None;
    }
    let xy: Vec<[f64; 2]> = points.iter().map(|p| p.0).collect();
    let c = fit_circle(&xy)?;
    if (c[0] - x0).hypot(c[1] - y0) > 0.2 * r0 || (c[2] / r0 - 1.0).abs() > 0.15 {
        return None;
    }
    let res = residuals(&points, c);
    let rms = (res.iter().map(|r| r * r).sum::<f64>() / res.len() as f64).sqrt();
    Some([c[0], c[1], c[2], rms])
}
