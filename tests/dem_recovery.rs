//! Exact DEM data → the DEM's forces, 2D and 3D, oedometer and box presets.

mod common;
use common::fixture;
use grainforce::dem::{simulate, DemConfig, Preset};
use grainforce::infer::{infer, InferOptions};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{Scene, Vec3};

fn qs_relerr(scene: &Scene, truth: &[Vec3]) -> (f64, grainforce::infer::InferenceReport) {
    let r = infer(scene, &InferOptions::default()).unwrap();
    (relative_error(truth, &r.forces_or_zero()), r.report)
}

#[test]
fn oedometer_2d_and_3d() {
    for name in ["oedometer", "regression/oedometer3d_seed1"] {
        let (scene, truth) = fixture(name);
        let (e, report) = qs_relerr(&scene, &truth);
        eprintln!("{name}: relerr {e:.2e}");
        assert!(e <= 1e-6, "{name}: relerr {e}\n{report}");
        assert_eq!(report.unique, Some(true));
    }
}

#[test]
fn box_2d_fresh_from_the_dem() {
    let run = simulate(
        &DemConfig::preset(Preset::Box, 2)
            .grains(150)
            .seed(4)
            .gate(1e-10),
    )
    .unwrap();
    assert!(run.report.passed, "gate not reached");
    let (e, report) = qs_relerr(&run.frames[0], &run.forces[0]);
    assert!(e <= 1e-6, "relerr {e}\n{report}");
}

#[test]
fn box_3d_at_the_gate() {
    // `grainforce dem box --dim 3 --grains 60 --seed 1 --gate 1e-10` (2.2·10⁶
    // steps, 11 s in release since the box servo gain went to 5 %): the DEM's
    // forces are recovered to the data's precision, many contacts sliding.
    let (scene, truth) = fixture("regression/box3d_gated");
    let (e, report) = qs_relerr(&scene, &truth);
    eprintln!("box3d_gated: relerr {e:.2e}");
    assert!(e <= 1e-6, "relerr {e}\n{report}");
    assert_eq!(report.unique, Some(true));
}

#[test]
fn box_3d_near_balance() {
    // The 3D box stops at its step limit short of the 1e-10 gate (unbalanced
    // ratio 1e-8, contacts sliding): the hard-equality answer would fit the
    // stresses to only 6e-2; the penalty form recovers the DEM to the data's precision.
    let (scene, truth) = fixture("regression/box3d_seed1");
    let (e, report) = qs_relerr(&scene, &truth);
    assert!(e <= 1e-4, "relerr {e}\n{report}");
    assert!(
        report.warnings.iter().any(|w| w.contains("almost no room")),
        "{report}"
    );
}

#[test]
fn collapsed_feasible_set_is_detected() {
    // Slightly out of balance (unbalanced ratio 2.4e-7) with contacts sliding:
    // the hard-equality feasible set is almost {0}. The answer must not be zero.
    let (scene, truth) = fixture("regression/box3d_ungated");
    let (e, report) = qs_relerr(&scene, &truth);
    assert!(e <= 1e-3, "relerr {e}\n{report}");
    assert!(
        report.warnings.iter().any(|w| w.contains("almost no room")),
        "{report}"
    );
}

#[test]
fn default_presets_balance_to_round_off() {
    // At the default gate (1e-4) the grains are out of balance at that level;
    // the written residual accelerations make the files balance anyway, so
    // the DEM's forces are the exact answer (`dem box --dim 3`, 155 s in the
    // dev profile, is checked the same way by hand: 2.6e-16).
    for (preset, dim) in [
        (Preset::Oedometer, 2),
        (Preset::Oedometer, 3),
        (Preset::Box, 2),
    ] {
        let run = simulate(&DemConfig::preset(preset, dim).seed(7)).unwrap();
        assert!(
            run.report.unbalanced_ratio > 1e-6,
            "gate met far below its default"
        );
        let (e, report) = qs_relerr(&run.frames[0], &run.forces[0]);
        eprintln!("{preset:?} {dim}D: relerr {e:.2e}");
        assert!(e <= 1e-6, "{preset:?} {dim}D: relerr {e}\n{report}");
    }
}
