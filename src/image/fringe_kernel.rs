//! The fringe model's per-pixel kernel, evaluated on batches of [`LANES`]
//! pixels laid out as arrays (structure of arrays), so that the compiler
//! vectorises the Flamant fields, the order, its gradient, the fade, the
//! fringe's sine and cosine and the Jacobian rows across pixels. Every
//! pixel's arithmetic is the scalar model's, in the same order
//! ([`super::fringe_fit`]'s `FlamantGeometry`, `order_and_gradient` and
//! `jacobian_weights` state it one pixel at a time), but for the sine,
//! cosine and exponential: branch-free series here ([`sin_cos_turns`],
//! [`exp_nonpositive`]) in place of libm's calls, within a few ulps of them.
//! Where the CPU has AVX2 the batch is compiled for it (chosen at run time).

// Loops over a batch's lanes index several arrays at once: the form the
// compiler vectorises, clearer than zipped iterators.
#![allow(clippy::needless_range_loop)]

use std::f64::consts::PI;

/// Pixels per batch.
const LANES: usize = 8;

type Lanes = [f64; LANES];

/// One load as the kernel needs it: its point and, per local unknown
/// (u_n, u_t), the force's direction on the disk.
#[derive(Clone, Copy)]
pub(super) struct KernelLoad {
    pub point: [f64; 2],
    pub directions: [[f64; 2]; 2],
}

/// The model's constants for one evaluation (see `Optics`).
#[derive(Clone, Copy)]
pub(super) struct KernelOptics {
    /// Fringe stress in the unknowns' force units per metre.
    pub fringe: f64,
    /// Blur variance [m²].
    pub blur2: f64,
    /// The envelope's gain c π / (√2 f_σ s_px) (None: the intensity model).
    pub envelope_gain: Option<f64>,
}

/// The direction-free part of the Flamant field of one load at a batch of
/// pixels (see `FlamantGeometry`).
struct Geometry {
    ex: Lanes,
    ey: Lanes,
    w2r: Lanes,
    w2i: Lanes,
    w3r: Lanes,
    w3i: Lanes,
    /// Nearer the load than the floor: no gradient.
    near: [bool; LANES],
    /// At the load itself: no field.
    at_load: [bool; LANES],
}

impl Geometry {
    #[inline(always)]
    fn new(q: [f64; 2], px: &Lanes, py: &Lanes, floor: f64) -> Geometry {
        let mut g = Geometry {
            ex: [0.0; LANES],
            ey: [0.0; LANES],
            w2r: [0.0; LANES],
            w2i: [0.0; LANES],
            w3r: [0.0; LANES],
            w3i: [0.0; LANES],
            near: [false; LANES],
            at_load: [false; LANES],
        };
        for i in 0..LANES {
            let (ex, ey) = (px[i] - q[0], py[i] - q[1]);
            let r2 = ex * ex + ey * ey;
            g.ex[i] = ex;
            g.ey[i] = ey;
            g.near[i] = r2 < floor * floor;
            g.at_load[i] = g.near[i] && r2 == 0.0;
        }
        // Points nearer than the floor are moved out to it (at the load
        // itself the field is zeroed in `field`); a rare case, so the root
        // and the division are skipped for a batch without one.
        if g.near.iter().any(|n| *n) {
            for i in 0..LANES {
                let (ex, ey) = (g.ex[i], g.ey[i]);
                let r2 = ex * ex + ey * ey;
                let k = if g.near[i] && !g.at_load[i] {
                    floor / r2.sqrt()
                } else {
                    1.0
                };
                if g.near[i] {
                    (g.ex[i], g.ey[i]) = (ex * k, ey * k);
                }
            }
        }
        for i in 0..LANES {
            let (ex, ey) = (g.ex[i], g.ey[i]);
            let r2 = ex * ex + ey * ey;
            let (wr, wi) = (ex / r2, ey / r2);
            let (w2r, w2i) = (wr * wr - wi * wi, 2.0 * wr * wi);
            g.w2r[i] = w2r;
            g.w2i[i] = w2i;
            g.w3r[i] = w2r * wr - w2i * wi;
            g.w3i[i] = w2r * wi + w2i * wr;
        }
        g
    }

