//! Issue 42: the fringe fit's imaging options on rendered disks: a disk lit
//! unevenly (its background a plane across it) with and without the
//! lighting term (`FringeFitSettings::lighting`), and dark fringes on a
//! bright disk with and without the bright-field model
//! (`FringeFitSettings::polariscope`).

mod common;
use common::relerr_2d as relerr;
use grainforce::image::fringe_fit::{fit_fringes, FringeFitSettings, Polariscope};
use grainforce::image::photoelastic::{render_photoelastic, PhotoelasticOptions};
use grainforce::image::FloatImage;
use grainforce::scene::{Body, Contact, Grain, Scene};
use std::f64::consts::FRAC_1_SQRT_2;

/// One disk (r = 40 px) held by three walls, above and at ±45° below, and
/// its balanced forces: under one fringe order, where a smooth change of
/// light looks like a fringe (the pattern is not symmetric top to bottom, so
/// a vertical gradient is not orthogonal to it).
fn held_disk() -> (Scene, Vec<[f64; 2]>) {
    let radius = 0.01;
    let mut scene = Scene::new(2);
    let mut g = Grain::new(
        "1",
        [0.05, 0.05, 0.0],
        std::f64::consts::PI * radius * radius,
        [0.0; 6],
    );
    g.radius = Some(radius);
    scene.grains.push(g);
    let top = 30.0;
    let side = top * FRAC_1_SQRT_2;
    let mut forces = Vec::new();
    for (name, n, f) in [
        ("top", [0.0, 1.0], top),
        ("left", [-FRAC_1_SQRT_2, -FRAC_1_SQRT_2], side),
        ("right", [FRAC_1_SQRT_2, -FRAC_1_SQRT_2], side),
    ] {
        let wall = scene.wall_or_insert(name);
        scene.contacts.push(Contact {
            id: name.into(),
            a: 0,
            b: Body::Wall(wall),
            point: [0.05 + radius * n[0], 0.05 + radius * n[1], 0.0],
            normal: [n[0], n[1], 0.0],
            mu: None,
        });
        // Compressive: against the outward normal.
        forces.push([-f * n[0], -f * n[1]]);
    }
    (scene, forces)
}

#[test]
fn a_light_gradient_across_a_disk_is_not_taken_for_fringes() {
    let (scene, truth) = held_disk();
    let fringe_stress = 1e4;
    let mut o = PhotoelasticOptions::new(4000.0, fringe_stress);
    o.blur_px = 0.8;
    let (rgb, frame) = render_photoelastic(&scene, &truth, &o).unwrap();
    // The light falls off by 0.3 (of a 0.7 fringe contrast) from the disk's
    // bottom to its top.
    let centre = frame.to_pixel([0.05, 0.05]);
    let image = FloatImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        let slope = 0.15 * (y as f64 - centre[1]) / 40.0;
        ::image::Luma([rgb.get_pixel(x, y)[1] + slope as f32])
    });
    let fit = |lighting: bool| {
        let mut s = FringeFitSettings::new(fringe_stress);
        s.blur_px = 0.8;
        s.lighting = lighting;
        // From the truth nudged by 10 %: the model's minimum, not the start.
        s.start = Some(truth.iter().map(|f| [1.1 * f[0], 0.9 * f[1]]).collect());
        let f = fit_fringes(&image, &frame, &scene, &s).unwrap();
        relerr(&f.forces, &truth)
    };
    let (flat, lit) = (fit(false), fit(true));
    // Measured: 0.0773 without the term, 0.0027 with it (at 200 N/m, three
    // fringes, the gradient costs only 0.0021 → 0.0013).
    eprintln!("relerr: constant background {flat:.4}, lighting plane {lit:.4}");
    assert!(lit < 0.01, "with the lighting term: relerr {lit}");
    assert!(flat > 3.0 * lit.max(0.01), "without it: relerr {flat}");
}

#[test]
fn dark_fringes_on_a_bright_disk_need_the_bright_field_model_and_auto_finds_it() {
    let (scene, truth) = held_disk();
    let truth: Vec<[f64; 2]> = truth.iter().map(|f| [4.0 * f[0], 4.0 * f[1]]).collect();
    let fringe_stress = 1e4;
    let mut o = PhotoelasticOptions::new(4000.0, fringe_stress);
    o.blur_px = 0.8;
    let (rgb, frame) = render_photoelastic(&scene, &truth, &o).unwrap();
    // A bright-field polariscope: the dark-field picture inverted.
    let image = FloatImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        ::image::Luma([1.0 - rgb.get_pixel(x, y)[1]])
    });
    let fit = |image: &FloatImage, polariscope: Polariscope| {
        let mut s = FringeFitSettings::new(fringe_stress);
        s.blur_px = 0.8;
        s.polariscope = polariscope;
        s.start = Some(truth.iter().map(|f| [1.1 * f[0], 0.9 * f[1]]).collect());
        let f = fit_fringes(image, &frame, &scene, &s).unwrap();
        (relerr(&f.forces, &truth), f.report.bright_field)
    };
    let (dark, _) = fit(&image, Polariscope::Dark);
    let (bright, _) = fit(&image, Polariscope::Bright);
    eprintln!("relerr: dark-field model {dark:.4}, bright-field model {bright:.4}");
    assert!(bright < 0.01, "bright-field model: relerr {bright}");
    assert!(dark > 0.05, "dark-field model: relerr {dark}");
    // Read from the picture: bright here, dark on the picture as rendered.
    let (auto, lit) = fit(&image, Polariscope::Auto);
    assert!(
        lit && auto == bright,
        "auto: bright field {lit}, relerr {auto}"
    );
    let rendered = FloatImage::from_fn(rgb.width(), rgb.height(), |x, y| {
        ::image::Luma([rgb.get_pixel(x, y)[1]])
    });
    let (auto, lit) = fit(&rendered, Polariscope::Auto);
    assert!(
        !lit && auto < 0.01,
        "auto on the dark field: bright {lit}, relerr {auto}"
    );
}
