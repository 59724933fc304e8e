//! Small self-contained PNG charts: line and scatter series on linear or log10
//! axes, ticks, legend, title, marked points and text notes, in the built-in
//! bitmap font.
//!
//! ```no_run
//! use grainforce::report::chart::{Chart, Scale, PALETTE, save_png};
//! let img = Chart::new(800, 500)
//!     .title("Pareto front")
//!     .x_axis("stress residual", Scale::Log)
//!     .y_axis("momentum residual", Scale::Log)
//!     .line("front", &[(1.0, 10.0), (2.0, 3.0), (10.0, 1.0)], PALETTE[0])
//!     .mark(2.0, 3.0, "knee")
//!     .render();
//! save_png(std::path::Path::new("front.png"), &img).unwrap();
//! ```
//!
//! Points that cannot be placed (non-finite, or ≤ 0 on a log axis) are left out;
//! a line breaks where it meets one.

use super::draw::{disk, fill_rect, rect_outline, ring, thick_line};
use super::font::{draw_text, draw_text_vertical, text_size};
use crate::error::{Error, Result};
use image::{Rgb, RgbImage};
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    Linear,
    /// log10; non-positive values are left out.
    Log,
}

/// Distinguishable series colours (matplotlib's "tab10" order).
pub const PALETTE: [Rgb<u8>; 10] = [
    Rgb([31, 119, 180]),
    Rgb([255, 127, 14]),
    Rgb([44, 160, 44]),
    Rgb([214, 39, 40]),
    Rgb([148, 103, 189]),
    Rgb([140, 86, 75]),
    Rgb([227, 119, 194]),
    Rgb([127, 127, 127]),
    Rgb([188, 189, 34]),
    Rgb([23, 190, 207]),
];

pub const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
pub(crate) const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const GRID: Rgb<u8> = Rgb([228, 228, 228]);
const MARK: Rgb<u8> = Rgb([220, 20, 60]);

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Line,
    Scatter,
}

#[derive(Debug, Clone)]
struct Series {
    name: String,
    points: Vec<(f64, f64)>,
    color: Rgb<u8>,
    kind: Kind,
}

#[derive(Debug, Clone)]
struct Axis {
    label: String,
    scale: Scale,
    range: Option<(f64, f64)>,
}

impl Axis {
    fn new() -> Self {
        Axis {
            label: String::new(),
            scale: Scale::Linear,
            range: None,
        }
    }

    /// The value in the axis' working space (log10 for log axes), if placeable.
    fn to_space(&self, v: f64) -> Option<f64> {
        match self.scale {
            Scale::Linear => v.is_finite().then_some(v),
            Scale::Log => (v.is_finite() && v > 0.0).then(|| v.log10()),
        }
    }
}

#[derive(Debug, Clone)]
struct Annotation {
    x: f64,
    y: f64,
    text: String,
    marked: bool,
}

/// A chart under construction; [`Chart::render`] draws it.
#[derive(Debug, Clone)]
pub struct Chart {
    width: u32,
    height: u32,
    title: String,
    x: Axis,
    y: Axis,
    series: Vec<Series>,
    annotations: Vec<Annotation>,
}

impl Chart {
    /// A chart of `width` × `height` pixels (at least 120 × 90).
    pub fn new(width: u32, height: u32) -> Self {
        Chart {
            width: width.max(120),
            height: height.max(90),
            title: String::new(),
            x: Axis::new(),
            y: Axis::new(),
            series: Vec::new(),
            annotations: Vec::new(),
        }
    }

    pub fn title(mut self, title: &str) -> Self {
        self.title = title.to_owned();
        self
    }

    pub fn x_axis(mut self, label: &str, scale: Scale) -> Self {
        self.x.label = label.to_owned();
        self.x.scale = scale;
        self
    }

    pub fn y_axis(mut self, label: &str, scale: Scale) -> Self {
        self.y.label = label.to_owned();
        self.y.scale = scale;
        self
    }

    /// Fixes the x range instead of fitting it to the data.
    pub fn x_range(mut self, lo: f64, hi: f64) -> Self {
        self.x.range = Some((lo, hi));
        self
    }

    pub fn y_range(mut self, lo: f64, hi: f64) -> Self {
        self.y.range = Some((lo, hi));
        self
    }

    /// A polyline through the points in the given order. An empty name keeps it out of the legend.
    pub fn line(mut self, name: &str, points: &[(f64, f64)], color: Rgb<u8>) -> Self {
        self.series.push(Series {
            name: name.to_owned(),
            points: points.to_vec(),
            color,
            kind: Kind::Line,
        });
        self
    }

