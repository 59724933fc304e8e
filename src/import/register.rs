//! One scene from two instruments: per-grain stresses measured in one frame
//! (a 3D X-ray diffraction grain map: `import gff`, `import imaged11`, or any
//! CSV of positions and stresses) attached to the grains of another (a CT
//! label volume) by position.
//!
//! The two frames differ by a rigid transform, unknown: a diffraction
//! sample frame is set by the goniometer, a CT frame by the reconstruction.
//! [`register`] finds it from the centroids alone, with grains missing on
//! either side and noisy positions:
//!
//! 1. each centroid gets a rotation-invariant signature, the sorted distances
//!    to its nearest neighbours in its own set;
//! 2. hypotheses: a few seeds of the second set, each with the first-set
//!    points of most similar signature (after centring each set on its
//!    centroid, the distances from the centre must agree too: in a packing
//!    of like grains the neighbour distances alone do not tell grains apart;
//!    a second, uncentred round covers a field of view seen only in part); a seed's neighbours are paired with
//!    the candidate's by distance, and every consistent triangle (the seed
//!    and two neighbours whose mutual distance agrees too) gives a rigid
//!    transform by Kabsch's method, scored on the whole set (centroids that
//!    land within the match distance of one);
//! 3. the best hypotheses are refined by trimmed ICP: one-to-one
//!    nearest-neighbour pairs within the match distance, Kabsch on them,
//!    until the pairs stop changing; the refinement with most pairs (then
//!    least residual) wins.
//!
//! Stresses are rotated with the frame (σ' = R σ Rᵀ).

use crate::error::{Error, Result};
use crate::scene::{self, Scene, Sym, Vec3};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use std::collections::{HashMap, HashSet};
use std::path::Path;

pub type Mat3 = [[f64; 3]; 3];

/// How the second set is brought into the first's frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransformModel {
    /// Any rotation and translation (fitted).
    Rigid,
    /// The frames are the same: pairs by nearest neighbour only.
    Identity,
}

