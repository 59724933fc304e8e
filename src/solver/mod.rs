//! Solver back-ends: faer for the sparse equality-constrained least squares
//! (the fast floor), the active set and an interior point on that
//! factorisation, and clarabel for the constrained QP/SOCP as the fallback.

pub mod active_set;
pub mod cascade;
pub mod clarabel;
mod polish;
pub mod problem;
pub mod solution;
pub mod sparse_interior_point;
pub mod sparse_ls;

pub use problem::{pyramid_facets, Cone, ConicProblem, StackedLeastSquares, Term};
pub use solution::{ActiveSetMiss, Attempt, InteriorPointFailure, Solution, SolveStatus};

/// The least-squares problem of the sparse route:
/// minimise ‖A x − b‖² + λ²‖x‖² subject to C x = d.
#[derive(Debug, Clone, Copy)]
pub struct LeastSquares<'a> {
    pub a: &'a Triplets,
    pub b: &'a [f64],
    pub c: &'a Triplets,
    pub d: &'a [f64],
    pub lambda: f64,
}

impl LeastSquares<'_> {
    /// ½‖A x − b‖² + ½λ²‖x‖².
    pub fn objective(&self, x: &[f64]) -> f64 {
        let r2: f64 = self
            .a
            .mul(x)
            .iter()
            .zip(self.b)
            .map(|(ax, b)| (ax - b).powi(2))
            .sum();
        0.5 * (r2 + self.lambda.powi(2) * x.iter().map(|v| v * v).sum::<f64>())
    }

    /// The objective's gradient Aᵀ(A x − b) + λ² x.
    pub fn gradient(&self, x: &[f64]) -> Vec<f64> {
        let r: Vec<f64> = self
            .a
            .mul(x)
            .iter()
            .zip(self.b)
            .map(|(ax, b)| ax - b)
            .collect();
        let mut g = self.a.mul_transpose(&r);
        for (gi, xi) in g.iter_mut().zip(x) {
            *gi += self.lambda * self.lambda * xi;
        }
        g
    }

    /// (AᵀA + λ²I) v.
    pub fn hessian_times(&self, v: &[f64]) -> Vec<f64> {
        let mut h = self.a.mul_transpose(&self.a.mul(v));
        for (hi, vi) in h.iter_mut().zip(v) {
            *hi += self.lambda * self.lambda * vi;
        }
        h
    }
}

/// A sparse matrix in triplet form (duplicates add up), the common currency
/// between assembly and the back-ends.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Triplets {
    pub nrows: usize,
    pub ncols: usize,
    pub rows: Vec<usize>,
    pub cols: Vec<usize>,
    pub vals: Vec<f64>,
}

impl Triplets {
    pub fn new(nrows: usize, ncols: usize) -> Self {
        Triplets {
            nrows,
            ncols,
            ..Default::default()
        }
    }

    pub fn push(&mut self, row: usize, col: usize, val: f64) {
        debug_assert!(row < self.nrows && col < self.ncols);
        if val != 0.0 {
            self.rows.push(row);
            self.cols.push(col);
            self.vals.push(val);
        }
    }

    pub fn nnz(&self) -> usize {
        self.vals.len()
    }

    /// y = A x.
    pub fn mul(&self, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; self.nrows];
        for ((&r, &c), &v) in self.rows.iter().zip(&self.cols).zip(&self.vals) {
            y[r] += v * x[c];
        }
        y
    }

    /// y = Aᵀ x.
    pub fn mul_transpose(&self, x: &[f64]) -> Vec<f64> {
        let mut y = vec![0.0; self.ncols];
        for ((&r, &c), &v) in self.rows.iter().zip(&self.cols).zip(&self.vals) {
            y[c] += v * x[r];
        }
        y
    }
}
