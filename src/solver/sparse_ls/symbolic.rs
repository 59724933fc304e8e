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

/// Ordering and symbolic Cholesky of the upper KKT pattern (None when empty),
/// with the ordering it used: AMD when nested dissection was asked for but
/// METIS gave no valid order (see [`ordering::nested_dissection`]).
/// `blocks` labels vertices that nested dissection may keep together.
pub(super) fn symbolic_analysis(
    size: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
    ordering: Ordering,
    blocks: Option<&[usize]>,
) -> Result<Option<(SymbolicCholesky<usize>, Ordering)>> {
    if size == 0 {
        return Ok(None);
    }
    let dissection = match ordering {
        Ordering::Amd => None,
        Ordering::NestedDissection => ordering::nested_dissection(size, col_ptr, row_idx, blocks),
    };
    analyse_in_order(size, col_ptr, row_idx, dissection).map(Some)
}

/// The symbolic Cholesky in the order `perm` (`perm[new] = old`), or by AMD
/// when there is none.
fn analyse_in_order(
    size: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
    perm: Option<Vec<usize>>,
) -> Result<(SymbolicCholesky<usize>, Ordering)> {
    let pattern = SymbolicSparseColMatRef::new_checked(size, size, col_ptr, None, row_idx);
    let used = match perm {
        None => Ordering::Amd,
        Some(_) => Ordering::NestedDissection,
    };
    let perm = perm.map(|fwd| {
        let mut inv = vec![0usize; size];
        for (new, &old) in fwd.iter().enumerate() {
            inv[old] = new;
        }
        (fwd, inv)
    });
    let method = match &perm {
        None => SymmetricOrdering::Amd,
        Some((fwd, inv)) => SymmetricOrdering::Custom(PermRef::new_checked(fwd, inv, size)),
    };
    factorize_symbolic_cholesky(pattern, Side::Upper, method, Default::default())
        .map(|symbolic| (symbolic, used))
        .map_err(|e| {
            Error::Solver(format!(
                "symbolic analysis of the {size}×{size} KKT matrix ({} stored entries, {used:?} ordering) failed: {e:?}",
                row_idx.len()
            ))
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Upper pattern (CSC, diagonal last in each column) of a path graph.
    fn path(n: usize) -> (Vec<usize>, Vec<usize>) {
        let (mut col_ptr, mut row_idx) = (vec![0], Vec::new());
        for j in 0..n {
            if j > 0 {
                row_idx.push(j - 1);
            }
            row_idx.push(j);
            col_ptr.push(row_idx.len());
        }
        (col_ptr, row_idx)
    }

    #[test]
    fn without_a_dissection_the_analysis_says_it_used_amd() {
        let (col_ptr, row_idx) = path(50);
        let (amd, used) = analyse_in_order(50, &col_ptr, &row_idx, None).expect("AMD");
        assert_eq!(used, Ordering::Amd);
        // A path has no fill under AMD: its factor holds the pattern's entries.
        assert_eq!(amd.len_val(), row_idx.len());
        // A given order is the one used: eliminating an inner vertex first
        // joins its two neighbours, one entry of fill that AMD avoids.
        let inner_first: Vec<usize> = std::iter::once(25)
            .chain((0..50).filter(|&v| v != 25))
            .collect();
        let (given, used) =
            analyse_in_order(50, &col_ptr, &row_idx, Some(inner_first)).expect("order");
        assert_eq!(used, Ordering::NestedDissection);
        assert_eq!(given.len_val(), row_idx.len() + 1);
    }

    #[test]
    fn nested_dissection_is_reported_when_metis_orders() {
        let (col_ptr, row_idx) = path(200);
        let (_, used) =
            symbolic_analysis(200, &col_ptr, &row_idx, Ordering::NestedDissection, None)
                .expect("analysis")
                .expect("non-empty");
        assert_eq!(used, Ordering::NestedDissection);
        assert!(
            symbolic_analysis(0, &[0], &[], Ordering::NestedDissection, None)
                .expect("empty")
                .is_none()
        );
    }
}