impl TransformModel {
    /// `rigid` or `none`.
    pub fn parse(text: &str) -> Result<TransformModel> {
        match text {
            "rigid" => Ok(TransformModel::Rigid),
            "none" => Ok(TransformModel::Identity),
            other => Err(Error::Invalid(format!(
                "the match transform must be rigid or none, got `{other}`"
            ))),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchOptions {
    /// Largest distance between matched centroids once the transform is
    /// applied [m]; `None`: 0.4 × the median nearest-neighbour spacing of
    /// the first set (grains in contact are about one spacing apart, so a
    /// match within 0.4 of it is unambiguous).
    pub max_distance: Option<f64>,
    pub transform: TransformModel,
    /// Seed of the choice of hypotheses (the result is deterministic).
    pub seed: u64,
}

impl Default for MatchOptions {
    fn default() -> Self {
        MatchOptions {
            max_distance: None,
            transform: TransformModel::Rigid,
            seed: 41,
        }
    }
}

/// The transform p ≈ R q + t taking the second set's positions q into the
/// first set's frame, and the pairs it makes.
#[derive(Debug, Clone, PartialEq)]
pub struct Registration {
    pub rotation: Mat3,
    pub translation: Vec3,
    /// (index in the first set, index in the second), by the first.
    pub pairs: Vec<(usize, usize)>,
    /// Distance of each pair once transformed [m], in `pairs` order.
    pub residuals: Vec<f64>,
    /// Root mean square of `residuals` [m].
    pub rms: f64,
    /// The match distance used [m].
    pub max_distance: f64,
    /// Median nearest-neighbour spacing of the first set [m].
    pub spacing: f64,
    pub unmatched_first: Vec<usize>,
    pub unmatched_second: Vec<usize>,
}

impl Registration {
    /// R q + t.
    pub fn apply(&self, q: Vec3) -> Vec3 {
        apply(&(self.rotation, self.translation), q)
    }

    /// Angle of the rotation [degrees].
    pub fn angle_degrees(&self) -> f64 {
        let r = &self.rotation;
        let c = ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0).clamp(-1.0, 1.0);
        c.acos().to_degrees()
    }
}

type Transform = (Mat3, Vec3);

/// (first index, second index, distance).
type Pair = (usize, usize, f64);

fn apply(t: &Transform, q: Vec3) -> Vec3 {
    let (r, d) = t;
    [
        r[0][0] * q[0] + r[0][1] * q[1] + r[0][2] * q[2] + d[0],
        r[1][0] * q[0] + r[1][1] * q[1] + r[1][2] * q[2] + d[1],
        r[2][0] * q[0] + r[2][1] * q[1] + r[2][2] * q[2] + d[2],
    ]
}

fn dist(a: Vec3, b: Vec3) -> f64 {
    scene::norm(scene::sub(a, b))
}

/// Points bucketed in cubes of edge `h`.
struct Grid<'a> {
    points: &'a [Vec3],
    h: f64,
    cells: HashMap<[i64; 3], Vec<usize>>,
}

impl<'a> Grid<'a> {
    fn new(points: &'a [Vec3], h: f64) -> Grid<'a> {
        let mut cells: HashMap<[i64; 3], Vec<usize>> = HashMap::new();
        for (i, &p) in points.iter().enumerate() {
            cells.entry(key(p, h)).or_default().push(i);
        }
        Grid { points, h, cells }
    }

    /// Calls `f(index, distance)` for every point within `r` of `p`.
    fn within(&self, p: Vec3, r: f64, mut f: impl FnMut(usize, f64)) {
        let lo = key(p.map(|x| x - r), self.h);
        let hi = key(p.map(|x| x + r), self.h);
        // A huge radius would visit every empty cell: scan the points instead.
        let span = (0..3).map(|k| (hi[k] - lo[k] + 1) as f64).product::<f64>();
        if span > 4.0 * self.points.len() as f64 {
            for (i, &q) in self.points.iter().enumerate() {
                let d = dist(p, q);
                if d <= r {
                    f(i, d);
                }
            }
            return;
        }
        for x in lo[0]..=hi[0] {
            for y in lo[1]..=hi[1] {
                for z in lo[2]..=hi[2] {
                    if let Some(list) = self.cells.get(&[x, y, z]) {
                        for &i in list {
                            let d = dist(p, self.points[i]);
                            if d <= r {
                                f(i, d);
                            }
                        }
                    }
                }
            }
        }
    }

    fn nearest(&self, p: Vec3, r: f64) -> Option<(usize, f64)> {
        let mut best: Option<(usize, f64)> = None;
        self.within(p, r, |i, d| {
            if best.is_none_or(|(j, e)| d < e || (d == e && i < j)) {
                best = Some((i, d));
            }
        });
        best
    }

    /// The `k` nearest other points of point `i` (distance, index), nearest first.
    fn neighbours(&self, i: usize, k: usize) -> Vec<(f64, usize)> {
        let p = self.points[i];
        let mut r = self.h;
        loop {
            let mut found = Vec::new();
            self.within(p, r, |j, d| {
                if j != i {
                    found.push((d, j));
                }
            });
            if found.len() >= k || found.len() + 1 >= self.points.len() {
                found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                found.truncate(k);
                return found;
            }
            r *= 2.0;
        }
    }
}

fn key(p: Vec3, h: f64) -> [i64; 3] {
    p.map(|x| (x / h).floor() as i64)
}

/// Edge of the grid's cells: the volume per point of the bounding box.
fn cell_size(points: &[Vec3]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in points {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let ext: Vec<f64> = (0..3).map(|k| hi[k] - lo[k]).collect();
    let largest = ext.iter().cloned().fold(0.0, f64::max);
    // A flat or thin set has no volume: fall back on its largest extent.
    let v: f64 = ext.iter().map(|&e| e.max(1e-3 * largest)).product();
    let h = (v / points.len() as f64).cbrt();
    if h > 0.0 && h.is_finite() {
        h
    } else {
        1.0
    }
}

/// Least-squares rotation and translation with p ≈ R q + t (Kabsch, proper
/// rotation), over pairs (p, q).
fn kabsch(pairs: &[(Vec3, Vec3)]) -> Option<Transform> {
    if pairs.len() < 3 {
        return None;
    }
    let n = pairs.len() as f64;
    let mut cp = [0.0; 3];
    let mut cq = [0.0; 3];
    for (p, q) in pairs {
        for k in 0..3 {
            cp[k] += p[k] / n;
            cq[k] += q[k] / n;
        }
    }
    let mut h = nalgebra::Matrix3::<f64>::zeros();
    for (p, q) in pairs {
        let a = nalgebra::Vector3::from_fn(|k, _| q[k] - cq[k]);
        let b = nalgebra::Vector3::from_fn(|k, _| p[k] - cp[k]);
        h += a * b.transpose();
    }
    let svd = h.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    let v = vt.transpose();
    let d = (v * u.transpose()).determinant().signum();
    let r =
        v * nalgebra::Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 1.0, d)) * u.transpose();
    let mut rot = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            rot[i][j] = r[(i, j)];
        }
    }
    if rot.iter().flatten().any(|x| !x.is_finite()) {
        return None;
    }
    let rq = apply(&(rot, [0.0; 3]), cq);
    Some((rot, [cp[0] - rq[0], cp[1] - rq[1], cp[2] - rq[2]]))
}

