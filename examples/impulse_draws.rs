//! The filtered pipeline on `impact` over twelve position-noise draws (0.1 %
//! of a diameter): relerr of the forces and the impulse check of the moving
//! grains, against the measured Δv and against the noise-free one.
//!
//!     cargo run --example impulse_draws [fir ORDER CUTOFF | savgol WINDOW DEGREE | whittaker CUTOFF _] [REL_ACCEL_SD | knee]
//!
//! Without REL_ACCEL_SD the momentum weights are the library's per-frame ones
//! for derived accelerations; with it, one relative m·a noise for all frames.

use grainforce::dem::perturb::{perturb, PerturbConfig};
use grainforce::dem::{simulate, DemConfig, Preset};
use grainforce::infer::kinematics::{
    derive_accelerations, impulse_check, weight_derived_momentum, ImpulseOptions, Smoother,
};
use grainforce::infer::{infer_frames, InferOptions, LambdaRule, Method};
use grainforce::report::metrics::relative_error;
use grainforce::scene::Vec3;

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize, d: f64| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let smoother = match args.first().map(String::as_str) {
        Some("savgol") => Smoother::SavitzkyGolay {
            window: num(1, 11.0) as usize,
            degree: num(2, 3.0) as usize,
        },
        Some("whittaker") => Smoother::Whittaker {
            cutoff: num(1, 0.15),
        },
        Some("fir") => Smoother::Fir {
            order: num(1, 20.0) as usize,
            cutoff: num(2, 0.15),
        },
        _ => Smoother::default_fir(),
    };
    let relative: Option<f64> = args.get(3).and_then(|s| s.parse().ok());
    let run = simulate(&DemConfig::preset(Preset::Impact, 2).seed(1))?;
    let fps = 5000.0;
    let gravity = run.frames[0].gravity();
    let diameter = 2.0 * run.frames[0].grains[0].radius.unwrap();
    let options = ImpulseOptions::default();
    let truth: Vec<Vec<Option<Vec3>>> = run
        .forces
        .iter()
        .map(|f| f.iter().map(|&x| Some(x)).collect())
        .collect();
    let exact = impulse_check(&run.frames, &truth, fps, gravity, &options)?;
    let base = InferOptions {
        method: Method::Dynamic,
        ..Default::default()
    };
    let (mut moving, mut vs_true, mut relerrs) = (Vec::new(), Vec::new(), Vec::new());
    for seed in 1..=12 {
        let config = PerturbConfig {
            position_noise: 1e-3 * diameter,
            seed,
            ..Default::default()
        };
        let mut noisy = perturb(&run.frames, &config)?;
        let report = derive_accelerations(&mut noisy, fps, smoother)?;
        let mut per_frame = vec![base.clone(); noisy.len()];
        match relative {
            _ if args.get(3).is_some_and(|a| a == "knee") => {
                for o in &mut per_frame {
                    o.dynamic.rule = LambdaRule::Knee;
                }
            }
            Some(sd) => {
                for o in &mut per_frame {
                    o.dynamic.rule = LambdaRule::Weights {
                        stress_sd: 0.1,
                        momentum_sd: sd,
                    };
                }
            }
            None => weight_derived_momentum(&noisy, &mut per_frame, &report, 0.1)?,
        }
        let results = infer_frames(&noisy, &per_frame, false)?;
        let t: Vec<Vec3> = run.forces.iter().flatten().copied().collect();
        let f: Vec<Vec3> = results.iter().flat_map(|r| r.forces_or_zero()).collect();
        let e = relative_error(&t, &f);
        relerrs.push(e);
        let inferred: Vec<Vec<Option<Vec3>>> = results.iter().map(|r| r.forces.clone()).collect();
        let check = impulse_check(&noisy, &inferred, fps, gravity, &options)?;
        let mut line =
            format!("seed {seed:2}: relerr {e:.4}; disagreement (vs measured/noise-free Δv)");
        for (r, x) in check.rows.iter().zip(&exact.rows) {
            let gap = (r.inferred[0] - x.measured[0]).hypot(r.inferred[1] - x.measured[1]);
            let d = gap / x.measured[0].hypot(x.measured[1]);
            let mark = if r.moves { "" } else { "~" };
            line.push_str(&format!(" {mark}{:.3}/{d:.3}", r.disagreement));
            if r.moves {
                moving.push(r.disagreement);
                vs_true.push(d);
            }
        }
        println!("{line}");
    }
    let summary = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        let within = v.iter().filter(|&&d| d <= 0.10).count();
        format!(
            "median {:.3}, 90th percentile {:.3}, worst {:.3}, {within}/{} within 10 %",
            v[v.len() / 2],
            v[(v.len() * 9) / 10],
            v[v.len() - 1],
            v.len()
        )
    };
    relerrs.sort_by(f64::total_cmp);
    let weights = match relative {
        _ if args.get(3).is_some_and(|a| a == "knee") => "knee".into(),
        Some(sd) => format!("relative m·a noise {sd}"),
        None => "per-frame derived-acceleration noise".into(),
    };
    println!(
        "{smoother:?}, {weights}: relerr {:.4}..{:.4}",
        relerrs[0], relerrs[11]
    );
    println!(
        "moving grains (~: not moving), vs measured Δv:   {}",
        summary(&mut moving)
    );
    println!("moving grains, vs noise-free Δv: {}", summary(&mut vs_true));
    Ok(())
}
