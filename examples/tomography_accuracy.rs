//! The normal/contact table of docs/tomography.md: DEM sphere packings (and
//! clumps made from them) voxelised at several resolutions, clean and after
//! the simulated segmentation, imported with the standard (PCA) normals and
//! with the surface fits.
//!
//! cargo run --release --example tomography_accuracy -- fixtures/regression/box3d_gated [15,30,60] [spheres,clumps]

use grainforce::import::labels::{self, synth, Options};
use grainforce::scene;
use std::path::Path;

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let dir = args
        .get(1)
        .map_or("fixtures/regression/box3d_gated", String::as_str);
    let resolutions: Vec<f64> = args
        .get(2)
        .map_or("15,30,60", String::as_str)
        .split(',')
        .map(|s| s.parse().expect("resolution"))
        .collect();
    let scene = scene::read_scene(Path::new(dir))?;
    let (spheres, truth) = synth::spheres_of(&scene);
    let points = synth::contact_points(&scene);
    let mean_d = 2.0 * spheres.iter().map(|g| g.spheres[0].1).sum::<f64>() / spheres.len() as f64;
    println!(
        "{dir}: {} grains, {} grain contacts, mean diameter {mean_d:.3e} m",
        spheres.len(),
        truth.len()
    );
    println!("| grains | vox/diam | volume | method | recall | precision | median ° | p90 ° | max ° | point err (vox, median) |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let shapes = args.get(3).map_or("spheres,clumps", String::as_str);
    for shape in shapes.split(',') {
        for &res in &resolutions {
            let voxel = mean_d / res;
            let grains = if shape == "spheres" {
                spheres.clone()
            } else {
                synth::clumps_of(&spheres, &points, 0.75, 2.0 * voxel)
            };
            if shape == "clumps" {
                let clumped = grains.iter().filter(|g| g.spheres.len() > 1).count();
                eprintln!("{res}: {clumped} of {} grains are clumps", grains.len());
            }
            let grid = synth::Grid::around(&grains, voxel, 3.0);
            let (clean, fraction) = synth::voxelise(&grains, &grid);
            let (seg, grey) = synth::segment(&grains, &grid, &fraction, &segmentation());
            for (volume, lab, g) in [("clean", &clean, None), ("segmented", &seg, Some(&grey))] {
                for method in [
                    "pca",
                    "fit",
                    "fit, gap ≤ 0.5",
                    "fit, grey ≥ 0.9",
                    "fit, grey gap",
                ] {
                    if method.contains("grey") && g.is_none() {
                        continue;
                    }
                    // TOMO_ONLY=fit: that method alone (for quick comparisons).
                    if std::env::var("TOMO_ONLY").is_ok_and(|m| m != method) {
                        continue;
                    }
                    let options = Options {
                        voxel_size: voxel,
                        origin: grid.origin,
                        normals: if method == "pca" {
                            labels::NormalMethod::Pca
                        } else {
                            labels::NormalMethod::SurfaceFit
                        },
                        max_gap: method.contains("gap ≤").then_some(0.5),
                        min_grey: 0.9,
                        // Round 7's grey rule (the neck's grey alone) beside
                        // the grey gap's (with the neck's).
                        grey_gap_spread: (method == "fit, grey gap").then(|| {
                            std::env::var("TOMO_GREY_SPREAD")
                                .ok()
                                .and_then(|v| v.parse().ok())
                                .unwrap_or(3.0)
                        }),
                        fit: fit_settings(),
                        ..Options::default()
                    };
                    let grey = if method.contains("grey") {
                        g.map(|v| v.as_slice())
                    } else {
                        None
                    };
                    let t = std::time::Instant::now();
                    let imported = labels::import_array(lab, grid.shape, grey, &options)?;
                    let elapsed = t.elapsed().as_secs_f64();
                    let s = synth::score(&imported, &truth, false);
                    let a = &s.angles;
                    let mut pe: Vec<f64> = s.point_errors.iter().map(|e| e / voxel).collect();
                    pe.sort_by(f64::total_cmp);
                    println!(
                        "| {shape} | {res} | {volume} | {method} | {:.3} | {:.3} | {:.2} | {:.2} | {:.1} | {:.2} |",
                        s.recall(),
                        s.precision(),
                        synth::quantile(a, 0.5),
                        synth::quantile(a, 0.9),
                        synth::quantile(a, 1.0),
                        synth::quantile(&pe, 0.5),
                    );
                    eprintln!("  {} voxels, import {elapsed:.2} s", grid.len());
                    if std::env::var("TOMO_WORST").is_ok() && method == "fit" {
                        worst(&imported, &truth, voxel, &grains);
                    }
                    if std::env::var("TOMO_DEBUG").is_ok() && method.contains("grey") {
                        let true_pairs: std::collections::HashSet<(usize, usize)> = truth
                            .iter()
                            .map(|t| (t.a.min(t.b) + 1, t.a.max(t.b) + 1))
                            .collect();
                        for c in &imported.detected {
                            if let labels::Other::Grain(b) = c.b {
                                let t = true_pairs.contains(&(c.a as usize, b as usize));
                                // The bodies' true separation (main spheres), voxels.
                                let (ga, gb) = (&grains[c.a as usize - 1], &grains[b as usize - 1]);
                                let apart =
                                    (scene::norm(scene::sub(ga.spheres[0].0, gb.spheres[0].0))
                                        - ga.spheres[0].1
                                        - gb.spheres[0].1)
                                        / voxel;
                                let vox = |g: Option<f64>| g.map_or(f64::NAN, |g| g / voxel);
                                eprintln!(
                                    "    {} {}-{} apart {apart:.3} faces {} gap {:.3} grey {:.3} grey_gap {:.4} sd {:.4} kept {} {}",
                                    if t { "TRUE " } else { "FALSE" },
                                    c.a,
                                    b,
                                    c.faces,
                                    vox(c.gap),
                                    c.grey.unwrap_or(f64::NAN),
                                    vox(c.grey_gap),
                                    vox(c.grey_gap_sd),
                                    c.kept as u8,
                                    c.method
                                );
                            }
                        }
                    }
                }
            }
        }
    }
    Ok(())
}