/// Matches in two sorted distance lists within `tol` (two pointers).
fn signature_score(a: &[f64], b: &[f64], tol: f64) -> usize {
    let (mut i, mut j, mut n) = (0, 0, 0);
    while i < a.len() && j < b.len() {
        if (a[i] - b[j]).abs() <= tol {
            n += 1;
            i += 1;
            j += 1;
        } else if a[i] < b[j] {
            i += 1;
        } else {
            j += 1;
        }
    }
    n
}

/// One-to-one nearest-neighbour pairs within `tau` under `t`, closest first
/// claimed; (first, second, distance), by the first index.
fn pair_up(grid: &Grid, second: &[Vec3], t: &Transform, tau: f64) -> Vec<(usize, usize, f64)> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (s, &q) in second.iter().enumerate() {
        let p = apply(t, q);
        grid.within(p, tau, |f, d| candidates.push((d, f, s)));
    }
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0).then((a.1, a.2).cmp(&(b.1, b.2))));
    let mut used_first = HashSet::new();
    let mut used_second = HashSet::new();
    let mut pairs = Vec::new();
    for (d, f, s) in candidates {
        if !used_first.contains(&f) && !used_second.contains(&s) {
            used_first.insert(f);
            used_second.insert(s);
            pairs.push((f, s, d));
        }
    }
    pairs.sort_unstable_by_key(|p| p.0);
    pairs
}

/// Trimmed ICP from `t`: the final transform and pairs.
fn refine(
    grid: &Grid,
    first: &[Vec3],
    second: &[Vec3],
    mut t: Transform,
    tau: f64,
    fit: bool,
) -> (Transform, Vec<(usize, usize, f64)>) {
    let mut pairs = pair_up(grid, second, &t, tau);
    if !fit {
        return (t, pairs);
    }
    for _ in 0..100 {
        let points: Vec<(Vec3, Vec3)> = pairs
            .iter()
            .map(|&(f, s, _)| (first[f], second[s]))
            .collect();
        let Some(next) = kabsch(&points) else { break };
        let next_pairs = pair_up(grid, second, &next, tau);
        if next_pairs.len() < pairs.len() {
            break;
        }
        let same = next_pairs
            .iter()
            .map(|p| (p.0, p.1))
            .eq(pairs.iter().map(|p| (p.0, p.1)));
        t = next;
        pairs = next_pairs;
        if same {
            break;
        }
    }
    (t, pairs)
}

