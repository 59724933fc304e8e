//! Nested-dissection fill-reducing ordering of a symmetric sparsity pattern.
//!
//! Packings are spatial graphs (2D/3D), which have small vertex separators; AMD
//! is a local greedy method and fills more, most of all in 3D. The graph is
//! bisected recursively: a BFS level structure from a pseudo-peripheral vertex,
//! cut at the level that minimises |S| · n / (|A| · |B|), the cut level thinned
//! to the vertices that really touch the other side. Separators are ordered
//! after both halves; disconnected pieces are ordered one after the other; small
//! pieces are ordered by faer's AMD on their induced subgraph.
//!
//! Purely graph based (no coordinates), deterministic, O(nnz · log n).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::amd;
use faer::sparse::SymbolicSparseColMatRef;

/// Pieces with at most this many vertices are ordered by AMD.
const LEAF_SIZE: usize = 256;
/// Pseudo-peripheral search: at most this many BFS sweeps.
const PERIPHERAL_SWEEPS: usize = 4;
/// Each side of a cut must hold at least this fraction of the piece.
const MIN_SIDE_FRACTION: f64 = 0.2;
/// Refinement passes per bisection, and uphill moves tried before a pass stops.
const REFINE_PASSES: usize = 8;
const UPHILL_MOVES: usize = 100;
/// Label of a vertex already placed in the output (separator or leaf).
const PLACED: usize = usize::MAX;

/// Undirected graph without self loops, adjacency in CSR form.
struct Graph {
    ptr: Vec<usize>,
    adj: Vec<usize>,
}

impl Graph {
    /// From the upper (i ≤ j) or full pattern of a symmetric matrix in CSC form.
    fn from_pattern(n: usize, col_ptr: &[usize], row_idx: &[usize]) -> Self {
        let mut degree = vec![0usize; n];
        for j in 0..n {
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                if i != j {
                    degree[i] += 1;
                    degree[j] += 1;
                }
            }
        }
        let mut ptr = vec![0usize; n + 1];
        for v in 0..n {
            ptr[v + 1] = ptr[v] + degree[v];
        }
        let mut fill = ptr[..n].to_vec();
        let mut adj = vec![0usize; ptr[n]];
        for j in 0..n {
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                if i != j {
                    adj[fill[i]] = j;
                    fill[i] += 1;
                    adj[fill[j]] = i;
                    fill[j] += 1;
                }
            }
        }
        // A full pattern lists each edge twice: sort and drop the repeats.
        let mut out_ptr = vec![0usize; n + 1];
        let mut out = Vec::with_capacity(adj.len());
        for v in 0..n {
            let list = &mut adj[ptr[v]..ptr[v + 1]];
            list.sort_unstable();
            let start = out.len();
            for &u in list.iter() {
                if out.len() == start || out[out.len() - 1] != u {
                    out.push(u);
                }
            }
            out_ptr[v + 1] = out.len();
        }
        Graph {
            ptr: out_ptr,
            adj: out,
        }
    }

    fn neighbours(&self, v: usize) -> &[usize] {
        &self.adj[self.ptr[v]..self.ptr[v + 1]]
    }
}

/// Scratch shared by all pieces; `level` is reset after each use.
struct Work {
    /// Piece each unplaced vertex belongs to.
    label: Vec<usize>,
    /// BFS level within the current piece (usize::MAX = not reached).
    level: Vec<usize>,
    /// Local index of a leaf vertex when building its induced subgraph.
    local: Vec<usize>,
    next_label: usize,
    /// Side of each vertex of the piece being bisected (LOWER, UPPER, SEPARATOR).
    side: Vec<u8>,
    /// Refinement gains of separator vertices towards each side.
    gain: Vec<[i64; 2]>,
    locked: Vec<bool>,
}

/// A piece of the graph to order into `out[start..start + vertices.len()]`.
struct Piece {
    vertices: Vec<usize>,
    start: usize,
}

