//! Input checks shared by the solvers, and small vector helpers.

use crate::solver::Triplets;
use crate::{Error, Result};

/// Sizes and indices of one triplet matrix.
pub(crate) fn check_triplets(t: &Triplets, name: &str) -> Result<()> {
    if t.rows.len() != t.vals.len() || t.cols.len() != t.vals.len() {
        return Err(Error::Invalid(format!(
            "{name}: {} row indices, {} column indices and {} values",
            t.rows.len(),
            t.cols.len(),
            t.vals.len()
        )));
    }
    for (k, (&r, &c)) in t.rows.iter().zip(&t.cols).enumerate() {
        if r >= t.nrows || c >= t.ncols {
            return Err(Error::Invalid(format!(
                "{name}: entry {k} at ({r}, {c}) lies outside the {}×{} matrix",
                t.nrows, t.ncols
            )));
        }
    }
    Ok(())
}

pub(crate) fn check_pair(a: &Triplets, c: &Triplets) -> Result<()> {
    check_triplets(a, "A")?;
    check_triplets(c, "C")?;
    if a.ncols != c.ncols {
        return Err(Error::Invalid(format!(
            "A has {} columns but C has {}; both act on the same unknowns",
            a.ncols, c.ncols
        )));
    }
    Ok(())
}

pub(crate) fn check_finite(v: &[f64], name: &str) -> Result<()> {
    match v.iter().position(|x| !x.is_finite()) {
        Some(k) => Err(Error::Invalid(format!(
            "{name} {k} is not finite ({})",
            v[k]
        ))),
        None => Ok(()),
    }
}

pub(super) fn norm2(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

pub(super) fn sub(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| x - y).collect()
}