/// Finds the rigid transform taking `second` into `first`'s frame and the
/// pairs of centroids it matches.
pub fn register(first: &[Vec3], second: &[Vec3], options: &MatchOptions) -> Result<Registration> {
    if first.len() < 3 || second.len() < 3 {
        return Err(Error::Invalid(format!(
            "matching grains by position needs at least 3 grains on each side, got {} and {}",
            first.len(),
            second.len()
        )));
    }
    if first.iter().chain(second).flatten().any(|x| !x.is_finite()) {
        return Err(Error::Invalid("a grain position is not finite".into()));
    }
    let grid1 = Grid::new(first, cell_size(first));
    let grid2 = Grid::new(second, cell_size(second));
    let mut spacings: Vec<f64> = (0..first.len())
        .map(|i| grid1.neighbours(i, 1)[0].0)
        .collect();
    spacings.sort_by(f64::total_cmp);
    let spacing = spacings[spacings.len() / 2];
    if spacing <= 0.0 {
        return Err(Error::Invalid(
            "half the grains or more share their centroid with another: positions cannot be matched"
                .into(),
        ));
    }
    let tau = match options.max_distance {
        Some(d) if d > 0.0 && d.is_finite() => d,
        Some(d) => {
            return Err(Error::Invalid(format!(
                "the match distance must be positive, got {d}"
            )))
        }
        None => 0.4 * spacing,
    };
    let identity: Transform = (
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        [0.0; 3],
    );
    let fit = options.transform == TransformModel::Rigid;
    let (t, pairs) = if fit {
        // Centred (the two sets cover the same sample, the usual case) and
        // not (one instrument saw a part of the other's field).
        let mut tries = hypotheses(&grid1, &grid2, tau, options.seed, true);
        tries.extend(hypotheses(&grid1, &grid2, tau, options.seed, false));
        tries.push(identity);
        // Whole-set scores, then the best few refined.
        let mut scored: Vec<(usize, usize)> = tries
            .iter()
            .enumerate()
            .map(|(h, t)| (pair_up(&grid1, second, t, tau).len(), h))
            .collect();
        scored.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut best: Option<(Transform, Vec<Pair>)> = None;
        for &(_, h) in scored.iter().take(4) {
            let (t, pairs) = refine(&grid1, first, second, tries[h], tau, true);
            let better = match &best {
                None => true,
                Some((_, b)) => {
                    pairs.len() > b.len() || (pairs.len() == b.len() && rms(&pairs) < rms(b))
                }
            };
            if better {
                best = Some((t, pairs));
            }
        }
        best.expect("the identity is always a hypothesis")
    } else {
        refine(&grid1, first, second, identity, tau, false)
    };
    if pairs.len() < 3 {
        return Err(Error::Invalid(format!(
            "no transform pairs more than {} of the {} and {} grains within {tau:.3e} m (0.4 of \
             the spacing {spacing:.3e} m unless given): are both files of the same sample, in \
             the same length unit?",
            pairs.len(),
            first.len(),
            second.len()
        )));
    }
    let matched1: HashSet<usize> = pairs.iter().map(|p| p.0).collect();
    let matched2: HashSet<usize> = pairs.iter().map(|p| p.1).collect();
    Ok(Registration {
        rotation: t.0,
        translation: t.1,
        rms: rms(&pairs),
        residuals: pairs.iter().map(|p| p.2).collect(),
        pairs: pairs.iter().map(|p| (p.0, p.1)).collect(),
        max_distance: tau,
        spacing,
        unmatched_first: (0..first.len()).filter(|i| !matched1.contains(i)).collect(),
        unmatched_second: (0..second.len())
            .filter(|i| !matched2.contains(i))
            .collect(),
    })
}

fn rms(pairs: &[(usize, usize, f64)]) -> f64 {
    if pairs.is_empty() {
        return 0.0;
    }
    (pairs.iter().map(|p| p.2 * p.2).sum::<f64>() / pairs.len() as f64).sqrt()
}

fn centroid(points: &[Vec3]) -> Vec3 {
    let n = points.len() as f64;
    let mut c = [0.0; 3];
    for p in points {
        for k in 0..3 {
            c[k] += p[k] / n;
        }
    }
    c
}

