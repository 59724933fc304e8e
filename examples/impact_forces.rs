//! The dynamic worked example: the `impact` preset (six disks struck in a
//! corner, 5000 frames/s), forces inferred every frame, and a plot of force
//! against time at the most loaded contacts, inferred vs DEM.
//!
//!     cargo run --release --example impact_forces [OUT.png]

use grainforce::dem::{simulate, DemConfig, Preset};
use grainforce::infer::{infer_sequence, InferOptions, Method};
use grainforce::report::chart::{save_png, Chart, Scale, PALETTE};
use grainforce::scene::norm;
use std::collections::BTreeMap;

fn main() -> grainforce::Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "impact-forces.png".into());
    let run = simulate(&DemConfig::preset(Preset::Impact, 2).seed(1))?;
    let fps = 5000.0;
    let start = std::time::Instant::now();
    let opts = InferOptions {
        method: Method::Dynamic,
        ..InferOptions::default()
    };
    let results = infer_sequence(&run.frames, &opts, None)?;
    let seconds = start.elapsed().as_secs_f64();
    eprintln!(
        "{} frames in {seconds:.2} s ({:.0} frames/s)",
        run.frames.len(),
        run.frames.len() as f64 / seconds
    );

    // |f| over time per contact id (a contact exists only while grains touch).
    let mut inferred: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    let mut truth: BTreeMap<String, Vec<(f64, f64)>> = BTreeMap::new();
    for ((frame, forces), r) in run.frames.iter().zip(&run.forces).zip(&results) {
        let t = frame.frame.unwrap_or(0) as f64 / fps * 1e3;
        for ((c, f), g) in frame.contacts.iter().zip(forces).zip(r.forces_or_zero()) {
            let name = format!(
                "{}-{}",
                frame.grains[c.a].id,
                grainforce::scene::body_name(frame, c.b)
            );
            truth.entry(name.clone()).or_default().push((t, norm(*f)));
            inferred.entry(name).or_default().push((t, norm(g)));
        }
    }
    let mut peaks: Vec<(String, f64)> = truth
        .iter()
        .map(|(k, v)| (k.clone(), v.iter().map(|p| p.1).fold(0.0, f64::max)))
        .collect();
    peaks.sort_by(|a, b| b.1.total_cmp(&a.1));
    let mut chart = Chart::new(900, 520)
        .title("impact preset: contact force vs time (lines: inferred, dots: DEM)")
        .x_axis("time [ms]", Scale::Linear)
        .y_axis("|f| [N/m]", Scale::Linear);
    for (k, (name, _)) in peaks.iter().take(4).enumerate() {
        chart = chart
            .line(&format!("contact {name}"), &inferred[name], PALETTE[k])
            .scatter("", &truth[name], PALETTE[k]);
    }
    save_png(std::path::Path::new(&out), &chart.render())?;
    eprintln!("wrote {out}");
    Ok(())
}
