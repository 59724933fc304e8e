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
use std::ops::{Add, Div, Mul, Neg, Sub};

/// Pixels per batch.
const LANES: usize = 8;

type Lanes<T> = [T; LANES];

/// The float a batch is computed in: f64, or f32 where the CPU has AVX2
/// (twice the lanes per register; [`Precision`]). The model's arithmetic
/// is written once over it; only the sine, cosine and exponential's series
/// differ (f32's shorter, to its own ulp).
trait Real:
    'static
    + Copy
    + PartialOrd
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    const ZERO: Self;
    fn of(v: f64) -> Self;
    fn wide(self) -> f64;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    /// (sin 2πt, cos 2πt) per lane.
    fn sin_cos_turns(t: &Lanes<Self>) -> (Lanes<Self>, Lanes<Self>);
    /// eˣ per lane, x ≤ 0.
    fn exp_nonpositive(x: &Lanes<Self>) -> Lanes<Self>;
    fn jacobian_values(values: Vec<Self>) -> JacobianValues;
    /// This thread's spare Jacobian buffer in this float, see [`Jacobian`]'s drop.
    fn spare() -> &'static SpareBuffer<Self>;
}

type SpareBuffer<T> = std::thread::LocalKey<std::cell::Cell<Vec<T>>>;

impl Real for f64 {
    const ZERO: f64 = 0.0;
    #[inline(always)]
    fn of(v: f64) -> f64 {
        v
    }
    #[inline(always)]
    fn wide(self) -> f64 {
        self
    }
    #[inline(always)]
    fn sqrt(self) -> f64 {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> f64 {
        f64::abs(self)
    }
    #[inline(always)]
    fn sin_cos_turns(t: &Lanes<f64>) -> (Lanes<f64>, Lanes<f64>) {
        sin_cos_turns(t)
    }
    #[inline(always)]
    fn exp_nonpositive(x: &Lanes<f64>) -> Lanes<f64> {
        exp_nonpositive(x)
    }
    fn jacobian_values(values: Vec<f64>) -> JacobianValues {
        JacobianValues::Double(values)
    }
    fn spare() -> &'static SpareBuffer<f64> {
        &SPARE_DOUBLE
    }
}

impl Real for f32 {
    const ZERO: f32 = 0.0;
    #[inline(always)]
    fn of(v: f64) -> f32 {
        v as f32
    }
    #[inline(always)]
    fn wide(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn sqrt(self) -> f32 {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> f32 {
        f32::abs(self)
    }
    #[inline(always)]
    fn sin_cos_turns(t: &Lanes<f32>) -> (Lanes<f32>, Lanes<f32>) {
        sin_cos_turns_f32(t)
    }
    #[inline(always)]
    fn exp_nonpositive(x: &Lanes<f32>) -> Lanes<f32> {
        exp_nonpositive_f32(x)
    }
    fn jacobian_values(values: Vec<f32>) -> JacobianValues {
        JacobianValues::Single(values)
    }
    fn spare() -> &'static SpareBuffer<f32> {
        &SPARE_SINGLE
    }
}

/// The float the kernel computes in. `Single` is f32 where the CPU has
/// AVX2 (f64 elsewhere): S to ~10⁻⁶ and the Jacobian rows to ~10⁻⁵ of
/// f64's (`single_precision_matches_double_on_random_disks`); every sum
/// the objective and the normal equations read is f64 either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Precision {
    Single,
    Double,
}

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
    pub precision: Precision,
}

/// ∂S/∂u at a disk's pixels, in the kernel's float and batches: pixel
/// `LANES` b + i's derivative by unknown m at [(b k + m) `LANES` + i], so
/// the kernel stores each unknown's lanes at once; a short last batch's
/// extra lanes are 0. Every sum over it is f64 ([`Jacobian::normal_equations`]).
pub(super) struct Jacobian {
    values: JacobianValues,
    unknowns: usize,
    pixels: usize,
}

pub(super) enum JacobianValues {
    Single(Vec<f32>),
    Double(Vec<f64>),
}

thread_local! {
    /// Each thread's last Jacobian buffer, handed to its next evaluation: a
    /// fresh one per evaluation cost the allocator and the kernel's page
    /// clearing ~9 % of a run (perf).
    static SPARE_SINGLE: std::cell::Cell<Vec<f32>> = const { std::cell::Cell::new(Vec::new()) };
    static SPARE_DOUBLE: std::cell::Cell<Vec<f64>> = const { std::cell::Cell::new(Vec::new()) };
}

impl Drop for Jacobian {
    fn drop(&mut self) {
        match std::mem::replace(&mut self.values, JacobianValues::Double(Vec::new())) {
            JacobianValues::Single(v) => give_back(v),
            JacobianValues::Double(v) => give_back(v),
        }
    }
}

/// Keeps `values`' allocation as this thread's spare buffer of its float.
fn give_back<T: Real>(mut values: Vec<T>) {
    values.clear();
    if values.capacity() > 0 {
        T::spare().set(values);
    }
}

impl Jacobian {
    /// ∂S_i/∂u_m.
    #[cfg(test)]
    pub fn at(&self, i: usize, m: usize) -> f64 {
        let at = (i / LANES * self.unknowns + m) * LANES + i % LANES;
        match &self.values {
            JacobianValues::Single(v) => v[at] as f64,
            JacobianValues::Double(v) => v[at],
        }
    }

