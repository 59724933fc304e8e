//! Charts, the bitmap font, force-chain pictures and Pareto CSVs: the drawn
//! elements must be where the layout says, in the expected colours.

use grainforce::report::chart::{format_tick, nice_step, save_png, Chart, Scale, PALETTE, WHITE};
use grainforce::report::font;
use grainforce::report::forcechain::{
    chain_layout, draw_force_chains, force_color, ForceChainOptions, Plane,
};
use grainforce::report::pareto::{pareto_chart, read_pareto_csv, write_pareto_csv, ParetoPoint};
use grainforce::scene::{Body, Contact, Grain, Scene, Vec3};
use image::{Rgb, RgbImage};

fn pixel(img: &RgbImage, p: (f64, f64)) -> Rgb<u8> {
    *img.get_pixel(p.0.floor() as u32, p.1.floor() as u32)
}

fn count(img: &RgbImage, color: Rgb<u8>) -> usize {
    img.pixels().filter(|p| **p == color).count()
}

#[test]
fn ticks_are_round_and_readable() {
    assert_eq!(nice_step(10.0, 5), 2.0);
    assert_eq!(nice_step(0.7, 7), 0.1);
    assert_eq!(format_tick(0.25, 0.05), "0.25");
    assert_eq!(format_tick(1200.0, 200.0), "1200");
    assert_eq!(format_tick(2.5e-5, 5e-6), "2.5e-5");
    assert_eq!(format_tick(3e7, 1e7), "3e7");
    assert_eq!(format_tick(0.0, 1.0), "0");
    assert_eq!(format_tick(-1.5, 0.5), "-1.5");
}

#[test]
fn font_draws_known_glyphs_and_boxes_for_unknown_ones() {
    assert_eq!(font::text_size("lambda", 2), ((6 * 6 - 1) * 2, 14));
    assert!(font::has_glyph('λ') && font::has_glyph('7') && !font::has_glyph('☃'));
    let mut img = RgbImage::from_pixel(40, 10, WHITE);
    font::draw_text(&mut img, 1, 1, "1", 1, Rgb([0, 0, 0]));
    // '1' has its stem in the middle column (x = 1 + 2) on every row but the top.
    for y in 2..=7 {
        assert_eq!(*img.get_pixel(3, y), Rgb([0, 0, 0]), "row {y}");
    }
    assert_eq!(*img.get_pixel(1, 4), WHITE);
    let mut boxed = RgbImage::from_pixel(10, 10, WHITE);
    font::draw_text(&mut boxed, 0, 0, "☃", 1, Rgb([0, 0, 0]));
    assert_eq!(count(&boxed, Rgb([0, 0, 0])), 5 + 5 + 2 * 5);
}

#[test]
fn chart_draws_lines_where_the_layout_places_them() {
    let red = Rgb([230, 0, 0]);
    let chart = Chart::new(640, 400)
        .title("test")
        .x_axis("x", Scale::Linear)
        .y_axis("y", Scale::Log)
        .line("rising", &[(0.0, 1.0), (10.0, 1000.0)], red)
        .scatter("dots", &[(5.0, 10.0)], PALETTE[2]);
    let img = chart.render();
    assert_eq!(img.dimensions(), (640, 400));
    // On log y the line is straight: its middle is at (5, √1000).
    let mid = chart.pixel_of(5.0, 1000f64.sqrt()).unwrap();
    assert_eq!(pixel(&img, mid), red);
    // The scatter dot sits below the line, at (5, 10).
    let dot = chart.pixel_of(5.0, 10.0).unwrap();
    assert_eq!(pixel(&img, dot), PALETTE[2]);
    // Above the line, well inside the frame, is background (or grid).
    let above = chart.pixel_of(2.0, 500.0).unwrap();
    let p = pixel(&img, above);
    assert!(p.0.iter().all(|&c| c >= 200), "{p:?}");
    // Non-positive values cannot be drawn on a log axis and are left out, not panicking.
    let img = Chart::new(300, 200)
        .y_axis("y", Scale::Log)
        .line("", &[(0.0, 0.0), (1.0, -1.0)], red)
        .render();
    assert_eq!(count(&img, red), 0);
}