    /// The field of a unit force along `dir` and its derivatives, in
    /// `FlamantGeometry::field`'s layout: [Re D, Im D, ∂x Re D, ∂y Re D,
    /// ∂x Im D, ∂y Im D].
    #[inline(always)]
    fn field(&self, dir: [f64; 2]) -> [Lanes; 6] {
        let mut c = [[0.0; LANES]; 6];
        let k = -2.0 / PI;
        for i in 0..LANES {
            let (ex, ey) = (self.ex[i], self.ey[i]);
            let (w2r, w2i, w3r, w3i) = (self.w2r[i], self.w2i[i], self.w3r[i], self.w3i[i]);
            let proj = ex * dir[0] + ey * dir[1];
            let (dr, di) = (k * proj * w2r, k * proj * w2i);
            let xr = k * (dir[0] * w2r - 2.0 * proj * w3r);
            let xi = k * (dir[0] * w2i - 2.0 * proj * w3i);
            // 2i·P·w³ = 2P(−w3i + i w3r).
            let yr = k * (dir[1] * w2r - 2.0 * proj * w3i);
            let yi = k * (dir[1] * w2i + 2.0 * proj * w3r);
            let (none, flat) = (self.at_load[i], self.near[i] || self.at_load[i]);
            c[0][i] = if none { 0.0 } else { dr };
            c[1][i] = if none { 0.0 } else { di };
            c[2][i] = if flat { 0.0 } else { xr };
            c[3][i] = if flat { 0.0 } else { yr };
            c[4][i] = if flat { 0.0 } else { xi };
            c[5][i] = if flat { 0.0 } else { yi };
        }
        c
    }
}

/// S per pixel and (with `u`'s Jacobian asked) ∂S/∂u row-major (pixel ×
/// unknown), for the local unknowns `u` (2 per load) at `points`.
pub(super) fn fringes(
    points: &[[f64; 2]],
    loads: &[KernelLoad],
    u: &[f64],
    optics: &KernelOptics,
    floor: f64,
    jacobian: bool,
) -> (Vec<f64>, Vec<f64>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { fringes_avx2(points, loads, u, optics, floor, jacobian) };
    }
    fringes_batched(points, loads, u, optics, floor, jacobian)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn fringes_avx2(
    points: &[[f64; 2]],
    loads: &[KernelLoad],
    u: &[f64],
    optics: &KernelOptics,
    floor: f64,
    jacobian: bool,
) -> (Vec<f64>, Vec<f64>) {
    fringes_batched(points, loads, u, optics, floor, jacobian)
}

