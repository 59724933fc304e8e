//! Compressed (CSR/CSC) copies of triplet matrices with duplicates merged, and the
//! Gram-matrix (BᵀB) pattern/values used by both the KKT system and the
//! identifiability test.

use crate::solver::Triplets;

/// The entries (rows, columns) of `top` with `below` stacked under it:
/// [top; below], for compressing the stacked pattern.
pub(crate) fn stacked_entries(top: &Triplets, below: &Triplets) -> (Vec<usize>, Vec<usize>) {
    let rows = (top.rows.iter().copied())
        .chain(below.rows.iter().map(|r| r + top.nrows))
        .collect();
    let cols = top.cols.iter().chain(&below.cols).copied().collect();
    (rows, cols)
}

/// A matrix compressed along its "major" index (rows for CSR, columns for CSC).
/// Minor indices are sorted and unique within each major slice.
#[derive(Debug, Clone)]
pub(crate) struct Compressed {
    pub nmajor: usize,
    pub ptr: Vec<usize>,
    pub idx: Vec<usize>,
    pub val: Vec<f64>,
    /// Slot in `idx`/`val` of every input triplet, so new values with the same
    /// pattern can be scattered without re-sorting (duplicates add up).
    slot: Vec<usize>,
}

impl Compressed {
    /// Indices must already be validated (`major[k] < nmajor`, `minor[k] < nminor`).
    pub fn from_entries(nmajor: usize, nminor: usize, major: &[usize], minor: &[usize]) -> Self {
        let nnz = major.len();
        // Two stable counting sorts (minor, then major) give (major, minor) order.
        let by_minor = counting_order(nminor, minor, None);
        let order = counting_order(nmajor, major, Some(&by_minor));
        let mut ptr = vec![0usize; nmajor + 1];
        let mut idx = Vec::with_capacity(nnz);
        let mut slot = vec![0usize; nnz];
        let mut last: Option<(usize, usize)> = None;
        for &k in &order {
            let key = (major[k], minor[k]);
            if last != Some(key) {
                idx.push(key.1);
                ptr[key.0 + 1] += 1;
                last = Some(key);
            }
            slot[k] = idx.len() - 1;
        }
        for i in 0..nmajor {
            ptr[i + 1] += ptr[i];
        }
        let val = vec![0.0; idx.len()];
        Compressed {
            nmajor,
            ptr,
            idx,
            val,
            slot,
        }
    }

    /// Replace the values by those of triplets with the same pattern.
    pub fn refill(&mut self, vals: &[f64]) {
        self.val.fill(0.0);
        for (&s, &v) in self.slot.iter().zip(vals) {
            self.val[s] += v;
        }
    }

    #[inline]
    pub fn range(&self, i: usize) -> std::ops::Range<usize> {
        self.ptr[i]..self.ptr[i + 1]
    }
}

/// Stable counting sort of `order` (or 0..n) by `key`.
fn counting_order(nkeys: usize, key: &[usize], order: Option<&[usize]>) -> Vec<usize> {
    let mut start = vec![0usize; nkeys + 1];
    for &k in key {
        start[k + 1] += 1;
    }
    for i in 0..nkeys {
        start[i + 1] += start[i];
    }
    let mut out = vec![0usize; key.len()];
    let mut place = |k: usize| {
        out[start[key[k]]] = k;
        start[key[k]] += 1;
    };
    match order {
        Some(o) => o.iter().for_each(|&k| place(k)),
        None => (0..key.len()).for_each(place),
    }
    out
}