/// Fill-reducing ordering of the symmetric pattern (CSC, upper or full; the
/// diagonal is ignored). Returns `perm` with `perm[new] = old`.
pub(crate) fn nested_dissection(n: usize, col_ptr: &[usize], row_idx: &[usize]) -> Vec<usize> {
    let graph = Graph::from_pattern(n, col_ptr, row_idx);
    let mut work = Work {
        label: vec![0; n],
        level: vec![usize::MAX; n],
        local: vec![usize::MAX; n],
        next_label: 1,
        side: vec![0; n],
        gain: vec![[0; 2]; n],
        locked: vec![false; n],
    };
    let mut out = vec![usize::MAX; n];
    let mut stack = vec![Piece {
        vertices: (0..n).collect(),
        start: 0,
    }];
    while let Some(piece) = stack.pop() {
        if piece.vertices.is_empty() {
            continue;
        }
        if piece.vertices.len() <= LEAF_SIZE {
            order_leaf(&graph, &mut work, &piece, &mut out);
            continue;
        }
        let label = work.label[piece.vertices[0]];
        let levels = bfs_levels(&graph, &mut work, label, piece.vertices[0]);
        let reached: usize = levels.iter().map(Vec::len).sum();
        if reached < piece.vertices.len() {
            // Disconnected: this component first, the rest after it.
            let component: Vec<usize> = levels.into_iter().flatten().collect();
            let rest: Vec<usize> = piece
                .vertices
                .iter()
                .copied()
                .filter(|&v| work.level[v] == usize::MAX)
                .collect();
            reset_levels(&mut work, &component);
            let split = piece.start + component.len();
            relabel(&mut work, &rest);
            stack.push(Piece {
                vertices: rest,
                start: split,
            });
            stack.push(Piece {
                vertices: component,
                start: piece.start,
            });
            continue;
        }
        reset_levels(&mut work, &piece.vertices);
        match bisect(&graph, &mut work, label, &piece.vertices) {
            Some((lower, upper, separator)) => {
                if std::env::var_os("ND_DEBUG").is_some() && piece.vertices.len() > 2000 {
                    eprintln!(
                        "piece {} -> {} / {} / sep {}",
                        piece.vertices.len(),
                        lower.len(),
                        upper.len(),
                        separator.len()
                    );
                }
                let upper_start = piece.start + lower.len();
                let separator_start = upper_start + upper.len();
                for (k, &v) in separator.iter().enumerate() {
                    out[separator_start + k] = v;
                    work.label[v] = PLACED;
                }
                relabel(&mut work, &lower);
                relabel(&mut work, &upper);
                stack.push(Piece {
                    vertices: upper,
                    start: upper_start,
                });
                stack.push(Piece {
                    vertices: lower,
                    start: piece.start,
                });
            }
            // Too dense to cut (diameter ≤ 2): AMD does as well as anything.
            None => order_leaf(&graph, &mut work, &piece, &mut out),
        }
    }
    debug_assert!(out.iter().all(|&v| v < n));
    out
}

fn relabel(work: &mut Work, vertices: &[usize]) {
    let label = work.next_label;
    work.next_label += 1;
    for &v in vertices {
        work.label[v] = label;
    }
}

fn reset_levels(work: &mut Work, vertices: &[usize]) {
    for &v in vertices {
        work.level[v] = usize::MAX;
    }
}

/// BFS within the piece `label` from `root`; leaves `work.level` set for the
/// reached vertices (the caller resets it).
fn bfs_levels(graph: &Graph, work: &mut Work, label: usize, root: usize) -> Vec<Vec<usize>> {
    let mut levels = vec![vec![root]];
    work.level[root] = 0;
    loop {
        let depth = levels.len();
        let mut next = Vec::new();
        for &v in &levels[depth - 1] {
            for &u in graph.neighbours(v) {
                if work.label[u] == label && work.level[u] == usize::MAX {
                    work.level[u] = depth;
                    next.push(u);
                }
            }
        }
        if next.is_empty() {
            return levels;
        }
        levels.push(next);
    }
}

