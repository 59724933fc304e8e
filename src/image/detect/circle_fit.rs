//! Robust geometric circle fitting to edge points.

use super::filters::median;
use super::refine::Edge;

/// Geometric circle fit with iterative trimming of outliers (edges of
/// neighbours, contacts, texture). Returns (cx, cy, r) and the inlier count.
pub(crate) fn robust_circle_fit(edges: &[Edge], c: [f64; 2], r: f64) -> Option<[f64; 3]> {
    if edges.len() < 8 {
        return None;
    }
    let mut strengths: Vec<f64> = edges.iter().map(|e| e.strength).collect();
    let median_strength = median(&mut strengths);
    let usable = |e: &Edge| e.aligned && e.strength >= 0.25 * median_strength;
    let mut use_edge: Vec<bool> = edges.iter().map(usable).collect();
    let mut p = [c[0], c[1], r];
    for round in 0..4 {
        p = circle_gauss_newton(edges, &use_edge, p)?;
        let mut res: Vec<f64> = edges
            .iter()
            .map(|e| (((e.x - p[0]).powi(2) + (e.y - p[1]).powi(2)).sqrt() - p[2]).abs())
            .collect();
        let mut used: Vec<f64> = res
            .iter()
            .zip(&use_edge)
            .filter(|(_, &u)| u)
            .map(|(&v, _)| v)
            .collect();
        let mad = median(&mut used);
        let cutoff = if round == 0 {
            (4.0 * 1.4826 * mad).max(1.5)
        } else {
            (3.0 * 1.4826 * mad).max(0.5)
        };
        let mut inliers = 0;
        for (k, e) in edges.iter().enumerate() {
            use_edge[k] = res[k] <= cutoff && usable(e);
            inliers += use_edge[k] as usize;
        }
        res.clear();
        if inliers < 8 {
            return None;
        }
    }
    Some(p)
}

/// Minimises Σ (|pₖ − c| − r)² over the used edge points.
pub(crate) fn circle_gauss_newton(
    edges: &[Edge],
    use_edge: &[bool],
    start: [f64; 3],
) -> Option<[f64; 3]> {
    let mut p = start;
    for _ in 0..20 {
        let mut jtj = [[0.0; 3]; 3];
        let mut jtr = [0.0; 3];
        for (e, _) in edges.iter().zip(use_edge).filter(|(_, &u)| u) {
            let (dx, dy) = (e.x - p[0], e.y - p[1]);
            let d = (dx * dx + dy * dy).sqrt().max(1e-9);
            let res = d - p[2];
            let j = [-dx / d, -dy / d, -1.0];
            for a in 0..3 {
                jtr[a] += j[a] * res;
                for b in 0..3 {
                    jtj[a][b] += j[a] * j[b];
                }
            }
        }
        let step = solve3(jtj, jtr)?;
        for k in 0..3 {
            p[k] -= step[k];
        }
        if step.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
            break;
        }
    }
    (p.iter().all(|v| v.is_finite()) && p[2] > 0.0).then_some(p)
}

/// Solves a 3×3 system by Cramer's rule; `None` when singular.
pub(crate) fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if d.abs().partial_cmp(&(1e-12 * scale.powi(3))) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let mut x = [0.0; 3];
    for k in 0..3 {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        x[k] = det(m) / d;
    }
    Some(x)
}
