//! faer's LDLᵀ factor walked node by node — its supernodes, or the single
//! columns of a simplicial factor — for two things its solve does not offer:
//! the forward (L⁻¹) and backward (L⁻ᵀ) halves apart, so that a bordered
//! solve can slip its correction between them, and the forward solve of a
//! sparse right-hand side over the nodes it reaches only (the elimination
//! tree path from its entries to the root), which is what a border column
//! costs instead of a full solve.

use faer::linalg::matmul::matmul;
use faer::linalg::triangular_solve;
use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::linalg::cholesky::{SymbolicCholesky, SymbolicCholeskyRaw};
use faer::{Accum, MatMut, MatRef, Par};

/// Marks a node without parent (a root of the elimination forest).
const ROOT: u32 = u32::MAX;
/// Nodes with at least this many columns go through faer's dense kernels
/// (vectorised); smaller ones through plain loops, without call overhead.
const DENSE_MIN: usize = 8;

/// The node structure of one numeric LDLᵀ factor and its D⁻¹.
pub(super) struct FactorNodes {
    /// Node holding each (permuted) column.
    node_of: Vec<u32>,
    /// Parent of each node in the elimination tree of the nodes.
    parent: Vec<u32>,
    /// 1 / D, per permuted column.
    d_inv: Vec<f64>,
}

/// One node: permuted columns `start..start + size`, the rows below them
/// (`pattern`) and its values, column-major `(size + pattern.len()) × size`
/// with D on the diagonal and the unit-lower L beneath it.
struct Node<'a> {
    start: usize,
    size: usize,
    pattern: &'a [usize],
    values: &'a [f64],
}

/// The forward solve of one sparse column, w = L⁻¹ P b: the nodes it
/// reaches (ascending) and, node after node, its entries on their columns.
#[derive(Clone)]
pub(super) struct SparseColumn {
    nodes: Vec<u32>,
    values: Vec<f64>,
}

/// A numeric factor: its symbolic part, its values and their nodes.
#[derive(Clone, Copy)]
pub(super) struct Factor<'a> {
    pub symbolic: &'a SymbolicCholesky<usize>,
    pub values: &'a [f64],
    pub nodes: &'a FactorNodes,
}

impl FactorNodes {
    pub fn new(symbolic: &SymbolicCholesky<usize>, values: &[f64]) -> Self {
        let n = symbolic.nrows();
        let count = node_count(symbolic);
        let mut node_of = vec![0u32; n];
        let mut parent = vec![ROOT; count];
        let mut d_inv = vec![0.0; n];
        for s in 0..count {
            let node = node(symbolic, values, s);
            let rows = node.size + node.pattern.len();
            for i in 0..node.size {
                node_of[node.start + i] = s as u32;
                d_inv[node.start + i] = 1.0 / node.values[i * rows + i];
            }
        }
        for (s, p) in parent.iter_mut().enumerate() {
            let first_below = node(symbolic, values, s).pattern.iter().min();
            if let Some(&row) = first_below {
                *p = node_of[row];
            }
        }
        FactorNodes {
            node_of,
            parent,
            d_inv,
        }
    }
}

fn node_count(symbolic: &SymbolicCholesky<usize>) -> usize {
    match symbolic.raw() {
        SymbolicCholeskyRaw::Simplicial(s) => s.nrows(),
        SymbolicCholeskyRaw::Supernodal(s) => s.n_supernodes(),
    }
}

fn node<'a>(symbolic: &'a SymbolicCholesky<usize>, values: &'a [f64], s: usize) -> Node<'a> {
    match symbolic.raw() {
        // Simplicial columns store their diagonal first.
        SymbolicCholeskyRaw::Simplicial(sym) => {
            let range = sym.col_ptr()[s]..sym.col_ptr()[s + 1];
            Node {
                start: s,
                size: 1,
                pattern: &sym.row_idx()[range.start + 1..range.end],
                values: &values[range],
            }
        }
        SymbolicCholeskyRaw::Supernodal(sym) => {
            let start = sym.supernode_begin()[s];
            Node {
                start,
                size: sym.supernode_end()[s] - start,
                pattern: sym.supernode(s).pattern(),
                values: &values[sym.col_ptr_for_val()[s]..sym.col_ptr_for_val()[s + 1]],
            }
        }
    }
}

