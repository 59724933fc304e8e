//! The automatic Tikhonov λ (eq. 2.17) scans with the unconstrained least
//! squares and makes at most `LambdaSearch::GUIDED_SOLVES` constrained solves;
//! the former search made 37. On DEM fixtures with measured wall forces and
//! the eq. 2.16 stress noise, the λ it picks must be as good against the
//! exact forces as the former one's.

mod common;
use grainforce::bench::{perturb, Noise};
use grainforce::infer::{
    infer, InferOptions, InferenceReport, LambdaPrecision, LambdaSearch, Method,
};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{Scene, Vec3};

/// relerr may differ by this much (absolute; the relerr is 0.02–0.05 here):
/// both searches stop at a precision of ~5e-4 decades of λ.
const RELERR_TOLERANCE: f64 = 1e-4;

/// Automatic Tikhonov with the given search: the report and relerr.
fn tikhonov(scene: &Scene, truth: &[Vec3], search: LambdaSearch) -> (InferenceReport, f64) {
    let r = infer(
        scene,
        &InferOptions {
            method: Method::Tikhonov,
            lambda_search: search,
            ..InferOptions::default()
        },
    )
    .unwrap();
    let relerr = relative_error(truth, &r.forces_or_zero());
    (r.report, relerr)
}

fn compare(fixture: &str, seeds: std::ops::RangeInclusive<u64>) {
    let (scene, truth) = common::fixture(fixture);
    for seed in seeds {
        let noisy = perturb(&scene, Noise::Stress, seed);
        let run = |search| tikhonov(&noisy, &truth, search);
        let fine = LambdaSearch {
            precision: LambdaPrecision::Fine,
            ..LambdaSearch::default()
        };
        let (new, new_err) = run(fine);
        let (old, old_err) = run(LambdaSearch::former());
        let (new_trace, old_trace) = (
            new.lambda_trace.as_ref().unwrap(),
            old.lambda_trace.as_ref().unwrap(),
        );
        let (new_lambda, old_lambda) = (new.lambda.unwrap(), old.lambda.unwrap());
        eprintln!(
            "{fixture} seed {seed}: λ {new_lambda:.4e} (was {old_lambda:.4e}), relerr {new_err:.6} (was {old_err:.6}), \
             constrained solves {} + {} least squares (was {})",
            new_trace.points.len(),
            new_trace.unconstrained.len(),
            old_trace.points.len()
        );
        // The noise inflates the stresses by 15 %: λ must do real work.
        let qs_err = relative_error(
            &truth,
            &infer(&noisy, &InferOptions::default())
                .unwrap()
                .forces_or_zero(),
        );
        assert!(
            new_err < 0.5 * qs_err,
            "relerr {new_err} against qs {qs_err}"
        );
        assert!(
            new_err <= old_err + RELERR_TOLERANCE,
            "relerr {new_err} against the former search's {old_err}"
        );
        assert!(
            (new_lambda / old_lambda).log10().abs() < 0.01,
            "λ {new_lambda} against {old_lambda}"
        );
        assert!(!new_trace.unconstrained.is_empty());
        assert!(
            new_trace.points.len() <= LambdaSearch::GUIDED_SOLVES,
            "{} constrained solves",
            new_trace.points.len()
        );
        assert_eq!(
            old_trace.points.len(),
            LambdaSearch::former().max_constrained_solves()
        );
        assert!(!new_trace.at_edge && !old_trace.at_edge);
    }
}

#[test]
fn oedometer_2d_lambda_as_good_with_at_most_six_constrained_solves() {
    compare("oedometer", 1..=3);
}

#[test]
fn oedometer_3d_lambda_as_good_with_at_most_six_constrained_solves() {
    compare("regression/oedometer3d_seed1", 1..=2);
}

/// `LambdaPrecision::Coarse`: the same unconstrained scan, then one
/// constrained solve at its optimum. The forces stay within ~1 % of the fine
/// search's and as close to the truth (eq. 2.16 noise: the λ precision the
/// fine steps buy moves the forces far less than the noise does).
#[test]
fn coarse_precision_solves_once_at_the_unconstrained_optimum() {
    for (fixture, seeds) in [
        ("oedometer", 1..=2),
        ("regression/oedometer3d_seed1", 1..=2),
    ] {
        let (scene, truth) = common::fixture(fixture);
        for seed in seeds {
            let noisy = perturb(&scene, Noise::Stress, seed);
            let run = |precision| {
                let search = LambdaSearch {
                    precision,
                    ..LambdaSearch::default()
                };
                let options = InferOptions {
                    method: Method::Tikhonov,
                    lambda_search: search,
                    ..InferOptions::default()
                };
                infer(&noisy, &options).unwrap()
            };
            let (fine, coarse) = (run(LambdaPrecision::Fine), run(LambdaPrecision::Coarse));
            let trace = coarse.report.lambda_trace.as_ref().unwrap();
            let fine_trace = fine.report.lambda_trace.as_ref().unwrap();
            let apart = relative_error(&fine.forces_or_zero(), &coarse.forces_or_zero());
            let fine_err = relative_error(&truth, &fine.forces_or_zero());
            let coarse_err = relative_error(&truth, &coarse.forces_or_zero());
            eprintln!(
                "{fixture} seed {seed}: coarse λ {:.4e} (fine {:.4e}), forces {apart:.2e} apart, \
                 relerr {coarse_err:.5} (fine {fine_err:.5}), constrained solves 1 (fine {})",
                coarse.report.lambda.unwrap(),
                fine.report.lambda.unwrap(),
                fine_trace.points.len()
            );
            assert_eq!(trace.points.len(), 1);
            assert_eq!(trace.unconstrained, fine_trace.unconstrained);
            let best = trace
                .unconstrained
                .iter()
                .min_by(|p, q| p.1.total_cmp(&q.1))
                .unwrap();
            assert!((trace.points[0].0 / best.0 - 1.0).abs() < 1e-12);
            assert!(apart < 0.02, "forces {apart:.2e} apart");
            assert!(
                coarse_err <= fine_err + 2e-3,
                "relerr {coarse_err} against fine's {fine_err}"
            );
        }
    }
}