    /// Row-major (pixel × unknown), for the tests.
    #[cfg(test)]
    pub fn rows(&self) -> Vec<f64> {
        let stored = match &self.values {
            JacobianValues::Single(v) => v.len(),
            JacobianValues::Double(v) => v.len(),
        };
        if stored == 0 {
            return Vec::new();
        }
        let k = self.unknowns;
        (0..self.pixels * k)
            .map(|j| self.at(j / k, j % k))
            .collect()
    }

    /// A double-precision Jacobian from row-major rows, for the tests.
    #[cfg(test)]
    pub fn from_rows(rows: &[f64], unknowns: usize) -> Jacobian {
        let pixels = rows.len() / unknowns;
        let mut values = Vec::new();
        for start in (0..pixels).step_by(LANES) {
            for m in 0..unknowns {
                for i in start..start + LANES {
                    values.push(if i < pixels {
                        rows[i * unknowns + m]
                    } else {
                        0.0
                    });
                }
            }
        }
        Jacobian {
            values: JacobianValues::Double(values),
            unknowns,
            pixels,
        }
    }

    /// Σ_i w_i ∂S_i/∂u per unknown, in f64 (w = 1 without `weights`).
    pub fn weighted_sums(&self, weights: Option<&[f64]>) -> Vec<f64> {
        match &self.values {
            JacobianValues::Single(v) => weighted_sums(v, self.unknowns, weights),
            JacobianValues::Double(v) => weighted_sums(v, self.unknowns, weights),
        }
    }

    /// The Gauss–Newton normal equations of one disk: over its pixels i,
    /// row = ∂S_i/∂u − `mean`, less its part along each lighting slope q
    /// (q_i × that slope's column sums `slope_ds`), then rhs += row r_i and
    /// the upper triangle of `normal` (k × k, row-major) += row rowᵀ, in f64.
    /// `normal` and `rhs` are zeros on entry.
    pub fn normal_equations(
        &self,
        residual: &[f64],
        mean: &[f64],
        slopes: &[Vec<f64>],
        slope_ds: &[Vec<f64>],
        normal: &mut [f64],
        rhs: &mut [f64],
    ) {
        let sums = NormalSums {
            pixels: self.pixels,
            residual,
            mean,
            slopes,
            slope_ds,
            normal,
            rhs,
        };
        match &self.values {
            JacobianValues::Single(v) => normal_equations(v, sums),
            JacobianValues::Double(v) => normal_equations(v, sums),
        }
    }
}

/// What [`Jacobian::normal_equations`] reads and fills.
pub(super) struct NormalSums<'a> {
    pixels: usize,
    residual: &'a [f64],
    mean: &'a [f64],
    slopes: &'a [Vec<f64>],
    slope_ds: &'a [Vec<f64>],
    normal: &'a mut [f64],
    rhs: &'a mut [f64],
}

/// The direction-free part of the Flamant field of one load at a batch of
/// pixels (see `FlamantGeometry`).
struct Geometry<T> {
    ex: Lanes<T>,
    ey: Lanes<T>,
    w2r: Lanes<T>,
    w2i: Lanes<T>,
    w3r: Lanes<T>,
    w3i: Lanes<T>,
    /// |e|² before the floor, and the floor's square: a lane below it has
    /// no gradient, one at 0 (the load itself) no field.
    r2: Lanes<T>,
    floor2: T,
    /// Some lane is below the floor (rare: the rim band keeps pixels away
    /// from the loads), so `field` must mask.
    any_near: bool,
}

