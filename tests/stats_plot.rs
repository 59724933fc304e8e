//! `grainforce stats --plot`: P(f/<f>) with its tail fit on a log-y chart.

use grainforce::scene::{read_forces, read_scene};
use grainforce::stats::plot::{distribution_chart, FIT_COLOR, HISTOGRAM_COLOR};
use grainforce::stats::{frame_stats, Options};
use std::path::Path;
use std::process::Command;

#[test]
fn the_chart_shows_the_histogram_and_the_tail_fit_where_the_layout_puts_them() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/oedometer");
    let scene = read_scene(&dir).unwrap();
    let forces = read_forces(&dir.join("forces.csv"))
        .unwrap()
        .for_scene(&scene, &dir)
        .unwrap();
    let stats = frame_stats(&scene, &forces, &Options::default()).unwrap();
    let tail = stats.tail.clone().expect("a tail fit on the oedometer");
    let chart = distribution_chart(&stats, 900, 600);
    let img = chart.render();
    let at = |x: f64, y: f64| {
        let (px, py) = chart.pixel_of(x, y).unwrap();
        *img.get_pixel(px.round() as u32, py.round() as u32)
    };
    let h = &stats.histogram;
    let mut checked = 0;
    // Bins below the mean: the tail fit (from x = 1) cannot overlap their dots.
    for (i, &d) in h.density.iter().enumerate() {
        if d > 0.0 && h.edges[i + 1] <= 1.0 + 1e-9 {
            let centre = 0.5 * (h.edges[i] + h.edges[i + 1]);
            assert_eq!(at(centre, d), HISTOGRAM_COLOR, "bin {i}");
            checked += 1;
        }
    }
    assert!(checked >= 5);
    // On the fit line, between bins where nothing else is drawn, at x = 2.5.
    let x = 2.5;
    assert!(h.edges.last().unwrap() > &x);
    assert_eq!(at(x, tail.amplitude * (-tail.rate * x).exp()), FIT_COLOR);
    // Far above the data: background, not a series.
    let top = h.density.iter().cloned().fold(0.0, f64::max);
    assert_ne!(at(x, top), HISTOGRAM_COLOR);
    assert_ne!(at(x, top), FIT_COLOR);
}

#[test]
fn stats_cli_writes_the_plot() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/oedometer");
    let out = tempfile::tempdir().unwrap();
    let png = out.path().join("stats.png");
    let status = Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .arg("stats")
        .arg(&dir)
        .arg(dir.join("forces.csv"))
        .arg("--plot")
        .arg(&png)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let img = image::open(&png).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (900, 600));
    let blue = img.pixels().filter(|p| **p == HISTOGRAM_COLOR).count();
    assert!(blue > 500, "{blue} histogram pixels");
}
