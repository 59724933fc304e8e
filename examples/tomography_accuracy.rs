//! The normal/contact table of docs/tomography.md: DEM sphere packings (and
//! clumps made from them) voxelised at several resolutions, clean and after
//! the simulated segmentation, imported with the standard (PCA) normals and
//! with the surface fits.
//!
//! cargo run --release --example tomography_accuracy -- fixtures/regression/box3d_gated [15,30,60] [spheres,clumps]

use grainforce::import::labels::{self, synth, Options};
use grainforce::scene;
use std::path::Path;

/// The sphere rule's limit when neither TOMO_WHOLE nor the import's
/// default gives one.
const WHOLE_SPHERE_LIMIT: f64 = 1.1;

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
                if std::env::var("TOMO_DEBUG").is_ok() {
                    let labels: Vec<usize> = (0..grains.len())
                        .filter(|&i| grains[i].spheres.len() > 1)
                        .map(|i| i + 1)
                        .collect();
                    eprintln!("  clumps' labels: {labels:?}");
                }
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
                    "fit, grey gap + spheres",
                ] {
                    if method.contains("grey") && g.is_none() {
                        continue;
                    }
                    // TOMO_ONLY=fit: that method alone (for quick comparisons);
                    // several separated by ';'.
                    if std::env::var("TOMO_ONLY").is_ok_and(|m| m.split(';').all(|m| m != method)) {
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
                        grey_gap_spread: method.starts_with("fit, grey gap").then(|| {
                            std::env::var("TOMO_GREY_SPREAD")
                                .ok()
                                .and_then(|v| v.parse().ok())
                                .unwrap_or(3.0)
                        }),
                        // "+ spheres": each grain's whole sphere combined
                        // with the neck fit (sphere rule: misfit ≤ TOMO_WHOLE).
                        grey_whole_spheres: if method.ends_with("+ spheres") {
                            std::env::var("TOMO_WHOLE")
                                .ok()
                                .and_then(|v| v.parse().ok())
                                .or(Options::default().grey_whole_spheres)
                                .or(Some(WHOLE_SPHERE_LIMIT))
                        } else {
                            None
                        },
                        // TOMO_MISFIT: the neck fit's misfit (over the
                        // zones' median) above which the grey gap drops nothing.
                        grey_gap_max_misfit: std::env::var("TOMO_MISFIT")
                            .ok()
                            .and_then(|v| v.parse().ok())
                            .unwrap_or(Options::default().grey_gap_max_misfit),
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
                        let rms = debug_zones(&imported, &truth, voxel, &grains);
                        gap_limit(&truth, voxel, &grains, res, &segmentation(), rms);
                    }
                    if let (Ok(dir), Some(g)) = (std::env::var("TOMO_DUMP"), grey) {
                        dump(
                            Path::new(&dir),
                            &format!("{shape}{res}"),
                            lab,
                            g,
                            &grid,
                            &imported,
                            &grains,
                        )?;
                    }
                }
            }
        }
    }
    Ok(())
}

