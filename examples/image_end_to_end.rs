//! The image chain end to end on the bundled oedometer (58 disks, exact DEM
//! forces): render at several resolutions → detect → contacts → DIC strain →
//! stress → infer (qs, tikhonov, scaled), each stage scored against the DEM.
//!
//!     cargo run --example image_end_to_end [PX_PER_DIAMETER ...] [--step N]

#[path = "../tests/e2e_pipeline/mod.rs"]
mod pipeline;

use grainforce::infer::Method;
use std::path::Path;

fn main() -> grainforce::Result<()> {
    let mut resolutions = Vec::new();
    let mut step = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        if a == "--step" {
            step = args.next().and_then(|s| s.parse().ok());
        } else if let Ok(v) = a.parse::<f64>() {
            resolutions.push(v);
        }
    }
    if resolutions.is_empty() {
        resolutions = vec![40.0, 70.0, 100.0, 140.0];
    }
    println!(
        "px/diam  image      disks  centre  radius  contacts found/true/matched  recall  precision  normal°  stress err | geometry-only qs/tik/scaled | relerr qs  tikhonov  scaled | all-contacts qs | time render/detect/strain/infer [s]"
    );
    for px in resolutions {
        let mut setup = pipeline::Setup::new(px);
        if let Some(s) = step {
            setup.dic.step = s;
        }
        let o = pipeline::run(Path::new("fixtures/oedometer"), &setup)?;
        let g = |m: Method| {
            o.geometry_only_relerr
                .iter()
                .find(|p| p.0 == m)
                .map(|p| p.1)
                .unwrap_or(f64::NAN)
        };
        println!(
            "{px:>7.0}  {:>4}×{:<4}  {:>2}/{:<2}  {:>6.3}  {:>6.3}  {:>3}/{:>3}/{:>3}  {:>6.3}  {:>9.3}  {:>7.2}  {:>10.4} | {:.4} {:.4} {:.4} | {:.4} {:.4} {:.4} | {:.4} | {:.1} {:.1} {:.1} {:.1}",
            o.image_size.0,
            o.image_size.1,
            o.disks_matched,
            o.grains_truth,
            o.worst_centre_px,
            o.worst_radius_px,
            o.contacts_found,
            o.contacts_truth,
            o.contacts_matched,
            o.recall(),
            o.precision(),
            o.worst_normal_deg,
            o.stress_relerr,
            g(Method::Qs),
            g(Method::Tikhonov),
            g(Method::Scaled),
            o.relerr_of(Method::Qs),
            o.relerr_of(Method::Tikhonov),
            o.relerr_of(Method::Scaled),
            o.relerr_all[0].1,
            o.seconds[0],
            o.seconds[1],
            o.seconds[2],
            o.seconds[3],
        );
    }
    Ok(())
}
