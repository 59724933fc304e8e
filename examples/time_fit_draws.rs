//! The joint time fit (`--time-fit joint`) on the twelve `impact` draws of
//! `impulse_draws` (position noise 0.1 % of a diameter): relerr and the
//! impulse check, beside the frame-by-frame pipeline it starts from.
//!
//!     cargo run --release --example time_fit_draws [STRESS_SD] [ROUGHNESS_N | SCALEx] [impact | bed-impact]
//!
//! ROUGHNESS_N fixes σ_r in newtons; `2x` sets it to twice the rms second
//! difference of the frame-by-frame answer (default: the library's choice,
//! `ROUGHNESS_FACTOR` times that).

#[path = "support/impact_draws.rs"]
mod impact_draws;

use grainforce::dem::Preset;
use grainforce::infer::kinematics::{derive_accelerations, weight_derived_momentum, Smoother};
use grainforce::infer::time_fit::{estimate_roughness, infer_time_fit, TimeFitOptions};
use grainforce::infer::{infer_frames, InferOptions, Method};
use impact_draws::ImpactDraws;

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let stress_sd: f64 = args.first().and_then(|s| s.parse().ok()).unwrap_or(0.1);
    let roughness = args.get(1).cloned().unwrap_or_else(|| "default".into());
    let opts = InferOptions {
        method: Method::Dynamic,
        ..Default::default()
    };
    let draws = match args.get(2).map(String::as_str) {
        Some("bed-impact") => ImpactDraws::of(Preset::BedImpact)?,
        _ => ImpactDraws::new()?,
    };
    let fps = draws.fps;
    let mut estimates = Vec::new();
    let tally = draws.tally(|mut noisy| {
        let report = derive_accelerations(&mut noisy, fps, Smoother::default_fir())?;
        let mut per_frame = vec![opts.clone(); noisy.len()];
        weight_derived_momentum(&noisy, &mut per_frame, &report, stress_sd)?;
        let frame_by_frame: Vec<_> = infer_frames(&noisy, &per_frame, None)?
            .into_iter()
            .map(|r| r.forces)
            .collect();
        let mut fit = TimeFitOptions::new(fps);
        fit.stress_sd = stress_sd;
        let estimate = estimate_roughness(&noisy, &frame_by_frame)
            .ok_or_else(|| grainforce::Error::Invalid("no roughness estimate".into()))?;
        estimates.push(estimate);
        fit.roughness = match roughness.strip_suffix('x') {
            Some(scale) => Some(scale.parse::<f64>().unwrap_or(1.0) * estimate),
            None => roughness.parse().ok(),
        };
        let joint = infer_time_fit(&noisy, &opts, &fit, Some(&frame_by_frame))?;
        eprint!("{}", joint.report);
        Ok((noisy, joint.forces))
    })?;
    if !estimates.is_empty() {
        estimates.sort_by(f64::total_cmp);
        println!(
            "rms second difference of the frame-by-frame answer: {:.0}..{:.0} N",
            estimates[0],
            estimates[estimates.len() - 1]
        );
    }
    tally.print(&format!("time fit, stress sd {stress_sd}, σ_r {roughness}"));
    Ok(())
}
