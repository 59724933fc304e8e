//! The library's one configuration and one run: a JSON configuration, the
//! CLI's flags and `infer::run` give the same files; errors name the field
//! (the CLI spells it as its flag); `wall_mu` sets the walls' friction.

use grainforce::infer::run::{self, Source};
use grainforce::infer::{InferConfig, Method};
use grainforce::scene::{self, Body};
use std::path::Path;

const OEDOMETER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/oedometer");

fn cli(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn a_json_configuration_gives_the_cli_files_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let config = InferConfig::from_json(
        r#"{"method": "tikhonov", "lambda_precision": "coarse", "solver": "active_set",
            "ordering": "nested_dissection", "mu": 0.4}"#,
    )
    .unwrap();
    assert_eq!(config.method, Some(Method::Tikhonov));
    let ran = run::run(Source::Folder(Path::new(OEDOMETER)), &config, None).unwrap();
    let mine = dir.path().join("mine.csv");
    scene::write_forces(&mine, &ran.forces()).unwrap();
    let theirs = dir.path().join("cli.csv");
    let out = cli(&[
        "-q",
        "infer",
        OEDOMETER,
        "-o",
        theirs.to_str().unwrap(),
        "-m",
        "tikhonov",
        "--lambda-precision",
        "coarse",
        "--ordering",
        "nested-dissection",
        "--mu",
        "0.4",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read(&mine).unwrap(),
        std::fs::read(&theirs).unwrap()
    );
    // A round trip through JSON keeps every field.
    let text = serde_json::to_string(&config).unwrap();
    assert_eq!(InferConfig::from_json(&text).unwrap(), config);
}

