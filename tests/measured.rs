//! Measured-like data that do not balance (issue 19): DEM packings with the
//! weakest contacts missed, stresses from all forces, and each grain seeing
//! its forces with its own error (`bench::measured`), as photoelastic frames.

mod common;
use grainforce::bench::measured::{measured_frame, MeasuredConfig, MeasuredFrame};
use grainforce::error::Error;
use grainforce::infer::{infer, InferOptions, LambdaRule, Method, OnCollapse};
use grainforce::report::metrics::score;
use grainforce::scene::{read_scene, write_scene};
use std::path::Path;
use std::process::Command;

fn fixture(name: &str, cfg: &MeasuredConfig) -> MeasuredFrame {
    let (scene, truth) = common::fixture(name);
    measured_frame(&scene, &truth, cfg).unwrap()
}

/// The case: 15 % of the contacts (the weakest) missed, 10 % force noise.
fn photoelastic() -> MeasuredConfig {
    MeasuredConfig {
        drop_weakest: 0.15,
        force_noise: 0.10,
        per_side: true,
        seed: 1,
    }
}

/// (relerr, relerr of the normal forces).
fn errors(frame: &MeasuredFrame, opts: &InferOptions) -> (f64, f64, grainforce::infer::Inference) {
    let inf = infer(&frame.scene, opts).unwrap();
    let s = score(&frame.scene, &frame.truth, &inf.forces_or_zero()).unwrap();
    (s.relerr(), s.normal.unwrap().relative, inf)
}

fn with(method: Method, on_collapse: OnCollapse) -> InferOptions {
    InferOptions {
        method,
        on_collapse,
        ..InferOptions::default()
    }
}

#[test]
fn the_frame_is_out_of_balance_like_photoelastic_data() {
    let f = fixture("measured/box2d600_mu03", &photoelastic());
    // The frame: median |Σf| 0.36 of the mean force.
    assert!(
        (0.1..0.6).contains(&f.median_imbalance),
        "{}",
        f.median_imbalance
    );
    assert_eq!(f.scene.contacts.len(), f.truth.len());
    assert!(f.dropped > 100);
}

#[test]
fn hard_balance_collapses_and_is_flagged_never_silent() {
    let f = fixture("measured/box2d600_mu03", &photoelastic());
    // Accepted: the zero forces come back, but flagged.
    let (relerr, _, inf) = errors(&f, &with(Method::Qs, OnCollapse::Accept));
    assert!(relerr > 0.9, "qs relerr {relerr}");
    let c = inf.report.collapse.as_ref().expect("collapse flagged");
    assert!(c.stress_residual > 0.8 && c.force_ratio < 0.1, "{c:?}");
    assert!((0.05..1.0).contains(&c.imbalance_median), "{c:?}");
    assert!(!c.worst_grains.is_empty());
    assert!(
        c.causes.iter().any(|s| s.contains("missing contacts")),
        "{c:?}"
    );
    // Grains whose contacts were pruned are not called contact-less: the
    // warning counts only the loaded grains the file gives no contact.
    let w = inf.report.warnings.join("\n");
    assert!(w.contains("fixed to zero by pruning"), "{w}");
    let bare = (0..f.scene.grains.len())
        .filter(|&p| {
            f.scene.grains[p].stress.iter().any(|&s| s != 0.0)
                && !f
                    .scene
                    .contacts
                    .iter()
                    .any(|c| c.a == p || c.b == grainforce::scene::Body::Grain(p))
        })
        .count();
    assert!(
        w.contains(&format!(
            "{bare} grains report load (stress or acceleration) but have no contacts in the file"
        )),
        "{bare}: {w}"
    );
    // Asked for explicitly without accepting: an error with the diagnosis.
    match infer(&f.scene, &with(Method::Qs, OnCollapse::Fail)) {
        Err(Error::Infeasible(msg)) => {
            assert!(
                msg.contains("do not balance") && msg.contains("worst grains"),
                "{msg}"
            )
        }
        other => panic!(
            "expected a collapse error, got {:?}",
            other.map(|i| i.report.method)
        ),
    }
}