impl Node<'_> {
    /// L_top and L_bottom as matrices.
    fn blocks(&self) -> (MatRef<'_, f64>, MatRef<'_, f64>) {
        let rows = self.size + self.pattern.len();
        MatRef::from_column_major_slice(self.values, rows, self.size).split_at_row(self.size)
    }

    /// x[cols] ← L_top⁻¹ x[cols]; x[pattern] −= L_bottom x[cols].
    fn forward(&self, x: &mut [f64], below: &mut Vec<f64>) {
        let rows = self.size + self.pattern.len();
        let top = &mut x[self.start..self.start + self.size];
        below.clear();
        below.resize(self.pattern.len(), 0.0);
        if self.size >= DENSE_MIN {
            let (l_top, l_bottom) = self.blocks();
            let mut top = MatMut::from_column_major_slice_mut(top, self.size, 1);
            triangular_solve::solve_unit_lower_triangular_in_place(l_top, top.rb_mut(), Par::Seq);
            let below = MatMut::from_column_major_slice_mut(below, self.pattern.len(), 1);
            matmul(below, Accum::Replace, l_bottom, top.rb(), 1.0, Par::Seq);
        } else {
            for j in 0..self.size {
                let column = &self.values[j * rows..(j + 1) * rows];
                let xj = top[j];
                if xj == 0.0 {
                    continue;
                }
                for (t, l) in top[j + 1..].iter_mut().zip(&column[j + 1..self.size]) {
                    *t -= l * xj;
                }
                for (b, l) in below.iter_mut().zip(&column[self.size..]) {
                    *b += l * xj;
                }
            }
        }
        for (&i, b) in self.pattern.iter().zip(below.iter()) {
            x[i] -= b;
        }
    }

    /// x[cols] −= L_bottomᵀ x[pattern]; x[cols] ← L_top⁻ᵀ x[cols].
    fn backward(&self, x: &mut [f64], below: &mut Vec<f64>) {
        let rows = self.size + self.pattern.len();
        below.clear();
        below.extend(self.pattern.iter().map(|&i| x[i]));
        let top = &mut x[self.start..self.start + self.size];
        if self.size >= DENSE_MIN {
            let (l_top, l_bottom) = self.blocks();
            let mut top = MatMut::from_column_major_slice_mut(top, self.size, 1);
            let below = MatRef::from_column_major_slice(below, self.pattern.len(), 1);
            matmul(
                top.rb_mut(),
                Accum::Add,
                l_bottom.transpose(),
                below,
                -1.0,
                Par::Seq,
            );
            triangular_solve::solve_unit_upper_triangular_in_place(
                l_top.transpose(),
                top,
                Par::Seq,
            );
        } else {
            for j in (0..self.size).rev() {
                let column = &self.values[j * rows..(j + 1) * rows];
                let mut sum: f64 = below
                    .iter()
                    .zip(&column[self.size..])
                    .map(|(b, l)| b * l)
                    .sum();
                sum += (top[j + 1..].iter())
                    .zip(&column[j + 1..self.size])
                    .map(|(t, l)| t * l)
                    .sum::<f64>();
                top[j] -= sum;
            }
        }
    }
}