/// Rigid transforms from consistent triangles of neighbours (step 2 of the
/// module's method), the best per seed–candidate pair by its local score.
///
/// `centred`: the distance of each point from its set's centroid is taken
/// as invariant too (true when both sets cover the same sample, a few
/// grains missing on each side). In a packing of nearly equal grains every
/// grain's neighbour distances look alike; the distance from the centre
/// narrows a seed's candidates to a thin shell, and the neighbours' own
/// distances from the centre pick the right one in it.
fn hypotheses(grid1: &Grid, grid2: &Grid, tau: f64, seed: u64, centred: bool) -> Vec<Transform> {
    let (first, second) = (grid1.points, grid2.points);
    let k = 8.min(first.len() - 1).min(second.len() - 1);
    let tol = 0.5 * tau;
    let (c1, c2) = (centroid(first), centroid(second));
    let r1: Vec<f64> = first.iter().map(|&p| dist(p, c1)).collect();
    let r2: Vec<f64> = second.iter().map(|&p| dist(p, c2)).collect();
    // The centroids move with the missing grains: a looser radial tolerance.
    let rtol = 2.0 * tol;
    let radial = |a: usize, b: usize| !centred || (r2[a] - r1[b]).abs() <= rtol;
    let sig1: Vec<Vec<(f64, usize)>> = (0..first.len()).map(|i| grid1.neighbours(i, k)).collect();
    let dist1: Vec<Vec<f64>> = sig1
        .iter()
        .map(|s| s.iter().map(|x| x.0).collect())
        .collect();
    let mut seeds: Vec<usize> = (0..second.len()).collect();
    seeds.shuffle(&mut rand_chacha::ChaCha8Rng::seed_from_u64(seed));
    seeds.truncate(24);
    let mut out: Vec<(usize, Transform)> = Vec::new();
    for &i in &seeds {
        let ni = grid2.neighbours(i, k);
        let di: Vec<f64> = ni.iter().map(|x| x.0).collect();
        let mut candidates: Vec<(usize, usize)> = (0..first.len())
            .filter(|&j| radial(i, j))
            .map(|j| {
                let score = if centred {
                    // Neighbours agreeing in distance from the seed and from the centre.
                    ni.iter()
                        .filter(|&&(da, a)| {
                            sig1[j]
                                .iter()
                                .any(|&(db, b)| (da - db).abs() <= tol && radial(a, b))
                        })
                        .count()
                } else {
                    signature_score(&di, &dist1[j], tol)
                };
                (score, j)
            })
            .collect();
        candidates.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        for &(score, j) in candidates.iter().take(6) {
            if score < 2 {
                break;
            }
            let nj = &sig1[j];
            // Neighbour pairs (a of i, b of j) at the same distance.
            let mut c = Vec::new();
            for &(da, a) in &ni {
                for &(db, b) in nj {
                    if (da - db).abs() <= tol && radial(a, b) {
                        c.push((a, b));
                    }
                }
            }
            let mut best: Option<(usize, Transform)> = None;
            for x in 0..c.len() {
                for y in x + 1..c.len() {
                    let ((a1, b1), (a2, b2)) = (c[x], c[y]);
                    if a1 == a2 || b1 == b2 {
                        continue;
                    }
                    if (dist(second[a1], second[a2]) - dist(first[b1], first[b2])).abs() > tol {
                        continue;
                    }
                    // A thin triangle fixes no rotation about its long side.
                    let area = 0.5
                        * scene::norm(scene::cross(
                            scene::sub(second[a1], second[i]),
                            scene::sub(second[a2], second[i]),
                        ));
                    if area < 0.1 * di[0] * di[0] {
                        continue;
                    }
                    let Some(t) = kabsch(&[
                        (first[j], second[i]),
                        (first[b1], second[a1]),
                        (first[b2], second[a2]),
                    ]) else {
                        continue;
                    };
                    let local = ni
                        .iter()
                        .filter(|&&(_, a)| grid1.nearest(apply(&t, second[a]), tau).is_some())
                        .count();
                    if best.as_ref().is_none_or(|b| local > b.0) {
                        best = Some((local, t));
                    }
                }
            }
            if let Some(b) = best {
                out.push(b);
            }
        }
    }
    out.sort_by_key(|b| std::cmp::Reverse(b.0));
    out.truncate(48);
    out.into_iter().map(|x| x.1).collect()
}