#[test]
fn default_switches_to_soft_equilibrium_and_meets_the_targets_2d() {
    let f = fixture("measured/box2d600_mu03", &photoelastic());
    let (relerr, normal, inf) = errors(&f, &with(Method::Qs, OnCollapse::Switch));
    eprintln!("2D 600 disks: switched relerr {relerr:.4}, normal {normal:.4}");
    assert_eq!(inf.report.method, Method::Soft);
    let c = inf.report.collapse.as_ref().expect("switch reported");
    assert!(c.action.contains("switched"), "{}", c.action);
    assert!(inf.report.warnings[0].contains("collapsed"));
    assert!(relerr <= 0.07, "relerr {relerr}");
    assert!(normal <= 0.045, "normal {normal}");
    // The knee of the Pareto front picks the stress-only end on these data.
    let mut knee = with(Method::Soft, OnCollapse::Fail);
    knee.dynamic.rule = LambdaRule::Knee;
    let (knee_relerr, _, _) = errors(&f, &knee);
    eprintln!("knee relerr {knee_relerr:.4}");
    assert!(
        relerr < 0.5 * knee_relerr,
        "variance {relerr} vs knee {knee_relerr}"
    );
}

#[test]
fn soft_equilibrium_meets_the_target_in_3d() {
    let f = fixture("measured/box3d300", &photoelastic());
    let (relerr, normal, inf) = errors(&f, &with(Method::Soft, OnCollapse::Fail));
    eprintln!("3D 300 spheres: soft relerr {relerr:.4}, normal {normal:.4}");
    assert!(inf.report.collapse.is_none());
    assert!(relerr <= 0.07, "relerr {relerr}");
    assert!(normal <= 0.055, "normal {normal}");
}

#[test]
fn balanced_data_are_not_flagged() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/oedometer");
    let scene = read_scene(&dir).unwrap();
    let inf = infer(&scene, &with(Method::Qs, OnCollapse::Switch)).unwrap();
    assert_eq!(inf.report.method, Method::Qs);
    assert!(inf.report.collapse.is_none());
    assert!(inf.report.stress_residual < 1e-6);
}

fn grainforce(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(args)
        .output()
        .expect("run grainforce")
}

#[test]
fn cli_switches_by_default_and_fails_on_explicit_qs() {
    let f = fixture("measured/box2d600_mu03", &photoelastic());
    let dir = tempfile::tempdir().unwrap();
    let scene_dir = dir.path().join("frame");
    write_scene(&scene_dir, &f.scene).unwrap();
    let s = scene_dir.to_str().unwrap();
    let forces = dir.path().join("forces.csv");
    let report = dir.path().join("report.json");
    let (o, r) = (forces.to_str().unwrap(), report.to_str().unwrap());

    let out = grainforce(&["infer", s, "-o", o, "--report", r]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("COLLAPSE") && stderr.contains("switched to soft"),
        "{stderr}"
    );
    let json: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(json["method"], "soft");
    assert!(json["collapse"]["imbalance_median"].as_f64().unwrap() > 0.0);

    std::fs::remove_file(&forces).unwrap();
    let out = grainforce(&["infer", s, "-o", o, "--method", "qs"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("do not balance") && !stderr.contains("panicked"),
        "{stderr}"
    );
    assert!(!forces.exists(), "no forces written on failure");

    let out = grainforce(&["infer", s, "-o", o, "--method", "qs", "--accept-degenerate"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("COLLAPSE") && stderr.contains("accepted"),
        "{stderr}"
    );
}

#[test]
fn variance_rule_lands_near_the_best_momentum_weight() {
    // The best λ of a sweep needs the truth; the variance rule does not.
    for name in ["oedometer", "regression/oedometer3d_seed1"] {
        let f = fixture(name, &photoelastic());
        let (chosen, _, inf) = errors(&f, &with(Method::Soft, OnCollapse::Fail));
        let best = (0..=20)
            .map(|i| {
                let mut o = with(Method::Soft, OnCollapse::Fail);
                o.dynamic.rule = LambdaRule::Fixed(10f64.powf(-4.0 + 0.5 * i as f64));
                errors(&f, &o).0
            })
            .fold(f64::INFINITY, f64::min);
        eprintln!(
            "{name}: variance λ {:.3e} relerr {chosen:.4}, best of sweep {best:.4}",
            inf.report.momentum_weight.unwrap()
        );
        assert!(!inf.report.variance_steps.is_empty());
        assert!(chosen <= 1.15 * best, "{name}: {chosen} vs best {best}");
    }
}