    /// Points as dots.
    pub fn scatter(mut self, name: &str, points: &[(f64, f64)], color: Rgb<u8>) -> Self {
        self.series.push(Series {
            name: name.to_owned(),
            points: points.to_vec(),
            color,
            kind: Kind::Scatter,
        });
        self
    }

    /// A highlighted point (ring) with a label, e.g. the knee of a Pareto front.
    pub fn mark(mut self, x: f64, y: f64, label: &str) -> Self {
        self.annotations.push(Annotation {
            x,
            y,
            text: label.to_owned(),
            marked: true,
        });
        self
    }

    /// A small text beside a data point, without a ring.
    pub fn note(mut self, x: f64, y: f64, text: &str) -> Self {
        self.annotations.push(Annotation {
            x,
            y,
            text: text.to_owned(),
            marked: false,
        });
        self
    }

    /// Text scale used for this chart's size.
    fn text_scale(&self) -> u32 {
        if self.width >= 500 && self.height >= 320 {
            2
        } else {
            1
        }
    }

    /// The plot frame and the ticks of both axes.
    fn layout(&self) -> (Frame, Vec<Tick>, Vec<Tick>) {
        let (w, h) = (self.width, self.height);
        let scale = self.text_scale();
        let x_range = self.fit(&self.x, |p| p.0);
        let y_range = self.fit(&self.y, |p| p.1);
        let x_ticks = ticks(&self.x, x_range, 7);
        let y_ticks = ticks(&self.y, y_range, 6);
        let (_, th) = text_size("0", scale);
        let tick_label_w = y_ticks
            .iter()
            .map(|t| text_size(&t.label, scale).0)
            .max()
            .unwrap_or(0) as i64;
        let pad = 6 * scale as i64;
        let title_h = if self.title.is_empty() {
            0
        } else {
            th as i64 + pad
        };
        let y_label_w = if self.y.label.is_empty() {
            0
        } else {
            th as i64 + pad
        };
        let x_label_h = if self.x.label.is_empty() {
            0
        } else {
            th as i64 + pad
        };
        let left = pad + y_label_w + tick_label_w + pad;
        let right = w as i64 - 3 * pad;
        let top = pad + title_h + pad;
        let bottom = h as i64 - (pad + x_label_h + th as i64 + pad);
        let (left, right, top, bottom) = if right - left < 20 || bottom - top < 20 {
            (2, w as i64 - 2, 2, h as i64 - 2)
        } else {
            (left, right, top, bottom)
        };
        let frame = Frame {
            left: left as f64,
            right: right as f64,
            top: top as f64,
            bottom: bottom as f64,
            x: x_range,
            y: y_range,
        };
        (frame, x_ticks, y_ticks)
    }

    /// Where a data point lands in the rendered image (None if it cannot be placed).
    pub fn pixel_of(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (frame, _, _) = self.layout();
        frame.place(&self.x, &self.y, (x, y))
    }

