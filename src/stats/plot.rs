//! P(f/⟨f⟩) on a log-y chart: the histogram as steps with a dot per non-empty
//! bin, and the exponential tail fit as a line from x = 1 to the largest bin.

use super::FrameStats;
use crate::report::chart::{Chart, Scale, PALETTE};

/// Colour of the histogram (steps and dots).
pub const HISTOGRAM_COLOR: image::Rgb<u8> = PALETTE[0];
/// Colour of the tail fit.
pub const FIT_COLOR: image::Rgb<u8> = PALETTE[3];

/// The chart of one frame's force distribution, `width` × `height` pixels.
pub fn distribution_chart(stats: &FrameStats, width: u32, height: u32) -> Chart {
    let h = &stats.histogram;
    let mut steps = Vec::with_capacity(2 * h.density.len());
    let mut dots = Vec::new();
    for (i, &d) in h.density.iter().enumerate() {
        steps.push((h.edges[i], d));
        steps.push((h.edges[i + 1], d));
        if d > 0.0 {
            dots.push((0.5 * (h.edges[i] + h.edges[i + 1]), d));
        }
    }
    let title = match stats.frame {
        Some(k) => format!("P(f/<f>), frame {k}, {} contacts", stats.force_carrying),
        None => format!("P(f/<f>), {} contacts", stats.force_carrying),
    };
    let mut chart = Chart::new(width, height)
        .title(&title)
        .x_axis("f / <f> (normal force)", Scale::Linear)
        .y_axis("probability density", Scale::Log)
        .line("", &steps, HISTOGRAM_COLOR)
        .scatter("histogram", &dots, HISTOGRAM_COLOR);
    if let Some(t) = &stats.tail {
        let x_end = h.edges.last().copied().unwrap_or(1.0).max(1.0);
        let fit: Vec<(f64, f64)> = (0..=40)
            .map(|k| {
                let x = 1.0 + (x_end - 1.0) * k as f64 / 40.0;
                (x, t.amplitude * (-t.rate * x).exp())
            })
            .collect();
        chart = chart.line(&format!("exp(-{:.2} x) tail fit", t.rate), &fit, FIT_COLOR);
    }
    chart
}
