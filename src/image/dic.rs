//! Subset-based digital image correlation inside one grain.
//!
//! 1. Seed: the reference subset at the grain's current centre is searched in
//!    the deformed image by zero-normalised cross-correlation (ZNCC) at integer
//!    shifts; this finds the grain's rigid motion, hence its reference centre.
//! 2. Subsets on a grid inside the disk (fully inside, with a margin): each
//!    starts from the seed's affine warp, checks ±1 px of integer ZNCC around
//!    that prediction, then is refined by inverse-compositional Gauss–Newton
//!    (first-order shape function, ZNSSD criterion) on a cubic B-spline
//!    interpolant of the deformed image.
//! 3. The grain's displacement gradient is the least-squares affine fit of the
//!    subset displacements (outliers trimmed); its strain is the left stretch
//!    V − I of F = I + ∇u, so rigid rotation gives no strain.
//!
//! Everything here is in pixel axes (y down).

use super::FloatImage;
use crate::error::{Error, Result};
use nalgebra::{Matrix3, Matrix6, Vector6};

#[derive(Debug, Clone)]
pub struct DicOptions {
    /// Subset side [px], odd.
    pub subset: usize,
    /// Grid spacing of the subsets [px].
    pub step: usize,
    /// Largest rigid motion of a grain between reference and deformed image [px].
    pub search_px: usize,
    /// Free band inside the disk's edge that subsets must not touch [px].
    pub margin_px: f64,
    pub max_iterations: usize,
    /// Convergence: size of the last update [px] (gradient terms times the subset half-size).
    pub tolerance_px: f64,
    /// Subsets matching worse than this ZNCC are dropped.
    pub min_zncc: f64,
}

impl Default for DicOptions {
    fn default() -> Self {
        DicOptions {
            subset: 15,
            step: 2,
            search_px: 10,
            margin_px: 2.0,
            max_iterations: 30,
            tolerance_px: 1e-4,
            min_zncc: 0.9,
        }
    }
}

impl DicOptions {
    pub fn validate(&self) -> Result<()> {
        if self.subset < 5 || self.subset % 2 == 0 {
            return Err(Error::Invalid(format!(
                "the subset must be an odd number of pixels ≥ 5, not {}",
                self.subset
            )));
        }
        if self.step == 0 {
            return Err(Error::Invalid(
                "the subset step must be at least 1 px".into(),
            ));
        }
        if !(self.margin_px >= 0.0 && self.min_zncc > 0.0 && self.min_zncc < 1.0) {
            return Err(Error::Invalid(
                "the DIC margin must be ≥ 0 and the ZNCC threshold in (0, 1)".into(),
            ));
        }
        Ok(())
    }
}

/// An image ready for correlation: its pixels and cubic B-spline coefficients.
pub struct Prepared {
    pub width: usize,
    pub height: usize,
    pixels: Vec<f32>,
    coefficients: Vec<f32>,
}

impl Prepared {
    pub fn new(image: &FloatImage) -> Self {
        let (w, h) = (image.width() as usize, image.height() as usize);
        let pixels = image.as_raw().clone();
        let mut c: Vec<f64> = pixels.iter().map(|&v| v as f64).collect();
        let mut line = Vec::new();
        for i in 0..h {
            line.clear();
            line.extend_from_slice(&c[i * w..(i + 1) * w]);
            prefilter(&mut line);
            c[i * w..(i + 1) * w].copy_from_slice(&line);
        }
        for j in 0..w {
            line.clear();
            line.extend((0..h).map(|i| c[i * w + j]));
            prefilter(&mut line);
            for (i, v) in line.iter().enumerate() {
                c[i * w + j] = *v;
            }
        }
        Prepared {
            width: w,
            height: h,
            pixels,
            coefficients: c.into_iter().map(|v| v as f32).collect(),
        }
    }

    fn pixel(&self, x: i64, y: i64) -> f64 {
        self.pixels[y as usize * self.width + x as usize] as f64
    }

