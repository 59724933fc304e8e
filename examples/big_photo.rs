//! Memory and time of `detect` on a 21-megapixel camera JPEG (5616 × 3744 px,
//! ~186 photoelastic disks of radius ≈ 122 px, as a DSLR photographs a hopper).
//!
//!     cargo run --release --example big_photo [-- DIR]
//!
//! Renders the photograph once into DIR (default: the system's temporary
//! folder; ~5 MB, not kept in the repository), then runs the detection in a
//! child process, as `grainforce detect big-photo.jpg --radius 110..135` does,
//! and prints its wall and CPU time, its peak resident memory (VmHWM) and the
//! disks and contacts scored against the rendered truth. The same figures for
//! the CLI itself: `/usr/bin/time -v grainforce detect DIR/big-photo.jpg -o
//! out/ --radius 110..135`.

use grainforce::image::photoelastic::{render_photoelastic, save_jpeg, PhotoelasticOptions};
use grainforce::image::synthetic::{match_disks, touching_disks, PackingSpec};
use grainforce::image::{detect_images, DetectSettings, PixelFrame};
use grainforce::scene::Scene;
use std::path::{Path, PathBuf};
use std::time::Instant;

const WIDTH: u32 = 5616;
const HEIGHT: u32 = 3744;
/// 1 px = 1 mm.
const PX_PER_M: f64 = 1000.0;
const MARGIN_PX: f64 = 20.0;

/// The packing: disks of radius 118–126 px grown tangent to each other,
/// non-touching pairs at least 10 px apart (as in the photographs), moved in
/// from the image border by the margin.
fn packing() -> Scene {
    let mut scene = touching_disks(&PackingSpec {
        width: (WIDTH as f64 - 2.0 * MARGIN_PX) / PX_PER_M,
        height: (HEIGHT as f64 - 2.0 * MARGIN_PX) / PX_PER_M,
        radius_min: 0.118,
        radius_max: 0.126,
        count: 186,
        min_gap: 0.010,
        seed: 21,
    })
    .expect("a packing");
    for g in &mut scene.grains {
        g.position[0] += MARGIN_PX / PX_PER_M;
        g.position[1] += MARGIN_PX / PX_PER_M;
    }
    for c in &mut scene.contacts {
        c.point[0] += MARGIN_PX / PX_PER_M;
        c.point[1] += MARGIN_PX / PX_PER_M;
    }
    scene
}

/// Compressive contact forces [N/m], one in five nearly unloaded (those
/// disks stay almost dark).
fn forces(scene: &Scene) -> Vec<[f64; 2]> {
    grainforce::image::photoelastic::sample_contact_forces(scene, 240.0, 21)
}

fn frame() -> PixelFrame {
    PixelFrame::at_origin(PX_PER_M, WIDTH, HEIGHT)
}

fn render(path: &Path) -> grainforce::Result<()> {
    let scene = packing();
    let mut options = PhotoelasticOptions::new(PX_PER_M, 600.0);
    options.rim_px = 5.0;
    // Unloaded disks darker than the background, as in the hopper photograph.
    options.unloaded = 0.08;
    options.uneven_lighting = 0.4;
    options.blur_px = 1.0;
    options.noise = 0.02;
    options.supersample = 2;
    options.frame = Some(frame());
    let t = Instant::now();
    let (image, _) = render_photoelastic(&scene, &forces(&scene), &options)?;
    save_jpeg(path, &image, 90)?;
    println!(
        "rendered {} disks, {} contacts into {} in {:.1} s",
        scene.grains.len(),
        scene.contacts.len(),
        path.display(),
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

fn cpu_seconds() -> f64 {
    grainforce::bench::cpu_seconds().unwrap_or(f64::NAN)
}

/// Peak resident memory of this process [MB].
fn peak_rss_mb() -> f64 {
    grainforce::bench::peak_memory().map_or(f64::NAN, |b| b as f64 / (1024.0 * 1024.0))
}

/// Runs the detection as the CLI does and scores it (in the child process, so
/// that the peak memory is the detection's alone).
fn detect(path: &Path) -> grainforce::Result<()> {
    let settings = DetectSettings::new(110.0, 135.0, PX_PER_M);
    let (t, cpu) = (Instant::now(), cpu_seconds());
    let detection = detect_images(&[path.to_path_buf()], &settings, &mut |_, _, _, _| Ok(()))?;
    let (wall, cpu) = (t.elapsed().as_secs_f64(), cpu_seconds() - cpu);
    let found = &detection.frames[0];
    let scene = packing();
    let frame = frame();
    let matched = match_disks(&scene, &frame, &found.disks, |r| 0.25 * r);
    for (g, disk) in matched.disk_of_grain.iter().enumerate() {
        if disk.is_none() {
            let grain = &scene.grains[g];
            let p = frame.to_pixel([grain.position[0], grain.position[1]]);
            println!("  missed the disk at ({:.0}, {:.0}) px", p[0], p[1]);
        }
    }
    let radius_px = |g: usize| scene.grains[g].radius.expect("packings have radii") * PX_PER_M;
    let mut errors: Vec<f64> = (matched.pairs.iter())
        .map(|&(g, _, distance, _)| distance / radius_px(g))
        .collect();
    errors.sort_by(f64::total_cmp);
    let (truth, detected) = matched.contact_pairs(&scene, &found.contacts);
    let right = detected.iter().filter(|d| truth.contains(d)).count();
    println!(
        "detect ({} threads): {wall:.2} s wall, {cpu:.2} CPU s, peak RSS {:.0} MB",
        rayon::current_num_threads(),
        peak_rss_mb()
    );
    println!(
        "disks: {} of {} found, {} false; centre error median {:.4} R; contacts: {right} of {} found, {} false",
        errors.len(),
        scene.grains.len(),
        found.disks.len() - errors.len(),
        errors.get(errors.len() / 2).copied().unwrap_or(f64::NAN),
        scene.contacts.len(),
        detected.len() - right
    );
    Ok(())
}

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if let Some(k) = args.iter().position(|a| a == "--detect") {
        let path = args.get(k + 1).expect("--detect needs the image");
        return detect(Path::new(path));
    }
    let dir = args
        .get(1)
        .map(PathBuf::from)
        .unwrap_or_else(std::env::temp_dir);
    std::fs::create_dir_all(&dir).map_err(|e| grainforce::Error::io(&dir, e))?;
    let path = dir.join("big-photo.jpg");
    if path.exists() {
        println!("using {} (delete it to render again)", path.display());
    } else {
        render(&path)?;
    }
    let me = std::env::current_exe().map_err(|e| grainforce::Error::io(&dir, e))?;
    let status = std::process::Command::new(me)
        .arg("--detect")
        .arg(&path)
        .status()
        .map_err(|e| grainforce::Error::io(&path, e))?;
    if !status.success() {
        return Err(grainforce::Error::Invalid(format!(
            "the detection failed ({status})"
        )));
    }
    Ok(())
}