#[inline(always)]
fn fringes_batched(
    points: &[[f64; 2]],
    loads: &[KernelLoad],
    u: &[f64],
    optics: &KernelOptics,
    floor: f64,
    jacobian: bool,
) -> (Vec<f64>, Vec<f64>) {
    let n = points.len();
    let k = 2 * loads.len();
    let mut s_all = vec![0.0; n];
    let mut ds_all = if jacobian {
        vec![0.0; n * k]
    } else {
        Vec::new()
    };
    // Each load's force vector, for a residual-only evaluation (the field
    // is linear in it).
    let forces: Vec<[f64; 2]> = (loads.iter().enumerate())
        .map(|(l, load)| {
            let [dn, dt] = load.directions;
            let (un, ut) = (u[2 * l], u[2 * l + 1]);
            [un * dn[0] + ut * dt[0], un * dn[1] + ut * dt[1]]
        })
        .collect();
    // Per unknown: its Flamant numbers at the batch's pixels.
    let mut coef = vec![[[0.0f64; LANES]; 6]; if jacobian { k } else { 0 }];
    for start in (0..n).step_by(LANES) {
        let len = (n - start).min(LANES);
        // A short last batch repeats its first pixel (computed, not kept).
        let (mut px, mut py) = ([0.0; LANES], [0.0; LANES]);
        for i in 0..LANES {
            let p = points[start + if i < len { i } else { 0 }];
            px[i] = p[0];
            py[i] = p[1];
        }
        let mut f = [[0.0f64; LANES]; 6];
        for (l, load) in loads.iter().enumerate() {
            let geometry = Geometry::new(load.point, &px, &py, floor);
            if !jacobian {
                let c = geometry.field(forces[l]);
                for (fa, ca) in f.iter_mut().zip(&c) {
                    for i in 0..LANES {
                        fa[i] += ca[i];
                    }
                }
                continue;
            }
            for (j, dir) in load.directions.iter().enumerate() {
                let c = geometry.field(*dir);
                let x = u[2 * l + j];
                for (fa, ca) in f.iter_mut().zip(&c) {
                    for i in 0..LANES {
                        fa[i] += ca[i] * x;
                    }
                }
                coef[2 * l + j] = c;
            }
        }
        let pixel = Pixels::of(&f, optics);
        let (s, by_order, by_gradient, row_live) = pixel.model(optics);
        s_all[start..start + len].copy_from_slice(&s[..len]);
        if !jacobian {
            continue;
        }
        let w = pixel.weights(&by_order, &by_gradient);
        for (m, c) in coef.iter().enumerate() {
            let mut row = [0.0; LANES];
            for i in 0..LANES {
                let v = w[0][i] * c[0][i]
                    + w[1][i] * c[1][i]
                    + w[2][i] * c[2][i]
                    + w[3][i] * c[3][i]
                    + w[4][i] * c[4][i]
                    + w[5][i] * c[5][i];
                row[i] = if row_live[i] { v } else { 0.0 };
            }
            for (i, v) in row[..len].iter().enumerate() {
                ds_all[(start + i) * k + m] = *v;
            }
        }
    }
    (s_all, ds_all)
}

/// 1.5 · 2⁵²: x + this − this rounds x to an integer (|x| < 2⁵¹), and the
/// sum's low mantissa bits hold that integer, without a branch or a call.
const ROUNDER: f64 = 6755399441055744.0;

/// (sin 2πt, cos 2πt) per lane to about an ulp, branch-free and step by
/// step over the lanes so that they vectorise (libm's `sin_cos` is a call
/// per pixel): t less its nearest quarter turn (exact) is at most ⅛ turn,
/// where the Taylor series to degree 17 / 18 is exact to below 10⁻¹⁸; the
/// quarter's index swaps and signs the pair.
#[inline(always)]
fn sin_cos_turns(t: &Lanes) -> (Lanes, Lanes) {
    let (mut r2, mut r, mut quadrant) = ([0.0; LANES], [0.0; LANES], [0u64; LANES]);
    for i in 0..LANES {
        let shifted = 4.0 * t[i] + ROUNDER;
        quadrant[i] = shifted.to_bits() & 3;
        r[i] = 2.0 * PI * (t[i] - 0.25 * (shifted - ROUNDER));
        r2[i] = r[i] * r[i];
    }
    // Horner in r² with the coefficients 1/n!.
    let mut sin = [1.0 / 355687428096000.0; LANES]; // 1/17!
    for c in [
        -1.0 / 1307674368000.0, // 1/15!
        1.0 / 6227020800.0,
        -1.0 / 39916800.0,
        1.0 / 362880.0,
        -1.0 / 5040.0,
        1.0 / 120.0,
        -1.0 / 6.0,
    ] {
        for i in 0..LANES {
            sin[i] = sin[i] * r2[i] + c;
        }
    }
    let mut cos = [1.0 / 6402373705728000.0; LANES]; // 1/18!
    for c in [
        -1.0 / 20922789888000.0, // 1/16!
        1.0 / 87178291200.0,
        -1.0 / 479001600.0,
        1.0 / 3628800.0,
        -1.0 / 40320.0,
        1.0 / 720.0,
        -1.0 / 24.0,
        0.5,
    ] {
        for i in 0..LANES {
            cos[i] = cos[i] * r2[i] + c;
        }
    }
    let (mut s_out, mut c_out) = ([0.0; LANES], [0.0; LANES]);
    for i in 0..LANES {
        let (s, c) = (r[i] + r[i] * r2[i] * sin[i], 1.0 - r2[i] * cos[i]);
        let swap = quadrant[i] & 1 == 1;
        let (s, c) = (if swap { c } else { s }, if swap { s } else { c });
        s_out[i] = if quadrant[i] & 2 == 2 { -s } else { s };
        c_out[i] = if (quadrant[i] + 1) & 2 == 2 { -c } else { c };
    }
    (s_out, c_out)
}