/// A grain of the stress source: an id, a position and a stress, with the
/// row it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct StressedGrain {
    pub id: String,
    pub position: Vec3,
    pub stress: Sym,
    pub stress_sd: Option<Sym>,
}

/// Reads per-grain positions and stresses: a scene folder (its `grains.csv`,
/// as `import gff`/`import imaged11` write it) or a CSV with the columns
/// `id,x,y,z,s_xx,s_yy,s_zz,s_xy,s_xz,s_yz` (SI: m, Pa; optional `sd_s_*`).
pub fn read_stressed_grains(path: &Path) -> Result<Vec<StressedGrain>> {
    let file = if path.is_dir() {
        path.join("grains.csv")
    } else {
        path.to_path_buf()
    };
    let (columns, rows) = scene::read_csv(&file)?;
    const S: [&str; 6] = ["s_xx", "s_yy", "s_zz", "s_xy", "s_xz", "s_yz"];
    let has_sd = columns.contains_key("sd_s_xx");
    let mut out = Vec::with_capacity(rows.len());
    let mut seen = HashSet::new();
    for (line, record) in &rows {
        let id = scene::csv_cell(&file, &columns, record, *line, "id")?.to_owned();
        if !seen.insert(id.clone()) {
            return Err(Error::data(
                &file,
                Some(*line),
                Some("id"),
                format!("grain `{id}` appears twice"),
            ));
        }
        let mut position = [0.0; 3];
        for (k, c) in ["x", "y", "z"].iter().enumerate() {
            position[k] = scene::csv_number(&file, &columns, record, *line, c)?;
        }
        let mut stress = [0.0; 6];
        for (k, c) in S.iter().enumerate() {
            stress[k] = scene::csv_number(&file, &columns, record, *line, c)?;
        }
        let stress_sd = if has_sd {
            let mut sd = [0.0; 6];
            for (k, c) in S.iter().enumerate() {
                let col = format!("sd_{c}");
                sd[k] = scene::csv_number(&file, &columns, record, *line, &col)?;
                if sd[k] < 0.0 {
                    return Err(Error::data(
                        &file,
                        Some(*line),
                        Some(&col),
                        "a standard error cannot be negative",
                    ));
                }
            }
            Some(sd)
        } else {
            None
        };
        out.push(StressedGrain {
            id,
            position,
            stress,
            stress_sd,
        });
    }
    if out.is_empty() {
        return Err(Error::data(&file, None, None, "no grains"));
    }
    Ok(out)
}

/// R σ Rᵀ in [`Sym`] order; with `sd`, the standard errors carried across
/// as for independent components.
pub fn rotate_stress(r: &Mat3, s: &Sym, sd: Option<&Sym>) -> (Sym, Option<Sym>) {
    let mut out = [0.0; 6];
    let mut var = [0.0; 6];
    for (k, &(i, j)) in scene::sym::PAIRS.iter().enumerate() {
        for (c, &(p, q)) in scene::sym::PAIRS.iter().enumerate() {
            // σ'_ij = Σ_c σ_c (R_ip R_jq + [p ≠ q] R_iq R_jp).
            let mut a = r[i][p] * r[j][q];
            if p != q {
                a += r[i][q] * r[j][p];
            }
            out[k] += a * s[c];
            if let Some(sd) = sd {
                var[k] += a * a * sd[c] * sd[c];
            }
        }
    }
    (out, sd.map(|_| var.map(f64::sqrt)))
}

/// What attaching stresses did.
#[derive(Debug, Clone, PartialEq)]
pub struct StressMatch {
    pub registration: Registration,
    /// (scene grain id, source grain id, distance [m]) per match.
    pub matches: Vec<(String, String, f64)>,
    /// Scene grains that got no stress (left at zero).
    pub unmatched_scene: Vec<String>,
    /// Source grains that matched no scene grain.
    pub unmatched_source: Vec<String>,
    pub warnings: Vec<String>,
}