impl<T: Real> Geometry<T> {
    #[inline(always)]
    fn new(q: [T; 2], px: &Lanes<T>, py: &Lanes<T>, floor: T) -> Geometry<T> {
        let floor2 = floor * floor;
        let mut g = Geometry {
            ex: [T::ZERO; LANES],
            ey: [T::ZERO; LANES],
            w2r: [T::ZERO; LANES],
            w2i: [T::ZERO; LANES],
            w3r: [T::ZERO; LANES],
            w3i: [T::ZERO; LANES],
            r2: [T::ZERO; LANES],
            floor2,
            any_near: false,
        };
        let mut any_near = false;
        for i in 0..LANES {
            let (ex, ey) = (px[i] - q[0], py[i] - q[1]);
            let r2 = ex * ex + ey * ey;
            g.ex[i] = ex;
            g.ey[i] = ey;
            g.r2[i] = r2;
            // Not short-circuited: a reduction the compiler vectorises.
            any_near |= r2 < floor2;
        }
        g.any_near = any_near;
        // Points nearer than the floor are moved out to it (at the load
        // itself the field is zeroed in `field`); a rare case, so the root
        // and the division are skipped for a batch without one.
        if any_near {
            for i in 0..LANES {
                let r2 = g.r2[i];
                if r2 < floor2 && r2 > T::ZERO {
                    let k = floor / r2.sqrt();
                    (g.ex[i], g.ey[i]) = (g.ex[i] * k, g.ey[i] * k);
                }
            }
        }
        for i in 0..LANES {
            let (ex, ey) = (g.ex[i], g.ey[i]);
            let inverse = T::of(1.0) / (ex * ex + ey * ey);
            let (wr, wi) = (ex * inverse, ey * inverse);
            let (w2r, w2i) = (wr * wr - wi * wi, T::of(2.0) * wr * wi);
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
    fn field(&self, dir: [T; 2]) -> [Lanes<T>; 6] {
        let mut c = [[T::ZERO; LANES]; 6];
        let k = T::of(-2.0 / PI);
        let two = T::of(2.0);
        for i in 0..LANES {
            let (ex, ey) = (self.ex[i], self.ey[i]);
            let (w2r, w2i, w3r, w3i) = (self.w2r[i], self.w2i[i], self.w3r[i], self.w3i[i]);
            let proj = ex * dir[0] + ey * dir[1];
            c[0][i] = k * proj * w2r;
            c[1][i] = k * proj * w2i;
            c[2][i] = k * (dir[0] * w2r - two * proj * w3r);
            c[4][i] = k * (dir[0] * w2i - two * proj * w3i);
            // 2i·P·w³ = 2P(−w3i + i w3r).
            c[3][i] = k * (dir[1] * w2r - two * proj * w3i);
            c[5][i] = k * (dir[1] * w2i + two * proj * w3r);
        }
        if self.any_near {
            for i in 0..LANES {
                let (none, flat) = (self.r2[i] == T::ZERO, self.r2[i] < self.floor2);
                for (j, cj) in c.iter_mut().enumerate() {
                    if none || (flat && j >= 2) {
                        cj[i] = T::ZERO;
                    }
                }
            }
        }
        c
    }
}

/// S per pixel and (with `u`'s Jacobian asked) ∂S/∂u row-major (pixel ×
/// unknown), for the local unknowns `u` (2 per load) at `points`. In
/// single precision the points and loads are taken relative to `origin`
/// (the disk's centre: f32 keeps ~10⁻¹⁰ m of a disk-sized offset, not of a
/// scene-sized position); double precision reads them as they are.
pub(super) fn fringes(
    points: &[[f64; 2]],
    origin: [f64; 2],
    loads: &[KernelLoad],
    u: &[f64],
    optics: &KernelOptics,
    floor: f64,
    jacobian: bool,
) -> (Vec<f64>, Jacobian) {
    #[cfg(target_arch = "x86_64")]
    if single_precision_runs() {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe {
            match optics.precision {
                Precision::Single => {
                    fringes_avx2::<f32>(points, origin, loads, u, optics, floor, jacobian)
                }
                Precision::Double => {
                    fringes_avx2::<f64>(points, [0.0; 2], loads, u, optics, floor, jacobian)
                }
            }
        };
    }
    fringes_batched::<f64>(points, [0.0; 2], loads, u, optics, floor, jacobian)
}

/// Whether [`Precision::Single`] computes in f32 here (the CPU has AVX2).
pub(super) fn single_precision_runs() -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        return true;
    }
    false
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn fringes_avx2<T: Real>(
    points: &[[f64; 2]],
    origin: [f64; 2],
    loads: &[KernelLoad],
    u: &[f64],
    optics: &KernelOptics,
    floor: f64,
    jacobian: bool,
) -> (Vec<f64>, Jacobian) {
    fringes_batched::<T>(points, origin, loads, u, optics, floor, jacobian)
}

#[inline(always)]
fn fringes_batched<T: Real>(
    points: &[[f64; 2]],
    origin: [f64; 2],
    loads: &[KernelLoad],
    u: &[f64],
    optics: &KernelOptics,
    floor: f64,
    jacobian: bool,
) -> (Vec<f64>, Jacobian) {
    let n = points.len();
    let k = 2 * loads.len();
    let mut s_all = vec![0.0; n];
    let batches = n.div_ceil(LANES);
    let mut ds_all: Vec<T> = if jacobian {
        let mut spare = T::spare().take();
        spare.reserve(batches * k * LANES);
        spare
    } else {
        Vec::new()
    };
    let constants = BatchOptics::<T>::of(optics);
    let floor = T::of(floor);
    let relative = |p: [f64; 2]| [T::of(p[0] - origin[0]), T::of(p[1] - origin[1])];
    let narrow = |v: [f64; 2]| [T::of(v[0]), T::of(v[1])];
    let at: Vec<[T; 2]> = loads.iter().map(|l| relative(l.point)).collect();
    let directions: Vec<[[T; 2]; 2]> = (loads.iter())
        .map(|l| [narrow(l.directions[0]), narrow(l.directions[1])])
        .collect();
    let unknowns: Vec<T> = u.iter().map(|&x| T::of(x)).collect();
    // Each load's force vector, for a residual-only evaluation (the field
    // is linear in it).
    let forces: Vec<[T; 2]> = (loads.iter().enumerate())
        .map(|(l, load)| {
            let [dn, dt] = load.directions;
            let (un, ut) = (u[2 * l], u[2 * l + 1]);
            narrow([un * dn[0] + ut * dt[0], un * dn[1] + ut * dt[1]])
        })
        .collect();
    // Per unknown: its Flamant numbers at the batch's pixels.
    let mut coef = vec![[[T::ZERO; LANES]; 6]; if jacobian { k } else { 0 }];
    for start in (0..n).step_by(LANES) {
        let len = (n - start).min(LANES);
        // A short last batch repeats its first pixel (computed, not kept).
        let (mut px, mut py) = ([T::ZERO; LANES], [T::ZERO; LANES]);
        for i in 0..LANES {
            [px[i], py[i]] = relative(points[start + if i < len { i } else { 0 }]);
        }
        let mut f = [[T::ZERO; LANES]; 6];
        for l in 0..loads.len() {
            let geometry = Geometry::new(at[l], &px, &py, floor);
            if !jacobian {
                let c = geometry.field(forces[l]);
                for (fa, ca) in f.iter_mut().zip(&c) {
                    for i in 0..LANES {
                        fa[i] = fa[i] + ca[i];
                    }
                }
                continue;
            }
            for (j, dir) in directions[l].iter().enumerate() {
                let c = geometry.field(*dir);
                let x = unknowns[2 * l + j];
                for (fa, ca) in f.iter_mut().zip(&c) {
                    for i in 0..LANES {
                        fa[i] = fa[i] + ca[i] * x;
                    }
                }
                coef[2 * l + j] = c;
            }
        }
        let pixel = Pixels::of(&f, &constants);
        let (s, by_order, by_gradient, live) = pixel.model(&constants);
        for (out, v) in s_all[start..start + len].iter_mut().zip(&s) {
            *out = v.wide();
        }
        if !jacobian {
            continue;
        }
        let w = pixel.weights(&by_order, &by_gradient, &live);
        for c in &coef {
            let mut row = [T::ZERO; LANES];
            for i in 0..LANES {
                row[i] = w[0][i] * c[0][i]
                    + w[1][i] * c[1][i]
                    + w[2][i] * c[2][i]
                    + w[3][i] * c[3][i]
                    + w[4][i] * c[4][i]
                    + w[5][i] * c[5][i];
            }
            // A short batch's repeated pixel is no row.
            row[len..].fill(T::ZERO);
            ds_all.extend_from_slice(&row);
        }
    }
    let jacobian = Jacobian {
        values: T::jacobian_values(ds_all),
        unknowns: k,
        pixels: n,
    };
    (s_all, jacobian)
}

/// [`KernelOptics`] in the batch's float, as the batch multiplies by them
/// (divisions are slow in the lanes).
struct BatchOptics<T> {
    /// 1 / fringe.
    per_fringe: T,
    /// blur² / fringe²: s² per |∇|D||².
    blur_per_fringe2: T,
    envelope_gain: Option<T>,
}

impl<T: Real> BatchOptics<T> {
    #[inline(always)]
    fn of(optics: &KernelOptics) -> BatchOptics<T> {
        BatchOptics {
            per_fringe: T::of(1.0 / optics.fringe),
            blur_per_fringe2: T::of(optics.blur2 / (optics.fringe * optics.fringe)),
            envelope_gain: optics.envelope_gain.map(T::of),
        }
    }
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
fn sin_cos_turns(t: &Lanes<f64>) -> (Lanes<f64>, Lanes<f64>) {
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
        (s_out[i], c_out[i]) = quarter_turned(s, c, quadrant[i] as u32);
    }
    (s_out, c_out)
}

/// (sin, cos) of the reduced angle turned by `quadrant` quarter turns.
#[inline(always)]
fn quarter_turned<T: Real>(s: T, c: T, quadrant: u32) -> (T, T) {
    let swap = quadrant & 1 == 1;
    let (s, c) = (if swap { c } else { s }, if swap { s } else { c });
    (
        if quadrant & 2 == 2 { -s } else { s },
        if (quadrant + 1) & 2 == 2 { -c } else { c },
    )
}

/// 1.5 · 2²³, [`ROUNDER`] for f32 (|x| < 2²²).
const ROUNDER_F32: f32 = 12582912.0;

/// [`sin_cos_turns`] in f32: the same reduction, the series to degree 9 /
/// 10 (below 2·10⁻⁹ on ⅛ turn, under f32's ulp).
#[inline(always)]
fn sin_cos_turns_f32(t: &Lanes<f32>) -> (Lanes<f32>, Lanes<f32>) {
    const TURN: f32 = 2.0 * std::f32::consts::PI;
    let (mut r2, mut r, mut quadrant) = ([0.0f32; LANES], [0.0f32; LANES], [0u32; LANES]);
    for i in 0..LANES {
        let shifted = 4.0 * t[i] + ROUNDER_F32;
        quadrant[i] = shifted.to_bits() & 3;
        r[i] = TURN * (t[i] - 0.25 * (shifted - ROUNDER_F32));
        r2[i] = r[i] * r[i];
    }
    let mut sin = [1.0f32 / 362880.0; LANES]; // 1/9!
    for c in [-1.0f32 / 5040.0, 1.0 / 120.0, -1.0 / 6.0] {
        for i in 0..LANES {
            sin[i] = sin[i] * r2[i] + c;
        }
    }
    let mut cos = [1.0f32 / 3628800.0; LANES]; // 1/10!
    for c in [-1.0f32 / 40320.0, 1.0 / 720.0, -1.0 / 24.0, 0.5] {
        for i in 0..LANES {
            cos[i] = cos[i] * r2[i] + c;
        }
    }
    let (mut s_out, mut c_out) = ([0.0f32; LANES], [0.0f32; LANES]);
    for i in 0..LANES {
        let (s, c) = (r[i] + r[i] * r2[i] * sin[i], 1.0 - r2[i] * cos[i]);
        (s_out[i], c_out[i]) = quarter_turned(s, c, quadrant[i]);
    }
    (s_out, c_out)
}

/// eˣ per lane for x ≤ 0 to about an ulp, branch-free (see
/// [`sin_cos_turns`]): x = n ln 2 + r with |r| ≤ ½ ln 2 (ln 2 in two parts,
/// n ln 2's high part exact), the Taylor series of eʳ to degree 13, times
/// 2ⁿ built in the exponent bits; 0 below −708 (eˣ < 10⁻³⁰⁷ there).
#[inline(always)]
fn exp_nonpositive(x: &Lanes<f64>) -> Lanes<f64> {
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

/// [`exp_nonpositive`] in f32: ln 2 split so that n ln 2's high part is
/// exact for |n| ≤ 2⁸, the series to degree 7 (below 6·10⁻⁹ on ½ ln 2);
/// 0 below −87 (eˣ under f32's smallest normal).
#[inline(always)]
fn exp_nonpositive_f32(x: &Lanes<f32>) -> Lanes<f32> {
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    let (mut r, mut scale) = ([0.0f32; LANES], [0.0f32; LANES]);
    for i in 0..LANES {
        let x = if x[i] < -87.0 { 0.0 } else { x[i] };
        let shifted = x * std::f32::consts::LOG2_E + ROUNDER_F32;
        let n = shifted - ROUNDER_F32;
        r[i] = (x - n * LN2_HI) - n * LN2_LO;
        let n_int = shifted.to_bits() as i32 - ROUNDER_F32.to_bits() as i32;
        scale[i] = f32::from_bits(((n_int + 127) as u32) << 23);
    }
    let mut p = [1.0f32 / 5040.0; LANES]; // 1/7!
    for c in [
        1.0f32 / 720.0,
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
    let mut out = [0.0f32; LANES];
    for i in 0..LANES {
        out[i] = if x[i] < -87.0 { 0.0 } else { p[i] * scale[i] };
    }
    out
}

/// A batch's field, |D|, ∇|D| and s² (`order_and_gradient`, per pixel).
struct Pixels<'a, T> {
    f: &'a [Lanes<T>; 6],
    d: Lanes<T>,
    /// 1 / |D| (infinite where |D| is 0: those lanes are not live).
    per_d: Lanes<T>,
    gd: [Lanes<T>; 2],
    s2: Lanes<T>,
    /// |D| above round-off (else no gradient): 1, or 0.
    live: Lanes<T>,
}

impl<'a, T: Real> Pixels<'a, T> {
    #[inline(always)]
    fn of(f: &'a [Lanes<T>; 6], optics: &BatchOptics<T>) -> Pixels<'a, T> {
        let mut out = Pixels {
            f,
            d: [T::ZERO; LANES],
            per_d: [T::ZERO; LANES],
            gd: [[T::ZERO; LANES]; 2],
            s2: [T::ZERO; LANES],
            live: [T::ZERO; LANES],
        };
        for i in 0..LANES {
            let (d1, d2) = (f[0][i], f[1][i]);
            let d = (d1 * d1 + d2 * d2).sqrt();
            let big = T::of(1e-12) * (d1.abs() + d2.abs() + T::of(1e-300));
            let live = d > big;
            let per_d = T::of(1.0) / d;
            let gx = (d1 * f[2][i] + d2 * f[4][i]) * per_d;
            let gy = (d1 * f[3][i] + d2 * f[5][i]) * per_d;
            let s2 = optics.blur_per_fringe2 * (gx * gx + gy * gy);
            out.d[i] = d;
            out.per_d[i] = per_d;
            out.gd[0][i] = if live { gx } else { T::ZERO };
            out.gd[1][i] = if live { gy } else { T::ZERO };
            out.s2[i] = if live { s2 } else { T::ZERO };
            out.live[i] = if live { T::of(1.0) } else { T::ZERO };
        }
        out
    }

    /// S per pixel, ∂S/∂|D| and ∂S/∂g / |g| (see `jacobian_weights`) and
    /// whether the pixel has a Jacobian row (1 or 0).
    #[inline(always)]
    fn model(&self, optics: &BatchOptics<T>) -> (Lanes<T>, Lanes<T>, Lanes<T>, Lanes<T>) {
        let mut exponent = [T::ZERO; LANES];
        for i in 0..LANES {
            exponent[i] = T::of(-2.0 * PI * PI) * self.s2[i];
        }
        let fade = T::exp_nonpositive(&exponent);
        let (mut s, mut by_order, mut by_gradient) =
            ([T::ZERO; LANES], [T::ZERO; LANES], [T::ZERO; LANES]);
        let mut live = self.live;
        if let Some(gain) = optics.envelope_gain {
            for i in 0..LANES {
                let (gx, gy) = (self.gd[0][i], self.gd[1][i]);
                let norm = (gx * gx + gy * gy).sqrt();
                s[i] = gain * norm * fade[i];
                by_gradient[i] =
                    gain * fade[i] * (T::of(1.0) - T::of(4.0 * PI * PI) * self.s2[i]) / norm;
                live[i] = if norm > T::ZERO { live[i] } else { T::ZERO };
            }
            return (s, by_order, by_gradient, live);
        }
        let mut turns = [T::ZERO; LANES];
        for i in 0..LANES {
            turns[i] = self.d[i] * optics.per_fringe;
        }
        let (sin, cos) = T::sin_cos_turns(&turns);
        let (half, pi) = (T::of(0.5), T::of(PI));
        let gradient_gain = T::of(2.0 * PI * PI) * optics.blur_per_fringe2;
        for i in 0..LANES {
            s[i] = half - half * cos[i] * fade[i];
            by_order[i] = pi * fade[i] * sin[i] * optics.per_fringe;
            by_gradient[i] = gradient_gain * fade[i] * cos[i];
        }
        (s, by_order, by_gradient, live)
    }

    /// `jacobian_weights` per pixel, 0 where the pixel has no row.
    #[inline(always)]
    fn weights(
        &self,
        by_order: &Lanes<T>,
        by_gradient: &Lanes<T>,
        live: &Lanes<T>,
    ) -> [Lanes<T>; 6] {
        let f = self.f;
        let mut w = [[T::ZERO; LANES]; 6];
        for i in 0..LANES {
            let per_d = self.per_d[i];
            let (g0, g1) = (self.gd[0][i], self.gd[1][i]);
            let (e1, e2) = (f[0][i] * per_d, f[1][i] * per_d);
            let q = by_gradient[i];
            let r = by_order[i] - q * (g0 * g0 + g1 * g1) * per_d;
            let row = [
                r * e1 + q * (g0 * f[2][i] + g1 * f[3][i]) * per_d,
                r * e2 + q * (g0 * f[4][i] + g1 * f[5][i]) * per_d,
                q * e1 * g0,
                q * e1 * g1,
                q * e2 * g0,
                q * e2 * g1,
            ];
            let keep = live[i] > T::ZERO;
            for (wj, v) in w.iter_mut().zip(row) {
                wj[i] = if keep { v } else { T::ZERO };
            }
        }
        w
    }
}

/// [`Jacobian::normal_equations`] on its values `ds`, in f64: each pixel's
/// row widened, centred and its slopes' parts taken out lane by lane, and
/// the products summed per lane (the same sums for any float of `ds`),
/// the lanes added at the end; held in fixed-size arrays for the usual k
/// (unrolled), the same sums bit for bit as the loop for any k.
fn normal_equations<T: Real>(ds: &[T], sums: NormalSums<'_>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { normal_equations_avx2(ds, sums) };
    }
    normal_equations_any(ds, sums)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn normal_equations_avx2<T: Real>(ds: &[T], sums: NormalSums<'_>) {
    normal_equations_any(ds, sums)
}

#[inline(always)]
fn normal_equations_any<T: Real>(ds: &[T], sums: NormalSums<'_>) {
    macro_rules! fixed {
        ($($k:literal)*) => {
            match sums.mean.len() {
                $($k => normal_equations_fixed::<T, $k>(ds, sums),)*
                _ => normal_equations_dyn(ds, sums),
            }
        };
    }
    fixed!(2 4 6 8 10 12 14 16);
}

/// One batch's lanes of `values` (pixels from `start`), 0 past the last.
#[inline(always)]
fn batch_lanes(values: &[f64], start: usize) -> Lanes<f64> {
    let mut out = [0.0; LANES];
    let len = values.len().saturating_sub(start).min(LANES);
    out[..len].copy_from_slice(&values[start..start + len]);
    out
}

#[inline(always)]
fn normal_equations_fixed<T: Real, const K: usize>(ds: &[T], sums: NormalSums<'_>) {
    let mean: [f64; K] = sums.mean.try_into().expect("K unknowns");
    let mut g = [[[0.0f64; LANES]; K]; K];
    let mut h = [[0.0f64; LANES]; K];
    for (b, block) in ds.chunks_exact(K * LANES).enumerate() {
        let start = b * LANES;
        let r = batch_lanes(sums.residual, start);
        let live = batch_lanes(&[1.0; LANES][..(sums.pixels - start).min(LANES)], 0);
        let mut row = [[0.0f64; LANES]; K];
        for m in 0..K {
            for i in 0..LANES {
                row[m][i] = (block[m * LANES + i].wide() - mean[m]) * live[i];
            }
        }
        for (q, c) in sums.slopes.iter().zip(sums.slope_ds) {
            let q = batch_lanes(q, start);
            for m in 0..K {
                for i in 0..LANES {
                    row[m][i] -= q[i] * c[m];
                }
            }
        }
        for a in 0..K {
            for i in 0..LANES {
                h[a][i] += row[a][i] * r[i];
            }
            for b in a..K {
                for i in 0..LANES {
                    g[a][b][i] += row[a][i] * row[b][i];
                }
            }
        }
    }
    for a in 0..K {
        sums.rhs[a] = lane_sum(&h[a]);
        for b in a..K {
            sums.normal[a * K + b] = lane_sum(&g[a][b]);
        }
    }
}

fn normal_equations_dyn<T: Real>(ds: &[T], sums: NormalSums<'_>) {
    let k = sums.mean.len();
    let mut g = vec![[0.0f64; LANES]; k * k];
    let mut h = vec![[0.0f64; LANES]; k];
    let mut row = vec![[0.0f64; LANES]; k];
    for (b, block) in ds.chunks_exact(k * LANES).enumerate() {
        let start = b * LANES;
        let r = batch_lanes(sums.residual, start);
        let live = batch_lanes(&[1.0; LANES][..(sums.pixels - start).min(LANES)], 0);
        for m in 0..k {
            for i in 0..LANES {
                row[m][i] = (block[m * LANES + i].wide() - sums.mean[m]) * live[i];
            }
        }
        for (q, c) in sums.slopes.iter().zip(sums.slope_ds) {
            let q = batch_lanes(q, start);
            for m in 0..k {
                for i in 0..LANES {
                    row[m][i] -= q[i] * c[m];
                }
            }
        }
        for a in 0..k {
            for i in 0..LANES {
                h[a][i] += row[a][i] * r[i];
            }
            for b in a..k {
                for i in 0..LANES {
                    g[a * k + b][i] += row[a][i] * row[b][i];
                }
            }
        }
    }
    for a in 0..k {
        sums.rhs[a] = lane_sum(&h[a]);
        for b in a..k {
            sums.normal[a * k + b] = lane_sum(&g[a * k + b]);
        }
    }
}

/// [`Jacobian::weighted_sums`] on its values `ds` (k unknowns).
fn weighted_sums<T: Real>(ds: &[T], k: usize, weights: Option<&[f64]>) -> Vec<f64> {
    let mut lanes = vec![[0.0f64; LANES]; k];
    for (b, block) in ds.chunks_exact(k * LANES).enumerate() {
        let w = weights.map_or([1.0; LANES], |w| batch_lanes(w, b * LANES));
        for m in 0..k {
            for i in 0..LANES {
                lanes[m][i] += w[i] * block[m * LANES + i].wide();
            }
        }
    }
    lanes.iter().map(lane_sum).collect()
}

/// The lanes' sum, in a fixed order.
#[inline(always)]
fn lane_sum(v: &Lanes<f64>) -> f64 {
    v.iter().sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The batch as run here (AVX2 where the CPU has it) and its portable
    /// build give the same numbers bit for bit (no fused multiply–adds), in
    /// either precision.
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
        let origin = [0.001, -0.002];
        for precision in [Precision::Single, Precision::Double] {
            for envelope_gain in [None, Some(2e-4)] {
                for jacobian in [false, true] {
                    let optics = KernelOptics {
                        fringe: 100.0,
                        blur2: 1e-8,
                        envelope_gain,
                        precision,
                    };
                    let (s, ds) = fringes(&points, origin, &loads, &u, &optics, 1e-5, jacobian);
                    let (s0, ds0) = if precision == Precision::Single && single_precision_runs() {
                        fringes_batched::<f32>(&points, origin, &loads, &u, &optics, 1e-5, jacobian)
                    } else {
                        fringes_batched::<f64>(
                            &points, [0.0; 2], &loads, &u, &optics, 1e-5, jacobian,
                        )
                    };
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&s), bits(&s0));
                    assert_eq!(bits(&ds.rows()), bits(&ds0.rows()));
                    assert!(s.iter().any(|v| *v != 0.0));
                }
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

    /// The f32 sine, cosine and exponential against libm at the same
    /// (f32) arguments: within a few of f32's ulps over 60 turns and the
    /// exponents the model meets.
    #[test]
    fn single_sin_cos_and_exp_match_libm() {
        let mut worst = (0.0f64, 0.0f64);
        for i in 0..200_001 {
            let t = (i as f64 * 3.1e-4) as f32;
            let (s, c) = sin_cos_turns_f32(&[t; LANES]);
            let (s0, c0) = (2.0 * PI * t as f64).sin_cos();
            worst.0 = worst
                .0
                .max((s[3] as f64 - s0).abs())
                .max((c[3] as f64 - c0).abs());
            let x = -(i as f32) * 4.3e-4;
            let (e, e0) = (exp_nonpositive_f32(&[x; LANES])[5] as f64, (x as f64).exp());
            worst.1 = worst.1.max((e - e0).abs() / e0);
        }
        assert!(worst.0 < 4e-7 && worst.1 < 4e-7, "{worst:?}");
        assert_eq!(exp_nonpositive_f32(&[0.0; LANES])[0], 1.0);
        assert_eq!(exp_nonpositive_f32(&[-90.0; LANES])[0], 0.0);
    }

    /// Single precision against double on random disks and loads (fixed
    /// seed; disks anywhere in a 0.6 m scene, 20–60 px in radius, 1–6 loads
    /// up to fringe order ~50, 8-bit photographs' pixel sets clear of the
    /// rim): S within 3·10⁻⁵ of its range (an 8-bit grey level is 4·10⁻³),
    /// each Jacobian column within 3·10⁻⁴ of its largest value (measured:
    /// 1.1·10⁻⁵ and 7.5·10⁻⁵, from the phase's f32 round-off at order 51).
    #[test]
    fn single_precision_matches_double_on_random_disks() {
        use rand::{Rng, SeedableRng};
        if !single_precision_runs() {
            eprintln!("no AVX2 here: single precision is double, nothing to compare");
            return;
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(19);
        let (mut worst_s, mut worst_ds, mut highest_order) = (0.0f64, 0.0f64, 0.0f64);
        for _ in 0..60 {
            let radius: f64 = rng.gen_range(0.002..0.02);
            let centre = [rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3)];
            let pixel = radius / rng.gen_range(20.0..60.0);
            let loads: Vec<KernelLoad> = (0..rng.gen_range(1..=6))
                .map(|_| {
                    let a: f64 = rng.gen_range(0.0..2.0 * PI);
                    let inward = [-a.cos(), -a.sin()];
                    KernelLoad {
                        point: [centre[0] + radius * a.cos(), centre[1] + radius * a.sin()],
                        directions: [inward, [-inward[1], inward[0]]],
                    }
                })
                .collect();
            let u: Vec<f64> = (0..loads.len())
                .flat_map(|_| {
                    let un: f64 = rng.gen_range(0.0..6.0);
                    [un, un * rng.gen_range(-0.5..0.5)]
                })
                .collect();
            let reach = (radius / pixel) as i64;
            let mut points = Vec::new();
            for i in -reach..=reach {
                for j in -reach..=reach {
                    let (x, y) = (i as f64 * pixel, j as f64 * pixel);
                    if x.hypot(y) <= radius - 6.0 * pixel {
                        points.push([centre[0] + x, centre[1] + y]);
                    }
                }
            }
            let fringe = 1.0 / radius;
            for p in &points {
                let (mut dr, mut di) = (0.0, 0.0);
                for (l, load) in loads.iter().enumerate() {
                    let (ex, ey) = (p[0] - load.point[0], p[1] - load.point[1]);
                    let [dn, dt] = load.directions;
                    let force = [
                        u[2 * l] * dn[0] + u[2 * l + 1] * dt[0],
                        u[2 * l] * dn[1] + u[2 * l + 1] * dt[1],
                    ];
                    let proj = ex * force[0] + ey * force[1];
                    let r2 = ex * ex + ey * ey;
                    // −(2/π) P / z̄² = −(2/π) P z² / |z|⁴.
                    let k = -2.0 / PI * proj / (r2 * r2);
                    dr += k * (ex * ex - ey * ey);
                    di += k * 2.0 * ex * ey;
                }
                highest_order = highest_order.max(dr.hypot(di) / fringe);
            }
            for envelope_gain in [None, Some(0.6 * PI * pixel / (2f64.sqrt() * fringe))] {
                let optics = |precision| KernelOptics {
                    fringe,
                    blur2: (0.8f64.powi(2) + 1.0 / 12.0) * pixel * pixel,
                    envelope_gain,
                    precision,
                };
                let floor = 1e-3 * radius;
                let run = |precision| {
                    fringes(&points, centre, &loads, &u, &optics(precision), floor, true)
                };
                let ((s, ds), (s0, ds0)) = (run(Precision::Single), run(Precision::Double));
                let (ds, ds0) = (ds.rows(), ds0.rows());
                let range = s0.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                for (a, b) in s.iter().zip(&s0) {
                    worst_s = worst_s.max((a - b).abs() / range);
                }
                let k = u.len();
                for m in 0..k {
                    let column =
                        |v: &[f64]| v.iter().skip(m).step_by(k).copied().collect::<Vec<_>>();
                    let (c, c0) = (column(&ds), column(&ds0));
                    let size = c0.iter().fold(1e-300f64, |m, v| m.max(v.abs()));
                    for (a, b) in c.iter().zip(&c0) {
                        worst_ds = worst_ds.max((a - b).abs() / size);
                    }
                }
            }
        }
        eprintln!(
            "single against double: S {worst_s:.2e}, Jacobian columns {worst_ds:.2e}, orders up to {highest_order:.1}"
        );
        assert!(highest_order > 20.0, "orders up to {highest_order}");
        assert!(
            worst_s < 3e-5 && worst_ds < 3e-4,
            "S {worst_s:.2e}, ∂S/∂u {worst_ds:.2e}"
        );
    }

    /// The unrolled sums give the plain loop's normal equations bit for
    /// bit, with and without a lighting slope, for each k they cover and
    /// one past them (the loop itself), and match the sums pixel by pixel.
    #[test]
    fn fixed_normal_equations_match_the_loop_bit_for_bit() {
        let n = 37;
        for k in [2, 6, 8, 16, 18] {
            let rows: Vec<f64> = (0..n * k)
                .map(|i| ((i * 7919 % 1000) as f64 / 997.0 - 0.4) * 1.7)
                .collect();
            let ds = Jacobian::from_rows(&rows, k);
            let JacobianValues::Double(values) = &ds.values else {
                unreachable!()
            };
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
                ds.normal_equations(&residual, &mean, &slopes, &slope_ds, &mut g, &mut h);
                let (mut g0, mut h0) = (vec![0.0; k * k], vec![0.0; k]);
                let sums = NormalSums {
                    pixels: n,
                    residual: &residual,
                    mean: &mean,
                    slopes: &slopes,
                    slope_ds: &slope_ds,
                    normal: &mut g0,
                    rhs: &mut h0,
                };
                normal_equations_dyn(values, sums);
                let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&g), bits(&g0), "k {k}, lit {lit}");
                assert_eq!(bits(&h), bits(&h0), "k {k}, lit {lit}");
                // Pixel by pixel, to round-off.
                for a in 0..k {
                    let row = |i: usize, m: usize| {
                        rows[i * k + m]
                            - mean[m]
                            - (slopes.iter().zip(&slope_ds))
                                .map(|(q, c)| q[i] * c[m])
                                .sum::<f64>()
                    };
                    let rhs: f64 = (0..n).map(|i| row(i, a) * residual[i]).sum();
                    assert!((rhs - h[a]).abs() < 1e-12 * (1.0 + rhs.abs()), "k {k}");
                    for b in a..k {
                        let gab: f64 = (0..n).map(|i| row(i, a) * row(i, b)).sum();
                        assert!(
                            (gab - g[a * k + b]).abs() < 1e-12 * (1.0 + gab.abs()),
                            "k {k}"
                        );
                    }
                }
            }
        }
    }
}