/// eˣ per lane for x ≤ 0 to about an ulp, branch-free (see
/// [`sin_cos_turns`]): x = n ln 2 + r with |r| ≤ ½ ln 2 (ln 2 in two parts,
/// n ln 2's high part exact), the Taylor series of eʳ to degree 13, times
/// 2ⁿ built in the exponent bits; 0 below −708 (eˣ < 10⁻³⁰⁷ there).
#[inline(always)]
fn exp_nonpositive(x: &Lanes) -> Lanes {
    const LN2_HI: f64 = 6.931_471_803_691_238e-1;
    const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
    let (mut r, mut scale) = ([0.0; LANES], [0.0; LANES]);
    for i in 0..LANES {
        let x = if x[i] < -708.0 { 0.0 } else { x[i] };
        let shifted = x * std::f64::consts::LOG2_E + ROUNDER;
        let n = shifted - ROUNDER;
        r[i] = (x - n * LN2_HI) - n * LN2_LO;
        // n in [−1022, 0] from the sum's bits (no float-to-integer call),
        // then 2ⁿ's exponent bits.
        let n_int = shifted.to_bits() as i64 - ROUNDER.to_bits() as i64;
        scale[i] = f64::from_bits(((n_int + 1023) as u64) << 52);
    }
    let mut p = [1.0 / 6227020800.0; LANES]; // 1/13!
    for c in [
        1.0 / 479001600.0,
        1.0 / 39916800.0,
        1.0 / 3628800.0,
        1.0 / 362880.0,
        1.0 / 40320.0,
        1.0 / 5040.0,
        1.0 / 720.0,
        1.0 / 120.0,
        1.0 / 24.0,
        1.0 / 6.0,
        0.5,
        1.0,
        1.0,
    ] {
        for i in 0..LANES {
            p[i] = p[i] * r[i] + c;
        }
    }
    let mut out = [0.0; LANES];
    for i in 0..LANES {
        out[i] = if x[i] < -708.0 { 0.0 } else { p[i] * scale[i] };
    }
    out
}

/// A batch's field, |D|, ∇|D| and s² (`order_and_gradient`, per pixel).
struct Pixels<'a> {
    f: &'a [Lanes; 6],
    d: Lanes,
    gd: [Lanes; 2],
    s2: Lanes,
    live: [bool; LANES],
}