#[test]
fn chart_marks_and_saves_atomically() {
    let chart = Chart::new(500, 350)
        .x_axis("a", Scale::Log)
        .y_axis("b", Scale::Log)
        .line(
            "front",
            &[(1e-6, 1e3), (1e-3, 1.0), (1.0, 1e-3)],
            PALETTE[0],
        )
        .mark(1e-3, 1.0, "knee");
    let img = chart.render();
    let knee = chart.pixel_of(1e-3, 1.0).unwrap();
    // The ring (radius 12 px at this size) passes 12 px right of the point.
    let ring_px = pixel(&img, (knee.0 + 12.0, knee.1));
    assert!(ring_px.0[0] > 180 && ring_px.0[1] < 80, "{ring_px:?}");

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("chart.png");
    save_png(&path, &img).unwrap();
    assert_eq!(image::open(&path).unwrap().to_rgb8(), img);
    let bad = dir.path().join("missing-dir").join("chart.png");
    let err = save_png(&bad, &img).unwrap_err().to_string();
    assert!(err.contains("chart.png"), "{err}");
}

/// Two disks of radius r touching along x at `origin`, with one contact of the
/// given force, plus a third grain with a weaker contact and a wall below.
fn pair_scene(origin: Vec3, r: f64) -> (Scene, Vec<Vec3>) {
    let mut s = Scene::new(2);
    let area = std::f64::consts::PI * r * r;
    let at = |dx: f64, dy: f64| [origin[0] + dx * r, origin[1] + dy * r, 0.0];
    s.grains.push(Grain::new("a", at(0.0, 0.0), area, [0.0; 6]));
    s.grains.push(Grain::new("b", at(2.0, 0.0), area, [0.0; 6]));
    s.grains
        .push(Grain::new("c", at(1.0, 3f64.sqrt()), area, [0.0; 6]));
    let contact = |id: &str, a, b, p: Vec3, n: Vec3| Contact {
        id: id.into(),
        a,
        b,
        point: p,
        normal: n,
        mu: None,
    };
    s.contacts.push(contact(
        "ab",
        0,
        Body::Grain(1),
        at(1.0, 0.0),
        [1.0, 0.0, 0.0],
    ));
    let h = 3f64.sqrt() / 2.0;
    s.contacts
        .push(contact("ac", 0, Body::Grain(2), at(0.5, h), [0.5, h, 0.0]));
    let floor = s.wall_or_insert("floor");
    s.contacts.push(contact(
        "af",
        0,
        Body::Wall(floor),
        at(0.0, -1.0),
        [0.0, -1.0, 0.0],
    ));
    s.contacts.push(contact(
        "bf",
        1,
        Body::Wall(floor),
        at(2.0, -1.0),
        [0.0, -1.0, 0.0],
    ));
    let forces = vec![
        [-100.0, 0.0, 0.0],
        [-10.0, -17.0, 0.0],
        [0.0, 20.0, 0.0],
        [0.0, 20.0, 0.0],
    ];
    (s, forces)
}

#[test]
fn force_chain_draws_the_strongest_force_in_the_darkest_colour() {
    let (s, forces) = pair_scene([0.0, 0.0, 0.0], 0.01);
    let opts = ForceChainOptions {
        width_px: 500,
        ..Default::default()
    };
    let img = draw_force_chains(&s, &forces, &opts).unwrap();
    let layout = chain_layout(&s, &opts).unwrap();
    assert_eq!(img.dimensions(), (layout.width, layout.height));
    assert_eq!(img.width(), 500);
    // Midpoint of the strongest line (the contact point of a and b).
    let mid = layout.to_pixel(s.contacts[0].point);
    assert_eq!(pixel(&img, mid), force_color(1.0));
    // Its width is about 0.75 grain radius: 0.3 r off the axis is still inside…
    let r_px = 0.01 * layout.scale;
    assert_eq!(pixel(&img, (mid.0, mid.1 + 0.3 * r_px)), force_color(1.0));
    // …and 0.6 r off it is background.
    assert_eq!(pixel(&img, (mid.0, mid.1 + 0.6 * r_px)), WHITE);
    // The weaker a–c contact is lighter, in its own colour at its midpoint.
    let t = (10f64.powi(2) + 17f64.powi(2)).sqrt() / 100.0;
    let ac_mid = layout.to_pixel(s.contacts[1].point);
    assert_eq!(pixel(&img, ac_mid), force_color(t));
    assert_ne!(force_color(t), force_color(1.0));
    // The floor is a dark line below the grains, between the two wall contacts.
    let floor_mid = layout.to_pixel([0.01, -0.01, 0.0]);
    let below = pixel(&img, (floor_mid.0, floor_mid.1 + 1.0));
    assert!(below.0.iter().all(|&c| c < 120), "{below:?}");
    // The colour bar shows the full range: dark at its right end.
    let bar_y = layout.colorbar_top() as f64 + 5.0;
    let right = pixel(
        &img,
        (
            img.width() as f64 - 0.5 - opts.width_px as f64 / 20.0 - 40.0,
            bar_y,
        ),
    );
    let left = pixel(&img, (70.0, bar_y));
    let luminance = |c: Rgb<u8>| c.0.iter().map(|&v| v as u32).sum::<u32>();
    assert!(luminance(right) < luminance(left), "{left:?} {right:?}");
}

