//! The gap at a contact from the grey image's partial volume at the neck.
//!
//! A scanner sees the solid through its point spread: the grey of a voxel is
//! void + (solid − void) × the solid's indicator blurred by a Gaussian of
//! width σ. For two spheres (each grain's local surface at the contact) a
//! gap g apart that blur is the sum of two blurred balls, exactly (disjoint
//! sets add), and the dip it leaves between them is a known function of g,
//! σ and the radii: a gap of 0.2 voxel darkens the neck by ~0.08 of the
//! contrast over a disc ~√(4Rσ) wide, which the voxels there measure
//! together. Each zone's gap is fitted to the grey of the voxels around its
//! neck (two unknowns: the gap and where the neck sits along the normal);
//! σ and the two grey levels are measured first from the image's own
//! surfaces around the necks of a sample of zones. Overlapping balls (true
//! contacts) count their lens twice, which the fit meets with a gap near 0.

use super::volume::SliceSource;
use crate::error::Result;
use crate::scene::dot;
use rayon::prelude::*;

/// One zone's neck in voxel units: the contact point, the unit normal from
/// grain a to grain b, the two grains' local radii of curvature, and the
/// neighbourhood of voxels that see the neck.
#[derive(Debug, Clone, Copy)]
pub(super) struct Neck {
    pub point: [f64; 3],
    pub normal: [f64; 3],
    pub radii: [f64; 2],
}

/// The scan's grey model: void and solid levels, the blur σ [voxels], and
/// the rms misfit of the sampled necks (noise and model error).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct GreyModel {
    pub void: f64,
    pub solid: f64,
    pub sigma: f64,
    pub noise: f64,
}

/// Half-width of the surfaces' blur the neighbourhood is cut for [voxels]:
/// the neck's dip spans where the two surfaces are within ~2 of it apart.
const NEIGHBOURHOOD_SIGMA: f64 = 1.0;
/// Voxels kept beyond each surface along the normal [voxels].
const DEPTH: f64 = 3.0;
/// The neighbourhood's largest half-size [voxels] (bounds the slices held).
const MAX_HALF: f64 = 16.0;
/// Zones the blur and levels are measured on (evenly spread over all).
const CALIBRATION_ZONES: usize = 48;
/// Tukey's biweight constant, in units of the necks' rms misfit (95 %
/// efficiency on Gaussian noise).
const TUKEY: f64 = 4.685;
/// A fit stops when its step is below this [voxels].
const STEP_TOLERANCE: f64 = 1e-4;
/// Golden-section steps of the blur's search (σ to ±6 %; in a numpy
/// prototype on the test scans, σ fixed 20 % off kept the same zones).
const SIGMA_STEPS: usize = 7;

impl Neck {
    fn reduced_radius(&self) -> f64 {
        let [a, b] = self.radii;
        a * b / (a + b)
    }

    /// Radius of the disc around the normal whose voxels are used: where
    /// the two surfaces are less than 4σ apart (ρ²/(2 r*) = 2σ), plus one.
    fn reach(&self) -> f64 {
        ((4.0 * self.reduced_radius() * NEIGHBOURHOOD_SIGMA).sqrt() + 1.0).min(MAX_HALF)
    }

    /// Whether the voxel at offset `d` from the contact point is used.
    fn sees(&self, d: [f64; 3]) -> bool {
        let t = dot(d, self.normal);
        let rho2 = dot(d, d) - t * t;
        let reach = self.reach();
        rho2 <= reach * reach && t.abs() <= DEPTH + rho2 / (2.0 * self.reduced_radius())
    }

    /// The box of voxels (inclusive, clamped to the volume) around the
    /// neighbourhood, `[x, y, z]`.
    fn bounds(&self, shape: [usize; 3]) -> Option<([usize; 3], [usize; 3])> {
        let reach = self.reach();
        let half = reach
            .max(DEPTH + reach * reach / (2.0 * self.reduced_radius()))
            .min(MAX_HALF);
        let dims = [shape[2], shape[1], shape[0]];
        let mut lo = [0; 3];
        let mut hi = [0; 3];
        for k in 0..3 {
            let a = (self.point[k] - half).ceil().max(0.0);
            let b = (self.point[k] + half).floor().min(dims[k] as f64 - 1.0);
            if a.is_nan() || b.is_nan() || a > b {
                return None;
            }
            (lo[k], hi[k]) = (a as usize, b as usize);
        }
        Some((lo, hi))
    }

