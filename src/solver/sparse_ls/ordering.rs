//! Nested-dissection fill-reducing ordering of a symmetric sparsity pattern.
//!
//! Packings are spatial graphs (2D/3D) with small vertex separators; AMD is a
//! local greedy method and fills more on them, most of all in 3D. Each piece of
//! the graph is bisected by a multilevel scheme (as METIS): coarsen by
//! heavy-edge matching, cut the coarsest graph at a BFS level of a
//! pseudo-peripheral vertex, then project back refining the vertex separator by
//! Fiduccia–Mattheyses at every level. Separators are ordered after both halves,
//! disconnected pieces one after the other, small pieces by faer's AMD.
//!
//! The cuts are made on a quotient graph of weighted supervariables: the
//! vertices a caller labels as one block (a contact's unknowns), then twins
//! (equal neighbourhoods, as a grain's momentum rows). A 3D KKT pattern has a
//! quarter of its vertices there; leaves are still ordered vertex by vertex.
//!
//! Purely graph based (no coordinates), deterministic, O(nnz · log n).

use std::borrow::Cow;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::sparse::linalg::amd;
use faer::sparse::SymbolicSparseColMatRef;

/// Pieces with at most this many vertices are ordered by AMD.
const LEAF_SIZE: usize = 200;
/// Coarsening stops at this many vertices, or when a level shrinks too little.
const COARSEST_SIZE: usize = 120;
const MIN_SHRINK: f64 = 0.9;
/// Pseudo-peripheral search: at most this many BFS sweeps.
const PERIPHERAL_SWEEPS: usize = 4;
/// Each side of a cut must hold at least this fraction of the piece's weight.
const MIN_SIDE_FRACTION: f64 = 0.25;
/// Refinement passes per level, and uphill moves tried before a pass stops.
const REFINE_PASSES: usize = 6;
const UPHILL_MOVES: usize = 64;

/// Leaf halos up to this size are linked as a clique for AMD.
const HALO_CLIQUE_MAX: usize = 200;
/// Vertices with the same neighbourhood hash compared with each new
/// supervariable: bounds the cost on adversarial patterns.
const TWIN_CANDIDATES: usize = 64;

const LOWER: u8 = 0;
const UPPER: u8 = 1;
const SEPARATOR: u8 = 2;

/// Undirected graph without self loops, vertex and edge weights, CSR.
#[derive(Clone)]
struct Graph {
    ptr: Vec<usize>,
    adj: Vec<usize>,
    edge_weight: Vec<usize>,
    weight: Vec<usize>,
}

impl Graph {
    fn len(&self) -> usize {
        self.weight.len()
    }

    fn neighbours(&self, v: usize) -> &[usize] {
        &self.adj[self.ptr[v]..self.ptr[v + 1]]
    }