    /// Draws the chart.
    pub fn render(&self) -> RgbImage {
        let (w, h) = (self.width, self.height);
        let mut img = RgbImage::from_pixel(w, h, WHITE);
        let scale = self.text_scale();
        let (frame, x_ticks, y_ticks) = self.layout();
        let (_, th) = text_size("0", scale);
        let pad = 6 * scale as i64;
        let (left, right, top, bottom) = (
            frame.left as i64,
            frame.right as i64,
            frame.top as i64,
            frame.bottom as i64,
        );

        // Grid and ticks.
        for t in &x_ticks {
            let px = frame.px(t.position);
            if t.major {
                thick_line(&mut img, (px, frame.top), (px, frame.bottom), 1.0, GRID);
            }
            let len = if t.major { 5.0 } else { 3.0 } * scale as f64;
            thick_line(
                &mut img,
                (px, frame.bottom),
                (px, frame.bottom - len),
                1.0,
                BLACK,
            );
            if !t.label.is_empty() {
                let (tw, _) = text_size(&t.label, scale);
                draw_text(
                    &mut img,
                    px.round() as i64 - tw as i64 / 2,
                    bottom + pad / 2,
                    &t.label,
                    scale,
                    BLACK,
                );
            }
        }
        for t in &y_ticks {
            let py = frame.py(t.position);
            if t.major {
                thick_line(&mut img, (frame.left, py), (frame.right, py), 1.0, GRID);
            }
            let len = if t.major { 5.0 } else { 3.0 } * scale as f64;
            thick_line(
                &mut img,
                (frame.left, py),
                (frame.left + len, py),
                1.0,
                BLACK,
            );
            if !t.label.is_empty() {
                let (tw, _) = text_size(&t.label, scale);
                draw_text(
                    &mut img,
                    left - pad / 2 - tw as i64,
                    py.round() as i64 - th as i64 / 2,
                    &t.label,
                    scale,
                    BLACK,
                );
            }
        }

        // Series, drawn on a copy and pasted back inside the frame so nothing spills out.
        let mut layer = img.clone();
        let mut drawn = 0usize;
        let stroke = scale as f64;
        for s in &self.series {
            let placed: Vec<Option<(f64, f64)>> = s
                .points
                .iter()
                .map(|&p| frame.place(&self.x, &self.y, p))
                .collect();
            drawn += placed.iter().flatten().count();
            match s.kind {
                Kind::Line => {
                    for pair in placed.windows(2) {
                        if let (Some(a), Some(b)) = (pair[0], pair[1]) {
                            thick_line(&mut layer, a, b, 1.5 * stroke, s.color);
                        }
                    }
                    // A lone point of a line would otherwise be invisible.
                    if placed.iter().flatten().count() == 1 {
                        if let Some(p) = placed.iter().flatten().next() {
                            disk(&mut layer, *p, 2.0 * stroke, s.color);
                        }
                    }
                }
                Kind::Scatter => {
                    for p in placed.iter().flatten() {
                        disk(&mut layer, *p, 2.5 * stroke, s.color);
                    }
                }
            }
        }
        for a in self.annotations.iter().filter(|a| a.marked) {
            if let Some(p) = frame.place(&self.x, &self.y, (a.x, a.y)) {
                ring(&mut layer, p, 6.0 * stroke, 1.5 * stroke, MARK);
            }
        }
        for y in top.max(0)..bottom.min(h as i64) {
            for x in left.max(0)..right.min(w as i64) {
                img.put_pixel(x as u32, y as u32, *layer.get_pixel(x as u32, y as u32));
            }
        }
        rect_outline(&mut img, left, top, right + 1, bottom + 1, BLACK);

        // Annotation texts may extend beyond the frame; they stay within the image.
        for a in &self.annotations {
            if let Some(p) = frame.place(&self.x, &self.y, (a.x, a.y)) {
                let s = (scale - 1).max(1);
                let (tw, tth) = text_size(&a.text, s);
                let gap = if a.marked { 9.0 } else { 4.0 } * stroke;
                let mut tx = p.0 + gap;
                if tx + tw as f64 > w as f64 - 2.0 {
                    tx = p.0 - gap - tw as f64;
                }
                let ty = (p.1 - gap - tth as f64).max(2.0);
                let color = if a.marked { MARK } else { Rgb([60, 60, 60]) };
                draw_text(
                    &mut img,
                    tx.round() as i64,
                    ty.round() as i64,
                    &a.text,
                    s,
                    color,
                );
            }
        }

        if drawn == 0 && !self.series.is_empty() {
            let msg = "no data to show";
            let (tw, _) = text_size(msg, scale);
            draw_text(
                &mut img,
                (left + right) / 2 - tw as i64 / 2,
                (top + bottom) / 2,
                msg,
                scale,
                Rgb([150, 150, 150]),
            );
        }

        // Titles.
        if !self.title.is_empty() {
            let (tw, _) = text_size(&self.title, scale);
            draw_text(
                &mut img,
                ((left + right) / 2 - tw as i64 / 2).max(2),
                pad,
                &self.title,
                scale,
                BLACK,
            );
        }
        if !self.x.label.is_empty() {
            let (tw, _) = text_size(&self.x.label, scale);
            draw_text(
                &mut img,
                ((left + right) / 2 - tw as i64 / 2).max(2),
                h as i64 - pad - th as i64,
                &self.x.label,
                scale,
                BLACK,
            );
        }
        if !self.y.label.is_empty() {
            let (tw, _) = text_size(&self.y.label, scale);
            draw_text_vertical(
                &mut img,
                pad,
                ((top + bottom) / 2 - tw as i64 / 2).max(2),
                &self.y.label,
                scale,
                BLACK,
            );
        }

        self.legend(&mut img, &frame, scale);
        img
    }