#[test]
fn force_chain_is_the_same_far_from_the_origin_and_at_any_scale() {
    let opts = ForceChainOptions {
        width_px: 400,
        ..Default::default()
    };
    let (s, f) = pair_scene([0.0, 0.0, 0.0], 0.01);
    let reference = draw_force_chains(&s, &f, &opts).unwrap();
    for (origin, r) in [
        ([1e6, -2e6, 0.0], 0.01),
        ([0.0, 0.0, 0.0], 1e-7),
        ([3e3, 3e3, 0.0], 40.0),
    ] {
        let (s, f) = pair_scene(origin, r);
        let img = draw_force_chains(&s, &f, &opts).unwrap();
        assert_eq!(img.dimensions(), reference.dimensions());
        let worst = img
            .pixels()
            .zip(reference.pixels())
            .flat_map(|(a, b)| (0..3).map(move |k| (a.0[k] as i32 - b.0[k] as i32).abs()))
            .max()
            .unwrap();
        assert!(
            worst <= 2,
            "origin {origin:?}, r {r}: pixels differ by {worst}"
        );
    }
}

#[test]
fn force_chain_copes_with_no_contacts_and_zero_forces() {
    let (mut s, _) = pair_scene([0.0, 0.0, 0.0], 1.0);
    let zero = vec![[0.0; 3]; s.contacts.len()];
    let opts = ForceChainOptions::default();
    let img = draw_force_chains(&s, &zero, &opts).unwrap();
    let layout = chain_layout(&s, &opts).unwrap();
    // Zero forces still show their contact, as a light grey hairline.
    let mid = pixel(&img, layout.to_pixel([0.5, 0.0, 0.0]));
    assert!(mid.0.iter().all(|&c| c > 150 && c < 255), "{mid:?}");
    assert!(
        mid.0[0] == mid.0[1] && mid.0[1] == mid.0[2],
        "grey: {mid:?}"
    );

    s.contacts.clear();
    let img = draw_force_chains(&s, &[], &opts).unwrap();
    assert_eq!(pixel(&img, layout.to_pixel([0.5, 0.0, 0.0])), WHITE);

    // Mismatched and non-finite forces are errors naming the contact.
    let (s, mut f) = pair_scene([0.0, 0.0, 0.0], 1.0);
    let err = draw_force_chains(&s, &f[..2], &opts)
        .unwrap_err()
        .to_string();
    assert!(err.contains("`af`"), "{err}");
    f[1][0] = f64::NAN;
    let err = draw_force_chains(&s, &f, &opts).unwrap_err().to_string();
    assert!(err.contains("`ac`"), "{err}");
    // No grains at all.
    assert!(draw_force_chains(&Scene::new(2), &[], &opts).is_err());
}

