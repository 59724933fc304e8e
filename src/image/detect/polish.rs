//! The final sub-pixel fit of a blurred-disk model to the raw pixels.

use super::options::Disk;
use crate::image::FloatImage;

/// Final sub-pixel fit of a disk model to the raw pixels of a ring around the
/// edge: I ≈ a + b / (1 + exp((|p − c| − r)/s)), by Levenberg–Marquardt over
/// (cx, cy, r, a, b, s). Under white noise this least-squares fit uses every
/// pixel's evidence (the ray edges use one point per ray), and texture inside
/// the disk only adds zero-mean scatter. Pixels on or near other disks are left
/// out, so contacts do not pull the fit. `None` when the fit does not settle
/// near the starting circle.
pub(crate) struct ModelFit {
    pub(crate) disk: Disk,
    /// Intensity step b across the edge and the edge's width s [px].
    pub(crate) step: f64,
    pub(crate) width: f64,
}

pub(crate) fn polish(image: &FloatImage, disks: &[Disk], k: usize) -> Option<ModelFit> {
    let d = disks[k];
    let (w, h) = (image.width() as i64, image.height() as i64);
    let half = 3.5;
    let neighbours: Vec<&Disk> = disks
        .iter()
        .enumerate()
        .filter(|(j, e)| *j != k && (e.x - d.x).hypot(e.y - d.y) < d.r + e.r + 2.0 * half)
        .map(|(_, e)| e)
        .collect();
    let mut pixels: Vec<(f64, f64, f64)> = Vec::new();
    let reach = d.r + half + 1.0;
    for i in ((d.y - reach).floor() as i64).max(0)..=((d.y + reach).ceil() as i64).min(h - 1) {
        for j in ((d.x - reach).floor() as i64).max(0)..=((d.x + reach).ceil() as i64).min(w - 1) {
            let (x, y) = (j as f64, i as f64);
            let rho = (x - d.x).hypot(y - d.y);
            if (rho - d.r).abs() > half {
                continue;
            }
            if neighbours
                .iter()
                .any(|e| (x - e.x).hypot(y - e.y) < e.r + half)
            {
                continue;
            }
            pixels.push((x, y, image.get_pixel(j as u32, i as u32)[0] as f64));
        }
    }
    if pixels.len() < 40 {
        return None;
    }
    // Start: the two intensity levels from the pixels inside and outside.
    let (mut inner, mut n_in, mut outer, mut n_out) = (0.0, 0, 0.0, 0);
    for &(x, y, v) in &pixels {
        if (x - d.x).hypot(y - d.y) < d.r - 1.5 {
            inner += v;
            n_in += 1;
        } else if (x - d.x).hypot(y - d.y) > d.r + 1.5 {
            outer += v;
            n_out += 1;
        }
    }
    if n_in < 10 || n_out < 10 {
        return None;
    }
    let (a0, b0) = (
        outer / n_out as f64,
        inner / n_in as f64 - outer / n_out as f64,
    );
    let mut p = nalgebra::Vector6::new(d.x, d.y, d.r, a0, b0, 0.7);
    let cost = |p: &nalgebra::Vector6<f64>| -> f64 {
        pixels
            .iter()
            .map(|&(x, y, v)| {
                let u = ((x - p[0]).hypot(y - p[1]) - p[2]) / p[5];
                let m = p[3] + p[4] / (1.0 + u.clamp(-50.0, 50.0).exp());
                (v - m) * (v - m)
            })
            .sum()
    };
    let mut current = cost(&p);
    let mut lambda = 1e-3;
    for _ in 0..20 {
        let mut jtj = nalgebra::Matrix6::<f64>::zeros();
        let mut jtr = nalgebra::Vector6::<f64>::zeros();
        for &(x, y, v) in &pixels {
            let (dx, dy) = (x - p[0], y - p[1]);
            let rho = dx.hypot(dy).max(1e-9);
            let u = (rho - p[2]) / p[5];
            let l = 1.0 / (1.0 + u.clamp(-50.0, 50.0).exp());
            let dl = -l * (1.0 - l); // dL/du
            let m = p[3] + p[4] * l;
            let g = p[4] * dl / p[5];
            let j = nalgebra::Vector6::new(-g * dx / rho, -g * dy / rho, -g, 1.0, l, -g * u);
            jtj += j * j.transpose();
            jtr += j * (v - m);
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = jtj;
            for a in 0..6 {
                damped[(a, a)] *= 1.0 + lambda;
            }
            let Some(step) = damped.lu().solve(&jtr) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = p + step;
            trial[5] = trial[5].clamp(0.2, 4.0);
            let c = cost(&trial);
            if c < current {
                let moved = (trial - p).norm();
                p = trial;
                current = c;
                lambda = (lambda * 0.3).max(1e-9);
                improved = moved > 1e-4;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    let shift = (p[0] - d.x).hypot(p[1] - d.y);
    let sign_ok = p[4] * (b0.signum()) > 0.0;
    if !(shift < 2.0 && (p[2] - d.r).abs() < 2.0 && sign_ok && p.iter().all(|v| v.is_finite())) {
        return None;
    }
    Some(ModelFit {
        disk: Disk {
            x: p[0],
            y: p[1],
            r: p[2],
            ..d
        },
        step: p[4],
        width: p[5],
    })
}