/// Every grain–grain zone with the bodies' true separation (main spheres),
/// its grey evidence and whether it was kept; then the grey-gap rule's
/// threshold and the estimate's error on the true contacts (TOMO_DEBUG=1);
/// returns that error's rms [voxels].
fn debug_zones(
    imported: &labels::LabelScene,
    truth: &[synth::TrueContact],
    voxel: f64,
    grains: &[synth::SynthGrain],
) -> f64 {
    let true_pairs = synth::true_pairs(truth);
    let vox = |g: Option<f64>| g.map_or(f64::NAN, |g| g / voxel);
    let gaps: Vec<f64> = imported
        .detected
        .iter()
        .filter_map(|c| c.grey_gap.map(|g| g / voxel))
        .collect();
    let median = synth::quantile(&gaps, 0.5);
    let deviations: Vec<f64> = gaps.iter().map(|g| (g - median).abs()).collect();
    let spread = 1.4826 * synth::quantile(&deviations, 0.5);
    let mut errors = Vec::new();
    let mut rows = Vec::new();
    for c in &imported.detected {
        let labels::Other::Grain(b) = c.b else {
            continue;
        };
        let t = true_pairs.contains(&(c.a, b));
        let apart = synth::apart(&grains[c.a as usize - 1], &grains[b as usize - 1]) / voxel;
        let g = vox(c.grey_gap);
        if t {
            errors.push(g - median - apart);
        }
        rows.push((apart, t, c, g));
    }
    rows.sort_by(|x, y| x.0.total_cmp(&y.0));
    gap_bias(&rows, median);
    for (apart, t, c, g) in rows {
        let labels::Other::Grain(b) = c.b else {
            continue;
        };
        eprintln!(
            "    {} {}-{} apart {apart:.3} faces {} gap {:.3} grey {:.3} grey_gap {:.4} (−median {:.3}) sd {:.4} misfit {:.3} kept {} {}",
            if t { "TRUE " } else { "FALSE" },
            c.a,
            b,
            c.faces,
            vox(c.gap),
            c.grey.unwrap_or(f64::NAN),
            g,
            g - median,
            vox(c.grey_gap_sd),
            c.grey_fit_misfit.unwrap_or(f64::NAN),
            c.kept as u8,
            c.method
        );
    }
    // Pairs that do not touch in the DEM but are closer than 0.1 voxel: no
    // image at this resolution tells them from contacts.
    let mut close = 0;
    for i in 0..grains.len() {
        for j in i + 1..grains.len() {
            let apart = synth::apart(&grains[i], &grains[j]) / voxel;
            let pair = (i as u32 + 1, j as u32 + 1);
            close += usize::from(apart < 0.1 && !true_pairs.contains(&pair));
        }
    }
    eprintln!("    near misses under 0.1 voxel apart: {close}");
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len().max(1) as f64).sqrt();
    eprintln!(
        "    grey gap: median {median:.3}, robust sd {spread:.3} voxel; contacts' error (grey gap − median − true) 5/50/95 % {:.3} / {:.3} / {:.3}, min {:.3} max {:.3}, rms {rms:.3}",
        synth::quantile(&errors, 0.05),
        synth::quantile(&errors, 0.5),
        synth::quantile(&errors, 0.95),
        synth::quantile(&errors, 0.0),
        synth::quantile(&errors, 1.0),
    );
    rms
}

/// What the grey gap could reach on this packing (TOMO_DEBUG=1): the
/// Cramér–Rao bounds on the gap for this scan (the neck fit's window, and
/// the two whole spheres) and the precision an unbiased estimate of each
/// spread would give with every near miss's true separation, against the
/// contacts' measured spread (`sd` from [`debug_zones`]' rms line).
fn gap_limit(
    truth: &[synth::TrueContact],
    voxel: f64,
    grains: &[synth::SynthGrain],
    res: f64,
    seg: &synth::Segmentation,
    measured: f64,
) {
    let true_pairs = synth::true_pairs(truth);
    let mut near_misses = Vec::new();
    for i in 0..grains.len() {
        for j in i + 1..grains.len() {
            let apart = synth::apart(&grains[i], &grains[j]) / voxel;
            if apart < 1.0 && !true_pairs.contains(&(i as u32 + 1, j as u32 + 1)) {
                near_misses.push(apart.max(0.0));
            }
        }
    }
    // The 4³ sub-sampled voxel is a box (variance 15/192 per axis) under the blur.
    let sigma = (seg.blur * seg.blur + 15.0 / 192.0).sqrt();
    let (neck, whole) = labels::gap_bounds([0.5 * res; 2], sigma, seg.noise);
    let mut line = format!(
        "    limit: Cramér–Rao sd of the gap {neck:.4} (neck window) / {whole:.4} (whole spheres) voxel; precision at z = 3 / 2.33 with sd"
    );
    for sd in [measured, neck, whole] {
        let p = |z| synth::precision_limit(true_pairs.len(), &near_misses, sd, z);
        line += &format!(" {sd:.4}: {:.3} / {:.3};", p(3.0), p(2.33));
    }
    eprintln!("{line}");
}

