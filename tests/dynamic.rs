//! Dynamic inference: the knee picker, accelerating assemblies, and the static limit.

mod common;
use common::*;
use grainforce::infer::{dynamic::knee, infer, InferOptions, LambdaRule, Method};
use grainforce::report::pareto::ParetoPoint;
use grainforce::scene::{self, Body, Inertia, Scene, Vec3};

fn front(points: &[(f64, f64)]) -> Vec<ParetoPoint> {
    points
        .iter()
        .enumerate()
        .map(|(i, &(s, m))| ParetoPoint {
            lambda: 10f64.powi(i as i32),
            stress_residual: s,
            momentum_residual: m,
        })
        .collect()
}

#[test]
fn knee_of_l_shaped_fronts() {
    for corner in [5usize, 10, 20] {
        let n = 30;
        // Momentum residual falls by decades while the stress residual barely moves,
        // then the stress residual grows while momentum stays put.
        let pts: Vec<(f64, f64)> = (0..n)
            .map(|i| {
                if i <= corner {
                    (
                        1.0 + 0.001 * i as f64,
                        10f64.powf(-(i as f64) * 4.0 / corner as f64),
                    )
                } else {
                    let t = (i - corner) as f64;
                    (
                        10f64.powf(t * 3.0 / (n - corner) as f64),
                        1e-4 * (1.0 - 0.0001 * t),
                    )
                }
            })
            .collect();
        let k = knee(&front(&pts)).unwrap();
        assert!(k.abs_diff(corner) <= 1, "corner {corner}: knee at {k}");
        // 5 % multiplicative noise on both residuals does not move it far.
        let noisy: Vec<(f64, f64)> = pts
            .iter()
            .enumerate()
            .map(|(i, &(s, m))| {
                let u = ((i as f64 * 12.9898).sin() * 43758.5453).fract();
                (s * (1.0 + 0.05 * u), m * (1.0 - 0.05 * u))
            })
            .collect();
        let k = knee(&front(&noisy)).unwrap();
        assert!(
            k.abs_diff(corner) <= 2,
            "noisy, corner {corner}: knee at {k}"
        );
    }
}

#[test]
fn knee_of_degenerate_fronts() {
    assert_eq!(knee(&[]), None);
    // Too few points for a curvature, or a front without a corner: the
    // middle point.
    assert_eq!(knee(&front(&[(1.0, 1.0)])), Some(0));
    assert_eq!(knee(&front(&[(1.0, 1.0), (2.0, 0.5)])), Some(1));
    assert_eq!(knee(&front(&[(1.0, 1.0); 12])), Some(6));
    assert_eq!(knee(&front(&[(0.0, 0.0); 5])), Some(2));
    // A straight line in log-log has no corner either.
    let line: Vec<(f64, f64)> = (0..9).map(|i| (10f64.powi(i), 10f64.powi(-i))).collect();
    assert_eq!(knee(&front(&line)), Some(4));
}

/// A 2D packing whose forces are out of balance: each grain accelerates as
/// Newton says, and the scene carries mass, acceleration, inertia and α.
fn accelerating_packing() -> (Scene, Vec<Vec3>) {
    let (s, truth) = square_2d(5, 4, 0.5);
    unbalance(s, truth)
}

/// Scales each contact force by its own factor and gives every grain the
/// acceleration and angular acceleration that the net force and moment imply.
fn unbalance(mut s: Scene, truth: Vec<Vec3>) -> (Scene, Vec<Vec3>) {
    let forces: Vec<Vec3> = truth
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let k = 1.0 + 0.2 * ((i as f64) * 1.7).sin();
            [f[0] * k, f[1] * k, f[2] * k]
        })
        .collect();
    let mut net = vec![([0.0; 3], [0.0; 3]); s.grains.len()];
    for (c, f) in s.contacts.iter().zip(&forces) {
        let mut sides = vec![(c.a, *f)];
        if let Body::Grain(b) = c.b {
            sides.push((b, [-f[0], -f[1], -f[2]]));
        }
        for (p, fp) in sides {
            let r = scene::sub(c.point, s.grains[p].position);
            let m = scene::cross(r, fp);
            for k in 0..3 {
                net[p].0[k] += fp[k];
                net[p].1[k] += m[k];
            }
        }
    }
    let dim = s.dim;
    for (g, (force, moment)) in s.grains.iter_mut().zip(net) {
        let m = 2650.0 * g.volume;
        let r = g.radius.unwrap();
        let i = if dim == 2 {
            0.5 * m * r * r
        } else {
            0.4 * m * r * r
        };
        g.mass = Some(m);
        g.acceleration = Some([force[0] / m, force[1] / m, force[2] / m]);
        g.inertia = Some(Inertia::Scalar(i));
        g.angular_acceleration = Some([moment[0] / i, moment[1] / i, moment[2] / i]);
    }
    set_stresses(&mut s, &forces);
    (s, forces)
}

