//! An overlay picture to check a detection at a glance: the image dimmed, each
//! disk's fitted circle (green; cyan when cut by the border) and id, walls
//! (blue), and each contact as a red line between the centres (to the wall
//! point for wall contacts) with its contact point; doubtful contacts dashed
//! in orange.

use super::contacts::{ContactBody, PixelContact, WallLine};
use super::detect::Disk;
use super::font::draw_text;
use super::FloatImage;
use crate::error::Result;
use ::image::{Rgb, RgbImage};
use imageproc::drawing::{draw_filled_circle_mut, draw_line_segment_mut};
use std::path::Path;

const GREEN: Rgb<u8> = Rgb([40, 230, 60]);
const CYAN: Rgb<u8> = Rgb([40, 220, 230]);
const RED: Rgb<u8> = Rgb([255, 40, 40]);
const BLUE: Rgb<u8> = Rgb([70, 110, 255]);
const YELLOW: Rgb<u8> = Rgb([255, 230, 40]);
const ORANGE: Rgb<u8> = Rgb([255, 150, 20]);

pub fn draw_overlay(
    image: &FloatImage,
    disks: &[Disk],
    ids: &[String],
    contacts: &[PixelContact],
    walls: &[WallLine],
) -> RgbImage {
    let (w, h) = image.dimensions();
    let mut out = RgbImage::from_fn(w, h, |x, y| {
        let v = (image.get_pixel(x, y)[0].clamp(0.0, 1.0) * 180.0) as u8;
        Rgb([v, v, v])
    });
    let f = |p: [f64; 2]| (p[0] as f32, p[1] as f32);
    for wall in walls {
        draw_line_segment_mut(&mut out, f(wall.p0), f(wall.p1), BLUE);
    }
    for d in disks {
        let colour = if d.cut_by_border() { CYAN } else { GREEN };
        let n = ((std::f64::consts::TAU * d.r / 2.0).ceil() as usize).max(16);
        let at = |k: usize| {
            let a = std::f64::consts::TAU * k as f64 / n as f64;
            [d.x + d.r * a.cos(), d.y + d.r * a.sin()]
        };
        for k in 0..n {
            draw_line_segment_mut(&mut out, f(at(k)), f(at(k + 1)), colour);
        }
    }
    let dot = (disks.iter().map(|d| d.r).fold(0.0, f64::max) / 25.0).clamp(1.0, 4.0) as i32;
    for c in contacts {
        let a = &disks[c.a];
        let end = match c.b {
            ContactBody::Disk(b) => [disks[b].x, disks[b].y],
            ContactBody::Wall(_) => c.point,
        };
        draw_line_segment_mut(&mut out, f([a.x, a.y]), f(end), RED);
        draw_filled_circle_mut(
            &mut out,
            (c.point[0].round() as i32, c.point[1].round() as i32),
            dot,
            RED,
        );
    }
    for (d, id) in disks.iter().zip(ids) {
        let scale = (d.r / 12.0).clamp(1.0, 4.0) as i64;
        draw_text(id, d.x.round() as i64, d.y.round() as i64, scale, |x, y| {
            if x >= 0 && y >= 0 && (x as u32) < w && (y as u32) < h {
                out.put_pixel(x as u32, y as u32, YELLOW);
            }
        });
    }
    out
}

/// Draws doubtful contacts (see `contacts-evidence.csv`) in orange: a
/// dashed line between the centres (to the wall point for wall contacts) and
/// a dot at the contact point, so they can be checked by eye.
pub fn mark_doubtful(out: &mut RgbImage, disks: &[Disk], doubtful: &[PixelContact]) {
    let f = |p: [f64; 2]| (p[0] as f32, p[1] as f32);
    let dot = (disks.iter().map(|d| d.r).fold(0.0, f64::max) / 25.0).clamp(1.0, 4.0) as i32;
    for c in doubtful {
        let a = &disks[c.a];
        let end = match c.b {
            ContactBody::Disk(b) => [disks[b].x, disks[b].y],
            ContactBody::Wall(_) => c.point,
        };
        let (p, q) = ([a.x, a.y], end);
        let length = (q[0] - p[0]).hypot(q[1] - p[1]);
        let dashes = (length / 4.0).ceil().max(1.0) as usize;
        for k in (0..dashes).step_by(2) {
            let at = |t: f64| [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])];
            let (t0, t1) = (
                k as f64 / dashes as f64,
                ((k + 1) as f64 / dashes as f64).min(1.0),
            );
            draw_line_segment_mut(out, f(at(t0)), f(at(t1)), ORANGE);
        }
        draw_filled_circle_mut(
            out,
            (c.point[0].round() as i32, c.point[1].round() as i32),
            dot,
            ORANGE,
        );
    }
}

pub fn save_overlay(path: &Path, overlay: &RgbImage) -> Result<()> {
    super::io::save_atomically(path, &::image::DynamicImage::ImageRgb8(overlay.clone()))
}