    fn legend(&self, img: &mut RgbImage, frame: &Frame, scale: u32) {
        let named: Vec<&Series> = self.series.iter().filter(|s| !s.name.is_empty()).collect();
        if named.is_empty() {
            return;
        }
        let (_, th) = text_size("0", scale);
        let row = th as i64 + 4 * scale as i64;
        let sample = 18 * scale as i64;
        let text_w = named
            .iter()
            .map(|s| text_size(&s.name, scale).0)
            .max()
            .unwrap_or(0) as i64;
        let pad = 4 * scale as i64;
        let box_w = pad + sample + pad + text_w + pad;
        let box_h = pad + row * named.len() as i64;
        let x0 = frame.right as i64 - box_w - pad;
        let y0 = frame.top as i64 + pad;
        fill_rect(img, x0, y0, x0 + box_w, y0 + box_h, WHITE);
        rect_outline(img, x0, y0, x0 + box_w, y0 + box_h, Rgb([160, 160, 160]));
        for (i, s) in named.iter().enumerate() {
            let ty = y0 + pad + i as i64 * row;
            let cy = ty as f64 + th as f64 / 2.0;
            let sx = (x0 + pad) as f64;
            match s.kind {
                Kind::Line => thick_line(
                    img,
                    (sx, cy),
                    (sx + sample as f64, cy),
                    1.5 * scale as f64,
                    s.color,
                ),
                Kind::Scatter => disk(
                    img,
                    (sx + sample as f64 / 2.0, cy),
                    2.5 * scale as f64,
                    s.color,
                ),
            }
            draw_text(img, x0 + pad + sample + pad, ty, &s.name, scale, BLACK);
        }
    }

    /// The axis range in working space: the fixed one, or the data's with a margin.
    fn fit(&self, axis: &Axis, coordinate: fn(&(f64, f64)) -> f64) -> (f64, f64) {
        if let Some((lo, hi)) = axis.range {
            if let (Some(a), Some(b)) = (axis.to_space(lo), axis.to_space(hi)) {
                if b > a {
                    return (a, b);
                }
            }
        }
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        // Only points placeable on both axes count.
        let placeable =
            |p: &(f64, f64)| self.x.to_space(p.0).is_some() && self.y.to_space(p.1).is_some();
        let values = self
            .series
            .iter()
            .flat_map(|s| s.points.iter())
            .copied()
            .chain(self.annotations.iter().map(|a| (a.x, a.y)))
            .filter(placeable)
            .filter_map(|p| axis.to_space(coordinate(&p)));
        for v in values {
            lo = lo.min(v);
            hi = hi.max(v);
        }
        if !lo.is_finite() {
            return match axis.scale {
                Scale::Linear => (0.0, 1.0),
                Scale::Log => (0.0, 1.0),
            };
        }
        if hi - lo <= f64::EPSILON * lo.abs().max(hi.abs()).max(1e-300) {
            let half = match axis.scale {
                Scale::Log => 0.5,
                Scale::Linear if lo != 0.0 => 0.1 * lo.abs(),
                Scale::Linear => 1.0,
            };
            return (lo - half, hi + half);
        }
        let margin = 0.05 * (hi - lo);
        (lo - margin, hi + margin)
    }
}

/// Maps working-space coordinates to pixels.
struct Frame {
    left: f64,
    right: f64,
    top: f64,
    bottom: f64,
    x: (f64, f64),
    y: (f64, f64),
}

impl Frame {
    fn px(&self, v: f64) -> f64 {
        self.left + (v - self.x.0) / (self.x.1 - self.x.0) * (self.right - self.left)
    }

    fn py(&self, v: f64) -> f64 {
        self.bottom - (v - self.y.0) / (self.y.1 - self.y.0) * (self.bottom - self.top)
    }

    fn place(&self, x: &Axis, y: &Axis, p: (f64, f64)) -> Option<(f64, f64)> {
        let (a, b) = (x.to_space(p.0)?, y.to_space(p.1)?);
        let (px, py) = (self.px(a), self.py(b));
        // Far-off points (fixed ranges) would only waste time in the rasteriser.
        let limit = 1e6;
        (px.abs() < limit && py.abs() < limit).then_some((px, py))
    }
}

struct Tick {
    /// In working space.
    position: f64,
    label: String,
    major: bool,
}

/// 1, 2 or 5 times a power of ten, near span / count.
pub fn nice_step(span: f64, count: usize) -> f64 {
    let raw = span / count.max(1) as f64;
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let power = 10f64.powf(raw.log10().floor());
    let m = raw / power;
    let nice = if m < 1.5 {
        1.0
    } else if m < 3.5 {
        2.0
    } else if m < 7.5 {
        5.0
    } else {
        10.0
    };
    nice * power
}