/// The grey gap's error (estimate − the zones' median − the true
/// separation, voxels) by band of true separation, contacts counted at 0,
/// and the slope of a line through all zones under 0.5 voxel apart: where
/// near misses sit against the contacts (TOMO_DEBUG=1).
fn gap_bias(rows: &[(f64, bool, &labels::DetectedContact, f64)], median: f64) {
    let bands = [(0.0, 0.05), (0.05, 0.1), (0.1, 0.2), (0.2, 0.5)];
    let mut line = String::from("    grey gap error by true separation:");
    let mut summary = |name: String, errors: Vec<f64>| {
        if errors.is_empty() {
            return;
        }
        let n = errors.len() as f64;
        let mean = errors.iter().sum::<f64>() / n;
        let sd = (errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n).sqrt();
        line += &format!(" {name} n {} mean {mean:+.3} sd {sd:.3};", errors.len());
    };
    let error = |&(apart, t, _, g): &(f64, bool, _, f64)| g - median - if t { 0.0 } else { apart };
    summary(
        "contacts".into(),
        rows.iter().filter(|r| r.1).map(error).collect(),
    );
    for (lo, hi) in bands {
        let band = rows.iter().filter(|r| !r.1 && r.0 >= lo && r.0 < hi);
        summary(format!("[{lo}, {hi})"), band.map(error).collect());
    }
    // Least squares of the estimate on the true separation (contacts at 0).
    let points: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.0 < 0.5 && r.3.is_finite())
        .map(|r| (if r.1 { 0.0 } else { r.0 }, r.3))
        .collect();
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), p| (a + p.0 / n, b + p.1 / n));
    let (sxy, sxx) = points.iter().fold((0.0, 0.0), |(a, b), p| {
        (a + (p.0 - mx) * (p.1 - my), b + (p.0 - mx).powi(2))
    });
    eprintln!("{line} slope {:.3}", sxy / sxx);
}

/// Writes the labels, the grey image (`.npy`) and every grain–grain zone
/// with the truth (csv, voxel units) for prototyping outside (TOMO_DUMP=DIR).
fn dump(
    dir: &Path,
    name: &str,
    labels_volume: &[u32],
    grey: &[f32],
    grid: &synth::Grid,
    imported: &labels::LabelScene,
    grains: &[synth::SynthGrain],
) -> grainforce::Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| grainforce::Error::io(dir, e))?;
    let npy = |suffix: &str| dir.join(format!("{name}_{suffix}.npy"));
    labels::volume::write_npy(&npy("labels"), labels_volume, grid.shape)?;
    labels::volume::write_npy(&npy("grey"), grey, grid.shape)?;
    let v = grid.voxel;
    let mut csv =
        String::from("a,b,apart,px,py,pz,nx,ny,nz,gap,grey,grey_gap,grey_gap_sd,kept,faces\n");
    for c in &imported.detected {
        let labels::Other::Grain(b) = c.b else {
            continue;
        };
        let apart = synth::apart(&grains[c.a as usize - 1], &grains[b as usize - 1]) / v;
        let p: Vec<f64> = (0..3).map(|k| (c.point[k] - grid.origin[k]) / v).collect();
        csv += &format!(
            "{},{b},{apart},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            c.a,
            p[0],
            p[1],
            p[2],
            c.normal[0],
            c.normal[1],
            c.normal[2],
            c.gap.map_or(f64::NAN, |g| g / v),
            c.grey.unwrap_or(f64::NAN),
            c.grey_gap.map_or(f64::NAN, |g| g / v),
            c.grey_gap_sd.map_or(f64::NAN, |g| g / v),
            c.kept as u8,
            c.faces
        );
    }
    scene::write_file_atomically(&dir.join(format!("{name}_zones.csv")), csv.as_bytes())?;
    let mut truth = String::from("x,y,z,r\n");
    for g in grains {
        let (c, r) = g.spheres[0];
        truth += &format!(
            "{},{},{},{}\n",
            (c[0] - grid.origin[0]) / v,
            (c[1] - grid.origin[1]) / v,
            (c[2] - grid.origin[2]) / v,
            r / v
        );
    }
    scene::write_file_atomically(&dir.join(format!("{name}_spheres.csv")), truth.as_bytes())
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
