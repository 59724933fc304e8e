//! The symbolic stage: fill-reducing ordering and symbolic Cholesky of an
//! upper pattern, shared by the KKT and SPD factorisations.

use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    factorize_symbolic_cholesky, SymbolicCholesky, SymmetricOrdering,
};
use faer::sparse::SymbolicSparseColMatRef;
use faer::Side;

use super::{ordering, Ordering};
use crate::{Error, Result};

/// Ordering and symbolic Cholesky of the upper KKT pattern (None when empty).
/// `blocks` labels vertices that nested dissection may keep together (see
/// [`ordering::nested_dissection`]).
pub(super) fn symbolic_analysis(
    size: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
    ordering: Ordering,
    blocks: Option<&[usize]>,
) -> Result<Option<SymbolicCholesky<usize>>> {
    if size == 0 {
        return Ok(None);
    }
    let pattern = SymbolicSparseColMatRef::new_checked(size, size, col_ptr, None, row_idx);
    let perm = match ordering {
        Ordering::Amd => None,
        // No valid METIS order (see `nested_dissection`): AMD instead.
        Ordering::NestedDissection => ordering::nested_dissection(size, col_ptr, row_idx, blocks)
            .map(|fwd| {
                let mut inv = vec![0usize; size];
                for (new, &old) in fwd.iter().enumerate() {
                    inv[old] = new;
                }
                (fwd, inv)
            }),
    };
    let method = match &perm {
        None => SymmetricOrdering::Amd,
        Some((fwd, inv)) => SymmetricOrdering::Custom(PermRef::new_checked(fwd, inv, size)),
    };
    factorize_symbolic_cholesky(pattern, Side::Upper, method, Default::default())
        .map(Some)
        .map_err(|e| {
            Error::Solver(format!(
                "symbolic analysis of the {size}×{size} KKT matrix ({} stored entries, {ordering:?} ordering) failed: {e:?}",
                row_idx.len()
            ))
        })
}