/// Upper-triangular CSC pattern (diagonal always present, rows sorted) of BᵀB for
/// an m×n matrix B given as CSR and CSC.
pub(crate) fn gram_upper_pattern(csr: &Compressed, csc: &Compressed) -> (Vec<usize>, Vec<usize>) {
    let n = csc.nmajor;
    let mut col_ptr = Vec::with_capacity(n + 1);
    col_ptr.push(0);
    let mut row_idx = Vec::new();
    let mut mark = vec![usize::MAX; n];
    for j in 0..n {
        let begin = row_idx.len();
        mark[j] = j;
        row_idx.push(j);
        for p in csc.range(j) {
            let r = csc.idx[p];
            for q in csr.range(r) {
                let i = csr.idx[q];
                if i < j && mark[i] != j {
                    mark[i] = j;
                    row_idx.push(i);
                }
            }
        }
        row_idx[begin..].sort_unstable();
        col_ptr.push(row_idx.len());
    }
    (col_ptr, row_idx)
}

/// Values of (T B S)ᵀ(T B S) on the pattern from [`gram_upper_pattern`], written into
/// `out[col_ptr[j]..]` for every column j < n; `row_scale` = T, `col_scale` = S.
/// `work` must be zero on entry (length n) and is left zero.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gram_upper_values(
    csr: &Compressed,
    csc: &Compressed,
    row_scale: &[f64],
    col_scale: &[f64],
    col_ptr: &[usize],
    row_idx: &[usize],
    out: &mut [f64],
    work: &mut [f64],
) {
    for j in 0..csc.nmajor {
        for p in csc.range(j) {
            let r = csc.idx[p];
            let brj = csc.val[p] * row_scale[r] * row_scale[r] * col_scale[j];
            for q in csr.range(r) {
                let i = csr.idx[q];
                if i <= j {
                    work[i] += csr.val[q] * col_scale[i] * brj;
                }
            }
        }
        for p in col_ptr[j]..col_ptr[j + 1] {
            let i = row_idx[p];
            out[p] = work[i];
            work[i] = 0.0;
        }
    }
}

/// y = T B S x (CSR B).
pub(crate) fn mul_scaled(
    csr: &Compressed,
    row_scale: &[f64],
    col_scale: &[f64],
    x: &[f64],
) -> Vec<f64> {
    (0..csr.nmajor)
        .map(|r| {
            let s: f64 = csr
                .range(r)
                .map(|q| csr.val[q] * col_scale[csr.idx[q]] * x[csr.idx[q]])
                .sum();
            s * row_scale[r]
        })
        .collect()
}

/// y = (T B S)ᵀ x (CSR B), n = number of columns.
pub(crate) fn mul_t_scaled(
    csr: &Compressed,
    row_scale: &[f64],
    col_scale: &[f64],
    x: &[f64],
    n: usize,
) -> Vec<f64> {
    let mut y = vec![0.0; n];
    for r in 0..csr.nmajor {
        let xr = x[r] * row_scale[r];
        if xr != 0.0 {
            for q in csr.range(r) {
                y[csr.idx[q]] += csr.val[q] * xr;
            }
        }
    }
    for (yj, s) in y.iter_mut().zip(col_scale) {
        *yj *= s;
    }
    y
}

/// |T B S| |x| (CSR B) — used for componentwise residual bounds.
pub(crate) fn abs_mul_scaled(
    csr: &Compressed,
    row_scale: &[f64],
    col_scale: &[f64],
    x: &[f64],
) -> Vec<f64> {
    (0..csr.nmajor)
        .map(|r| {
            let s: f64 = csr
                .range(r)
                .map(|q| (csr.val[q] * col_scale[csr.idx[q]] * x[csr.idx[q]]).abs())
                .sum();
            s * row_scale[r].abs()
        })
        .collect()
}

/// |T B S|ᵀ |x| (CSR B).
pub(crate) fn abs_mul_t_scaled(
    csr: &Compressed,
    row_scale: &[f64],
    col_scale: &[f64],
    x: &[f64],
    n: usize,
) -> Vec<f64> {
    let mut y = vec![0.0; n];
    for r in 0..csr.nmajor {
        let xr = (x[r] * row_scale[r]).abs();
        if xr != 0.0 {
            for q in csr.range(r) {
                y[csr.idx[q]] += csr.val[q].abs() * xr;
            }
        }
    }
    for (yj, s) in y.iter_mut().zip(col_scale) {
        *yj *= s.abs();
    }
    y
}