fn dynamic(rule: LambdaRule) -> InferOptions {
    let mut o = InferOptions {
        method: Method::Dynamic,
        ..InferOptions::default()
    };
    o.dynamic.rule = rule;
    o
}

#[test]
fn accelerating_assembly_exact_accelerations() {
    let (s, truth) = accelerating_packing();
    let hard = infer(&s, &dynamic(LambdaRule::Hard)).unwrap();
    let e = relerr(&truth, &hard.forces_or_zero());
    assert!(e <= 1e-7, "hard momentum: relerr {e}\n{}", hard.report);
    // The default rule treats accelerations as exact unless told otherwise.
    let default = infer(&s, &dynamic(InferOptions::default().dynamic.rule)).unwrap();
    assert!(relerr(&truth, &default.forces_or_zero()) <= 1e-7);
    // Weighted with a stated 1 % acceleration noise: still close on exact data.
    let weighted = infer(
        &s,
        &dynamic(LambdaRule::Weights {
            stress_sd: 0.1,
            momentum_sd: 0.01,
        }),
    )
    .unwrap();
    let e = relerr(&truth, &weighted.forces_or_zero());
    assert!(e <= 1e-4, "weighted: relerr {e}\n{}", weighted.report);
    // The knee on exact data: the front's corner is still a good force field.
    let knee = infer(&s, &dynamic(LambdaRule::Knee)).unwrap();
    let e = relerr(&truth, &knee.forces_or_zero());
    assert!(knee.report.pareto.as_ref().unwrap().points.len() == 31);
    assert!(e <= 1e-4, "knee: relerr {e}\n{}", knee.report);
}

#[test]
fn static_scene_reduces_to_static_answer() {
    let (s, truth) = lattice_2d(4, 3, 0.5);
    let qs = infer(&s, &InferOptions::default()).unwrap();
    for rule in [LambdaRule::Hard, LambdaRule::Fixed(1e3), LambdaRule::Knee] {
        let d = infer(&s, &dynamic(rule)).unwrap();
        let diff = relerr(&qs.forces_or_zero(), &d.forces_or_zero());
        assert!(diff <= 1e-4, "{rule:?}: differs from qs by {diff}");
        assert!(relerr(&truth, &d.forces_or_zero()) <= 1e-4);
    }
}

#[test]
fn lambda_at_both_ends_tends_to_the_right_limits() {
    let (s, truth) = accelerating_packing();
    // λ → ∞: momentum exact, the stress rows fit as well as they can: the truth.
    let r = infer(&s, &dynamic(LambdaRule::Fixed(1e12))).unwrap();
    let e = relerr(&truth, &r.forces_or_zero());
    assert!(e <= 1e-4, "λ = 1e12: relerr {e}\n{}", r.report);
    // λ → 0: only the stress rows count (fewer rows than unknowns here), so the
    // answer fits them exactly and is finite, but need not be the truth.
    let r = infer(&s, &dynamic(LambdaRule::Fixed(1e-12))).unwrap();
    assert!(r.forces_or_zero().iter().flatten().all(|x| x.is_finite()));
    assert!(r.report.stress_residual <= 1e-6, "{}", r.report);
}

#[test]
fn accelerating_sphere_stack_3d() {
    let (s, truth) = cubic_stack(0.5);
    let (s, truth) = unbalance(s, truth);
    for rule in [
        LambdaRule::Hard,
        LambdaRule::Weights {
            stress_sd: 0.1,
            momentum_sd: 0.01,
        },
    ] {
        let r = infer(&s, &dynamic(rule)).unwrap();
        let e = relerr(&truth, &r.forces_or_zero());
        assert!(e <= 1e-4, "{rule:?}: relerr {e}\n{}", r.report);
    }
}
