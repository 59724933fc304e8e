//! Solver back-ends: clarabel for the constrained QP/SOCP, faer for the sparse
//! equality-constrained least squares (the fast floor).

pub mod active_set;
pub mod conic;
pub mod sparse_ls;

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