/// Degree of `v` within the piece `label`.
fn piece_degree(graph: &Graph, work: &Work, label: usize, v: usize) -> usize {
    graph
        .neighbours(v)
        .iter()
        .filter(|&&u| work.label[u] == label)
        .count()
}

/// Splits a connected piece into (lower, upper, separator) with no edge between
/// lower and upper, or None when no level cut leaves both sides non-empty.
fn bisect(
    graph: &Graph,
    work: &mut Work,
    label: usize,
    vertices: &[usize],
) -> Option<(Vec<usize>, Vec<usize>, Vec<usize>)> {
    // Pseudo-peripheral root: restart from a minimum-degree vertex of the last
    // level while the eccentricity grows.
    let mut root = vertices[0];
    let mut levels = bfs_levels(graph, work, label, root);
    for _ in 1..PERIPHERAL_SWEEPS {
        let last = levels.last().expect("BFS has a root level");
        let candidate = *last
            .iter()
            .min_by_key(|&&v| (piece_degree(graph, work, label, v), v))
            .expect("levels are non-empty");
        reset_levels(work, vertices);
        let trial = bfs_levels(graph, work, label, candidate);
        if trial.len() <= levels.len() {
            reset_levels(work, vertices);
            levels = bfs_levels(graph, work, label, root);
            break;
        }
        root = candidate;
        levels = trial;
    }
    let depth = levels.len();
    if depth < 3 {
        reset_levels(work, vertices);
        return None;
    }
    // For the cut between levels l and l + 1: vertices of l touching l + 1, and
    // vertices of l + 1 touching l. Either set separates.
    let mut touch_up = vec![0usize; depth];
    let mut touch_down = vec![0usize; depth];
    for (l, level) in levels.iter().enumerate() {
        for &v in level {
            let (mut up, mut down) = (false, false);
            for &u in graph.neighbours(v) {
                if work.label[u] != label {
                    continue;
                }
                let lu = work.level[u];
                up |= lu == l + 1;
                down |= l > 0 && lu == l - 1;
            }
            touch_up[l] += usize::from(up);
            touch_down[l] += usize::from(down);
        }
    }
    let total = vertices.len();
    let mut below = 0usize;
    // (score, level l, separator taken from level l (true) or l + 1 (false))
    let mut best: Option<(f64, usize, bool)> = None;
    let mut fallback: Option<(f64, usize, bool)> = None;
    for l in 0..depth - 1 {
        let here = levels[l].len();
        for from_lower in [true, false] {
            let sep = if from_lower {
                touch_up[l]
            } else {
                touch_down[l + 1]
            };
            // Vertices of the separator's level not in it join their own side.
            let lower = if from_lower {
                below + here - sep
            } else {
                below + here
            };
            let upper = total - lower - sep;
            if lower == 0 || upper == 0 {
                continue;
            }
            let score = sep as f64 * total as f64 / (lower as f64 * upper as f64);
            let candidate = Some((score, l, from_lower));
            let small_side = lower.min(upper) as f64;
            let slot = if small_side >= MIN_SIDE_FRACTION * total as f64 {
                &mut best
            } else {
                &mut fallback
            };
            if slot.is_none_or(|(s, _, _)| score < s) {
                *slot = candidate;
            }
        }
        below += here;
    }
    let Some((_, cut, from_lower)) = best.or(fallback) else {
        reset_levels(work, vertices);
        return None;
    };
    let (mut lower, mut upper, mut separator) = (Vec::new(), Vec::new(), Vec::new());
    for (l, level) in levels.iter().enumerate() {
        for &v in level {
            let side = if l < cut || (l == cut && !from_lower) {
                0
            } else if l > cut + 1 || (l == cut + 1 && from_lower) {
                2
            } else {
                // On the separator's level: in it only if touching the other side.
                let other = if from_lower { cut + 1 } else { cut };
                let touches = graph
                    .neighbours(v)
                    .iter()
                    .any(|&u| work.label[u] == label && work.level[u] == other);
                if touches {
                    1
                } else if from_lower {
                    0
                } else {
                    2
                }
            };
            match side {
                0 => lower.push(v),
                1 => separator.push(v),
                _ => upper.push(v),
            }
        }
    }
    reset_levels(work, vertices);
    for (list, side) in [(&lower, LOWER), (&upper, UPPER), (&separator, SEPARATOR)] {
        for &v in list {
            work.side[v] = side;
        }
    }
    refine_separator(graph, work, label, &separator, [lower.len(), upper.len()]);
    let (mut lower, mut upper, mut separator) = (Vec::new(), Vec::new(), Vec::new());
    for &v in vertices {
        match work.side[v] {
            LOWER => lower.push(v),
            UPPER => upper.push(v),
            _ => separator.push(v),
        }
    }
    (!lower.is_empty() && !upper.is_empty()).then_some((lower, upper, separator))
}