impl Factor<'_> {
    fn node(&self, s: usize) -> Node<'_> {
        node(self.symbolic, self.values, s)
    }

    fn count(&self) -> usize {
        self.nodes.parent.len()
    }

    /// Solves F z = rhs in place, F = Pᵀ L D Lᵀ P, calling `between` on
    /// v = D⁻¹ L⁻¹ P rhs (permuted) before the backward half.
    pub fn solve_with(&self, rhs: &mut [f64], mut between: impl FnMut(&mut [f64])) {
        let perm = self.symbolic.perm();
        let mut x: Vec<f64> = match perm {
            Some(p) => p.arrays().0.iter().map(|&old| rhs[old]).collect(),
            None => rhs.to_vec(),
        };
        let mut below = Vec::new();
        for s in 0..self.count() {
            self.node(s).forward(&mut x, &mut below);
        }
        for (xi, d) in x.iter_mut().zip(&self.nodes.d_inv) {
            *xi *= d;
        }
        between(&mut x);
        for s in (0..self.count()).rev() {
            self.node(s).backward(&mut x, &mut below);
        }
        match perm {
            Some(p) => {
                for (r, &new) in rhs.iter_mut().zip(p.arrays().1) {
                    *r = x[new];
                }
            }
            None => rhs.copy_from_slice(&x),
        }
    }

    /// w = L⁻¹ P b for a sparse b (original indices), over the nodes b's
    /// entries reach only. `scratch` (one entry per row) and `marked` (one per
    /// node) are all zero / false on entry and are left so.
    pub fn forward_sparse(
        &self,
        b: &[(usize, f64)],
        scratch: &mut [f64],
        marked: &mut [bool],
    ) -> SparseColumn {
        let mut nodes = Vec::new();
        self.reach(b, marked, &mut nodes);
        // Parents follow their children in the factor's column order.
        nodes.sort_unstable();
        for &(i, v) in b {
            scratch[self.permuted(i)] += v;
        }
        let mut below = Vec::new();
        let mut values = Vec::new();
        for &s in &nodes {
            let node = self.node(s as usize);
            node.forward(scratch, &mut below);
            let cols = &mut scratch[node.start..node.start + node.size];
            values.extend_from_slice(cols);
            cols.fill(0.0);
            marked[s as usize] = false;
        }
        SparseColumn { nodes, values }
    }

    /// Appends to `nodes` the nodes on the paths from b's entries to the
    /// root that are not marked yet, and marks them.
    fn reach(&self, b: &[(usize, f64)], marked: &mut [bool], nodes: &mut Vec<u32>) {
        for &(i, _) in b {
            let mut s = self.nodes.node_of[self.permuted(i)];
            while s != ROOT && !marked[s as usize] {
                marked[s as usize] = true;
                nodes.push(s);
                s = self.nodes.parent[s as usize];
            }
        }
    }

    /// Row i of the original order in the factor's order.
    fn permuted(&self, i: usize) -> usize {
        self.symbolic.perm().map_or(i, |p| p.arrays().1[i])
    }

    /// The share of a full solve (both halves) that forward solves of these
    /// sparse columns cost: the factor entries of the nodes each reaches.
    pub fn reach_share<'c>(&self, columns: impl Iterator<Item = &'c [(usize, f64)]>) -> f64 {
        let mut marked = vec![false; self.count()];
        let mut path = Vec::new();
        let mut entries = 0usize;
        for b in columns {
            self.reach(b, &mut marked, &mut path);
            for s in path.drain(..) {
                marked[s as usize] = false;
                let node = self.node(s as usize);
                entries += node.size * (node.size + node.pattern.len());
            }
        }
        entries as f64 / (2 * self.values.len()).max(1) as f64
    }

    /// The share of a full solve that the dense Schur complement of a
    /// border with these columns costs to form (a dot product of every pair
    /// of their forward solves, each as long as the nodes its column
    /// reaches) and to factorise (k³/3).
    pub fn schur_share<'c>(&self, columns: impl Iterator<Item = &'c [(usize, f64)]>) -> f64 {
        let mut marked = vec![false; self.count()];
        let mut path = Vec::new();
        let (mut k, mut length) = (0usize, 0usize);
        for b in columns {
            self.reach(b, &mut marked, &mut path);
            for s in path.drain(..) {
                marked[s as usize] = false;
                length += self.node(s as usize).size;
            }
            k += 1;
        }
        let k = k as f64;
        (0.5 * k * length as f64 + k * k * k / 3.0) / (2 * self.values.len()).max(1) as f64
    }

    /// The numeric factorisation's cost in full solves: its multiply-adds
    /// (w³/6 + p w²/2 + p² w/2 for a node of w columns over p rows below)
    /// against a solve's two per factor entry.
    pub fn factorisation_share(&self) -> f64 {
        let products: f64 = (0..self.count())
            .map(|s| {
                let node = self.node(s);
                let (w, p) = (node.size as f64, node.pattern.len() as f64);
                w * w * w / 6.0 + p * w * w / 2.0 + p * p * w / 2.0
            })
            .sum();
        products / (2 * self.values.len()).max(1) as f64
    }

    /// Each node's column range reached by w, with w's entries there.
    fn segments<'w>(
        &'w self,
        w: &'w SparseColumn,
    ) -> impl Iterator<Item = (std::ops::Range<usize>, &'w [f64])> + 'w {
        let mut offset = 0;
        w.nodes.iter().map(move |&s| {
            let node = self.node(s as usize);
            let range = node.start..node.start + node.size;
            let values = &w.values[offset..offset + node.size];
            offset += node.size;
            (range, values)
        })
    }

    /// wᵀ v over w's entries.
    pub fn dot(&self, w: &SparseColumn, v: &[f64]) -> f64 {
        self.segments(w)
            .map(|(range, values)| {
                values
                    .iter()
                    .zip(&v[range])
                    .map(|(a, b)| a * b)
                    .sum::<f64>()
            })
            .sum()
    }

    /// v −= t D⁻¹ w.
    pub fn sub_scaled(&self, v: &mut [f64], t: f64, w: &SparseColumn) {
        for (range, values) in self.segments(w) {
            let d_inv = &self.nodes.d_inv[range.clone()];
            for ((vi, wi), d) in v[range].iter_mut().zip(values).zip(d_inv) {
                *vi -= t * wi * d;
            }
        }
    }

    /// Scatters D⁻¹ w into `dense` (zero on w's entries before).
    pub fn scatter_scaled(&self, w: &SparseColumn, dense: &mut [f64]) {
        for (range, values) in self.segments(w) {
            let d_inv = &self.nodes.d_inv[range.clone()];
            for ((x, wi), d) in dense[range].iter_mut().zip(values).zip(d_inv) {
                *x = wi * d;
            }
        }
    }

    /// Zeroes `dense` on w's entries.
    pub fn clear(&self, w: &SparseColumn, dense: &mut [f64]) {
        for (range, _) in self.segments(w) {
            dense[range].fill(0.0);
        }
    }

    pub fn rows(&self) -> usize {
        self.symbolic.nrows()
    }

    pub fn node_total(&self) -> usize {
        self.count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::cholesky::ldlt::factor::LdltRegularization;
    use faer::sparse::linalg::cholesky::{
        factorize_symbolic_cholesky, CholeskySymbolicParams, LdltRef, SymmetricOrdering,
    };
    use faer::sparse::linalg::SupernodalThreshold;
    use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
    use faer::{Conj, MatMut, Par, Side};

    /// A quasi-definite KKT-like matrix (upper triangle, CSC): a 2D grid
    /// Laplacian + I on `side²` unknowns, then `m` rows coupling a few
    /// unknowns each with −0.01 on their diagonal.
    fn kkt(side: usize, m: usize) -> (usize, Vec<usize>, Vec<usize>, Vec<f64>) {
        let n = side * side;
        let size = n + m;
        let mut cols: Vec<Vec<(usize, f64)>> = vec![Vec::new(); size];
        for y in 0..side {
            for x in 0..side {
                let j = y * side + x;
                if x > 0 {
                    cols[j].push((j - 1, -1.0));
                }
                if y > 0 {
                    cols[j].push((j - side, -1.0));
                }
                cols[j].push((j, 5.0));
                cols[j].sort_by_key(|e| e.0);
            }
        }
        for i in 0..m {
            let j = n + i;
            for k in 0..3 {
                cols[j].push(((i * 37 + k * 11) % n, 1.0 + k as f64));
            }
            cols[j].sort_by_key(|e| e.0);
            cols[j].dedup_by_key(|e| e.0);
            cols[j].push((j, -0.01));
        }
        let mut col_ptr = vec![0];
        let (mut rows, mut vals) = (Vec::new(), Vec::new());
        for col in cols {
            for (i, v) in col {
                rows.push(i);
                vals.push(v);
            }
            col_ptr.push(rows.len());
        }
        (size, col_ptr, rows, vals)
    }

    /// A factored test matrix: symbolic part, L values and size.
    fn factor(threshold: SupernodalThreshold) -> (SymbolicCholesky<usize>, Vec<f64>, usize) {
        let (size, col_ptr, rows, vals) = kkt(30, 40);
        let pattern = SymbolicSparseColMatRef::new_checked(size, size, &col_ptr, None, &rows);
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: threshold,
            ..Default::default()
        };
        let symbolic =
            factorize_symbolic_cholesky(pattern, Side::Upper, SymmetricOrdering::Amd, params)
                .unwrap();
        let mut l_values = vec![0.0; symbolic.len_val()];
        let mut buf = MemBuffer::new(
            symbolic.factorize_numeric_ldlt_scratch::<f64>(Par::Seq, Default::default()),
        );
        symbolic
            .factorize_numeric_ldlt(
                &mut l_values,
                SparseColMatRef::new(pattern, &vals),
                Side::Upper,
                LdltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut buf),
                Default::default(),
            )
            .unwrap();
        (symbolic, l_values, size)
    }

    /// F⁻¹ b by faer's own solve.
    fn faer_solve(symbolic: &SymbolicCholesky<usize>, l_values: &[f64], b: &[f64]) -> Vec<f64> {
        let mut x = b.to_vec();
        let mut buf = MemBuffer::new(symbolic.solve_in_place_scratch::<f64>(1, Par::Seq));
        LdltRef::new(symbolic, l_values).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut x, b.len(), 1),
            Par::Seq,
            MemStack::new(&mut buf),
        );
        x
    }

    /// The split solve is faer's solve, and the sparse forward solves give
    /// the Schur products b₁ᵀF⁻¹b₂ = w₁ᵀD⁻¹w₂, on both kinds of factor.
    #[test]
    fn split_and_sparse_solves_match_faer_on_simplicial_and_supernodal_factors() {
        for (threshold, supernodal) in [
            (SupernodalThreshold::FORCE_SIMPLICIAL, false),
            (SupernodalThreshold::FORCE_SUPERNODAL, true),
        ] {
            let (symbolic, l_values, size) = factor(threshold);
            assert_eq!(
                matches!(symbolic.raw(), SymbolicCholeskyRaw::Supernodal(_)),
                supernodal
            );
            let nodes = FactorNodes::new(&symbolic, &l_values);
            let f = Factor {
                symbolic: &symbolic,
                values: &l_values,
                nodes: &nodes,
            };
            let rhs: Vec<f64> = (0..size).map(|i| ((i * 7) % 13) as f64 - 6.0).collect();
            let want = faer_solve(&symbolic, &l_values, &rhs);
            let mut got = rhs.clone();
            let mut called = false;
            f.solve_with(&mut got, |_| called = true);
            assert!(called);
            for (g, w) in got.iter().zip(&want) {
                assert!((g - w).abs() <= 1e-12 * (1.0 + w.abs()), "{g} vs {w}");
            }

            // Sparse columns: one unknown, a constraint row, and a mix.
            let columns: Vec<Vec<(usize, f64)>> = vec![
                vec![(5, 1.0)],
                vec![(size - 3, 2.0)],
                vec![(0, 1.0), (450, -0.5), (899, 0.25), (size - 1, 1.0)],
            ];
            let mut scratch = vec![0.0; size];
            let mut marked = vec![false; f.node_total()];
            let w: Vec<SparseColumn> = (columns.iter())
                .map(|b| f.forward_sparse(b, &mut scratch, &mut marked))
                .collect();
            assert!(scratch.iter().all(|&v| v == 0.0) && marked.iter().all(|&m| !m));
            let reached = w[0].values.len();
            assert!(
                reached < size / 4,
                "a local column reaches little: {reached}"
            );
            let mut dense = vec![0.0; size];
            for (i, bi) in columns.iter().enumerate() {
                let mut b = vec![0.0; size];
                for &(r, v) in bi {
                    b[r] += v;
                }
                let fb = faer_solve(&symbolic, &l_values, &b);
                f.scatter_scaled(&w[i], &mut dense);
                for (j, bj) in columns.iter().enumerate() {
                    let want: f64 = bj.iter().map(|&(r, v)| v * fb[r]).sum();
                    let got = f.dot(&w[j], &dense);
                    assert!(
                        (got - want).abs() <= 1e-12 * (1.0 + want.abs()),
                        "supernodal {supernodal}: b{j}ᵀF⁻¹b{i} = {want}, sparse {got}"
                    );
                }
                f.clear(&w[i], &mut dense);
            }
            let share = f.reach_share(columns.iter().map(|c| c.as_slice()));
            assert!(share > 0.0 && share < 3.0, "{share}");
            let schur = f.schur_share(columns.iter().map(|c| c.as_slice()));
            assert!(schur > 0.0 && schur < share, "{schur} vs {share}");
        }
    }
}
