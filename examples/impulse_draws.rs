//! The filtered pipeline on `impact` over twelve position-noise draws (0.1 %
//! of a diameter): relerr of the forces and the impulse check of the moving
//! grains, against the measured Δv and against the noise-free one.
//!
//!     cargo run --example impulse_draws [fir ORDER CUTOFF | savgol WINDOW DEGREE | whittaker CUTOFF _] [REL_ACCEL_SD | knee]
//!
//! Without REL_ACCEL_SD the momentum weights are the library's per-frame ones
//! for derived accelerations; with it, one relative m·a noise for all frames.

#[path = "support/impact_draws.rs"]
mod impact_draws;

use grainforce::infer::kinematics::{derive_accelerations, weight_derived_momentum, Smoother};
use grainforce::infer::{infer_frames, InferOptions, LambdaRule, Method};
use impact_draws::ImpactDraws;

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
    let knee = args.get(3).is_some_and(|a| a == "knee");
    let relative: Option<f64> = args.get(3).and_then(|s| s.parse().ok());
    let base = InferOptions {
        method: Method::Dynamic,
        ..Default::default()
    };
    let draws = ImpactDraws::new()?;
    let tally = draws.tally(|mut noisy| {
        let report = derive_accelerations(&mut noisy, draws.fps, smoother)?;
        let mut per_frame = vec![base.clone(); noisy.len()];
        match relative {
            _ if knee => {
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
        let results = infer_frames(&noisy, &per_frame, None)?;
        let forces = results.into_iter().map(|r| r.forces).collect();
        Ok((noisy, forces))
    })?;
    let weights = match relative {
        _ if knee => "knee".into(),
        Some(sd) => format!("relative m·a noise {sd}"),
        None => "per-frame derived-acceleration noise".into(),
    };
    tally.print(&format!("{smoother:?}, {weights}"));
    Ok(())
}