const LOWER: u8 = 0;
const UPPER: u8 = 1;
const SEPARATOR: u8 = 2;

/// Fiduccia–Mattheyses refinement of a vertex separator (as in METIS's node
/// refinement): a separator vertex moves to one side and pulls its neighbours
/// on the other side into the separator. Moves are taken best gain first, each
/// vertex at most once per pass, uphill moves allowed for a while, and each pass
/// rolls back to its best state (smallest |S| · n / (|A| · |B|)). Level cuts are
/// wavefronts, longer than straight cuts; this straightens them.
fn refine_separator(
    graph: &Graph,
    work: &mut Work,
    label: usize,
    separator: &[usize],
    sides: [usize; 2],
) {
    use std::cmp::Reverse;
    use std::collections::BinaryHeap;
    let mut weight = [sides[0], sides[1], separator.len()];
    let total = weight[0] + weight[1] + weight[2];
    let score = |w: &[usize; 3]| {
        if w[0] == 0 || w[1] == 0 {
            f64::INFINITY
        } else {
            w[2] as f64 * total as f64 / (w[0] as f64 * w[1] as f64)
        }
    };
    let max_side = ((1.0 - MIN_SIDE_FRACTION) * total as f64) as usize;
    let mut in_separator: Vec<usize> = separator.to_vec();
    for _ in 0..REFINE_PASSES {
        let start_score = score(&weight);
        // gain[k] of moving v to side k = 1 − (neighbours of v on side 1 − k).
        let gain_of = |work: &Work, v: usize, k: u8| -> i64 {
            let other = 1 - k;
            let pulled = graph
                .neighbours(v)
                .iter()
                .filter(|&&u| work.label[u] == label && work.side[u] == other)
                .count();
            1 - pulled as i64
        };
        let mut heaps = [BinaryHeap::new(), BinaryHeap::new()];
        for &v in &in_separator {
            for k in [LOWER, UPPER] {
                let g = gain_of(work, v, k);
                work.gain[v][k as usize] = g;
                heaps[k as usize].push((g, Reverse(v)));
            }
        }
        let mut log: Vec<(usize, u8)> = Vec::new();
        let mut moved: Vec<usize> = Vec::new();
        let (mut best_score, mut best_len) = (start_score, 0usize);
        let mut since_best = 0usize;
        loop {
            // Top valid entry of each heap (lazy deletion of stale gains).
            let mut top = [None, None];
            for k in 0..2 {
                while let Some(&(g, Reverse(v))) = heaps[k].peek() {
                    if work.side[v] == SEPARATOR && !work.locked[v] && work.gain[v][k] == g {
                        top[k] = Some((g, v));
                        break;
                    }
                    heaps[k].pop();
                }
            }
            let fits = |k: usize, g: i64| {
                weight[k] + 1 <= max_side && {
                    // The side losing vertices must not become empty.
                    let pulled = (1 - g) as usize;
                    weight[1 - k] > pulled
                }
            };
            let lighter = if weight[0] <= weight[1] { 0 } else { 1 };
            let mut order = [lighter, 1 - lighter];
            if let (Some((g0, _)), Some((g1, _))) = (top[order[0]], top[order[1]]) {
                if g1 > g0 {
                    order.swap(0, 1);
                }
            }
            let Some((k, v)) = order
                .iter()
                .find_map(|&k| top[k].filter(|&(g, _)| fits(k, g)).map(|(_, v)| (k, v)))
            else {
                break;
            };
            let side = k as u8;
            let other = 1 - side;
            heaps[k].pop();
            work.locked[v] = true;
            moved.push(v);
            log.push((v, SEPARATOR));
            work.side[v] = side;
            weight[2] -= 1;
            weight[k] += 1;
            // Separator neighbours of v now see one more vertex on `side`.
            for &w in graph.neighbours(v) {
                if work.label[w] == label && work.side[w] == SEPARATOR && !work.locked[w] {
                    work.gain[w][1 - k] -= 1;
                    heaps[1 - k].push((work.gain[w][1 - k], Reverse(w)));
                }
            }
            for &u in graph.neighbours(v) {
                if work.label[u] != label || work.side[u] != other {
                    continue;
                }
                log.push((u, other));
                work.side[u] = SEPARATOR;
                weight[1 - k] -= 1;
                weight[2] += 1;
                in_separator.push(u);
                // Separator neighbours of u see one vertex fewer on `other`.
                for &w in graph.neighbours(u) {
                    if work.label[w] == label
                        && work.side[w] == SEPARATOR
                        && !work.locked[w]
                        && w != u
                    {
                        work.gain[w][k] += 1;
                        heaps[k].push((work.gain[w][k], Reverse(w)));
                    }
                }
                if !work.locked[u] {
                    for j in [LOWER, UPPER] {
                        let g = gain_of(work, u, j);
                        work.gain[u][j as usize] = g;
                        heaps[j as usize].push((g, Reverse(u)));
                    }
                }
            }
            let now = score(&weight);
            if now < best_score {
                best_score = now;
                best_len = log.len();
                since_best = 0;
            } else {
                since_best += 1;
                if since_best > UPHILL_MOVES {
                    break;
                }
            }
        }
        for &(v, previous) in log[best_len..].iter().rev() {
            let current = work.side[v];
            weight[current as usize] -= 1;
            weight[previous as usize] += 1;
            work.side[v] = previous;
        }
        for &v in &moved {
            work.locked[v] = false;
        }
        in_separator.retain(|&v| work.side[v] == SEPARATOR);
        in_separator.sort_unstable();
        in_separator.dedup();
        if best_score >= start_score {
            break;
        }
    }
}