/// Exact stresses: the mismatch is smallest, and flat, at the low end, so the
/// scan stops early and one constrained solve at the range's smallest λ
/// suffices; the answer is as exact as the former search's.
#[test]
fn exact_data_take_one_constrained_solve() {
    let (scene, truth) = common::fixture("oedometer");
    let run = |search| tikhonov(&scene, &truth, search);
    let (r, relerr) = run(LambdaSearch::default());
    let (_, former) = run(LambdaSearch::former());
    let trace = r.lambda_trace.as_ref().unwrap();
    eprintln!(
        "exact: λ {:.3e}, relerr {relerr:.2e} (former search {former:.2e}), {} least squares, {} constrained",
        r.lambda.unwrap(),
        trace.unconstrained.len(),
        trace.points.len()
    );
    assert_eq!(trace.points.len(), 1);
    assert!(trace.unconstrained.len() < LambdaSearch::default().grid);
    assert!(relerr < 1e-8, "relerr {relerr}");
    assert!(
        relerr <= 1.01 * former + 1e-12,
        "relerr {relerr} against {former}"
    );
}

/// On a sheared packing the active set cannot settle at any λ: after the
/// first constrained solve the search skips it and starts the interior point
/// from the previous λ's mid-path iterate, in fewer iterations. Those solves
/// only rank λ, at a looser tolerance; the chosen λ is solved once more at
/// the default one, so the answer is still the optimum there: a cold solve by
/// clarabel agrees to the two interior points' tolerances.
#[test]
fn sheared_3d_search_restarts_the_interior_point_and_keeps_the_optimum() {
    use grainforce::infer::ConstrainedSolver;
    let dir =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/regression/box3d_sheared");
    let scene = perturb(
        &grainforce::scene::read_scene(&dir).unwrap(),
        Noise::Stress,
        18,
    );
    // To the tolerance, not the data's accuracy (tests/data_accuracy.rs).
    let mut exact = InferOptions {
        method: Method::Tikhonov,
        lambda_search: LambdaSearch {
            precision: LambdaPrecision::Fine,
            ..LambdaSearch::default()
        },
        ..InferOptions::default()
    };
    exact.conic.noise_share = None;
    let r = infer(&scene, &exact).unwrap();
    let attempts = &r.report.solver_attempts;
    eprintln!("{attempts:#?}");
    let iterations = |a: &str| -> usize {
        let (_, tail) = a
            .split_once("factorisation: ")
            .expect("the sparse interior point");
        tail.split(' ').next().unwrap().parse().unwrap()
    };
    let (notes, solves): (Vec<&String>, Vec<&String>) =
        attempts.iter().partition(|a| a.starts_with("λ search: "));
    assert_eq!(notes.len(), 1, "the chosen λ solved again: {attempts:?}");
    assert!(notes[0].contains("tolerance 1e-4"), "{}", notes[0]);
    assert!(solves.len() >= 2, "{attempts:?}");
    assert!(solves[0].starts_with("active set: no descent"));
    for later in &solves[1..] {
        assert!(
            later.starts_with("active set: skipped (it did not settle at a nearby λ)"),
            "{later}"
        );
        assert!(iterations(later) < iterations(solves[0]), "{later}");
    }
    let lambda = r.report.lambda.unwrap();
    let cold = infer(
        &scene,
        &InferOptions {
            method: Method::Tikhonov,
            lambda: Some(lambda),
            solver: ConstrainedSolver::InteriorPoint,
            ..InferOptions::default()
        },
    )
    .unwrap();
    let gap = relative_error(&cold.forces_or_zero(), &r.forces_or_zero());
    eprintln!("λ {lambda:.4e}: {gap:.2e} from a cold clarabel solve");
    assert!(gap < 1e-5, "{gap:.2e}");
}