    fn coefficient(&self, x: i64, y: i64) -> f64 {
        let x = x.clamp(0, self.width as i64 - 1) as usize;
        let y = y.clamp(0, self.height as i64 - 1) as usize;
        self.coefficients[y * self.width + x] as f64
    }

    /// Interpolated value and gradient at (x, y).
    pub fn sample(&self, x: f64, y: f64) -> (f64, f64, f64) {
        let (fx, fy) = (x.floor(), y.floor());
        let (tx, ty) = (x - fx, y - fy);
        let (wx, dx) = weights(tx);
        let (wy, dy) = weights(ty);
        let (ix, iy) = (fx as i64 - 1, fy as i64 - 1);
        let (mut v, mut gx, mut gy) = (0.0, 0.0, 0.0);
        for b in 0..4 {
            let (mut row_v, mut row_d) = (0.0, 0.0);
            for a in 0..4 {
                let c = self.coefficient(ix + a as i64, iy + b as i64);
                row_v += wx[a] * c;
                row_d += dx[a] * c;
            }
            v += wy[b] * row_v;
            gx += wy[b] * row_d;
            gy += dy[b] * row_v;
        }
        (v, gx, gy)
    }

    /// Interpolated value only (cheaper).
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let (fx, fy) = (x.floor(), y.floor());
        let (wx, _) = weights(x - fx);
        let (wy, _) = weights(y - fy);
        let (ix, iy) = (fx as i64 - 1, fy as i64 - 1);
        let mut v = 0.0;
        if ix >= 0 && iy >= 0 && ix + 3 < self.width as i64 && iy + 3 < self.height as i64 {
            // The common case, without per-tap bounds checks.
            let base = iy as usize * self.width + ix as usize;
            for (b, wyb) in wy.iter().enumerate() {
                let row = &self.coefficients[base + b * self.width..base + b * self.width + 4];
                let r = wx[0] * row[0] as f64
                    + wx[1] * row[1] as f64
                    + wx[2] * row[2] as f64
                    + wx[3] * row[3] as f64;
                v += wyb * r;
            }
            return v;
        }
        for (b, wyb) in wy.iter().enumerate() {
            let mut row = 0.0;
            for (a, wxa) in wx.iter().enumerate() {
                row += wxa * self.coefficient(ix + a as i64, iy + b as i64);
            }
            v += wyb * row;
        }
        v
    }
}

