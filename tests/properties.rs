//! Property-based tests over random synthetic packings (grainforce::bench
//! generator): exact data are recovered; the answer is invariant under a change
//! of units and under translation.

use grainforce::bench::{generate, PackingSpec};
use grainforce::infer::{infer, InferOptions, Method};
use grainforce::scene::{Scene, Vec3};
use proptest::prelude::*;

fn relerr(truth: &[Vec3], f: &[Vec3]) -> f64 {
    let (mut e, mut n) = (0.0, 0.0);
    for (t, x) in truth.iter().zip(f) {
        for k in 0..3 {
            e += (t[k] - x[k]).powi(2);
            n += t[k] * t[k];
        }
    }
    (e / n).sqrt()
}

fn solve(scene: &Scene, method: Method) -> Vec<Vec3> {
    let o = InferOptions {
        method,
        ..InferOptions::default()
    };
    infer(scene, &o).expect("inference").forces_or_zero()
}

fn spec_strategy() -> impl Strategy<Value = PackingSpec> {
    (
        prop_oneof![Just(2usize), Just(3usize)],
        4usize..40,
        1.0f64..3.0,
        // Below ~1e-4 the lattice's momentum rows are redundant to within the
        // jitter: see `near_perfect_lattice_is_recovered`.
        1e-4f64..0.2,
        0.2f64..1.0,
        any::<u64>(),
    )
        .prop_map(|(dim, grains, size_ratio, jitter, mu, seed)| {
            let mut s = PackingSpec::new(dim, if dim == 3 { grains.min(27) } else { grains });
            s.size_ratio = size_ratio;
            s.jitter = jitter;
            s.mu = mu;
            s.seed = seed;
            s
        })
}

fn moved(scene: &Scene, scale: f64, force: f64, offset: Vec3) -> Scene {
    let mut s = scene.clone();
    let dim = s.dim as i32;
    for g in &mut s.grains {
        g.position = [0, 1, 2].map(|k| g.position[k] * scale + offset[k]);
        g.volume *= scale.powi(dim);
        g.radius = g.radius.map(|r| r * scale);
        g.stress = g.stress.map(|x| x * force / scale.powi(dim - 1));
    }
    for c in &mut s.contacts {
        c.point = [0, 1, 2].map(|k| c.point[k] * scale + offset[k]);
    }
    s
}

/// A case drawn by a fresh clone's run: a nearly perfect simple-cubic lattice
/// (jitter 1.2e-5 R₀). Its momentum rows are redundant to within the jitter,
/// so the generator's projection needed more than three sweeps to balance the
/// truth; out of balance by 3e-10, exact data were inconsistent along a
/// nearly redundant row and `ls` amplified that to 1.3e-5.
#[test]
fn near_perfect_lattice_is_recovered() {
    let mut spec = PackingSpec::new(3, 16);
    spec.size_ratio = 1.0;
    spec.jitter = 1.2062503082440919e-5;
    spec.mu = 0.2;
    spec.seed = 47554150908145;
    let p = generate(&spec).unwrap();
    assert!(
        p.equilibrium_residual <= 1e-12,
        "truth out of balance by {:e}",
        p.equilibrium_residual
    );
    for method in [Method::Ls, Method::Qs] {
        let e = relerr(&p.truth, &solve(&p.scene, method));
        assert!(e <= 1e-6, "{method}: relerr {e:e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn exact_data_are_recovered(spec in spec_strategy()) {
        let p = generate(&spec).unwrap();
        prop_assert!(p.equilibrium_residual <= 1e-12, "truth out of balance by {:e}", p.equilibrium_residual);
        for method in [Method::Ls, Method::Qs] {
            let e = relerr(&p.truth, &solve(&p.scene, method));
            prop_assert!(e <= 1e-6, "{}D {} grains, {}: relerr {}", spec.dim, p.scene.grains.len(), method, e);
        }
    }

    #[test]
    fn units_and_translation_do_not_change_the_answer(
        spec in spec_strategy(),
        log_scale in -6.0f64..3.0,
        log_force in -6.0f64..6.0,
        shift in prop::array::uniform3(-1.0f64..1.0),
    ) {
        let p = generate(&spec).unwrap();
        let (l, f) = (10f64.powf(log_scale), 10f64.powf(log_force));
        // Offsets up to 100 packing sizes: round-off stays ≤ 1e-12 of the arms.
        let size = 2.0 * spec.radius * (p.scene.grains.len() as f64).sqrt() * l;
        let mut offset = shift.map(|x| 100.0 * size * x);
        if spec.dim == 2 {
            offset[2] = 0.0;
        }
        let base = solve(&p.scene, Method::Qs);
        let other = solve(&moved(&p.scene, l, f, offset), Method::Qs);
        let back: Vec<Vec3> = other.iter().map(|v| v.map(|x| x / f)).collect();
        let e = relerr(&base, &back);
        prop_assert!(e <= 1e-7, "scale {l:e}, force {f:e}, offset {offset:?}: differs by {e}");
    }
}
