//! The one problem type of every constrained solve: weighted least-squares
//! terms, hard equalities, a Tikhonov λ and one friction cone per contact.

use super::{LeastSquares, Triplets};
use std::borrow::Cow;

/// A constraint on a contact's unknowns (u₀ = compressive normal force).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Cone {
    /// u₀ ≥ 0.
    NonNegative { normal: usize },
    /// 2D Coulomb: μ u₀ ≥ |u₁| (two linear inequalities).
    Wedge {
        normal: usize,
        tangent: usize,
        mu: f64,
    },
    /// 3D Coulomb: μ u₀ ≥ ‖(u₁, u₂)‖ (a second-order cone).
    Circular {
        normal: usize,
        t1: usize,
        t2: usize,
        mu: f64,
    },
    /// 3D Coulomb by an inscribed pyramid of `facets` planes (a linear QP).
    Pyramid {
        normal: usize,
        t1: usize,
        t2: usize,
        mu: f64,
        facets: usize,
    },
}

impl Cone {
    /// The same cone on unknowns shifted by `by` (a block placed in a larger problem).
    pub fn shifted(self, by: usize) -> Cone {
        match self {
            Cone::NonNegative { normal } => Cone::NonNegative {
                normal: normal + by,
            },
            Cone::Wedge {
                normal,
                tangent,
                mu,
            } => Cone::Wedge {
                normal: normal + by,
                tangent: tangent + by,
                mu,
            },
            Cone::Circular { normal, t1, t2, mu } => Cone::Circular {
                normal: normal + by,
                t1: t1 + by,
                t2: t2 + by,
                mu,
            },
            Cone::Pyramid {
                normal,
                t1,
                t2,
                mu,
                facets,
            } => Cone::Pyramid {
                normal: normal + by,
                t1: t1 + by,
                t2: t2 + by,
                mu,
                facets,
            },
        }
    }

    /// How far `x` lies outside the cone (0 inside), in the units of x.
    pub fn violation(&self, x: &[f64]) -> f64 {
        match *self {
            Cone::NonNegative { normal } => (-x[normal]).max(0.0),
            Cone::Wedge {
                normal,
                tangent,
                mu,
            } => (x[tangent].abs() - mu * x[normal]).max(-x[normal]).max(0.0),
            Cone::Circular { normal, t1, t2, mu } => (x[t1].hypot(x[t2]) - mu * x[normal])
                .max(-x[normal])
                .max(0.0),
            Cone::Pyramid {
                normal,
                t1,
                t2,
                mu,
                facets,
            } => {
                let worst = pyramid_facets(facets, mu)
                    .map(|(m, c, s)| c * x[t1] + s * x[t2] - m * x[normal])
                    .fold(-x[normal], f64::max);
                worst.max(0.0)
            }
        }
    }

    /// Moves `x` onto the cone by the smallest change of its tangential part
    /// (or of the normal part when that is negative) — for removing round-off.
    pub fn project(&self, x: &mut [f64]) {
        let (normal, tangents, mu): (usize, &[usize], f64) = match self {
            Cone::NonNegative { normal } => (*normal, &[], 0.0),
            Cone::Wedge {
                normal,
                tangent,
                mu,
            } => (*normal, std::slice::from_ref(tangent), *mu),
            Cone::Circular { normal, t1, t2, mu }
            | Cone::Pyramid {
                normal, t1, t2, mu, ..
            } => {
                x[*normal] = x[*normal].max(0.0);
                // Inside a pyramid's inscribed circle the point is inside the pyramid.
                let limit = match self {
                    Cone::Pyramid { facets, .. } => inscribed_mu(*facets, *mu),
                    _ => *mu,
                } * x[*normal];
                let t = x[*t1].hypot(x[*t2]);
                if t > limit && t > 0.0 {
                    x[*t1] *= limit / t;
                    x[*t2] *= limit / t;
                }
                return;
            }
        };
        x[normal] = x[normal].max(0.0);
        for &t in tangents {
            x[t] = x[t].clamp(-mu * x[normal], mu * x[normal]);
        }
    }
}

/// The facets of the pyramid inscribed in the cone μ u₀ ≥ ‖(u₁, u₂)‖: each
/// (μ', cos θ, sin θ) stands for μ' u₀ − cos θ u₁ − sin θ u₂ ≥ 0, with
/// μ' = μ cos(π/k) so the pyramid touches the cone along its edges.
pub fn pyramid_facets(facets: usize, mu: f64) -> impl Iterator<Item = (f64, f64, f64)> {
    let k = facets.max(3);
    let inscribed = inscribed_mu(k, mu);
    (0..k).map(move |i| {
        let theta = 2.0 * std::f64::consts::PI * i as f64 / k as f64;
        (inscribed, theta.cos(), theta.sin())
    })
}

