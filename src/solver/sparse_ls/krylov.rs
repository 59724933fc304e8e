//! Right-preconditioned GMRES: the refinement step on a factor that no
//! longer matches the system exactly (rows it holds stale), where plain
//! iterative refinement converges only linearly, or not at all.

/// Solves K d = r approximately by at most `iterations` steps of GMRES with
/// right preconditioner M⁻¹ (`precondition`, in place) and operator K
/// (`apply`), from d = 0, stopping once the residual is below `tolerance`
/// times ‖r‖₂. Overwrites `r` with d and returns the steps taken.
pub(super) fn gmres(
    r: &mut [f64],
    iterations: usize,
    tolerance: f64,
    precondition: &mut impl FnMut(&mut [f64]),
    apply: &mut impl FnMut(&[f64]) -> Vec<f64>,
) -> usize {
    let beta = norm(r);
    if beta == 0.0 || !beta.is_finite() || iterations == 0 {
        return 0;
    }
    // Orthonormal basis V of the Krylov space of K M⁻¹ and the preconditioned
    // directions Z = M⁻¹ V; the Hessenberg matrix reduced by Givens rotations.
    let mut basis: Vec<Vec<f64>> = vec![r.iter().map(|v| v / beta).collect()];
    let mut directions: Vec<Vec<f64>> = Vec::new();
    let mut hessenberg: Vec<Vec<f64>> = Vec::new();
    let mut rotations: Vec<(f64, f64)> = Vec::new();
    let mut g = vec![beta];
    for j in 0..iterations {
        let mut z = basis[j].clone();
        precondition(&mut z);
        let mut w = apply(&z);
        directions.push(z);
        let mut h = Vec::with_capacity(j + 2);
        // Modified Gram–Schmidt.
        for v in &basis {
            let hij = dot(&w, v);
            for (wk, vk) in w.iter_mut().zip(v) {
                *wk -= hij * vk;
            }
            h.push(hij);
        }
        let next = norm(&w);
        h.push(next);
        for (i, &(c, s)) in rotations.iter().enumerate() {
            let (a, b) = (h[i], h[i + 1]);
            h[i] = c * a + s * b;
            h[i + 1] = -s * a + c * b;
        }
        let (a, b) = (h[j], h[j + 1]);
        let radius = a.hypot(b);
        let (c, s) = if radius == 0.0 {
            (1.0, 0.0)
        } else {
            (a / radius, b / radius)
        };
        h[j] = radius;
        h[j + 1] = 0.0;
        rotations.push((c, s));
        g.push(-s * g[j]);
        g[j] *= c;
        hessenberg.push(h);
        let converged = g[j + 1].abs() <= tolerance * beta;
        if converged || next == 0.0 || !next.is_finite() || j + 1 == iterations {
            break;
        }
        basis.push(w.iter().map(|v| v / next).collect());
    }
    // Back substitution for the coefficients y of d = Z y.
    let k = hessenberg.len();
    let mut y = vec![0.0; k];
    for i in (0..k).rev() {
        let sum: f64 = ((i + 1)..k).map(|l| hessenberg[l][i] * y[l]).sum();
        y[i] = if hessenberg[i][i] == 0.0 {
            0.0
        } else {
            (g[i] - sum) / hessenberg[i][i]
        };
    }
    r.fill(0.0);
    for (z, yi) in directions.iter().zip(&y) {
        for (dk, zk) in r.iter_mut().zip(z) {
            *dk += yi * zk;
        }
    }
    k
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A nonsymmetric 3×3 system, preconditioned by its diagonal: GMRES
    /// solves it exactly in 3 steps.
    #[test]
    fn solves_a_small_system_exactly_in_its_dimension() {
        let k = [[4.0, 1.0, 0.5], [-2.0, 5.0, 1.0], [0.0, 3.0, 6.0]];
        let x = [1.0, -2.0, 0.5];
        let mut r: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|j| k[i][j] * x[j]).sum())
            .collect();
        let mut apply = |v: &[f64]| -> Vec<f64> {
            (0..3)
                .map(|i| (0..3).map(|j| k[i][j] * v[j]).sum())
                .collect()
        };
        let mut precondition = |v: &mut [f64]| {
            for (i, vi) in v.iter_mut().enumerate() {
                *vi /= k[i][i];
            }
        };
        let steps = gmres(&mut r, 10, 1e-14, &mut precondition, &mut apply);
        assert!(steps <= 3, "{steps} steps");
        for (got, want) in r.iter().zip(&x) {
            assert!((got - want).abs() < 1e-12, "{got} vs {want}");
        }
    }

    /// With the exact inverse as preconditioner one step is enough.
    #[test]
    fn an_exact_preconditioner_takes_one_step() {
        let mut r = vec![3.0, -1.0];
        let mut apply = |v: &[f64]| vec![2.0 * v[0], 4.0 * v[1]];
        let mut precondition = |v: &mut [f64]| {
            v[0] /= 2.0;
            v[1] /= 4.0;
        };
        assert_eq!(gmres(&mut r, 5, 1e-14, &mut precondition, &mut apply), 1);
        assert!((r[0] - 1.5).abs() < 1e-15 && (r[1] + 0.25).abs() < 1e-15);
    }

    #[test]
    fn a_zero_right_hand_side_takes_no_step() {
        let mut r = vec![0.0; 4];
        let steps = gmres(
            &mut r,
            5,
            1e-14,
            &mut |_: &mut [f64]| {},
            &mut |v: &[f64]| v.to_vec(),
        );
        assert_eq!(steps, 0);
        assert!(r.iter().all(|&v| v == 0.0));
    }
}