/// Tick positions (in data units) of a linear range.
pub(crate) fn linear_ticks(lo: f64, hi: f64, count: usize) -> (Vec<f64>, f64) {
    let step = nice_step(hi - lo, count);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    let values = (first..=last.min(first + 100))
        .map(|k| {
            let v = k as f64 * step;
            if (v / step).abs() < 1e-9 {
                0.0
            } else {
                v
            }
        })
        .collect();
    (values, step)
}

fn ticks(axis: &Axis, (lo, hi): (f64, f64), count: usize) -> Vec<Tick> {
    match axis.scale {
        Scale::Linear => {
            let (values, step) = linear_ticks(lo, hi, count);
            values
                .into_iter()
                .map(|v| Tick {
                    position: v,
                    label: format_tick(v, step),
                    major: true,
                })
                .collect()
        }
        Scale::Log if hi - lo < 1.0 => {
            // Less than a decade: linear ticks placed logarithmically.
            let (a, b) = (10f64.powf(lo), 10f64.powf(hi));
            let (values, step) = linear_ticks(a, b, count.min(5));
            values
                .into_iter()
                .filter(|v| *v > 0.0)
                .map(|v| Tick {
                    position: v.log10(),
                    label: format_tick(v, step),
                    major: true,
                })
                .collect()
        }
        Scale::Log => {
            let decades = hi - lo;
            let every = ((decades / count as f64).ceil() as i64).max(1);
            let mut out = Vec::new();
            let first = lo.floor() as i64;
            let last = hi.ceil() as i64;
            for k in first..=last {
                let exponent = k as f64;
                if exponent >= lo && exponent <= hi && k.rem_euclid(every) == 0 {
                    out.push(Tick {
                        position: exponent,
                        label: format_power(k),
                        major: true,
                    });
                }
                if every == 1 && decades <= 6.0 {
                    for m in 2..10 {
                        let p = exponent + (m as f64).log10();
                        if p >= lo && p <= hi {
                            out.push(Tick {
                                position: p,
                                label: String::new(),
                                major: false,
                            });
                        }
                    }
                }
            }
            out
        }
    }
}

/// 10^k as text: plain for moderate k, else "1e-6".
fn format_power(k: i64) -> String {
    if (0..=4).contains(&k) {
        format!("{}", 10i64.pow(k as u32))
    } else if (-3..0).contains(&k) {
        format!("{:.*}", (-k) as usize, 10f64.powi(k as i32))
    } else {
        format!("1e{k}")
    }
}

/// A tick value with just the digits its step needs: "0.25", "1200", "2.5e-5".
pub fn format_tick(v: f64, step: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v == 0.0 { "0".into() } else { v.to_string() };
    }
    let step_exponent = step.abs().log10().floor() as i32;
    let magnitude = v.abs().log10().floor() as i32;
    if (-3..5).contains(&magnitude) && step_exponent >= -6 {
        let decimals = (-step_exponent).max(0) as usize;
        // A step of 2.5 × 10^k needs one more digit.
        let decimals = if (step / 10f64.powi(step_exponent)
            - (step / 10f64.powi(step_exponent)).round())
        .abs()
            > 1e-6
        {
            decimals + 1
        } else {
            decimals
        };
        format!("{:.*}", decimals, v)
    } else {
        let digits = (magnitude - step_exponent).clamp(0, 6) as usize;
        let text = format!("{:.*e}", digits, v);
        // Trim trailing zeros of the mantissa: 2.50e-5 → 2.5e-5.
        match text.split_once('e') {
            Some((mantissa, exponent)) if mantissa.contains('.') => {
                let mantissa = mantissa.trim_end_matches('0').trim_end_matches('.');
                format!("{mantissa}e{exponent}")
            }
            _ => text,
        }
    }
}

/// Writes a PNG atomically: a temporary file beside the target, renamed into place.
/// Errors name the path.
pub fn save_png(path: &Path, img: &RgbImage) -> Result<()> {
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| Error::io(path, std::io::Error::other(e.to_string())))?;
    crate::scene::write_file_atomically(path, bytes.get_ref())
}

/// Lightens a colour towards white by `amount` ∈ [0, 1].
pub(crate) fn lighten(color: Rgb<u8>, amount: f64) -> Rgb<u8> {
    let a = amount.clamp(0.0, 1.0);
    Rgb(color
        .0
        .map(|c| (c as f64 + (255.0 - c as f64) * a).round() as u8))
}