/// Cubic B-spline weights and their derivatives for the four nodes around t ∈ [0, 1).
fn weights(t: f64) -> ([f64; 4], [f64; 4]) {
    let s = 1.0 - t;
    let t2 = t * t;
    let t3 = t2 * t;
    (
        [
            s * s * s / 6.0,
            (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
            (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
            t3 / 6.0,
        ],
        [
            -s * s / 2.0,
            (3.0 * t2 - 4.0 * t) / 2.0,
            (-3.0 * t2 + 2.0 * t + 1.0) / 2.0,
            t2 / 2.0,
        ],
    )
}

/// In-place cubic B-spline prefilter (Unser's recursive filter, mirror boundaries).
fn prefilter(c: &mut [f64]) {
    let n = c.len();
    if n < 2 {
        return;
    }
    let z = 3f64.sqrt() - 2.0;
    let gain = (1.0 - z) * (1.0 - 1.0 / z);
    for v in c.iter_mut() {
        *v *= gain;
    }
    // Causal initialisation: truncated mirror sum.
    let horizon = n.min(30);
    let mut zn = z;
    let mut sum = c[0];
    for v in c.iter().take(horizon).skip(1) {
        sum += zn * v;
        zn *= z;
    }
    c[0] = sum;
    for k in 1..n {
        c[k] += z * c[k - 1];
    }
    c[n - 1] = (z / (z * z - 1.0)) * (z * c[n - 2] + c[n - 1]);
    for k in (0..n - 1).rev() {
        c[k] = z * (c[k + 1] - c[k]);
    }
}

/// The result for one subset: its reference centre [px], the displacement and
/// its gradient there, and how well it matched.
#[derive(Debug, Clone, Copy)]
pub struct SubsetResult {
    pub x: f64,
    pub y: f64,
    pub u: f64,
    pub v: f64,
    /// ∂u/∂x, ∂u/∂y, ∂v/∂x, ∂v/∂y.
    pub gradient: [f64; 4],
    pub zncc: f64,
    pub iterations: usize,
}

/// A grain's correlation result, pixel axes.
#[derive(Debug, Clone)]
pub struct GrainDic {
    /// Centre in the reference image [px].
    pub reference_centre: [f64; 2],
    /// Displacement of that centre [px].
    pub translation: [f64; 2],
    /// ∇u = [[∂u/∂x, ∂u/∂y], [∂v/∂x, ∂v/∂y]] from the affine fit.
    pub displacement_gradient: [[f64; 2]; 2],
    /// Strain V − I (xx, yy, xy), pixel axes.
    pub strain: [f64; 3],
    /// Subsets used in the fit / tried.
    pub used: usize,
    pub tried: usize,
    pub mean_zncc: f64,
    /// RMS misfit of the subset displacements to the affine field [px].
    pub fit_rms_px: f64,
}

/// Correlates one grain: `centre` and `radius` [px] locate it in the deformed
/// image (its current configuration).
pub(crate) fn correlate_grain(
    reference: &Prepared,
    deformed: &Prepared,
    centre: [f64; 2],
    radius: f64,
    o: &DicOptions,
) -> Result<GrainDic> {
    o.validate()?;
    let half = (o.subset / 2) as i64;
    let inner = radius - o.margin_px - half as f64 * std::f64::consts::SQRT_2;
    if inner < 0.0 {
        return Err(Error::Invalid(format!(
            "a {} px subset does not fit inside a disk of radius {radius:.1} px; use a smaller --subset",
            o.subset
        )));
    }
    let search = o.search_px as i64;
    // 1. Seed at the current centre: find the rigid motion.
    let c0 = [centre[0].round() as i64, centre[1].round() as i64];
    let shift = integer_search(reference, deformed, c0, half, [0, 0], search)
        .ok_or_else(|| outside(centre))?;
    // The grain's reference centre: the current one minus its motion.
    let ref_centre = [centre[0] - shift.0[0] as f64, centre[1] - shift.0[1] as f64];
    let rc = [ref_centre[0].round() as i64, ref_centre[1].round() as i64];
    let seed_shift =
        integer_search(reference, deformed, rc, half, shift.0, 2).ok_or_else(|| outside(centre))?;
    let seed = icgn(reference, deformed, rc, half, initial(seed_shift.0, [0.0; 4]), o)
        .ok_or_else(|| {
            Error::Invalid(format!(
                "image correlation found no match for the grain at ({:.1}, {:.1}) px; is the speckle visible, and the motion within --search?",
                centre[0], centre[1]
            ))
        })?;
    let seed_gradient = [seed.p[1], seed.p[2], seed.p[4], seed.p[5]];
    // 2. Subsets on a grid.
    let reach = inner.floor() as i64;
    let mut tried = 0;
    let mut results = Vec::new();
    for dy in (-reach..=reach).step_by(o.step) {
        for dx in (-reach..=reach).step_by(o.step) {
            let (qx, qy) = (rc[0] + dx, rc[1] + dy);
            if ((qx as f64 - ref_centre[0]).powi(2) + (qy as f64 - ref_centre[1]).powi(2)).sqrt()
                > inner
            {
                continue;
            }
            tried += 1;
            let predicted = [
                seed.p[0] + seed_gradient[0] * dx as f64 + seed_gradient[1] * dy as f64,
                seed.p[3] + seed_gradient[2] * dx as f64 + seed_gradient[3] * dy as f64,
            ];
            let guess = [predicted[0].round() as i64, predicted[1].round() as i64];
            let Some((best, _)) = integer_search(reference, deformed, [qx, qy], half, guess, 2)
            else {
                continue;
            };
            let start = initial(best, seed_gradient);
            if let Some(fit) = icgn(reference, deformed, [qx, qy], half, start, o) {
                if fit.zncc >= o.min_zncc {
                    results.push(SubsetResult {
                        x: qx as f64,
                        y: qy as f64,
                        u: fit.p[0],
                        v: fit.p[3],
                        gradient: [fit.p[1], fit.p[2], fit.p[4], fit.p[5]],
                        zncc: fit.zncc,
                        iterations: fit.iterations,
                    });
                }
            }
        }
    }
    if results.len() < 6 {
        return Err(Error::Invalid(format!(
            "only {} of {tried} subsets of the grain at ({:.1}, {:.1}) px correlated (ZNCC ≥ {}); try a larger --subset or check the speckle",
            results.len(),
            centre[0],
            centre[1],
            o.min_zncc
        )));
    }
    // 3. Affine fit with trimming.
    let (fit, used, rms) = affine_fit(&results, ref_centre)
        .ok_or_else(|| Error::Invalid("the subset displacements admit no affine fit".into()))?;
    let gradient = [[fit[1], fit[2]], [fit[4], fit[5]]];
    let strain = left_stretch_strain(gradient);
    let mean_zncc = results.iter().map(|r| r.zncc).sum::<f64>() / results.len() as f64;
    Ok(GrainDic {
        reference_centre: ref_centre,
        translation: [fit[0], fit[3]],
        displacement_gradient: gradient,
        strain,
        used,
        tried,
        mean_zncc,
        fit_rms_px: rms,
    })
}

fn outside(centre: [f64; 2]) -> Error {
    Error::Invalid(format!(
        "the grain at ({:.1}, {:.1}) px (with its search window) reaches outside the image",
        centre[0], centre[1]
    ))
}

fn initial(shift: [i64; 2], gradient: [f64; 4]) -> Vector6<f64> {
    Vector6::new(
        shift[0] as f64,
        gradient[0],
        gradient[1],
        shift[1] as f64,
        gradient[2],
        gradient[3],
    )
}

/// Best integer shift (and its ZNCC) of the reference subset at `c` within
/// `around ± radius` in the deformed image; `None` when the windows leave the image.
fn integer_search(
    reference: &Prepared,
    deformed: &Prepared,
    c: [i64; 2],
    half: i64,
    around: [i64; 2],
    radius: i64,
) -> Option<([i64; 2], f64)> {
    let inside = |img: &Prepared, x: i64, y: i64, extra: i64| {
        x - half - extra >= 0
            && y - half - extra >= 0
            && x + half + extra < img.width as i64
            && y + half + extra < img.height as i64
    };
    if !inside(reference, c[0], c[1], 0)
        || !inside(deformed, c[0] + around[0], c[1] + around[1], radius)
    {
        return None;
    }
    let n = ((2 * half + 1) * (2 * half + 1)) as f64;
    let mut f = Vec::with_capacity(n as usize);
    for dy in -half..=half {
        for dx in -half..=half {
            f.push(reference.pixel(c[0] + dx, c[1] + dy));
        }
    }
    let mean_f = f.iter().sum::<f64>() / n;
    let norm_f = f.iter().map(|v| (v - mean_f).powi(2)).sum::<f64>().sqrt();
    if norm_f <= 1e-9 {
        return None;
    }
    let mut best = ([0i64; 2], f64::NEG_INFINITY);
    for sy in -radius..=radius {
        for sx in -radius..=radius {
            let (ox, oy) = (c[0] + around[0] + sx, c[1] + around[1] + sy);
            let (mut sum, mut sum2, mut cross) = (0.0, 0.0, 0.0);
            let mut k = 0;
            for dy in -half..=half {
                for dx in -half..=half {
                    let g = deformed.pixel(ox + dx, oy + dy);
                    sum += g;
                    sum2 += g * g;
                    cross += (f[k] - mean_f) * g;
                    k += 1;
                }
            }
            let var_g = sum2 - sum * sum / n;
            if var_g <= 1e-12 {
                continue;
            }
            let zncc = cross / (norm_f * var_g.sqrt());
            if zncc > best.1 {
                best = ([around[0] + sx, around[1] + sy], zncc);
            }
        }
    }
    best.1.is_finite().then_some(best)
}

struct IcgnFit {
    p: Vector6<f64>,
    zncc: f64,
    iterations: usize,
}

fn warp_matrix(p: &Vector6<f64>) -> Matrix3<f64> {
    Matrix3::new(
        1.0 + p[1],
        p[2],
        p[0],
        p[4],
        1.0 + p[5],
        p[3],
        0.0,
        0.0,
        1.0,
    )
}

/// Inverse-compositional Gauss–Newton for the subset centred at `c` (integer
/// reference pixel), first-order warp p = (u, ∂u/∂x, ∂u/∂y, v, ∂v/∂x, ∂v/∂y).
fn icgn(
    reference: &Prepared,
    deformed: &Prepared,
    c: [i64; 2],
    half: i64,
    start: Vector6<f64>,
    o: &DicOptions,
) -> Option<IcgnFit> {
    let side = (2 * half + 1) as usize;
    let n = side * side;
    let mut offsets = Vec::with_capacity(n);
    let mut f = Vec::with_capacity(n);
    let mut jac: Vec<Vector6<f64>> = Vec::with_capacity(n);
    for dy in -half..=half {
        for dx in -half..=half {
            let (x, y) = ((c[0] + dx) as f64, (c[1] + dy) as f64);
            let (_, fx, fy) = reference.sample(x, y);
            offsets.push((dx as f64, dy as f64));
            f.push(reference.pixel(c[0] + dx, c[1] + dy));
            let (dxf, dyf) = (dx as f64, dy as f64);
            jac.push(Vector6::new(fx, fx * dxf, fx * dyf, fy, fy * dxf, fy * dyf));
        }
    }
    let mean_f = f.iter().sum::<f64>() / n as f64;
    let norm_f = f.iter().map(|v| (v - mean_f).powi(2)).sum::<f64>().sqrt();
    if norm_f <= 1e-9 {
        return None;
    }
    let mut hessian = Matrix6::<f64>::zeros();
    for j in &jac {
        hessian += j * j.transpose();
    }
    let inverse = hessian.try_inverse()?;
    let mut p = start;
    let (w, h) = (deformed.width as f64, deformed.height as f64);
    let mut g = vec![0.0; n];
    for iteration in 1..=o.max_iterations {
        // Sample the deformed subset under the current warp.
        let mut sum = 0.0;
        for (k, &(dx, dy)) in offsets.iter().enumerate() {
            let x = c[0] as f64 + dx + p[0] + p[1] * dx + p[2] * dy;
            let y = c[1] as f64 + dy + p[3] + p[4] * dx + p[5] * dy;
            if !(x >= 1.0 && y >= 1.0 && x < w - 2.0 && y < h - 2.0) {
                return None;
            }
            g[k] = deformed.value(x, y);
            sum += g[k];
        }
        let mean_g = sum / n as f64;
        let norm_g = g.iter().map(|v| (v - mean_g).powi(2)).sum::<f64>().sqrt();
        if norm_g <= 1e-9 {
            return None;
        }
        let ratio = norm_f / norm_g;
        let mut b = Vector6::<f64>::zeros();
        let mut znssd = 0.0;
        for k in 0..n {
            let e = (f[k] - mean_f) - ratio * (g[k] - mean_g);
            b += jac[k] * e;
            znssd += (e / norm_f).powi(2);
        }
        let dp = -(inverse * b);
        // W(p) ← W(p) ∘ W(Δp)⁻¹
        let composed = warp_matrix(&p) * warp_matrix(&dp).try_inverse()?;
        p = Vector6::new(
            composed[(0, 2)],
            composed[(0, 0)] - 1.0,
            composed[(0, 1)],
            composed[(1, 2)],
            composed[(1, 0)],
            composed[(1, 1)] - 1.0,
        );
        let m = half as f64;
        let size = (dp[0].powi(2)
            + dp[3].powi(2)
            + m * m * (dp[1].powi(2) + dp[2].powi(2) + dp[4].powi(2) + dp[5].powi(2)))
        .sqrt();
        if size < o.tolerance_px || iteration == o.max_iterations {
            let converged = size < o.tolerance_px.max(1e-2);
            return converged.then_some(IcgnFit {
                p,
                zncc: 1.0 - znssd / 2.0,
                iterations: iteration,
            });
        }
    }
    None
}

/// Least-squares u = a + b (x − cx) + c (y − cy) (and likewise v) over the
/// subsets, refitted after dropping those beyond 3 robust standard deviations.
/// Returns (u0, ∂u/∂x, ∂u/∂y, v0, ∂v/∂x, ∂v/∂y), the count used and the RMS misfit.
fn affine_fit(results: &[SubsetResult], centre: [f64; 2]) -> Option<([f64; 6], usize, f64)> {
    let mut keep = vec![true; results.len()];
    let mut out = None;
    for _round in 0..3 {
        let mut m = [[0.0; 3]; 3];
        let (mut bu, mut bv) = ([0.0; 3], [0.0; 3]);
        let mut count = 0;
        for (r, _) in results.iter().zip(&keep).filter(|(_, &k)| k) {
            let basis = [1.0, r.x - centre[0], r.y - centre[1]];
            for a in 0..3 {
                bu[a] += basis[a] * r.u;
                bv[a] += basis[a] * r.v;
                for b in 0..3 {
                    m[a][b] += basis[a] * basis[b];
                }
            }
            count += 1;
        }
        if count < 6 {
            return out;
        }
        let u = super::detect::solve3(m, bu)?;
        let v = super::detect::solve3(m, bv)?;
        let misfit = |r: &SubsetResult| {
            let (dx, dy) = (r.x - centre[0], r.y - centre[1]);
            let eu = r.u - (u[0] + u[1] * dx + u[2] * dy);
            let ev = r.v - (v[0] + v[1] * dx + v[2] * dy);
            (eu * eu + ev * ev).sqrt()
        };
        let mut misfits: Vec<f64> = results
            .iter()
            .zip(&keep)
            .filter(|(_, &k)| k)
            .map(|(r, _)| misfit(r))
            .collect();
        let rms = (misfits.iter().map(|e| e * e).sum::<f64>() / count as f64).sqrt();
        out = Some(([u[0], u[1], u[2], v[0], v[1], v[2]], count, rms));
        misfits.sort_by(|a, b| a.total_cmp(b));
        let median = misfits[misfits.len() / 2];
        let cutoff = (3.0 * 1.4826 * median).max(0.01);
        let mut changed = false;
        for (k, r) in results.iter().enumerate() {
            let now = misfit(r) <= cutoff;
            if now != keep[k] {
                changed = true;
            }
            keep[k] = now;
        }
        if !changed {
            break;
        }
    }
    out
}

/// Strain V − I of the deformation gradient F = I + ∇u, where F = V R (polar
/// decomposition): free of rigid rotation. Returns (xx, yy, xy).
pub(crate) fn left_stretch_strain(gradient: [[f64; 2]; 2]) -> [f64; 3] {
    let f = [
        [1.0 + gradient[0][0], gradient[0][1]],
        [gradient[1][0], 1.0 + gradient[1][1]],
    ];
    // B = F Fᵀ, V = √B; for a 2×2 SPD matrix √B = (B + √det B I)/√(tr B + 2√det B).
    let b = [
        f[0][0] * f[0][0] + f[0][1] * f[0][1],
        f[1][0] * f[1][0] + f[1][1] * f[1][1],
        f[0][0] * f[1][0] + f[0][1] * f[1][1],
    ];
    let s = (b[0] * b[1] - b[2] * b[2]).max(0.0).sqrt();
    let t = (b[0] + b[1] + 2.0 * s).sqrt();
    [(b[0] + s) / t - 1.0, (b[1] + s) / t - 1.0, b[2] / t]
}