impl<'a> Pixels<'a> {
    #[inline(always)]
    fn of(f: &'a [Lanes; 6], optics: &KernelOptics) -> Pixels<'a> {
        let fr = optics.fringe;
        let mut out = Pixels {
            f,
            d: [0.0; LANES],
            gd: [[0.0; LANES]; 2],
            s2: [0.0; LANES],
            live: [false; LANES],
        };
        for i in 0..LANES {
            let (d1, d2) = (f[0][i], f[1][i]);
            let d = (d1 * d1 + d2 * d2).sqrt();
            let big = 1e-12 * (d1.abs() + d2.abs() + 1e-300);
            let live = d > big;
            let gx = (d1 * f[2][i] + d2 * f[4][i]) / d;
            let gy = (d1 * f[3][i] + d2 * f[5][i]) / d;
            let s2 = optics.blur2 * (gx * gx + gy * gy) / (fr * fr);
            out.d[i] = d;
            out.gd[0][i] = if live { gx } else { 0.0 };
            out.gd[1][i] = if live { gy } else { 0.0 };
            out.s2[i] = if live { s2 } else { 0.0 };
            out.live[i] = live;
        }
        out
    }

    /// S per pixel, ∂S/∂|D| and ∂S/∂g / |g| (see `jacobian_weights`) and
    /// whether the pixel has a Jacobian row.
    #[inline(always)]
    fn model(&self, optics: &KernelOptics) -> (Lanes, Lanes, Lanes, [bool; LANES]) {
        let fr = optics.fringe;
        let mut exponent = [0.0; LANES];
        for i in 0..LANES {
            exponent[i] = -2.0 * PI * PI * self.s2[i];
        }
        let fade = exp_nonpositive(&exponent);
        let (mut s, mut by_order, mut by_gradient) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
        let mut live = self.live;
        if let Some(gain) = optics.envelope_gain {
            for i in 0..LANES {
                let (gx, gy) = (self.gd[0][i], self.gd[1][i]);
                let norm = (gx * gx + gy * gy).sqrt();
                s[i] = gain * norm * fade[i];
                by_gradient[i] = gain * fade[i] * (1.0 - 4.0 * PI * PI * self.s2[i]) / norm;
                live[i] = live[i] && norm > 0.0;
            }
            return (s, by_order, by_gradient, live);
        }
        let mut turns = [0.0; LANES];
        for i in 0..LANES {
            turns[i] = self.d[i] / fr;
        }
        let (sin, cos) = sin_cos_turns(&turns);
        for i in 0..LANES {
            s[i] = 0.5 - 0.5 * cos[i] * fade[i];
            by_order[i] = PI * fade[i] * sin[i] / fr;
            by_gradient[i] = 2.0 * PI * PI * fade[i] * cos[i] * optics.blur2 / (fr * fr);
        }
        (s, by_order, by_gradient, live)
    }

    /// `jacobian_weights` per pixel.
    #[inline(always)]
    fn weights(&self, by_order: &Lanes, by_gradient: &Lanes) -> [Lanes; 6] {
        let f = self.f;
        let mut w = [[0.0; LANES]; 6];
        for i in 0..LANES {
            let d = self.d[i];
            let (g0, g1) = (self.gd[0][i], self.gd[1][i]);
            let (e1, e2) = (f[0][i] / d, f[1][i] / d);
            let q = by_gradient[i];
            let r = by_order[i] - q * (g0 * g0 + g1 * g1) / d;
            w[0][i] = r * e1 + q * (g0 * f[2][i] + g1 * f[3][i]) / d;
            w[1][i] = r * e2 + q * (g0 * f[4][i] + g1 * f[5][i]) / d;
            w[2][i] = q * e1 * g0;
            w[3][i] = q * e1 * g1;
            w[4][i] = q * e2 * g0;
            w[5][i] = q * e2 * g1;
        }
        w
    }
}

/// The Gauss–Newton normal equations of one disk: over its pixels i (in
/// order), row = ds_i − `mean`, less its part along each lighting slope q
/// (q_i × that slope's column sums `slope_ds`), then rhs += row r_i and
/// the upper triangle of `normal` (k × k, row-major) += row rowᵀ. The
/// same sums as one loop over pixels, bit for bit, with the sums held in
/// fixed-size arrays for the usual k (unrolled, kept near the registers).
/// `normal` and `rhs` are zeros on entry.
pub(super) fn normal_equations(
    ds: &[f64],
    residual: &[f64],
    mean: &[f64],
    slopes: &[Vec<f64>],
    slope_ds: &[Vec<f64>],
    normal: &mut [f64],
    rhs: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { normal_equations_avx2(ds, residual, mean, slopes, slope_ds, normal, rhs) };
    }
    normal_equations_any(ds, residual, mean, slopes, slope_ds, normal, rhs)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn normal_equations_avx2(
    ds: &[f64],
    residual: &[f64],
    mean: &[f64],
    slopes: &[Vec<f64>],
    slope_ds: &[Vec<f64>],
    normal: &mut [f64],
    rhs: &mut [f64],
) {
    normal_equations_any(ds, residual, mean, slopes, slope_ds, normal, rhs)
}

#[inline(always)]
fn normal_equations_any(
    ds: &[f64],
    residual: &[f64],
    mean: &[f64],
    slopes: &[Vec<f64>],
    slope_ds: &[Vec<f64>],
    normal: &mut [f64],
    rhs: &mut [f64],
) {
    macro_rules! fixed {
        ($($k:literal)*) => {
            match mean.len() {
                $($k => normal_equations_fixed::<$k>(ds, residual, mean, slopes, slope_ds, normal, rhs),)*
                _ => normal_equations_dyn(ds, residual, mean, slopes, slope_ds, normal, rhs),
            }
        };
    }
    fixed!(2 4 6 8 10 12 14 16);
}

#[inline(always)]
fn normal_equations_fixed<const K: usize>(
    ds: &[f64],
    residual: &[f64],
    mean: &[f64],
    slopes: &[Vec<f64>],
    slope_ds: &[Vec<f64>],
    normal: &mut [f64],
    rhs: &mut [f64],
) {
    let mean: [f64; K] = mean.try_into().expect("K unknowns");
    let mut g = [[0.0f64; K]; K];
    let mut h = [0.0f64; K];
    for (i, (ds_i, r)) in ds.chunks_exact(K).zip(residual).enumerate() {
        let mut row = [0.0f64; K];
        for m in 0..K {
            row[m] = ds_i[m] - mean[m];
        }
        for (q, c) in slopes.iter().zip(slope_ds) {
            for m in 0..K {
                row[m] -= q[i] * c[m];
            }
        }
        for a in 0..K {
            let ra = row[a];
            h[a] += ra * r;
            for b in a..K {
                g[a][b] += ra * row[b];
            }
        }
    }
    for a in 0..K {
        rhs[a] = h[a];
        normal[a * K + a..(a + 1) * K].copy_from_slice(&g[a][a..]);
    }
}

fn normal_equations_dyn(
    ds: &[f64],
    residual: &[f64],
    mean: &[f64],
    slopes: &[Vec<f64>],
    slope_ds: &[Vec<f64>],
    normal: &mut [f64],
    rhs: &mut [f64],
) {
    let k = mean.len();
    let mut row = vec![0.0; k];
    for (i, (ds_i, r)) in ds.chunks_exact(k).zip(residual).enumerate() {
        for ((out, v), m) in row.iter_mut().zip(ds_i).zip(mean) {
            *out = v - m;
        }
        for (q, c) in slopes.iter().zip(slope_ds) {
            for (out, cm) in row.iter_mut().zip(c) {
                *out -= q[i] * cm;
            }
        }
        for a in 0..k {
            let ra = row[a];
            rhs[a] += ra * r;
            let upper = &mut normal[a * k + a..(a + 1) * k];
            for (g, rb) in upper.iter_mut().zip(&row[a..]) {
                *g += ra * rb;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The batch as run here (AVX2 where the CPU has it) and its portable
    /// build give the same numbers bit for bit (no fused multiply–adds).
    #[test]
    fn the_portable_batch_matches_the_dispatched_one() {
        let loads = [
            KernelLoad {
                point: [0.01, 0.0],
                directions: [[-1.0, 0.0], [0.0, 1.0]],
            },
            KernelLoad {
                point: [-0.006, 0.008],
                directions: [[0.6, -0.8], [0.8, 0.6]],
            },
        ];
        let points: Vec<[f64; 2]> = (0..37)
            .map(|i| {
                let (a, r) = (i as f64 * 0.7, 0.0016 * ((i % 5) as f64 + 1.0));
                [r * a.cos(), r * a.sin()]
            })
            .collect();
        let u = [1.1, 0.2, 0.6, -0.1];
        for envelope_gain in [None, Some(2e-4)] {
            for jacobian in [false, true] {
                let optics = KernelOptics {
                    fringe: 100.0,
                    blur2: 1e-8,
                    envelope_gain,
                };
                let (s, ds) = fringes(&points, &loads, &u, &optics, 1e-5, jacobian);
                let (s0, ds0) = fringes_batched(&points, &loads, &u, &optics, 1e-5, jacobian);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&s), bits(&s0));
                assert_eq!(bits(&ds), bits(&ds0));
                assert!(s.iter().any(|v| *v != 0.0));
            }
        }
    }

    /// The branch-free sine, cosine and exponential against libm: within a
    /// few ulps over the turns and exponents the model meets (and at the
    /// quarter turns, where the pair swaps).
    #[test]
    fn sin_cos_and_exp_match_libm() {
        let one = |t: f64| {
            let (s, c) = sin_cos_turns(&[t; LANES]);
            (s[LANES - 1], c[LANES - 1])
        };
        let exp = |x: f64| exp_nonpositive(&[x; LANES])[0];
        let mut worst = (0.0f64, 0.0f64);
        for i in 0..200_001 {
            let t = i as f64 * 3.1e-4
                + if i % 7 == 0 {
                    0.25 * (i % 13) as f64
                } else {
                    0.0
                };
            let (s, c) = one(t);
            let (s0, c0) = (2.0 * PI * t).sin_cos();
            worst.0 = worst.0.max((s - s0).abs()).max((c - c0).abs());
            // libm's own phase 2πt is rounded: an ulp of it moves sin by that much.
            let allowed = 4e-16 + 2.0 * f64::EPSILON * 2.0 * PI * t;
            assert!((s - s0).abs() <= allowed, "sin at {t}");
            assert!((c - c0).abs() <= allowed, "cos at {t}");
            let x = -(i as f64) * 3.6e-3;
            let (e, e0) = (exp(x), x.exp());
            let relative = (e - e0).abs() / e0.max(f64::MIN_POSITIVE);
            if x >= -708.0 {
                worst.1 = worst.1.max(relative);
                assert!(relative <= 4.0 * f64::EPSILON, "exp at {x}");
            }
        }
        for t in [0.0, 0.25, 0.5, 0.75, 1.0, 12.25] {
            let (s, c) = one(t);
            let (s0, c0) = (2.0 * PI * t).sin_cos();
            assert!((s - s0).abs() < 1e-14 && (c - c0).abs() < 1e-14, "at {t}");
        }
        assert_eq!(exp(0.0), 1.0);
        assert_eq!(exp(-800.0), 0.0);
        assert!(worst.0 < 1e-13 && worst.1 < 1e-15, "{worst:?}");
    }

    /// The unrolled sums give the plain loop's normal equations bit for
    /// bit, with and without a lighting slope, for each k they cover and
    /// one past them (the loop itself).
    #[test]
    fn fixed_normal_equations_match_the_loop_bit_for_bit() {
        let n = 37;
        for k in [2, 6, 8, 16, 18] {
            let ds: Vec<f64> = (0..n * k)
                .map(|i| ((i * 7919 % 1000) as f64 / 997.0 - 0.4) * 1.7)
                .collect();
            let residual: Vec<f64> = (0..n).map(|i| (i as f64 * 0.37).sin()).collect();
            let mean: Vec<f64> = (0..k).map(|m| 0.1 * m as f64 - 0.3).collect();
            for lit in [false, true] {
                let slopes: Vec<Vec<f64>> = (0..lit as usize)
                    .map(|_| (0..n).map(|i| (i as f64 * 0.11).cos()).collect())
                    .collect();
                let slope_ds: Vec<Vec<f64>> = (slopes.iter())
                    .map(|_| (0..k).map(|m| 0.05 * m as f64).collect())
                    .collect();
                let (mut g, mut h) = (vec![0.0; k * k], vec![0.0; k]);
                normal_equations(&ds, &residual, &mean, &slopes, &slope_ds, &mut g, &mut h);
                let (mut g0, mut h0) = (vec![0.0; k * k], vec![0.0; k]);
                normal_equations_dyn(&ds, &residual, &mean, &slopes, &slope_ds, &mut g0, &mut h0);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&g), bits(&g0), "k {k}, lit {lit}");
                assert_eq!(bits(&h), bits(&h0), "k {k}, lit {lit}");
                assert!(g[k - 1] != 0.0 && h[0] != 0.0);
            }
        }
    }
}