/// Attaches the source's stresses to the scene's grains by position: the
/// rigid transform from the source's frame to the scene's is fitted
/// ([`register`]), each matched grain gets the source's stress rotated into
/// the scene's frame; unmatched scene grains keep their stress (zero from a
/// label import) and are listed.
pub fn attach_stresses(
    scene: &mut Scene,
    source: &[StressedGrain],
    options: &MatchOptions,
) -> Result<StressMatch> {
    if scene.dim != 3 {
        return Err(Error::Invalid(
            "stresses are attached by position to 3D scenes only".into(),
        ));
    }
    let first: Vec<Vec3> = scene.grains.iter().map(|g| g.position).collect();
    let second: Vec<Vec3> = source.iter().map(|g| g.position).collect();
    let reg = register(&first, &second, options)?;
    let mut matches = Vec::new();
    for (&(f, s), &d) in reg.pairs.iter().zip(&reg.residuals) {
        let (stress, sd) = rotate_stress(
            &reg.rotation,
            &source[s].stress,
            source[s].stress_sd.as_ref(),
        );
        let g = &mut scene.grains[f];
        g.stress = stress;
        g.stress_sd = sd;
        matches.push((g.id.clone(), source[s].id.clone(), d));
    }
    let unmatched_scene: Vec<String> = reg
        .unmatched_first
        .iter()
        .map(|&i| scene.grains[i].id.clone())
        .collect();
    let unmatched_source: Vec<String> = reg
        .unmatched_second
        .iter()
        .map(|&i| source[i].id.clone())
        .collect();
    let mut warnings = Vec::new();
    let fewest = first.len().min(second.len());
    if reg.pairs.len() * 2 < fewest {
        warnings.push(format!(
            "only {} of {} possible grains matched: the transform may be wrong (check the \
             residual, the length units, --match-distance)",
            reg.pairs.len(),
            fewest
        ));
    }
    if !unmatched_scene.is_empty() {
        warnings.push(format!(
            "{} grain(s) of the label volume matched no stressed grain; their stress is left at \
             zero (infer on the matched grains with `infer --grains`, or give them stresses): {}",
            unmatched_scene.len(),
            preview(&unmatched_scene)
        ));
    }
    Ok(StressMatch {
        registration: reg,
        matches,
        unmatched_scene,
        unmatched_source,
        warnings,
    })
}

fn preview(ids: &[String]) -> String {
    let mut s = ids.iter().take(10).cloned().collect::<Vec<_>>().join(", ");
    if ids.len() > 10 {
        s.push_str(&format!(" … ({} more)", ids.len() - 10));
    }
    s
}

impl StressMatch {
    /// `stress_match.csv` (one row per scene grain matched or not, and per
    /// unmatched source grain) and `stress_match.json` (the transform, the
    /// residual, the counts).
    pub fn write(&self, dir: &Path) -> Result<()> {
        let (csv, json) = self.texts();
        scene::write_file_atomically(&dir.join("stress_match.csv"), csv.as_bytes())?;
        scene::write_file_atomically(&dir.join("stress_match.json"), json.as_bytes())
    }

    /// The texts of `stress_match.csv` and `stress_match.json`.
    pub fn texts(&self) -> (String, String) {
        let mut csv = String::from("grain,source,distance\n");
        for (g, s, d) in &self.matches {
            csv.push_str(&format!("{g},{s},{d}\n"));
        }
        for g in &self.unmatched_scene {
            csv.push_str(&format!("{g},,\n"));
        }
        for s in &self.unmatched_source {
            csv.push_str(&format!(",{s},\n"));
        }
        let r = &self.registration;
        let json = serde_json::json!({
            "transform": "p_scene = rotation · p_source + translation",
            "rotation": r.rotation,
            "translation": r.translation,
            "rotation_angle_degrees": r.angle_degrees(),
            "matched": r.pairs.len(),
            "rms_distance": r.rms,
            "max_distance_found": r.residuals.iter().cloned().fold(0.0, f64::max),
            "match_distance": r.max_distance,
            "spacing": r.spacing,
            "unmatched_scene_grains": self.unmatched_scene,
            "unmatched_source_grains": self.unmatched_source,
        });
        (csv, format!("{json:#}\n"))
    }
}