    fn edges(&self, v: usize) -> impl Iterator<Item = (usize, usize)> + '_ {
        let r = self.ptr[v]..self.ptr[v + 1];
        self.adj[r.clone()]
            .iter()
            .copied()
            .zip(self.edge_weight[r].iter().copied())
    }

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
        let edges = out.len();
        Graph {
            ptr: out_ptr,
            adj: out,
            edge_weight: vec![1; edges],
            weight: vec![1; n],
        }
    }

    /// Subgraph induced by `vertices`, with their weights; `local` must be
    /// usize::MAX on entry and is left so.
    fn induced(&self, vertices: &[usize], local: &mut [usize]) -> Graph {
        for (k, &v) in vertices.iter().enumerate() {
            local[v] = k;
        }
        let mut ptr = Vec::with_capacity(vertices.len() + 1);
        ptr.push(0);
        let mut adj = Vec::new();
        let mut edge_weight = Vec::new();
        for &v in vertices {
            for (u, w) in self.edges(v) {
                if local[u] != usize::MAX {
                    adj.push(local[u]);
                    edge_weight.push(w);
                }
            }
            ptr.push(adj.len());
        }
        for &v in vertices {
            local[v] = usize::MAX;
        }
        Graph {
            ptr,
            adj,
            edge_weight,
            weight: vertices.iter().map(|&v| self.weight[v]).collect(),
        }
    }

    /// Twins: vertices with equal closed neighbourhoods (a contact's
    /// tangential components) or equal open ones (a grain's momentum rows, which
    /// meet only through the unknowns). Returns each vertex's group, numbered
    /// by smallest member, and the group count. Neighbour lists must be sorted.
    fn twin_groups(&self) -> (Vec<usize>, usize) {
        let n = self.len();
        let degree = |v: usize| self.ptr[v + 1] - self.ptr[v];
        // Twins have equal neighbourhood index sums (with or without
        // themselves) and degrees.
        let open_sum: Vec<usize> = (0..n)
            .map(|v| {
                self.neighbours(v)
                    .iter()
                    .fold(0usize, |h, &u| h.wrapping_add(u))
            })
            .collect();
        // Vertices sorted by (key, degree), each one's place in that order,
        // and the keys; isolated vertices have no twins.
        let buckets = |key: Vec<usize>| {
            let mut sorted: Vec<usize> = (0..n).filter(|&v| degree(v) > 0).collect();
            sorted.sort_unstable_by_key(|&v| (key[v], degree(v), v));
            let mut position = vec![usize::MAX; n];
            for (k, &v) in sorted.iter().enumerate() {
                position[v] = k;
            }
            (sorted, position, key)
        };
        let closed_sum = (0..n).map(|v| open_sum[v].wrapping_add(v)).collect();
        let both = [buckets(closed_sum), buckets(open_sum)];
        let twins = |u: usize, v: usize| {
            // Adjacent twins' lists differ by each other only.
            let (nu, nv) = (self.neighbours(u), self.neighbours(v));
            if nu.binary_search(&v).is_ok() {
                nu.iter()
                    .filter(|&&x| x != v)
                    .eq(nv.iter().filter(|&&x| x != u))
            } else {
                nu == nv
            }
        };
        let mut group = vec![usize::MAX; n];
        let mut count = 0;
        for v in 0..n {
            if group[v] != usize::MAX {
                continue;
            }
            group[v] = count;
            if degree(v) > 0 {
                for (sorted, position, key) in &both {
                    let bucket = (key[v], degree(v));
                    let candidates = sorted[position[v] + 1..]
                        .iter()
                        .take_while(|&&u| (key[u], degree(u)) == bucket)
                        .take(TWIN_CANDIDATES);
                    for &u in candidates {
                        if group[u] == usize::MAX && twins(u, v) {
                            group[u] = count;
                        }
                    }
                }
            }
            count += 1;
        }
        (group, count)
    }

    /// The quotient graph of `group` (ids below `count`): weights and edge
    /// weights summed, loops dropped, neighbour lists sorted.
    fn contract(&self, group: &[usize], count: usize) -> Graph {
        let groups = Supervariables::from_groups(group, count);
        let mut ptr = Vec::with_capacity(count + 1);
        ptr.push(0);
        let mut adj = Vec::new();
        let mut edge_weight = Vec::new();
        let mut weight = vec![0usize; count];
        let mut slot = vec![usize::MAX; count];
        for g in 0..count {
            let begin = adj.len();
            for &v in &groups.members[groups.ptr[g]..groups.ptr[g + 1]] {
                weight[g] += self.weight[v];
                for (u, w) in self.edges(v) {
                    let h = group[u];
                    if h == g {
                        continue;
                    }
                    if slot[h] == usize::MAX {
                        slot[h] = adj.len();
                        adj.push(h);
                        edge_weight.push(w);
                    } else {
                        edge_weight[slot[h]] += w;
                    }
                }
            }
            for &h in &adj[begin..] {
                slot[h] = usize::MAX;
            }
            let mut list: Vec<(usize, usize)> = adj[begin..]
                .iter()
                .copied()
                .zip(edge_weight[begin..].iter().copied())
                .collect();
            list.sort_unstable();
            for (k, (h, w)) in list.into_iter().enumerate() {
                adj[begin + k] = h;
                edge_weight[begin + k] = w;
            }
            ptr.push(adj.len());
        }
        Graph {
            ptr,
            adj,
            edge_weight,
            weight,
        }
    }

    /// Heavy-edge matching and contraction: the coarse graph and the coarse
    /// vertex of each vertex.
    fn coarsen(&self) -> (Graph, Vec<usize>) {
        let n = self.len();
        let mut map = vec![usize::MAX; n];
        // Low-degree vertices first: they have the fewest chances to match.
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&v| (self.ptr[v + 1] - self.ptr[v], v));
        let mut coarse_n = 0;
        for &v in &order {
            if map[v] != usize::MAX {
                continue;
            }
            let partner = self
                .edges(v)
                .filter(|&(u, _)| map[u] == usize::MAX)
                .max_by_key(|&(u, w)| (w, Reverse(self.weight[u]), Reverse(u)))
                .map(|(u, _)| u);
            map[v] = coarse_n;
            if let Some(u) = partner {
                map[u] = coarse_n;
            }
            coarse_n += 1;
        }
        (self.contract(&map, coarse_n), map)
    }

    /// BFS from `root`; the levels, and each reached vertex's level in `level`
    /// (usize::MAX elsewhere; `level` must be all usize::MAX on entry).
    fn bfs(&self, root: usize, level: &mut [usize]) -> Vec<Vec<usize>> {
        level[root] = 0;
        let mut levels = vec![vec![root]];
        loop {
            let depth = levels.len();
            let mut next = Vec::new();
            for &v in &levels[depth - 1] {
                for &u in self.neighbours(v) {
                    if level[u] == usize::MAX {
                        level[u] = depth;
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
}

/// A piece of the graph to order into `out[start..start + its weight]`.
struct Piece {
    vertices: Vec<usize>,
    start: usize,
}

/// Members of each supervariable: `members[ptr[s]..ptr[s + 1]]`.
struct Supervariables {
    ptr: Vec<usize>,
    members: Vec<usize>,
}

impl Supervariables {
    /// From each vertex's supervariable (ids below `count`); members ascend.
    fn from_groups(group: &[usize], count: usize) -> Self {
        let mut ptr = vec![0usize; count + 1];
        for &g in group {
            ptr[g + 1] += 1;
        }
        for g in 0..count {
            ptr[g + 1] += ptr[g];
        }
        let mut fill = ptr.clone();
        let mut members = vec![0usize; group.len()];
        for (v, &g) in group.iter().enumerate() {
            members[fill[g]] = v;
            fill[g] += 1;
        }
        Supervariables { ptr, members }
    }

    /// The original vertices of some supervariables, each one's together.
    fn expand(&self, supervariables: &[usize]) -> Vec<usize> {
        supervariables
            .iter()
            .flat_map(|&s| self.members[self.ptr[s]..self.ptr[s + 1]].iter().copied())
            .collect()
    }
}

/// The graph of `blocks` (one vertex per label; labels are vertices) and
/// then, when `merge_twins`, of its twins, with each of its vertices'
/// members. Borrows `graph` when nothing merges.
fn quotient<'g>(
    graph: &'g Graph,
    blocks: Option<&[usize]>,
    merge_twins: bool,
) -> (Cow<'g, Graph>, Supervariables) {
    let n = graph.len();
    let mut quotient = Cow::Borrowed(graph);
    let (mut group, mut count) = match blocks {
        Some(labels) => {
            debug_assert!(labels.len() == n && labels.iter().all(|&l| l < n));
            // Labels renumbered 0.. by first appearance.
            let mut id = vec![usize::MAX; n];
            let mut count = 0;
            let group: Vec<usize> = labels
                .iter()
                .map(|&label| {
                    if id[label] == usize::MAX {
                        id[label] = count;
                        count += 1;
                    }
                    id[label]
                })
                .collect();
            if count < n {
                quotient = Cow::Owned(graph.contract(&group, count));
            }
            (group, count)
        }
        None => ((0..n).collect(), n),
    };
    if merge_twins {
        let (twin, twin_count) = quotient.twin_groups();
        if twin_count < count {
            quotient = Cow::Owned(quotient.contract(&twin, twin_count));
            group.iter_mut().for_each(|g| *g = twin[*g]);
            count = twin_count;
        }
    }
    (quotient, Supervariables::from_groups(&group, count))
}

/// Fill-reducing ordering of the symmetric pattern (CSC, upper or full; the
/// diagonal is ignored). Returns `perm` with `perm[new] = old`.
///
/// `blocks`, if given, labels vertices the caller knows belong together (a
/// contact's unknowns): vertices with one label are dissected as one, which
/// also makes the rows that meet them twins. Only separators and pieces are
/// chosen on blocks; each leaf is ordered vertex by vertex.
pub(crate) fn nested_dissection(
    n: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
    blocks: Option<&[usize]>,
) -> Vec<usize> {
    dissect(n, col_ptr, row_idx, blocks, true)
}

/// Nested dissection of the quotient graph (see [`quotient`]), leaves
/// ordered on the full graph.
fn dissect(
    n: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
    blocks: Option<&[usize]>,
    merge_twins: bool,
) -> Vec<usize> {
    let graph = Graph::from_pattern(n, col_ptr, row_idx);
    let (quotient, supervariables) = quotient(&graph, blocks, merge_twins);
    let mut local = vec![usize::MAX; quotient.len()];
    let mut original_local = vec![usize::MAX; n];
    let mut out = vec![usize::MAX; n];
    let weight_of = |vs: &[usize]| -> usize { vs.iter().map(|&v| quotient.weight[v]).sum() };
    let mut order_leaf = |piece: &Piece, out: &mut [usize]| {
        let leaf = Piece {
            vertices: supervariables.expand(&piece.vertices),
            start: piece.start,
        };
        order_by_amd(&graph, &leaf, &mut original_local, out);
    };
    let mut stack = vec![Piece {
        vertices: (0..quotient.len()).collect(),
        start: 0,
    }];
    while let Some(piece) = stack.pop() {
        if piece.vertices.is_empty() {
            continue;
        }
        if weight_of(&piece.vertices) <= LEAF_SIZE {
            order_leaf(&piece, &mut out);
            continue;
        }
        let sub = quotient.induced(&piece.vertices, &mut local);
        let mut level = vec![usize::MAX; sub.len()];
        let component = sub.bfs(0, &mut level);
        let reached: usize = component.iter().map(Vec::len).sum();
        if reached < sub.len() {
            // Disconnected: this component first, the rest after it.
            let (first, rest): (Vec<usize>, Vec<usize>) =
                (0..sub.len()).partition(|&k| level[k] != usize::MAX);
            let to_global = |ks: Vec<usize>| -> Vec<usize> {
                ks.into_iter().map(|k| piece.vertices[k]).collect()
            };
            let first = to_global(first);
            stack.push(Piece {
                vertices: to_global(rest),
                start: piece.start + weight_of(&first),
            });
            stack.push(Piece {
                vertices: first,
                start: piece.start,
            });
            continue;
        }
        let Some(side) = bisect(&sub) else {
            // Too dense to cut: AMD does as well as anything.
            order_leaf(&piece, &mut out);
            continue;
        };
        let mut parts: [Vec<usize>; 3] = Default::default();
        for (k, &v) in piece.vertices.iter().enumerate() {
            parts[side[k] as usize].push(v);
        }
        let [lower, upper, separator] = parts;
        debug_assert!((0..sub.len())
            .all(|v| side[v] != LOWER || sub.neighbours(v).iter().all(|&u| side[u] != UPPER)));
        let upper_start = piece.start + weight_of(&lower);
        let separator_start = upper_start + weight_of(&upper);
        let separator = supervariables.expand(&separator);
        out[separator_start..separator_start + separator.len()].copy_from_slice(&separator);
        stack.push(Piece {
            vertices: upper,
            start: upper_start,
        });
        stack.push(Piece {
            vertices: lower,
            start: piece.start,
        });
    }
    debug_assert!(out.iter().all(|&v| v < n));
    out
}

/// Side (LOWER, UPPER, SEPARATOR) of each vertex of a connected graph, with no
/// edge between LOWER and UPPER and both non-empty; None if no cut was found.
fn bisect(graph: &Graph) -> Option<Vec<u8>> {
    let mut hierarchy: Vec<(Graph, Vec<usize>)> = Vec::new();
    loop {
        let current = hierarchy.last().map_or(graph, |(g, _)| g);
        if current.len() <= COARSEST_SIZE {
            break;
        }
        let (coarse, map) = current.coarsen();
        if coarse.len() as f64 > MIN_SHRINK * current.len() as f64 {
            break;
        }
        hierarchy.push((coarse, map));
    }
    let coarsest = hierarchy.last().map_or(graph, |(g, _)| g);
    let mut side = initial_cut(coarsest)?;
    refine(coarsest, &mut side);
    for k in (0..hierarchy.len()).rev() {
        let fine = if k == 0 { graph } else { &hierarchy[k - 1].0 };
        let map = &hierarchy[k].1;
        side = map.iter().map(|&c| side[c]).collect();
        refine(fine, &mut side);
    }
    let has = |s: u8| side.contains(&s);
    (has(LOWER) && has(UPPER)).then_some(side)
}

/// Weights of the three parts.
fn part_weights(graph: &Graph, side: &[u8]) -> [usize; 3] {
    let mut w = [0; 3];
    for (v, &s) in side.iter().enumerate() {
        w[s as usize] += graph.weight[v];
    }
    w
}

/// |S| · W / (|A| · |B|): small separators, balanced sides.
fn cut_score(w: &[usize; 3]) -> f64 {
    if w[0] == 0 || w[1] == 0 {
        return f64::INFINITY;
    }
    let total = (w[0] + w[1] + w[2]) as f64;
    w[2] as f64 * total / (w[0] as f64 * w[1] as f64)
}

/// Best BFS-level cut from a pseudo-peripheral vertex and from the far end of
/// its level structure, each refined; None when every level structure has
/// fewer than three levels.
fn initial_cut(graph: &Graph) -> Option<Vec<u8>> {
    let n = graph.len();
    let mut level = vec![usize::MAX; n];
    let degree = |v: usize| graph.ptr[v + 1] - graph.ptr[v];
    // The lowest-degree vertex of the last BFS level.
    let farthest = |levels: &[Vec<usize>]| -> usize {
        *levels
            .last()
            .expect("BFS has a root level")
            .iter()
            .min_by_key(|&&v| (degree(v), v))
            .expect("levels are non-empty")
    };
    let mut root = 0;
    let mut levels = graph.bfs(root, &mut level);
    for _ in 1..PERIPHERAL_SWEEPS {
        let far = farthest(&levels);
        level.fill(usize::MAX);
        let trial = graph.bfs(far, &mut level);
        if trial.len() <= levels.len() {
            break;
        }
        root = far;
        levels = trial;
    }
    let far = farthest(&levels);
    let mut best: Option<(f64, Vec<u8>)> = None;
    for start in [root, far] {
        level.fill(usize::MAX);
        let levels = graph.bfs(start, &mut level);
        if let Some(mut side) = level_cut(graph, &levels, &level) {
            refine(graph, &mut side);
            let score = cut_score(&part_weights(graph, &side));
            if best.as_ref().is_none_or(|(s, _)| score < *s) {
                best = Some((score, side));
            }
        }
    }
    best.map(|(_, side)| side)
}

/// The cut between two consecutive BFS levels with the best score; the
/// separator is the vertices of one of them that touch the other.
fn level_cut(graph: &Graph, levels: &[Vec<usize>], level: &[usize]) -> Option<Vec<u8>> {
    let depth = levels.len();
    if depth < 3 {
        return None;
    }
    let mut level_weight = vec![0usize; depth];
    let mut touch_up = vec![0usize; depth];
    let mut touch_down = vec![0usize; depth];
    for (l, vs) in levels.iter().enumerate() {
        for &v in vs {
            let w = graph.weight[v];
            level_weight[l] += w;
            let nb = graph.neighbours(v);
            if nb.iter().any(|&u| level[u] == l + 1) {
                touch_up[l] += w;
            }
            if l > 0 && nb.iter().any(|&u| level[u] == l - 1) {
                touch_down[l] += w;
            }
        }
    }
    let total: usize = level_weight.iter().sum();
    let mut below = 0usize;
    // (score, cut level l, separator drawn from level l (true) or l + 1)
    let mut best: Option<(f64, usize, bool)> = None;
    let mut fallback: Option<(f64, usize, bool)> = None;
    for l in 0..depth - 1 {
        for from_lower in [true, false] {
            let sep = if from_lower {
                touch_up[l]
            } else {
                touch_down[l + 1]
            };
            let lower = below + level_weight[l] - if from_lower { sep } else { 0 };
            let w = [lower, total - lower - sep, sep];
            let score = cut_score(&w);
            if !score.is_finite() {
                continue;
            }
            let balanced = w[0].min(w[1]) as f64 >= MIN_SIDE_FRACTION * total as f64;
            let slot = if balanced { &mut best } else { &mut fallback };
            if slot.is_none_or(|(s, _, _)| score < s) {
                *slot = Some((score, l, from_lower));
            }
        }
        below += level_weight[l];
    }
    let (_, cut, from_lower) = best.or(fallback)?;
    let side = (0..graph.len())
        .map(|v| {
            let l = level[v];
            let (sep_level, other, rest) = if from_lower {
                (cut, cut + 1, LOWER)
            } else {
                (cut + 1, cut, UPPER)
            };
            if l < cut || (l == cut && !from_lower) {
                LOWER
            } else if l > cut + 1 || (l == cut + 1 && from_lower) {
                UPPER
            } else if l == sep_level && graph.neighbours(v).iter().any(|&u| level[u] == other) {
                SEPARATOR
            } else {
                rest
            }
        })
        .collect();
    Some(side)
}

/// Fiduccia–Mattheyses refinement of a vertex separator (as METIS's node
/// refinement): a separator vertex moves to one side and pulls its neighbours on
/// the other side into the separator. Moves go best gain first, each vertex at
/// most once per pass, uphill for a while, and each pass rolls back to its best
/// state by [`cut_score`].
fn refine(graph: &Graph, side: &mut [u8]) {
    let n = graph.len();
    let mut weight = part_weights(graph, side);
    let total = weight[0] + weight[1] + weight[2];
    let max_side = ((1.0 - MIN_SIDE_FRACTION) * total as f64) as usize;
    let mut gain = vec![[0i64; 2]; n];
    let mut locked = vec![false; n];
    // gain of moving v to side k: w(v) − weight of its neighbours on side 1 − k.
    let gain_of = |side: &[u8], v: usize, k: usize| -> i64 {
        let pulled: usize = graph
            .neighbours(v)
            .iter()
            .filter(|&&u| side[u] as usize == 1 - k)
            .map(|&u| graph.weight[u])
            .sum();
        graph.weight[v] as i64 - pulled as i64
    };
    for _ in 0..REFINE_PASSES {
        let start_score = cut_score(&weight);
        let mut heaps = [BinaryHeap::new(), BinaryHeap::new()];
        for v in (0..n).filter(|&v| side[v] == SEPARATOR) {
            for (k, heap) in heaps.iter_mut().enumerate() {
                gain[v][k] = gain_of(side, v, k);
                heap.push((gain[v][k], Reverse(v)));
            }
        }
        let mut log: Vec<(usize, u8)> = Vec::new();
        let mut moved: Vec<usize> = Vec::new();
        let (mut best_score, mut best_len, mut since_best) = (start_score, 0usize, 0usize);
        loop {
            // Top valid entry of each heap (stale gains are skipped lazily).
            let mut top = [None, None];
            for (k, heap) in heaps.iter_mut().enumerate() {
                while let Some(&(g, Reverse(v))) = heap.peek() {
                    if side[v] == SEPARATOR && !locked[v] && gain[v][k] == g {
                        top[k] = Some((g, v));
                        break;
                    }
                    heap.pop();
                }
            }
            let fits = |k: usize, v: usize| {
                let pulled = (graph.weight[v] as i64 - gain[v][k]) as usize;
                weight[k] + graph.weight[v] <= max_side && weight[1 - k] > pulled
            };
            let lighter = usize::from(weight[0] > weight[1]);
            let mut order = [lighter, 1 - lighter];
            if let (Some((g0, _)), Some((g1, _))) = (top[order[0]], top[order[1]]) {
                if g1 > g0 {
                    order.swap(0, 1);
                }
            }
            let Some((k, v)) = order
                .iter()
                .find_map(|&k| top[k].filter(|&(_, v)| fits(k, v)).map(|(_, v)| (k, v)))
            else {
                break;
            };
            locked[v] = true;
            moved.push(v);
            log.push((v, SEPARATOR));
            side[v] = k as u8;
            weight[2] -= graph.weight[v];
            weight[k] += graph.weight[v];
            let wv = graph.weight[v] as i64;
            for &w in graph.neighbours(v) {
                if side[w] == SEPARATOR && !locked[w] {
                    // One more neighbour of w on side k.
                    gain[w][1 - k] -= wv;
                    heaps[1 - k].push((gain[w][1 - k], Reverse(w)));
                }
            }
            let other = (1 - k) as u8;
            for &u in graph.neighbours(v) {
                if side[u] != other {
                    continue;
                }
                log.push((u, other));
                side[u] = SEPARATOR;
                let wu = graph.weight[u];
                weight[1 - k] -= wu;
                weight[2] += wu;
                for &w in graph.neighbours(u) {
                    if side[w] == SEPARATOR && !locked[w] && w != u {
                        // One neighbour fewer of w on the other side.
                        gain[w][k] += wu as i64;
                        heaps[k].push((gain[w][k], Reverse(w)));
                    }
                }
                if !locked[u] {
                    for (j, heap) in heaps.iter_mut().enumerate() {
                        gain[u][j] = gain_of(side, u, j);
                        heap.push((gain[u][j], Reverse(u)));
                    }
                }
            }
            let now = cut_score(&weight);
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
            weight[side[v] as usize] -= graph.weight[v];
            weight[previous as usize] += graph.weight[v];
            side[v] = previous;
        }
        for &v in &moved {
            locked[v] = false;
        }
        if best_score >= start_score {
            break;
        }
    }
}

/// AMD on the piece together with its halo (the neighbouring vertices of the
/// ancestors' separators, eliminated later), written to the piece's output
/// slots. Without the halo, AMD sees the piece's border as a boundary of low
/// degree and eliminates it first, which drags the separators into every
/// front; the halo, linked as a clique (its vertices are coupled through the
/// pieces already eliminated), keeps them last (an approximate halo AMD).
fn order_by_amd(graph: &Graph, piece: &Piece, local: &mut [usize], out: &mut [usize]) {
    let m = piece.vertices.len();
    for (k, &v) in piece.vertices.iter().enumerate() {
        local[v] = k;
    }
    let mut halo: Vec<usize> = Vec::new();
    for &v in &piece.vertices {
        for &u in graph.neighbours(v) {
            if local[u] == usize::MAX {
                local[u] = m + halo.len();
                halo.push(u);
            }
        }
    }
    // A huge halo only arises for pieces too dense to cut; keep AMD cheap there.
    let clique = halo.len() <= HALO_CLIQUE_MAX;
    let size = m + halo.len();
    let mut col_ptr = Vec::with_capacity(size + 1);
    col_ptr.push(0usize);
    let mut row_idx = Vec::new();
    for &v in piece.vertices.iter().chain(&halo) {
        let begin = row_idx.len();
        let inside = local[v] < m;
        row_idx.extend(
            graph
                .neighbours(v)
                .iter()
                .map(|&u| local[u])
                .filter(|&k| k < m || (inside && k != usize::MAX)),
        );
        if !inside && clique {
            row_idx.extend((m..size).filter(|&k| k != local[v]));
        }
        row_idx[begin..].sort_unstable();
        col_ptr.push(row_idx.len());
    }
    for &v in piece.vertices.iter().chain(&halo) {
        local[v] = usize::MAX;
    }
    let mut perm = vec![0usize; size];
    let mut perm_inv = vec![0usize; size];
    let pattern = SymbolicSparseColMatRef::new_checked(size, size, &col_ptr, None, &row_idx);
    let mut buffer = MemBuffer::new(amd::order_scratch::<usize>(size, row_idx.len()));
    let ordered = amd::order(
        &mut perm,
        &mut perm_inv,
        pattern,
        amd::Control::default(),
        MemStack::new(&mut buffer),
    )
    .is_ok();
    // AMD fails only on index overflow; keep the given order then.
    let order: Vec<usize> = if ordered {
        perm.into_iter().filter(|&k| k < m).collect()
    } else {
        (0..m).collect()
    };
    for (k, &local_index) in order.iter().enumerate() {
        out[piece.start + k] = piece.vertices[local_index];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::perm::PermRef;
    use faer::sparse::linalg::cholesky::{
        factorize_symbolic_cholesky, CholeskySymbolicParams, SymmetricOrdering,
    };
    use faer::sparse::linalg::SupernodalThreshold;
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

    /// Exact number of entries of L (simplicial, so no supernodal padding).
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
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SIMPLICIAL,
            ..Default::default()
        };
        factorize_symbolic_cholesky(pattern, Side::Upper, ordering, params)
            .expect("symbolic analysis")
            .len_val()
    }

    #[test]
    fn permutation_is_valid_and_deterministic() {
        let (n, col_ptr, row_idx) = grid(40);
        let perm = nested_dissection(n, &col_ptr, &row_idx, None);
        assert!(is_permutation(&perm));
        assert_eq!(perm, nested_dissection(n, &col_ptr, &row_idx, None));
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
        assert!(is_permutation(&nested_dissection(
            n, &col_ptr, &row_idx, None
        )));
        assert!(nested_dissection(0, &[0], &[], None).is_empty());
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
            nested_dissection(n, &fcp, &fri, None),
            nested_dissection(n, &col_ptr, &row_idx, None)
        );
    }

    /// The largest cluster's system of a synthetic 3D packing.
    fn packing_system(grains: usize) -> crate::assemble::System {
        use crate::assemble::{assemble, AssembleOptions};
        use crate::bench::{generate, PackingSpec};
        let packing = generate(&PackingSpec::new(3, grains)).expect("packing");
        let assembly = assemble(&packing.scene, &AssembleOptions::default()).expect("assembly");
        assembly
            .systems
            .into_iter()
            .max_by_key(|s| s.n)
            .expect("a cluster")
    }

    #[test]
    fn fills_less_than_amd_on_a_3d_packing() {
        // The KKT matrix of a 1000-grain 3D packing (measured in release: ND
        // 1.53 M vs AMD 1.79 M factor entries, 0.86×).
        use crate::solver::sparse_ls::{EqualityLeastSquares, Ordering};
        let system = packing_system(1000);
        let mut ls = EqualityLeastSquares::with_coupling(
            &system.stress,
            &system.momentum,
            &system.contact_blocks(),
        )
        .expect("analysis");
        ls.set_ordering(Ordering::Amd).expect("AMD");
        let amd = ls.factor_nnz();
        ls.set_ordering(Ordering::NestedDissection).expect("ND");
        let nd = ls.factor_nnz();
        assert!(
            (nd as f64) < 0.92 * amd as f64,
            "nested dissection {nd} vs AMD {amd} factor entries"
        );
    }

    /// Upper pattern of `base` with each vertex replaced by a clique of
    /// `copies` twins (the Kronecker product with K_copies, self loops kept).
    fn with_twins(
        n: usize,
        col_ptr: &[usize],
        row_idx: &[usize],
        copies: usize,
    ) -> (usize, Vec<usize>, Vec<usize>) {
        let mut out_ptr = vec![0];
        let mut out_idx = Vec::new();
        for j in 0..n {
            for b in 0..copies {
                for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
                    let top = if i == j { b + 1 } else { copies };
                    out_idx.extend((0..top).map(|a| i * copies + a));
                }
                out_ptr.push(out_idx.len());
            }
        }
        (n * copies, out_ptr, out_idx)
    }

    #[test]
    fn twins_become_one_weighted_supervariable() {
        let (n, col_ptr, row_idx) = grid(12);
        let (m, cp, ri) = with_twins(n, &col_ptr, &row_idx, 3);
        let twinned = Graph::from_pattern(m, &cp, &ri);
        let (group, count) = twinned.twin_groups();
        assert_eq!(count, n);
        assert!((0..m).all(|v| group[v] == v / 3), "{group:?}");
        // The quotient is the grid, weighted by 3 per vertex and 3 · 3 per edge.
        let quotient = twinned.contract(&group, count);
        let plain = Graph::from_pattern(n, &col_ptr, &row_idx);
        assert_eq!(quotient.adj, plain.adj);
        assert!(quotient.weight.iter().all(|&w| w == 3));
        assert!(quotient.edge_weight.iter().all(|&w| w == 9));
        // Vertices whose neighbourhoods differ stay apart.
        assert_eq!(plain.twin_groups().1, n);
        // Open twins (equal neighbours, not adjacent): the leaves of a star.
        let star_ptr = [0, 1, 2, 3, 7];
        let star_idx = [0, 1, 2, 0, 1, 2, 3];
        let star = Graph::from_pattern(4, &star_ptr, &star_idx);
        assert_eq!(star.twin_groups(), (vec![0, 0, 0, 1], 2));
        // Twins change the cost, not the fill (measured: 12 636 entries with
        // twins merged, 13 122 without).
        let perm = nested_dissection(m, &cp, &ri, None);
        assert!(is_permutation(&perm));
        let merged = factor_nnz(m, &cp, &ri, Some(&perm));
        let apart = factor_nnz(m, &cp, &ri, Some(&dissect(m, &cp, &ri, None, false)));
        assert!(
            (merged as f64) < 1.05 * apart as f64,
            "twins merged {merged} vs apart {apart} factor entries"
        );
    }

    #[test]
    fn contact_blocks_fill_as_the_plain_graph_on_a_3d_packing() {
        // Dissecting contacts, not unknowns, and grains, not momentum rows
        // (measured on this 1000-grain packing: 4 300 supervariables of 14 700
        // vertices, fill 1.01 × the plain dissection's; at 10⁴ grains 0.28 ×
        // the vertices, 0.95 × the fill, a quarter of the time).
        use crate::solver::sparse_ls::kkt::kkt_blocks;
        use crate::solver::sparse_ls::EqualityLeastSquares;
        let system = packing_system(1000);
        let coupling = system.contact_blocks();
        let ls = EqualityLeastSquares::with_coupling(&system.stress, &system.momentum, &coupling)
            .expect("analysis");
        let (cp, ri) = (&ls.kkt_col_ptr, &ls.kkt_row_idx);
        let n = cp.len() - 1;
        let blocks = kkt_blocks(system.n, system.momentum.nrows, &coupling);
        // Each contact's unknowns carry its first unknown's label; every
        // label is a vertex of its own block.
        let mut first = vec![usize::MAX; coupling.nrows];
        for (&row, &col) in coupling.rows.iter().zip(&coupling.cols) {
            first[row] = first[row].min(col);
        }
        assert!(coupling
            .rows
            .iter()
            .zip(&coupling.cols)
            .all(|(&row, &col)| blocks[col] == first[row]));
        assert!(blocks.iter().all(|&label| blocks[label] == label));
        let graph = Graph::from_pattern(n, cp, ri);
        let (merged, _) = quotient(&graph, Some(&blocks), true);
        assert!(
            (merged.len() as f64) < 0.35 * n as f64,
            "{} supervariables of {n} vertices",
            merged.len()
        );
        let with_blocks = factor_nnz(
            n,
            cp,
            ri,
            Some(&nested_dissection(n, cp, ri, Some(&blocks))),
        );
        let plain = factor_nnz(n, cp, ri, Some(&dissect(n, cp, ri, None, false)));
        assert!(
            (with_blocks as f64) < 1.05 * plain as f64,
            "contact blocks {with_blocks} vs plain {plain} factor entries"
        );
    }

    #[test]
    fn fill_on_a_2d_grid_is_near_amd() {
        // On small regular grids AMD is hard to beat (measured: ND ≈ 1.16 × AMD
        // on this 120² 9-point grid, 1.06 × on a 22³ 7-point grid); guard
        // against gross regressions of the separators.
        let (n, col_ptr, row_idx) = grid(120);
        let perm = nested_dissection(n, &col_ptr, &row_idx, None);
        let nd = factor_nnz(n, &col_ptr, &row_idx, Some(&perm));
        let amd = factor_nnz(n, &col_ptr, &row_idx, None);
        assert!(
            (nd as f64) < 1.25 * amd as f64,
            "nested dissection {nd} vs AMD {amd} factor entries"
        );
    }
}