/// The simulated segmentation, with TOMO_BLUR / TOMO_NOISE / TOMO_SEED
/// overriding the defaults (σ = 1 voxel, noise 0.1 of the contrast).
fn segmentation() -> synth::Segmentation {
    let mut seg = synth::Segmentation::default();
    let var = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<f64>().ok());
    if let Some(v) = var("TOMO_BLUR") {
        seg.blur = v;
    }
    if let Some(v) = var("TOMO_NOISE") {
        seg.noise = v;
    }
    if let Some(v) = var("TOMO_SEED") {
        seg.seed = v as u64;
    }
    seg
}

/// The fit settings, with TOMO_PRIOR / TOMO_GEO / TOMO_GATE overriding the
/// defaults (to compare settings without a rebuild).
fn fit_settings() -> labels::FitSettings {
    let mut fit = labels::FitSettings::default();
    let var = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<f64>().ok());
    if let Some(v) = var("TOMO_PRIOR") {
        fit.radius_prior = v;
    }
    if let Some(v) = var("TOMO_GEO") {
        fit.geometric_refits = v as usize;
    }
    if let Some(v) = var("TOMO_GATE") {
        fit.gate = v;
    }
    if let Some(v) = var("TOMO_WINDOW") {
        fit.window = v;
    }
    if let Some(v) = var("TOMO_NECK") {
        fit.max_neck = v;
    }
    if let Some(v) = var("TOMO_APART") {
        fit.max_apart = v;
    }
    if let Some(v) = var("TOMO_SHELL") {
        fit.min_shell = v;
    }
    if let Some(v) = var("TOMO_ROBUST") {
        fit.robust_samples = v as usize;
    }
    if let Some(v) = var("TOMO_RGATE") {
        fit.robust_gate = v;
    }
    if let Some(v) = var("TOMO_EXCL") {
        fit.exclusion = v;
    }
    if let Some(v) = var("TOMO_GREY_PRIOR") {
        fit.grey_radius_prior = v;
    }
    fit
}

/// The worst-placed normals of a run, with what the fit saw (TOMO_WORST=1).
fn worst(
    imported: &labels::LabelScene,
    truth: &[synth::TrueContact],
    voxel: f64,
    grains: &[synth::SynthGrain],
) {
    // Voxels from the contact to the nearest crease of a grain: its
    // satellite's surface and its cut plane (infinite: none).
    let features = |g: usize, p: [f64; 3]| {
        let sat = grains[g].spheres[1..]
            .iter()
            .map(|(c, r)| (scene::norm(scene::sub(p, *c)) - r) / voxel)
            .fold(f64::INFINITY, f64::min);
        let cut = grains[g]
            .cuts
            .iter()
            .map(|(n, d)| (d - scene::dot(*n, p)) / voxel)
            .fold(f64::INFINITY, f64::min);
        (sat, cut)
    };
    let mut rows = Vec::new();
    for t in truth {
        let key = (t.a.min(t.b) + 1, t.a.max(t.b) + 1);
        let zones: Vec<_> = imported
            .detected
            .iter()
            .filter(|c| match c.b {
                labels::Other::Grain(b) => (c.a as usize, b as usize) == key,
                _ => false,
            })
            .collect();
        let Some(c) = zones.iter().max_by_key(|c| c.faces) else {
            continue;
        };
        let sign = if c.a as usize - 1 == t.a { 1.0 } else { -1.0 };
        let angle = |n: [f64; 3]| {
            (sign * scene::dot(n, t.normal))
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        };
        rows.push((
            angle(c.normal),
            angle(c.pca_normal),
            c.method,
            c.faces,
            zones.len(),
            c.fit_rms.map(|r| r.map(|r| r / voxel)),
            c.gap.map(|g| g / voxel),
            features(t.a, t.point),
            features(t.b, t.point),
        ));
    }
    rows.sort_by(|x, y| y.0.total_cmp(&x.0));
    let show = std::env::var("TOMO_WORST")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(15);
    for r in rows.iter().take(show) {
        eprintln!(
            "    fit {:5.2}° pca {:5.2}° {} faces {} zones {} rms {:.2?} gap {:.2?} sat/cut a {:.1}/{:.1} b {:.1}/{:.1}",
            r.0, r.1, r.2, r.3, r.4, r.5, r.6, r.7 .0, r.7 .1, r.8 .0, r.8 .1
        );
    }
    let rms: Vec<f64> = rows
        .iter()
        .flat_map(|r| r.5.into_iter().flatten())
        .collect();
    eprintln!(
        "    rms quantiles 10/50/90: {:.2} {:.2} {:.2}",
        synth::quantile(&rms, 0.1),
        synth::quantile(&rms, 0.5),
        synth::quantile(&rms, 0.9)
    );
}
