//! Camera JPEGs: colour images reduced to one channel, compression artefacts
//! at camera quality, through the library and the command line.

mod common;
use grainforce::image::synthetic::{touching_disks, PackingSpec};
use grainforce::image::{
    detect_images, load_channel, render_scene, Channel, DetectSettings, Elasticity, FloatImage,
    PlaneCondition, RenderOptions,
};
use grainforce::scene::Scene;
use image::codecs::jpeg::JpegEncoder;
use image::{ImageEncoder, RgbImage};
use std::path::{Path, PathBuf};

fn rubber() -> Elasticity {
    Elasticity::new(5.5e6, 0.45, PlaneCondition::Stress).unwrap()
}

fn packing(seed: u64) -> Scene {
    touching_disks(&PackingSpec {
        width: 0.3,
        height: 0.25,
        radius_min: 0.025,
        radius_max: 0.035,
        count: 16,
        min_gap: 0.004,
        seed,
    })
    .unwrap()
}

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Writes an RGB JPEG at the given quality: the disks in `shown` go into
/// `channel`, the other channels get `other` (a uniform level, or the negative).
fn write_rgb_jpeg(path: &Path, shown: &FloatImage, channel: usize, negative: bool, quality: u8) {
    let (w, h) = shown.dimensions();
    let mut rgb = RgbImage::new(w, h);
    for (x, y, p) in rgb.enumerate_pixels_mut() {
        let v = shown.get_pixel(x, y)[0];
        let other = if negative { 1.0 - v } else { 0.3 };
        for c in 0..3 {
            p[c] = to_u8(if c == channel { v } else { other });
        }
    }
    let file = std::fs::File::create(path).unwrap();
    JpegEncoder::new_with_quality(std::io::BufWriter::new(file), quality)
        .write_image(rgb.as_raw(), w, h, image::ExtendedColorType::Rgb8)
        .unwrap();
}

/// Median and worst centre error [px] of detected disks against the scene,
/// and the number of grains without a detection within 3 px.
fn centre_errors(scene: &Scene, settings: &DetectSettings, path: PathBuf) -> (f64, f64, usize) {
    let detection = detect_images(&[path], settings, &mut |_, _, _, _| Ok(())).unwrap();
    let disks = &detection.frames[0].disks;
    let frame = settings.frame.unwrap();
    let mut errors = Vec::new();
    let mut missed = 0;
    for g in &scene.grains {
        let p = frame.to_pixel([g.position[0], g.position[1]]);
        let nearest = disks
            .iter()
            .map(|d| (d.x - p[0]).hypot(d.y - p[1]))
            .fold(f64::INFINITY, f64::min);
        if nearest < 3.0 {
            errors.push(nearest);
        } else {
            missed += 1;
        }
    }
    assert_eq!(
        disks.len(),
        errors.len(),
        "false disks among {}",
        disks.len()
    );
    errors.sort_by(f64::total_cmp);
    let median = errors.get(errors.len() / 2).copied().unwrap_or(f64::NAN);
    (median, errors.last().copied().unwrap_or(f64::NAN), missed)
}

#[test]
fn colour_jpeg_is_read_in_the_chosen_channel() {
    let scene = packing(3);
    let rendered = render_scene(&scene, &RenderOptions::new(1000.0, rubber())).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Disks only in red; green and blue are a flat 0.3.
    let red_only = dir.path().join("red.jpg");
    write_rgb_jpeg(&red_only, &rendered.deformed, 0, false, 90);

    // The channel read back is the red one, within JPEG's error, and green is flat.
    let red = load_channel(&red_only, Channel::Red).unwrap();
    let green = load_channel(&red_only, Channel::Green).unwrap();
    let (mut err, mut spread) = (0.0f64, 0.0f64);
    for (a, b) in red.iter().zip(rendered.deformed.iter()) {
        err += ((a - b) as f64).powi(2);
    }
    for v in green.iter() {
        spread = spread.max((v - 0.3).abs() as f64);
    }
    let rms = (err / red.len() as f64).sqrt();
    assert!(
        rms < 0.03,
        "red channel differs by {rms} rms from what was written"
    );
    // Chroma is subsampled, so the flat channels pick up a little of the red edges.
    assert!(spread < 0.15, "green channel varies by {spread}");

    let mut settings = DetectSettings::new(20.0, 40.0, 1000.0);
    settings.frame = Some(rendered.frame);
    settings.channel = Channel::Red;
    let (median, worst, missed) = centre_errors(&scene, &settings, red_only.clone());
    println!(
        "red channel of a q90 JPEG: median {median:.3} px, worst {worst:.3} px, missed {missed}"
    );
    assert_eq!(missed, 0);
    assert!(
        median <= 0.3 && worst <= 1.0,
        "median {median}, worst {worst}"
    );

    // The green channel shows no disks: a clear error naming the file.
    settings.channel = Channel::Green;
    let e = detect_images(&[red_only], &settings, &mut |_, _, _, _| Ok(())).unwrap_err();
    assert!(
        e.to_string().contains("red.jpg") && e.to_string().contains("no disks"),
        "{e}"
    );
}

#[test]
fn default_auto_channel_and_camera_quality() {
    let scene = packing(4);
    let mut options = RenderOptions::new(1000.0, rubber());
    options.noise = 0.01;
    options.seed = 4;
    let rendered = render_scene(&scene, &options).unwrap();
    let dir = tempfile::tempdir().unwrap();
    // Disks bright in green, dark in red and blue (the negative): luma would
    // mix the two and lose most of the contrast; the colour distance from
    // the background keeps all of it.
    let path = dir.path().join("camera.jpeg");
    write_rgb_jpeg(&path, &rendered.deformed, 1, true, 85);
    let mut settings = DetectSettings::new(20.0, 40.0, 1000.0);
    settings.frame = Some(rendered.frame);
    assert_eq!(settings.channel, Channel::Auto, "the documented default");
    let (median, worst, missed) = centre_errors(&scene, &settings, path);
    println!("default channel of a q85 JPEG: median {median:.3} px, worst {worst:.3} px");
    assert_eq!(missed, 0);
    assert!(
        median <= 0.3 && worst <= 1.0,
        "median {median}, worst {worst}"
    );
}

#[test]
fn detect_takes_a_jpeg_and_names_bad_channels() {
    let scene = packing(5);
    let rendered = render_scene(&scene, &RenderOptions::new(1000.0, rubber())).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let jpeg = dir.path().join("photo.jpg");
    write_rgb_jpeg(&jpeg, &rendered.deformed, 0, false, 90);
    let out = dir.path().join("found");
    let (ok, err) = common::run(&[
        "detect",
        jpeg.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--radius",
        "20..40",
        "--channel",
        "red",
    ]);
    assert!(ok, "{err}");
    let grains = grainforce::scene::read_scene(&out).unwrap().grains.len();
    assert_eq!(grains, scene.grains.len());

    let (ok, err) = common::run(&[
        "detect",
        jpeg.to_str().unwrap(),
        "-o",
        dir.path().join("never").to_str().unwrap(),
        "--radius",
        "20..40",
        "--channel",
        "purple",
    ]);
    assert!(
        !ok && err.contains("purple") && err.contains("red, green, blue or luma"),
        "{err}"
    );
    assert!(!dir.path().join("never").exists());
}
