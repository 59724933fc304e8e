//! Benchmark of the image pipeline: disk detection on a 2000 × 2000 image with
//! about 500 disks, and DIC of every grain of that frame.
//!
//!     cargo run --release --example image_bench [-- --quick] [--overlay PATH]
//!
//! `--resolution` prints how detection and strain errors fall with disk size.
//! `--overlay PATH` instead draws the detection overlay of a small packing (the
//! picture in docs/image.md).

use grainforce::image::dic::DicOptions;
use grainforce::image::synthetic::{assign_random_stresses, touching_disks, PackingSpec};
use grainforce::image::{
    detect_disks, measure_stresses, render_scene, DetectOptions, Elasticity, PixelFrame,
    PlaneCondition, RenderOptions, StrainOptions,
};
use std::time::Instant;

/// CPU seconds used so far by this process (all threads): on a shared
/// machine, wall time alone says little.
fn cpu_seconds() -> f64 {
    grainforce::bench::cpu_seconds().unwrap_or(f64::NAN)
}

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    if args.iter().any(|a| a == "--resolution") {
        return resolution();
    }
    if let Some(k) = args.iter().position(|a| a == "--overlay") {
        let path = args.get(k + 1).expect("--overlay needs a path");
        return overlay(std::path::Path::new(path));
    }
    let side = if quick { 700 } else { 2000 };
    let count = if quick { 60 } else { 500 };
    let s = 1000.0; // px per m: 1 px = 1 mm
    let elasticity = Elasticity::new(5.5e6, 0.4, PlaneCondition::Stress)?;
    let mut scene = touching_disks(&PackingSpec {
        width: (side as f64 - 20.0) / s,
        height: (side as f64 - 20.0) / s,
        radius_min: 0.03,
        radius_max: 0.05,
        count,
        min_gap: 0.003,
        seed: 7,
    })?;
    for g in &mut scene.grains {
        g.position[0] += 10.0 / s;
        g.position[1] += 10.0 / s;
    }
    assign_random_stresses(&mut scene, &elasticity, 2e-3, 7);
    let mut options = RenderOptions::new(s, elasticity);
    options.noise = 0.01;
    options.frame = Some(PixelFrame::at_origin(s, side, side));
    let t = Instant::now();
    let rendered = render_scene(&scene, &options)?;
    println!(
        "threads: {}; rendered {} disks (radius 30–50 px) on {side}×{side} px in {:.2} s",
        rayon::current_num_threads(),
        scene.grains.len(),
        t.elapsed().as_secs_f64()
    );

    let detect = DetectOptions::new(25.0, 55.0);
    let mut times = Vec::new();
    let mut disks = Vec::new();
    let cpu = cpu_seconds();
    for _ in 0..3 {
        let t = Instant::now();
        disks = detect_disks(&rendered.deformed, &detect)?;
        times.push(t.elapsed().as_secs_f64());
    }
    let detect_cpu = (cpu_seconds() - cpu) / 3.0;
    times.sort_by(|a, b| a.total_cmp(b));
    let mut worst = 0.0f64;
    let mut matched = 0;
    for g in &scene.grains {
        let p = rendered.frame.to_pixel([g.position[0], g.position[1]]);
        if let Some(d) = disks
            .iter()
            .map(|d| (d.x - p[0]).hypot(d.y - p[1]))
            .min_by(|a, b| a.total_cmp(b))
        {
            if d < 3.0 {
                matched += 1;
                worst = worst.max(d);
            } else {
                println!(
                    "  missed grain {} at ({:.1}, {:.1}) px, radius {:.1} px",
                    g.id,
                    p[0],
                    p[1],
                    g.equivalent_radius(2) * s
                );
            }
        }
    }
    println!(
        "detection: {} disks found ({matched} of {} matched, worst centre error {worst:.3} px) in {:.3} s wall (median of 3), {detect_cpu:.2} CPU s",
        disks.len(),
        scene.grains.len(),
        times[1]
    );

    for step in [2usize, 4] {
        let mut measured = scene.clone();
        let strain_options = StrainOptions {
            elasticity,
            dic: DicOptions {
                step,
                ..DicOptions::default()
            },
        };
        let t = Instant::now();
        let cpu = cpu_seconds();
        let report = measure_stresses(
            &rendered.reference,
            &rendered.deformed,
            &mut measured,
            &rendered.frame,
            &strain_options,
        )?;
        let elapsed = t.elapsed().as_secs_f64();
        let dic_cpu = cpu_seconds() - cpu;
        let mut worst = 0.0f64;
        let mut sum = 0.0;
        for (g, truth) in report.grains.iter().zip(&scene.grains) {
            let e =
                elasticity.strain_from_stress([truth.stress[0], truth.stress[1], truth.stress[3]]);
            let err = (0..3)
                .map(|c| (g.strain[c] - e[c]).abs())
                .fold(0.0, f64::max);
            worst = worst.max(err);
            sum += err;
        }
        let subsets: usize = report.grains.iter().map(|g| g.dic.used).sum();
        println!(
            "DIC subset 15, step {step}: {} grains ({subsets} subsets) in {elapsed:.2} s wall, {dic_cpu:.2} CPU s = {:.1} ms per grain (wall); strain error mean {:.1e}, worst {worst:.1e}",
            report.grains.len(),
            1e3 * elapsed / report.grains.len() as f64,
            sum / report.grains.len() as f64
        );
    }
    Ok(())
}