#[test]
fn errors_name_the_field_and_the_cli_spells_it_as_its_flag() {
    let e = InferConfig::from_json(r#"{"colour": "red"}"#).unwrap_err();
    assert!(e.to_string().contains("unknown field `colour`"), "{e}");
    let e = InferConfig::from_json(r#"{"solver": "active-set"}"#).unwrap_err();
    assert!(
        e.to_string().contains("unknown variant `active-set`"),
        "{e}"
    );
    let cases: [(InferConfig, &str, &str); 5] = [
        (
            InferConfig {
                tolerance: Some(2.0),
                ..Default::default()
            },
            "tolerance",
            "(0, 1)",
        ),
        (
            InferConfig {
                time_fit: grainforce::infer::config::TimeFitChoice::Joint,
                ..Default::default()
            },
            "time_fit",
            "`method` = dynamic",
        ),
        (
            InferConfig {
                wall_mu: Some(-0.1),
                ..Default::default()
            },
            "wall_mu",
            "non-negative",
        ),
        (
            InferConfig {
                uncertainty: Some(1),
                ..Default::default()
            },
            "uncertainty",
            "at least 2 draws",
        ),
        (
            InferConfig {
                lambda_rule: grainforce::infer::config::RuleChoice::Fixed,
                ..Default::default()
            },
            "lambda",
            "`lambda_rule` = fixed needs `lambda`",
        ),
    ];
    for (config, field, text) in cases {
        let e = config.validate().unwrap_err();
        assert_eq!(e.field, field, "{e}");
        assert!(e.message.contains(text), "{e}");
        assert!(!e.message.contains("--"), "{e}");
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("f.csv");
    let run = cli(&[
        "infer",
        OEDOMETER,
        "-o",
        out.to_str().unwrap(),
        "--lambda-rule",
        "fixed",
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success() && !out.exists());
    assert!(
        stderr.contains("--lambda-rule fixed needs --lambda"),
        "{stderr}"
    );
}

/// Lubricated walls: the oedometer's DEM walls are frictionless, its
/// grains not. Without the `mu` column the scene's μ = 0.5 applies to every
/// contact; `wall_mu` = 0 makes each grain–wall force normal, as in the
/// truth, and leaves the grain contacts their friction.
#[test]
fn wall_mu_sets_the_friction_of_the_wall_contacts_only() {
    let mut scene = scene::read_scene(Path::new(OEDOMETER)).unwrap();
    for c in &mut scene.contacts {
        c.mu = None;
    }
    let truth = scene::read_forces(&Path::new(OEDOMETER).join("forces.csv")).unwrap();
    let frames = [scene.clone()];
    let infer = |wall_mu: Option<f64>| {
        let config = InferConfig {
            method: Some(Method::Qs),
            wall_mu,
            ..Default::default()
        };
        run::run(Source::Frames(&frames), &config, None).unwrap()
    };
    // |f_t| / |f_n| of a 2D contact force.
    let slip = |c: &scene::Contact, f: [f64; 3]| {
        let n = c.normal;
        let normal = f[0] * n[0] + f[1] * n[1];
        let tangential = -f[0] * n[1] + f[1] * n[0];
        tangential.abs() / normal.abs().max(1e-300)
    };
    let smooth = infer(Some(0.0));
    let (mut walls, mut grains_slip) = (0, 0.0f64);
    for (i, c) in scene.contacts.iter().enumerate() {
        let f = smooth.results[0].forces[i].unwrap();
        match c.b {
            Body::Wall(_) if f != [0.0; 3] => {
                walls += 1;
                assert!(slip(c, f) < 1e-9, "contact {}: {f:?}", c.id);
            }
            Body::Grain(_) if f != [0.0; 3] => grains_slip = grains_slip.max(slip(c, f)),
            _ => {}
        }
    }
    assert!(walls >= 10, "{walls} loaded wall contacts");
    assert!(
        grains_slip > 0.05 && grains_slip <= 0.5 + 1e-9,
        "{grains_slip}"
    );
    // Exact data: both answers recover the truth, which either model admits.
    let scale = truth
        .rows
        .iter()
        .map(|r| r.force[0].abs().max(r.force[1].abs()))
        .fold(0.0f64, f64::max);
    for ran in [&smooth, &infer(None)] {
        for (c, f) in scene.contacts.iter().zip(&ran.results[0].forces) {
            let t = truth.rows.iter().find(|r| r.contact == c.id).unwrap().force;
            let f = f.unwrap();
            let gap = (f[0] - t[0]).abs().max((f[1] - t[1]).abs());
            assert!(gap <= 1e-6 * scale, "contact {}: {f:?} vs {t:?}", c.id);
        }
    }
    let e = run::run(
        Source::Frames(&frames),
        &InferConfig {
            wall_mu: Some(f64::NAN),
            ..Default::default()
        },
        None,
    )
    .unwrap_err();
    assert!(e.to_string().contains("`wall_mu`"), "{e}");
}

/// The options bench's method names stood for before they became presets of
/// the configuration (the former `method_spec`, written out).
fn former_spec(name: &str) -> grainforce::infer::InferOptions {
    use grainforce::infer::{
        ConeModel, ConstrainedSolver, InferOptions, LambdaPrecision, StressNoise,
    };
    let mut o = InferOptions::default();
    match name {
        "qs" => o.method = Method::Qs,
        "tikhonov" => {
            o.method = Method::Tikhonov;
            o.lambda = Some(0.25);
        }
        "tikhonov-coarse" => {
            o.method = Method::Tikhonov;
            o.lambda_search.precision = LambdaPrecision::Coarse;
        }
        "qs-pyr8" => {
            o.method = Method::Qs;
            o.cone = ConeModel::Pyramid(8);
        }
        "tikhonov-relaxed-relative-nocheck" => {
            o.method = Method::Tikhonov;
            o.lambda = Some(0.25);
            o.conic.tolerance = 1e-4;
            o.conic.noise_share = None;
            o.solver = ConstrainedSolver::InteriorPoint;
            o.stress_noise = StressNoise::Relative;
            o.identifiability_limit = 0;
        }
        "ls-nocheck" => {
            o.method = Method::Ls;
            o.identifiability_limit = 0;
        }
        "soft" => o.method = Method::Soft,
        _ => panic!("no former spec for {name}"),
    }
    o
}

#[test]
fn bench_names_are_presets_of_the_configuration() {
    use grainforce::bench;
    for name in [
        "qs",
        "tikhonov",
        "tikhonov-coarse",
        "qs-pyr8",
        "tikhonov-relaxed-relative-nocheck",
        "ls-nocheck",
        "soft",
    ] {
        let preset = bench::preset(name, 0.25).unwrap();
        preset.validate().unwrap();
        // A preset is a configuration like any other: it survives a file.
        let text = serde_json::to_string(&preset).unwrap();
        assert_eq!(InferConfig::from_json(&text).unwrap(), preset);
        let (options, _) = preset.options().unwrap();
        assert_eq!(
            format!("{options:?}"),
            format!("{:?}", former_spec(name)),
            "{name}"
        );
        assert_eq!(bench::method_spec(name, 0.25).unwrap().name, name);
    }
    for bad in [
        "ls-ip",
        "scaled-relaxed",
        "qs-pyr2",
        "qs-nocheck-relative",
        "lasso",
    ] {
        let e = bench::preset(bad, 0.25).unwrap_err().to_string();
        assert!(e.contains(&format!("unknown bench method `{bad}`")), "{e}");
    }
}

#[test]
fn uniqueness_limit_skips_the_check_and_is_a_checked_field() {
    let config = InferConfig::from_json(r#"{"method": "qs", "uniqueness_limit": 0}"#).unwrap();
    assert_eq!(config.options().unwrap().0.identifiability_limit, 0);
    let skipped = run::run(Source::Folder(Path::new(OEDOMETER)), &config, None).unwrap();
    assert_eq!(skipped.results[0].report.unique, None);
    let checked = run::run(
        Source::Folder(Path::new(OEDOMETER)),
        &InferConfig {
            method: Some(Method::Qs),
            ..Default::default()
        },
        None,
    )
    .unwrap();
    assert_eq!(checked.results[0].report.unique, Some(true));
    // The same answer either way: the check only reports.
    assert_eq!(skipped.forces().rows, checked.forces().rows);
    for bad in [
        r#"{"uniqueness_limit": -1}"#,
        r#"{"uniqueness_limit": 1.5}"#,
    ] {
        let e = InferConfig::from_json(bad).unwrap_err().to_string();
        assert!(e.contains("field `uniqueness_limit`: invalid"), "{e}");
    }
}

#[test]
fn a_config_file_fills_the_configuration_and_flags_override_it() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("config.json");
    std::fs::write(
        &file,
        r#"{"method": "tikhonov", "lambda_precision": "coarse", "mu": 0.3}"#,
    )
    .unwrap();
    let run_cli = |extra: &[&str], out: &Path| {
        let mut args = vec!["-q", "infer", OEDOMETER, "-o", out.to_str().unwrap()];
        args.extend_from_slice(extra);
        let o = cli(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    // The file alone is its fields as flags.
    let (from_file, as_flags) = (dir.path().join("file.csv"), dir.path().join("flags.csv"));
    run_cli(&["--config", file.to_str().unwrap()], &from_file);
    run_cli(
        &[
            "-m",
            "tikhonov",
            "--lambda-precision",
            "coarse",
            "--mu",
            "0.3",
        ],
        &as_flags,
    );
    assert_eq!(
        std::fs::read(&from_file).unwrap(),
        std::fs::read(&as_flags).unwrap()
    );
    // A flag given on the command line wins over the file; the others stay.
    let (overridden, expected) = (dir.path().join("over.csv"), dir.path().join("exp.csv"));
    run_cli(
        &["--config", file.to_str().unwrap(), "-m", "qs"],
        &overridden,
    );
    run_cli(
        &["-m", "qs", "--lambda-precision", "coarse", "--mu", "0.3"],
        &expected,
    );
    assert_eq!(
        std::fs::read(&overridden).unwrap(),
        std::fs::read(&expected).unwrap()
    );
    assert_ne!(
        std::fs::read(&overridden).unwrap(),
        std::fs::read(&from_file).unwrap()
    );
}

#[test]
fn config_file_errors_name_the_file_and_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("forces.csv");
    let cases = [
        (
            r#"{"method": "qs", "colour": "red"}"#,
            "field `colour`: unknown field `colour`",
        ),
        (
            r#"{"mu": "high"}"#,
            "field `mu`: invalid type: string \"high\"",
        ),
        (
            r#"{"solver": "active-set"}"#,
            "field `solver`: unknown variant `active-set`",
        ),
        (r#"{"tolerance": 2.0}"#, "`tolerance` in "),
        (
            r#"{"method": "qs""#,
            "not JSON: EOF while parsing an object at line 1",
        ),
        (r#"["qs"]"#, "a configuration is a JSON object of fields"),
        (r#"{"impulse": true}"#, "give --impulse FILE"),
    ];
    for (text, expected) in cases {
        let file = dir.path().join("bad.json");
        std::fs::write(&file, text).unwrap();
        let (failed, stderr) = infer_with_config(&out, &file, &[]);
        assert!(failed, "{text}");
        assert!(stderr.contains(file.to_str().unwrap()), "{text}: {stderr}");
        assert!(stderr.contains(expected), "{text}: {stderr}");
        assert!(!out.exists(), "{text}: no output on an error");
    }
    // A bad value given as a flag is still spelled as the flag.
    let file = dir.path().join("good.json");
    std::fs::write(&file, r#"{"method": "qs"}"#).unwrap();
    let (failed, stderr) = infer_with_config(&out, &file, &["--tolerance", "2"]);
    assert!(
        failed && stderr.contains("--tolerance must lie in (0, 1)"),
        "{stderr}"
    );
    let missing = dir.path().join("missing.json");
    let (failed, stderr) = infer_with_config(&out, &missing, &[]);
    assert!(
        failed && stderr.contains(missing.to_str().unwrap()),
        "{stderr}"
    );
}

/// `infer` on the oedometer with a config file and extra flags: whether it
/// failed, and its stderr.
fn infer_with_config(out: &Path, config: &Path, extra: &[&str]) -> (bool, String) {
    let mut args = vec![
        "infer",
        OEDOMETER,
        "-o",
        out.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    let o = cli(&args);
    (
        !o.status.success(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}