/// AMD on the subgraph induced by the piece, written to its output slots.
fn order_leaf(graph: &Graph, work: &mut Work, piece: &Piece, out: &mut [usize]) {
    let vertices = &piece.vertices;
    let m = vertices.len();
    let label = work.label[vertices[0]];
    for (k, &v) in vertices.iter().enumerate() {
        work.local[v] = k;
    }
    let mut col_ptr = Vec::with_capacity(m + 1);
    col_ptr.push(0usize);
    let mut row_idx = Vec::new();
    for &v in vertices {
        let begin = row_idx.len();
        for &u in graph.neighbours(v) {
            if work.label[u] == label {
                row_idx.push(work.local[u]);
            }
        }
        row_idx[begin..].sort_unstable();
        col_ptr.push(row_idx.len());
    }
    let mut perm = vec![0usize; m];
    let mut perm_inv = vec![0usize; m];
    let pattern = SymbolicSparseColMatRef::new_checked(m, m, &col_ptr, None, &row_idx);
    let mut buffer = MemBuffer::new(amd::order_scratch::<usize>(m, row_idx.len()));
    let ordered = amd::order(
        &mut perm,
        &mut perm_inv,
        pattern,
        amd::Control::default(),
        MemStack::new(&mut buffer),
    );
    for (k, &v) in vertices.iter().enumerate() {
        work.local[v] = usize::MAX;
        work.label[v] = PLACED;
        // AMD only fails on index overflow, impossible at leaf size; keep the
        // given order then.
        let local = if ordered.is_ok() { perm[k] } else { k };
        out[piece.start + k] = vertices[local];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::perm::PermRef;
    use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, SymmetricOrdering};
    use faer::Side;

    /// Upper pattern (with diagonal) of a k×k grid with the 9-point stencil.
    fn grid(k: usize) -> (usize, Vec<usize>, Vec<usize>) {
        let n = k * k;
        let mut col_ptr = vec![0];
        let mut row_idx = Vec::new();
        for j in 0..n {
            let (x, y) = (j % k, j / k);
            let mut rows = Vec::new();
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx >= 0 && ny >= 0 && (nx as usize) < k && (ny as usize) < k {
                        let i = ny as usize * k + nx as usize;
                        if i <= j {
                            rows.push(i);
                        }
                    }
                }
            }
            rows.sort_unstable();
            row_idx.extend(rows);
            col_ptr.push(row_idx.len());
        }
        (n, col_ptr, row_idx)
    }

    fn is_permutation(perm: &[usize]) -> bool {
        let mut seen = vec![false; perm.len()];
        perm.iter()
            .all(|&v| v < seen.len() && !std::mem::replace(&mut seen[v], true))
    }

    fn factor_nnz(n: usize, col_ptr: &[usize], row_idx: &[usize], perm: Option<&[usize]>) -> usize {
        let pattern = SymbolicSparseColMatRef::new_checked(n, n, col_ptr, None, row_idx);
        let inverse = perm.map(|p| {
            let mut inv = vec![0; n];
            for (new, &old) in p.iter().enumerate() {
                inv[old] = new;
            }
            inv
        });
        let ordering = match (perm, &inverse) {
            (Some(p), Some(inv)) => SymmetricOrdering::Custom(PermRef::new_checked(p, inv, n)),
            _ => SymmetricOrdering::Amd,
        };
        factorize_symbolic_cholesky(pattern, Side::Upper, ordering, Default::default())
            .expect("symbolic analysis")
            .len_val()
    }

    #[test]
    fn permutation_is_valid_and_deterministic() {
        let (n, col_ptr, row_idx) = grid(40);
        let perm = nested_dissection(n, &col_ptr, &row_idx);
        assert!(is_permutation(&perm));
        assert_eq!(perm, nested_dissection(n, &col_ptr, &row_idx));
    }

    #[test]
    fn handles_disconnected_and_trivial_graphs() {
        // Two disjoint grids and isolated vertices (diagonal only).
        let (m, cp, ri) = grid(30);
        let mut col_ptr = cp.clone();
        let mut row_idx = ri.clone();
        for j in 0..m {
            row_idx.extend(ri[cp[j]..cp[j + 1]].iter().map(|i| i + m));
            col_ptr.push(row_idx.len());
        }
        for j in 2 * m..2 * m + 500 {
            row_idx.push(j);
            col_ptr.push(row_idx.len());
        }
        let n = 2 * m + 500;
        assert!(is_permutation(&nested_dissection(n, &col_ptr, &row_idx)));
        assert!(nested_dissection(0, &[0], &[]).is_empty());
        // A full (both triangles) pattern gives the same graph as the upper one.
        let (n, col_ptr, row_idx) = grid(25);
        let mut full: Vec<Vec<usize>> = vec![Vec::new(); n];
        for j in 0..n {
            for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                full[j].push(i);
                if i != j {
                    full[i].push(j);
                }
            }
        }
        let mut fcp = vec![0];
        let mut fri = Vec::new();
        for mut col in full {
            col.sort_unstable();
            fri.extend(col);
            fcp.push(fri.len());
        }
        assert_eq!(
            nested_dissection(n, &fcp, &fri),
            nested_dissection(n, &col_ptr, &row_idx)
        );
    }

    #[test]
    fn fills_less_than_amd_on_a_grid() {
        let (n, col_ptr, row_idx) = grid(120);
        let perm = nested_dissection(n, &col_ptr, &row_idx);
        let nd = factor_nnz(n, &col_ptr, &row_idx, Some(&perm));
        let amd = factor_nnz(n, &col_ptr, &row_idx, None);
        assert!(
            nd < amd,
            "nested dissection {nd} vs AMD {amd} factor entries"
        );
    }
}