/// μ' = μ cos(π/k): the friction coefficient of a k-facet pyramid's faces
/// (and of the circle inscribed in it).
fn inscribed_mu(facets: usize, mu: f64) -> f64 {
    mu * (std::f64::consts::PI / facets.max(3) as f64).cos()
}

/// One term w‖K x − b‖² of the objective.
#[derive(Debug, Clone, Copy)]
pub struct Term<'a> {
    pub matrix: &'a Triplets,
    pub rhs: &'a [f64],
    pub weight: f64,
}

/// minimise Σ w‖K x − b‖² + λ² Σ_{i<regularized} x_i²  s.t. C x = d, cones:
/// the one problem type of every constrained solve (interior point, active
/// set through [`ConicProblem::least_squares`], polishing).
#[derive(Debug, Clone, Default)]
pub struct ConicProblem<'a> {
    pub n: usize,
    pub terms: Vec<Term<'a>>,
    pub equalities: Vec<(&'a Triplets, &'a [f64])>,
    /// Tikhonov λ (dimensionless); the objective carries λ².
    pub lambda: f64,
    /// The first `regularized` unknowns carry the λ² term.
    pub regularized: usize,
    pub cones: Vec<Cone>,
}

/// A [`ConicProblem`] without its cones as one least squares
/// min ‖A x − b‖² + λ²‖x‖² s.t. C x = d: the terms stacked with weights √w,
/// the equalities stacked; borrowed when there is only one of each.
#[derive(Debug, Clone)]
pub struct StackedLeastSquares<'a> {
    a: Cow<'a, Triplets>,
    b: Cow<'a, [f64]>,
    c: Cow<'a, Triplets>,
    d: Cow<'a, [f64]>,
    lambda: f64,
}

impl StackedLeastSquares<'_> {
    pub fn view(&self) -> LeastSquares<'_> {
        LeastSquares {
            a: &self.a,
            b: &self.b,
            c: &self.c,
            d: &self.d,
            lambda: self.lambda,
        }
    }
}

/// Stacks blocks of rows (each scaled by its factor) into one matrix.
fn stack<'a>(
    n: usize,
    blocks: &[(&'a Triplets, &'a [f64], f64)],
) -> (Cow<'a, Triplets>, Cow<'a, [f64]>) {
    if let [(m, rhs, scale)] = blocks {
        if *scale == 1.0 {
            return (Cow::Borrowed(*m), Cow::Borrowed(*rhs));
        }
    }
    let rows = blocks.iter().map(|(m, ..)| m.nrows).sum();
    let mut a = Triplets::new(rows, n);
    let mut b = Vec::with_capacity(rows);
    let mut offset = 0;
    for &(m, rhs, scale) in blocks {
        for k in 0..m.nnz() {
            a.push(offset + m.rows[k], m.cols[k], scale * m.vals[k]);
        }
        b.extend(rhs.iter().map(|v| scale * v));
        offset += m.nrows;
    }
    (Cow::Owned(a), Cow::Owned(b))
}

impl<'a> ConicProblem<'a> {
    /// The problem as one sparse least squares, when λ covers every unknown
    /// (or is zero); `None` otherwise.
    pub fn least_squares(&self) -> Option<StackedLeastSquares<'a>> {
        if self.lambda > 0.0 && self.regularized != self.n {
            return None;
        }
        let terms: Vec<_> = self
            .terms
            .iter()
            .map(|t| (t.matrix, t.rhs, t.weight.sqrt()))
            .collect();
        let (a, b) = stack(self.n, &terms);
        let equalities: Vec<_> = self.equalities.iter().map(|&(c, d)| (c, d, 1.0)).collect();
        let (c, d) = if equalities.is_empty() {
            (Cow::Owned(Triplets::new(0, self.n)), Cow::Owned(Vec::new()))
        } else {
            stack(self.n, &equalities)
        };
        Some(StackedLeastSquares {
            a,
            b,
            c,
            d,
            lambda: self.lambda,
        })
    }

    /// Σ w‖K x − b‖² + λ²‖x_reg‖².
    pub fn objective(&self, x: &[f64]) -> f64 {
        let reg: f64 = x[..self.regularized].iter().map(|a| a * a).sum();
        let mut v = self.lambda * self.lambda * reg;
        for t in &self.terms {
            v += t.weight
                * t.matrix
                    .mul(x)
                    .iter()
                    .zip(t.rhs)
                    .map(|(a, b)| (a - b).powi(2))
                    .sum::<f64>();
        }
        v
    }
}