#[test]
fn force_chain_projects_3d_scenes() {
    let mut s = Scene::new(3);
    let vol = 4.0 / 3.0 * std::f64::consts::PI;
    // Two unit spheres stacked along z, touching at z = 1.
    s.grains
        .push(Grain::new("low", [5.0, 5.0, 0.0], vol, [0.0; 6]));
    s.grains
        .push(Grain::new("high", [5.0, 5.0, 2.0], vol, [0.0; 6]));
    s.contacts.push(Contact {
        id: "k".into(),
        a: 0,
        b: Body::Grain(1),
        point: [5.0, 5.0, 1.0],
        normal: [0.0, 0.0, 1.0],
        mu: None,
    });
    let f = vec![[0.0, 0.0, -3.0]];
    for plane in [Plane::XZ, Plane::YZ] {
        let opts = ForceChainOptions {
            width_px: 300,
            plane,
            ..Default::default()
        };
        let img = draw_force_chains(&s, &f, &opts).unwrap();
        let layout = chain_layout(&s, &opts).unwrap();
        // Tall packing: taller than wide.
        assert!(img.height() > img.width());
        assert_eq!(
            pixel(&img, layout.to_pixel([5.0, 5.0, 1.0])),
            force_color(1.0)
        );
        // Beside the chain, inside a sphere's outline: background.
        assert_eq!(pixel(&img, layout.to_pixel([5.6, 5.6, 0.5])), WHITE);
    }
    // Seen from above, the spheres coincide and the force is a dot at the centre.
    let opts = ForceChainOptions {
        width_px: 300,
        plane: Plane::XY,
        ..Default::default()
    };
    let img = draw_force_chains(&s, &f, &opts).unwrap();
    let layout = chain_layout(&s, &opts).unwrap();
    assert_eq!(
        pixel(&img, layout.to_pixel([5.0, 5.0, 0.0])),
        force_color(1.0)
    );
    assert_eq!(img.width(), 300);
}

#[test]
fn pareto_csv_round_trips_and_locates_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("pareto.csv");
    let points: Vec<ParetoPoint> = (0..6)
        .map(|i| ParetoPoint {
            lambda: 10f64.powi(i - 3) * 0.7,
            stress_residual: 1e-3 * (i as f64 + 1.0).powi(2),
            momentum_residual: 1.0 / (i as f64 + 1.0).powi(3),
        })
        .collect();
    write_pareto_csv(&path, &points, Some(2)).unwrap();
    let (back, knee) = read_pareto_csv(&path).unwrap();
    assert_eq!(back, points);
    assert_eq!(knee, Some(2));
    write_pareto_csv(&path, &points, None).unwrap();
    assert_eq!(read_pareto_csv(&path).unwrap().1, None);
    assert!(write_pareto_csv(&path, &points, Some(6)).is_err());

    let bad = |content: &str| {
        std::fs::write(&path, content).unwrap();
        read_pareto_csv(&path).unwrap_err().to_string()
    };
    let err = bad("lambda,stress_residual,momentum_residual\n1,2,3\n0.1,x,3\n");
    assert!(
        err.contains("line 3") && err.contains("stress_residual") && err.contains("pareto.csv"),
        "{err}"
    );
    let err = bad("lambda,momentum_residual\n1,2\n");
    assert!(
        err.contains("line 1") && err.contains("stress_residual"),
        "{err}"
    );
    let err = bad("lambda,stress_residual,momentum_residual,knee\n1,2,3,1\n2,2,3,1\n");
    assert!(
        err.contains("line 3") && err.contains("second knee"),
        "{err}"
    );
    let err = bad("lambda,stress_residual,momentum_residual,knee\n1,-2,3,0\n");
    assert!(err.contains("line 2") && err.contains("≥ 0"), "{err}");
}

#[test]
fn pareto_chart_marks_the_knee() {
    let points: Vec<ParetoPoint> = (0..9)
        .map(|i| {
            let t = i as f64;
            ParetoPoint {
                lambda: 10f64.powf(t - 4.0),
                stress_residual: 10f64.powf(-3.0 + 0.4 * t),
                momentum_residual: 10f64.powf(1.0 - 0.5 * t),
            }
        })
        .collect();
    let chart = pareto_chart(&points, Some(4));
    let img = chart.render();
    let knee = chart
        .pixel_of(points[4].stress_residual, points[4].momentum_residual)
        .unwrap();
    let ring = pixel(&img, (knee.0, knee.1 - 12.0));
    assert!(
        ring.0[0] > 180 && ring.0[1] < 80,
        "ring at the knee: {ring:?}"
    );
    // The front's own colour runs through its points.
    let first = chart
        .pixel_of(points[0].stress_residual, points[0].momentum_residual)
        .unwrap();
    assert_eq!(pixel(&img, first), PALETTE[0]);
}