    /// Offsets from the contact point of the voxels used, in the order their
    /// greys are stored (z, y, x within the box).
    fn offsets(&self, shape: [usize; 3]) -> Vec<[f64; 3]> {
        let mut out = Vec::new();
        if let Some((lo, hi)) = self.bounds(shape) {
            self.for_each_seen(lo, hi, |_, d| out.push(d));
        }
        out
    }

    /// Calls `visit` with the voxel [x, y, z] and its offset from the contact
    /// point for every voxel of the box `lo..=hi` that the neck uses, in the
    /// order its greys are stored (z, y, x).
    fn for_each_seen(
        &self,
        lo: [usize; 3],
        hi: [usize; 3],
        mut visit: impl FnMut([usize; 3], [f64; 3]),
    ) {
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    let d = [
                        x as f64 - self.point[0],
                        y as f64 - self.point[1],
                        z as f64 - self.point[2],
                    ];
                    if self.sees(d) {
                        visit([x, y, z], d);
                    }
                }
            }
        }
    }
}

/// erfc(x), fractional error below 1.2·10⁻⁷ (Numerical Recipes' erfcc, a
/// Chebyshev fit).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 {
        r
    } else {
        2.0 - r
    }
}

/// Standard normal distribution function and density.
pub(super) fn cdf(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

fn pdf(x: f64) -> f64 {
    (-0.5 * x * x).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// A ball of radius `radius` blurred by a Gaussian of width `sigma`, at
/// distance `r` from its centre, and its derivative in `r`:
/// Φ((R−r)/σ) − Φ((−R−r)/σ) + σ/r·(φ((R+r)/σ) − φ((R−r)/σ)).
pub(super) fn ball(r: f64, radius: f64, sigma: f64) -> (f64, f64) {
    let r = r.max(1e-9);
    let (a, b) = ((radius + r) / sigma, (radius - r) / sigma);
    // The far side of the ball (a > 9: terms below 10⁻¹⁸) is skipped.
    let (pa, qa) = if a < 9.0 {
        (pdf(a), cdf(-a))
    } else {
        (0.0, 0.0)
    };
    let pb = pdf(b);
    let value = cdf(b) - qa + sigma / r * (pa - pb);
    let slope = -radius / (sigma * r) * (pa + pb) - sigma / (r * r) * (pa - pb);
    (value, slope)
}

/// The fitted gap and its standard deviation, the sum of squared residuals
/// and the number of voxels.
#[derive(Debug, Clone, Copy)]
struct NeckFit {
    /// (position along the normal, gap), the start of a refit.
    x: [f64; 2],
    gap: f64,
    sd: f64,
    sse: f64,
    /// The rms residual of the voxels that count, in units of the scan's rms
    /// misfit (`robust` / [`TUKEY`]): high where the two balls do not
    /// explain the neck (a cut, a satellite, a third grain inside the cut).
    misfit: f64,
    /// Σ over voxels of the blurred union (f) and f², f·grey, for the levels.
    sums: [f64; 5],
}

/// Gauss–Newton on (position along the normal, gap) of the two blurred
/// balls against the voxels' greys.
fn fit(
    neck: &Neck,
    offsets: &[[f64; 3]],
    greys: &[f32],
    model: &GreyModel,
    start: [f64; 2],
    robust: f64,
) -> Option<NeckFit> {
    let n = neck.normal;
    let [ra, rb] = neck.radii;
    let contrast = model.solid - model.void;
    if offsets.len() < 8 || contrast == 0.0 {
        return None;
    }
    let mut x = start;
    // Residuals and the normal equations at `x`.
    let evaluate = |x: [f64; 2]| {
        let (t0, gap) = (x[0], x[1]);
        let ca = (t0 - 0.5 * gap - ra, -1.0);
        let cb = (t0 + 0.5 * gap + rb, 1.0);
        let mut jtj = [[0.0; 2]; 2];
        let mut jtr = [0.0; 2];
        let (mut sse, mut loss, mut weights) = (0.0, 0.0, 0.0);
        let mut sums = [0.0; 5];
        for (d, &g) in offsets.iter().zip(greys) {
            let mut f = 0.0;
            let mut grad = [0.0; 2];
            for (&(along, side), radius) in [ca, cb].iter().zip([ra, rb]) {
                // The voxel relative to the ball's centre (centre = point + along·n).
                let v = [
                    d[0] - along * n[0],
                    d[1] - along * n[1],
                    d[2] - along * n[2],
                ];
                let dist = dot(v, v).sqrt();
                let (value, slope) = ball(dist, radius, model.sigma);
                f += value;
                // ∂dist/∂along = −(v·n)/dist; along = t0 ± gap/2.
                let dd = -dot(v, n) / dist.max(1e-9);
                grad[0] += slope * dd;
                grad[1] += slope * dd * 0.5 * side;
            }
            let residual = model.void + contrast * f - f64::from(g);
            // Tukey's biweight: voxels the two balls do not explain (a flat
            // cut, another lobe, a third grain) stop counting.
            let u2 = (residual / robust).powi(2);
            let (w, rho) = if u2 < 1.0 {
                ((1.0 - u2).powi(2), (1.0 - (1.0 - u2).powi(3)) / 6.0)
            } else {
                (0.0, 1.0 / 6.0)
            };
            let (w, rho) = if robust.is_finite() {
                (w, rho * robust * robust)
            } else {
                (1.0, residual * residual)
            };
            let j = [contrast * grad[0], contrast * grad[1]];
            for a in 0..2 {
                jtr[a] += w * j[a] * residual;
                for b in 0..2 {
                    jtj[a][b] += w * j[a] * j[b];
                }
            }
            sse += residual * residual;
            loss += rho;
            weights += w;
            let g = f64::from(g);
            sums = [
                sums[0] + f,
                sums[1] + f * f,
                sums[2] + g,
                sums[3] + f * g,
                sums[4] + 1.0,
            ];
        }
        (jtj, jtr, sse, sums, loss, weights)
    };
    let mut current = evaluate(x);
    let mut damping = 1e-3;
    for _ in 0..40 {
        let (jtj, jtr, _, _, loss, _) = current;
        let a = [
            [jtj[0][0] * (1.0 + damping), jtj[0][1]],
            [jtj[1][0], jtj[1][1] * (1.0 + damping)],
        ];
        let det = a[0][0] * a[1][1] - a[0][1] * a[1][0];
        if !(det.abs() > 0.0 && det.is_finite()) {
            return None;
        }
        let step = [
            -(a[1][1] * jtr[0] - a[0][1] * jtr[1]) / det,
            -(a[0][0] * jtr[1] - a[1][0] * jtr[0]) / det,
        ];
        // At most half a voxel a step: the model is far from linear beyond.
        let scale = (0.5 / step[0].abs().max(step[1].abs())).min(1.0);
        let trial = [x[0] + scale * step[0], x[1] + scale * step[1]];
        let next = evaluate(trial);
        if next.4 <= loss {
            x = trial;
            current = next;
            damping = (damping * 0.3).max(1e-6);
            if step[0].abs().max(step[1].abs()) * scale < STEP_TOLERANCE {
                break;
            }
        } else {
            damping *= 10.0;
            if damping > 1e6 {
                break;
            }
        }
    }
    let (jtj, _, sse, sums, loss, weights) = current;
    let det = jtj[0][0] * jtj[1][1] - jtj[0][1] * jtj[1][0];
    if !(det > 0.0 && x[1].is_finite()) {
        return None;
    }
    let dof = (weights - 2.0).max(1.0);
    // ≈ Σ w·r² for the biweight (2ρ/c² ≈ w·r²/c² near 0): the residual
    // variance of the voxels that count.
    let scatter = if robust.is_finite() { 2.0 * loss } else { sse };
    let variance = jtj[0][0] / det * scatter / dof;
    Some(NeckFit {
        x,
        gap: x[1],
        sd: variance.max(0.0).sqrt(),
        sse,
        misfit: (scatter / dof).sqrt() * TUKEY / robust,
        sums,
    })
}

/// Reads the grey image once, in z order, and returns each wanted neck's
/// voxel greys (in [`Neck::offsets`] order); a ring of slices as deep as the
/// tallest neighbourhood is held.
fn collect(
    grey: &mut dyn SliceSource,
    necks: &[Option<Neck>],
    wanted: &[usize],
) -> Result<Vec<Vec<f32>>> {
    let [nz, ny, nx] = grey.shape();
    let bounds: Vec<Option<([usize; 3], [usize; 3])>> = wanted
        .iter()
        .map(|&k| necks[k].and_then(|n| n.bounds([nz, ny, nx])))
        .collect();
    let depth = bounds
        .iter()
        .flatten()
        .map(|(lo, hi)| hi[2] - lo[2] + 1)
        .max()
        .unwrap_or(1);
    let mut out = vec![Vec::new(); wanted.len()];
    // Necks by the last slice they need.
    let mut order: Vec<usize> = (0..wanted.len()).filter(|&i| bounds[i].is_some()).collect();
    order.sort_by_key(|&i| bounds[i].map(|(_, hi)| hi[2]));
    let mut ring = vec![vec![0f32; ny * nx]; depth];
    let mut next = 0;
    for z in 0..nz {
        if next == order.len() {
            break;
        }
        grey.greys(z, &mut ring[z % depth])?;
        grey.release(z, z + 1);
        while next < order.len() {
            let i = order[next];
            let (lo, hi) = bounds[i].expect("bounded");
            if hi[2] != z {
                break;
            }
            let neck = necks[wanted[i]].expect("a neck");
            let mut greys = Vec::new();
            neck.for_each_seen(lo, hi, |[x, y, zz], _| {
                greys.push(ring[zz % depth][y * nx + x]);
            });
            out[i] = greys;
            next += 1;
        }
    }
    Ok(out)
}

/// A zone's grey gap, its standard deviation [voxels] and the fit's misfit.
pub(super) type ZoneGap = (f64, f64, f64);

/// Per zone (`None`: not a grain pair, or no neck): the gap fitted to the
/// grey at its neck, its standard deviation [voxels] and the fit's misfit
/// (rms residual over the scan's), with the scan's
/// model measured on the image (`levels`: the mean void and solid greys of
/// the labels, the start), which is returned too (`None`: no neck).
pub(super) fn gaps(
    grey: &mut dyn SliceSource,
    necks: &[Option<Neck>],
    levels: (f64, f64),
) -> Result<(Vec<Option<ZoneGap>>, Option<GreyModel>)> {
    let shape = grey.shape();
    let all: Vec<usize> = (0..necks.len()).filter(|&k| necks[k].is_some()).collect();
    if all.is_empty() {
        return Ok((vec![None; necks.len()], None));
    }
    let greys = collect(grey, necks, &all)?;
    let offsets: Vec<Vec<[f64; 3]>> = all
        .par_iter()
        .map(|&k| necks[k].expect("a neck").offsets(shape))
        .collect();
    let step = all.len().div_ceil(CALIBRATION_ZONES);
    let sample: Vec<usize> = (0..all.len()).step_by(step).collect();
    let model = calibrate(necks, &all, &offsets, &greys, &sample, levels);
    let fitted: Vec<Option<NeckFit>> = (0..all.len())
        .into_par_iter()
        .map(|i| {
            let neck = necks[all[i]].expect("a neck");
            fit(
                &neck,
                &offsets[i],
                &greys[i],
                &model,
                [0.0; 2],
                TUKEY * model.noise,
            )
        })
        .collect();
    let mut out = vec![None; necks.len()];
    for (i, f) in fitted.into_iter().enumerate() {
        out[all[i]] = f.map(|f| (f.gap, f.sd, f.misfit));
    }
    Ok((out, Some(model)))
}

/// The blur σ and the void and solid levels that explain the sampled necks
/// best: σ by a golden-section search on log σ, the levels refitted (linear
/// least squares) twice per σ on the zones' fitted gaps.
fn calibrate(
    necks: &[Option<Neck>],
    all: &[usize],
    offsets: &[Vec<[f64; 3]>],
    greys: &[Vec<f32>],
    sample: &[usize],
    (void, solid): (f64, f64),
) -> GreyModel {
    // Each zone's last (position, gap): the start of its next fit.
    let mut starts = vec![[0.0f64; 2]; sample.len()];
    let mut evaluate = |sigma: f64| -> (f64, GreyModel) {
        let mut model = GreyModel {
            void,
            solid,
            sigma,
            noise: f64::NAN,
        };
        let mut sse = f64::INFINITY;
        for round in 0..2 {
            let fits: Vec<Option<NeckFit>> = sample
                .par_iter()
                .zip(&starts)
                .map(|(&i, &x)| {
                    let neck = necks[all[i]].expect("a neck");
                    fit(&neck, &offsets[i], &greys[i], &model, x, f64::INFINITY)
                })
                .collect();
            for (x, f) in starts.iter_mut().zip(&fits) {
                *x = f.map_or([0.0; 2], |f| f.x);
            }
            let fits: Vec<NeckFit> = fits.into_iter().flatten().collect();
            sse = fits.iter().map(|f| f.sse).sum();
            let voxels: f64 = fits.iter().map(|f| f.sums[4]).sum();
            model.noise = (sse / voxels.max(1.0)).sqrt();
            if round == 1 {
                break;
            }
            // grey ≈ void + contrast·f, least squares over every voxel.
            let [sf, sff, sg, sfg, n] = fits
                .iter()
                .fold([0.0; 5], |a, f| std::array::from_fn(|j| a[j] + f.sums[j]));
            let det = n * sff - sf * sf;
            if det.abs() > 1e-12 * n * n {
                let contrast = (n * sfg - sf * sg) / det;
                let v = (sg - contrast * sf) / n;
                if contrast > 0.0 {
                    model.void = v;
                    model.solid = v + contrast;
                }
            }
        }
        (sse, model)
    };
    // Golden section on ln σ over [0.25, 4] voxels.
    let (mut a, mut b) = (0.25f64.ln(), 4f64.ln());
    let ratio = 0.5 * (5f64.sqrt() - 1.0);
    let mut c = b - ratio * (b - a);
    let mut d = a + ratio * (b - a);
    let (mut fc, mut fd) = (evaluate(c.exp()), evaluate(d.exp()));
    for _ in 0..SIGMA_STEPS {
        if fc.0 <= fd.0 {
            b = d;
            (d, fd) = (c, fc);
            c = b - ratio * (b - a);
            fc = evaluate(c.exp());
        } else {
            a = c;
            (c, fc) = (d, fd);
            d = a + ratio * (b - a);
            fd = evaluate(d.exp());
        }
    }
    if fc.0 <= fd.0 {
        fc.1
    } else {
        fd.1
    }
}

/// The Cramér–Rao bound on the gap [voxels] between two touching spheres of
/// radii `radii` [voxels] seen through a Gaussian blur `sigma` [voxels] with
/// white noise `noise` (a fraction of the contrast, levels known): no
/// unbiased estimator from these voxels has a smaller standard deviation.
/// Returns (the neck fit's own window with its two unknowns, position and
/// gap; the two whole spheres, every voxel within 4σ of either surface, with
/// eight unknowns, both centres and radii), each averaged over a few
/// orientations and sub-voxel offsets.
pub fn gap_bounds(radii: [f64; 2], sigma: f64, noise: f64) -> (f64, f64) {
    const SAMPLES: usize = 4;
    let (mut neck_sum, mut whole_sum) = (0.0, 0.0);
    for k in 0..SAMPLES {
        // Golden-spiral normals and offsets: deterministic, spread out.
        let u = (k as f64 + 0.5) / SAMPLES as f64;
        let phi = 2.399_963_229_728_653 * k as f64;
        let (cz, sz) = (1.0 - 2.0 * u, (1.0 - (1.0 - 2.0 * u).powi(2)).sqrt());
        let normal = [sz * phi.cos(), sz * phi.sin(), cz];
        let point = [0.31 * k as f64 % 1.0, 0.57 * k as f64 % 1.0, 0.13];
        // The spheres reach 2r along the normal and r across it; the neck's
        // window at most MAX_HALF.
        let big = (2.0 * radii[0].max(radii[1]) + 4.0 * sigma + 2.0)
            .max(MAX_HALF + 1.0)
            .ceil();
        // The contact point inside a box large enough for the window.
        let neck = Neck {
            point: point.map(|v| v + big),
            normal,
            radii,
        };
        let offsets = neck.offsets([2 * big as usize + 1; 3]);
        // Centres relative to the contact point.
        let centre = |along: f64| normal.map(|v| v * along);
        let spheres = [(centre(-radii[0]), radii[0]), (centre(radii[1]), radii[1])];
        let blurred = |p: &[f64; 3], x: &[f64; 8]| -> f64 {
            (0..2)
                .map(|s| {
                    let c = [x[4 * s], x[4 * s + 1], x[4 * s + 2]];
                    let v = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
                    ball(dot(v, v).sqrt(), x[4 * s + 3], sigma).0
                })
                .sum()
        };
        let x0: [f64; 8] = std::array::from_fn(|i| {
            let (c, r) = spheres[i / 4];
            if i % 4 == 3 {
                r
            } else {
                c[i % 4]
            }
        });
        // The neck's window: the gap moves the two balls apart along the
        // normal, the position moves both.
        let neck_jacobian = |p: &[f64; 3]| -> Vec<f64> {
            let shift = |along: [f64; 2]| {
                let mut x = x0;
                for (s, a) in along.iter().enumerate() {
                    for (k, n) in normal.iter().enumerate() {
                        x[4 * s + k] += a * n;
                    }
                }
                blurred(p, &x)
            };
            let h = 1e-4;
            let position = (shift([h, h]) - shift([-h, -h])) / (2.0 * h);
            let gap = (shift([-0.5 * h, 0.5 * h]) - shift([0.5 * h, -0.5 * h])) / (2.0 * h);
            vec![position, gap]
        };
        neck_sum += bound_on(&offsets, neck_jacobian, &[0.0, 1.0], noise);
        // Whole spheres: every voxel of the box within 4σ of a surface.
        let half = big as i64;
        let mut shell = Vec::new();
        for z in -half..=half {
            for y in -half..=half {
                for x in -half..=half {
                    let p = [
                        x as f64 - point[0],
                        y as f64 - point[1],
                        z as f64 - point[2],
                    ];
                    let near = spheres.iter().any(|(c, r)| {
                        let v = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
                        (dot(v, v).sqrt() - r).abs() < 4.0 * sigma
                    });
                    if near {
                        shell.push(p);
                    }
                }
            }
        }
        let whole_jacobian = |p: &[f64; 3]| -> Vec<f64> {
            let h = 1e-4;
            (0..8)
                .map(|i| {
                    let (mut up, mut down) = (x0, x0);
                    up[i] += h;
                    down[i] -= h;
                    (blurred(p, &up) - blurred(p, &down)) / (2.0 * h)
                })
                .collect()
        };
        // gap = |c_b − c_a| − r_a − r_b: its gradient in the eight unknowns.
        let n = normal;
        let gradient = [-n[0], -n[1], -n[2], -1.0, n[0], n[1], n[2], -1.0];
        whole_sum += bound_on(&shell, whole_jacobian, &gradient, noise);
    }
    (neck_sum / SAMPLES as f64, whole_sum / SAMPLES as f64)
}

/// √(gᵀ F⁻¹ g) with F = JᵀJ / noise² the Fisher information of the voxels
/// `points` (their Jacobian rows from `jacobian`) and `g` the gradient of the
/// quantity estimated.
fn bound_on(
    points: &[[f64; 3]],
    jacobian: impl Fn(&[f64; 3]) -> Vec<f64>,
    gradient: &[f64],
    noise: f64,
) -> f64 {
    let m = gradient.len();
    let mut fisher = nalgebra::DMatrix::<f64>::zeros(m, m);
    for p in points {
        let j = nalgebra::DVector::from_vec(jacobian(p));
        fisher += &j * j.transpose();
    }
    let g = nalgebra::DVector::from_column_slice(gradient);
    match fisher.try_inverse() {
        Some(inverse) => noise * g.dot(&(inverse * &g)).max(0.0).sqrt(),
        None => f64::INFINITY,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn erfc_and_the_blurred_ball_match_known_values() {
        // erfc(0.5) = 0.4795001221869535, erfc(−1) = 1.8427007929497148.
        assert!((erfc(0.5) - 0.479_500_122_186_953_5).abs() < 1e-7);
        assert!((erfc(-1.0) - 1.842_700_792_949_714_8).abs() < 2e-7);
        // A huge ball is a half-space: Φ of the distance inside.
        let (v, _) = ball(1000.0 - 0.7, 1000.0, 1.0);
        assert!((v - cdf(0.7)).abs() < 1e-3, "{v}");
        // Its slope is the numerical derivative.
        for (r, radius, sigma) in [(6.8, 7.5, 1.0), (3.0, 4.0, 1.5), (15.2, 15.0, 0.8)] {
            let h = 1e-5;
            let numeric = (ball(r + h, radius, sigma).0 - ball(r - h, radius, sigma).0) / (2.0 * h);
            let (_, slope) = ball(r, radius, sigma);
            assert!((slope - numeric).abs() < 1e-5, "{slope} {numeric}");
        }
        // The centre of a ball of radius 2σ: P(|N(0, σ²I)| < 2σ) in 3D.
        let (v, _) = ball(1e-6, 2.0, 1.0);
        assert!((v - 0.738_535_870_9).abs() < 1e-5, "{v}");
    }

    /// Two balls drawn by the model itself, a known gap apart, with a fixed
    /// pseudo-random noise: the fit finds the gap within a few σ of its sd.
    #[test]
    fn the_fit_finds_the_gap_of_two_blurred_balls() {
        let model = GreyModel {
            void: 0.1,
            solid: 0.9,
            sigma: 1.1,
            noise: 0.03,
        };
        for gap in [-0.1, 0.0, 0.15, 0.4, 1.0] {
            let neck = Neck {
                point: [20.3, 19.8, 20.1],
                normal: {
                    let n = [0.3f64, -0.5, 0.8];
                    let l = dot(n, n).sqrt();
                    n.map(|v| v / l)
                },
                radii: [7.5, 6.0],
            };
            let offsets = neck.offsets([40, 40, 40]);
            // Ball centres relative to the neck's point: the truth sits
            // 0.2 voxel further along the normal than the start.
            let centre = |along: f64| neck.normal.map(|v| v * along);
            let (ca, cb) = (centre(0.2 - 0.5 * gap - 7.5), centre(0.2 + 0.5 * gap + 6.0));
            let distance = |d: &[f64; 3], c: [f64; 3]| {
                let v = [d[0] - c[0], d[1] - c[1], d[2] - c[2]];
                dot(v, v).sqrt()
            };
            let mut state = 0x2545_f491u64;
            let greys: Vec<f32> = offsets
                .iter()
                .map(|d| {
                    let f = ball(distance(d, ca), 7.5, 1.1).0 + ball(distance(d, cb), 6.0, 1.1).0;
                    // An overlap's lens is solid once.
                    let f = if gap < 0.0 { f.min(1.0) } else { f };
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    let noise = ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.1;
                    (0.1 + 0.8 * f + noise) as f32
                })
                .collect();
            let f = fit(
                &neck,
                &offsets,
                &greys,
                &model,
                [0.0; 2],
                TUKEY * model.noise,
            )
            .expect("a fit");
            assert!(f.sd > 0.0 && f.sd < 0.05, "sd {}", f.sd);
            if gap >= 0.0 {
                assert!(
                    (f.gap - gap).abs() < 4.0 * f.sd + 0.01,
                    "{gap}: {} ± {}",
                    f.gap,
                    f.sd
                );
            } else {
                // Overlap: the lens is solid once, so the fit sees a touch.
                assert!(f.gap < 0.1, "{gap}: {}", f.gap);
            }
        }
    }

    /// The bounds against an independent numerical computation (numpy, the
    /// same blurred balls, round 12): 15 voxels per diameter, σ = 1.038
    /// (a 1-voxel blur of 4³-sub-sampled voxels), noise 0.1: 0.0272 in the
    /// neck's window, 0.0187 over the whole spheres; both scale with the noise.
    #[test]
    fn the_gap_bounds_match_an_independent_computation() {
        let (neck, whole) = gap_bounds([7.5, 7.5], 1.038, 0.1);
        assert!((neck - 0.0272).abs() < 0.0272 * 0.08, "neck {neck}");
        assert!((whole - 0.0187).abs() < 0.0187 * 0.08, "whole {whole}");
        let (neck2, whole2) = gap_bounds([7.5, 7.5], 1.038, 0.2);
        assert!((neck2 / neck - 2.0).abs() < 1e-9 && (whole2 / whole - 2.0).abs() < 1e-9);
        // At twice the resolution, the bound in voxels falls (0.0097 whole).
        let (_, whole30) = gap_bounds([15.0, 15.0], 1.038, 0.1);
        assert!(
            (whole30 - 0.0097).abs() < 0.0097 * 0.1,
            "whole at 30: {whole30}"
        );
    }
}