/// A small packing with walls at the image edges, detected and drawn.
fn overlay(path: &std::path::Path) -> grainforce::Result<()> {
    use grainforce::image::contacts::edge_walls;
    use grainforce::image::{find_contacts, overlay::draw_overlay, overlay::save_overlay};
    let elasticity = Elasticity::new(5.5e6, 0.4, PlaneCondition::Stress)?;
    let scene = touching_disks(&PackingSpec {
        width: 0.36,
        height: 0.26,
        radius_min: 0.03,
        radius_max: 0.045,
        count: 20,
        min_gap: 0.004,
        seed: 2,
    })?;
    let mut options = RenderOptions::new(1000.0, elasticity);
    options.margin_px = 4.0;
    let rendered = render_scene(&scene, &options)?;
    let disks = detect_disks(&rendered.deformed, &DetectOptions::new(25.0, 50.0))?;
    let walls = edge_walls(rendered.frame.width, rendered.frame.height);
    let contacts = find_contacts(&disks, &walls, 6.0);
    let ids: Vec<String> = (0..disks.len()).map(|k| k.to_string()).collect();
    let picture = draw_overlay(&rendered.deformed, &disks, &ids, &contacts, &[]);
    save_overlay(path, &picture)?;
    println!(
        "{} disks, {} contacts → {}",
        disks.len(),
        contacts.len(),
        path.display()
    );
    Ok(())
}

/// Errors against disk size: a touching packing drawn at several scales, with
/// random strains of 2e-3, noise 0.01.
fn resolution() -> grainforce::Result<()> {
    let elasticity = Elasticity::new(5.5e6, 0.4, PlaneCondition::Stress)?;
    let mut scene = touching_disks(&PackingSpec {
        width: 0.36,
        height: 0.3,
        radius_min: 0.03,
        radius_max: 0.045,
        count: 16,
        min_gap: 0.004,
        seed: 9,
    })?;
    assign_random_stresses(&mut scene, &elasticity, 2e-3, 9);
    println!("mean radius [px] | worst centre error [px] | strain error mean / worst");
    for s in [600.0, 1000.0, 1600.0, 2400.0] {
        let mut options = RenderOptions::new(s, elasticity);
        options.noise = 0.01;
        let rendered = render_scene(&scene, &options)?;
        let mean_r = scene
            .grains
            .iter()
            .map(|g| g.radius.unwrap_or(0.0))
            .sum::<f64>()
            * s
            / scene.grains.len() as f64;
        let disks = detect_disks(&rendered.deformed, &DetectOptions::new(0.025 * s, 0.05 * s))?;
        let mut worst = 0.0f64;
        for g in &scene.grains {
            let p = rendered.frame.to_pixel([g.position[0], g.position[1]]);
            let d = disks
                .iter()
                .map(|d| (d.x - p[0]).hypot(d.y - p[1]))
                .fold(f64::INFINITY, f64::min);
            worst = worst.max(d);
        }
        let mut measured = scene.clone();
        let report = measure_stresses(
            &rendered.reference,
            &rendered.deformed,
            &mut measured,
            &rendered.frame,
            &StrainOptions {
                elasticity,
                dic: DicOptions {
                    step: 4,
                    ..DicOptions::default()
                },
            },
        )?;
        let (mut sum, mut top) = (0.0, 0.0f64);
        for (g, truth) in report.grains.iter().zip(&scene.grains) {
            let e =
                elasticity.strain_from_stress([truth.stress[0], truth.stress[1], truth.stress[3]]);
            let err = (0..3)
                .map(|c| (g.strain[c] - e[c]).abs())
                .fold(0.0, f64::max);
            sum += err;
            top = top.max(err);
        }
        println!(
            "{mean_r:6.1} | {worst:.3} | {:.1e} / {top:.1e}",
            sum / report.grains.len() as f64
        );
    }
    Ok(())
}
