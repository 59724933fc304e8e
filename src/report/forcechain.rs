//! Force-chain pictures: grains as outlines, every contact force a line whose
//! width and colour grow with its magnitude, walls, and a colour bar in the
//! data's units. 3D scenes are projected onto a coordinate plane.
//!
//! The picture is fitted to the data's bounding box, working relative to its
//! centre, so coordinates far from the origin and any length scale draw alike.

use super::chart::{format_tick, lighten, linear_ticks, BLACK, WHITE};
use super::draw::{colormap, disk, fill_rect, rect_outline, ring, thick_line};
use super::font::{draw_text, text_size};
use crate::error::{Error, Result};
use crate::scene::{norm, Body, Scene, Vec3};
use image::{Rgb, RgbImage};

/// The coordinate plane a scene is drawn in (3D scenes are projected onto it).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Plane {
    #[default]
    XY,
    XZ,
    YZ,
}

impl Plane {
    /// Indices of the horizontal and vertical coordinates.
    pub fn axes(self) -> (usize, usize) {
        match self {
            Plane::XY => (0, 1),
            Plane::XZ => (0, 2),
            Plane::YZ => (1, 2),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Plane::XY => "xy",
            Plane::XZ => "xz",
            Plane::YZ => "yz",
        }
    }
}

impl std::str::FromStr for Plane {
    type Err = Error;
    fn from_str(s: &str) -> Result<Plane> {
        match s.to_ascii_lowercase().as_str() {
            "xy" => Ok(Plane::XY),
            "xz" => Ok(Plane::XZ),
            "yz" => Ok(Plane::YZ),
            _ => Err(Error::Invalid(format!(
                "unknown plane `{s}`: use xy, xz or yz"
            ))),
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct ForceChainOptions {
    /// Image width in pixels; the height follows the packing's aspect ratio.
    pub width_px: u32,
    pub plane: Plane,
    /// Write each grain's id at its centroid.
    pub show_ids: bool,
    /// The force drawn at full width and darkest colour; the data's largest when
    /// None. Fix it to compare pictures of several frames.
    pub max_force: Option<f64>,
    pub title: Option<String>,
    /// Unit text of the colour bar; "N" in 3D and "N/m" in 2D when None.
    pub units: Option<String>,
}

impl Default for ForceChainOptions {
    fn default() -> Self {
        ForceChainOptions {
            width_px: 1000,
            plane: Plane::XY,
            show_ids: false,
            max_force: None,
            title: None,
            units: None,
        }
    }
}

/// Colour of a force at fraction t ∈ [0, 1] of the maximum: inferno from orange
/// (weak) to dark purple (strong), which reads well on white.
pub fn force_color(t: f64) -> Rgb<u8> {
    colormap::inferno(0.85 - 0.75 * t.clamp(0.0, 1.0))
}

const OUTLINE: Rgb<u8> = Rgb([150, 150, 150]);
const WALL: Rgb<u8> = Rgb([70, 70, 70]);
const ZERO_FORCE: Rgb<u8> = Rgb([200, 200, 200]);

/// Where things land in the picture: the data-to-pixel transform and the image size.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainLayout {
    pub width: u32,
    pub height: u32,
    axes: (usize, usize),
    /// Data centre of the drawn box.
    centre: (f64, f64),
    /// Pixel position of the centre.
    origin: (f64, f64),
    /// Pixels per metre.
    pub scale: f64,
    text_scale: u32,
    colorbar_top: i64,
    title_h: i64,
    margin: i64,
}

impl ChainLayout {
    /// Pixel position of a point of the scene (y up in data, down in the image).
    pub fn to_pixel(&self, p: Vec3) -> (f64, f64) {
        let (u, v) = (p[self.axes.0], p[self.axes.1]);
        (
            self.origin.0 + (u - self.centre.0) * self.scale,
            self.origin.1 - (v - self.centre.1) * self.scale,
        )
    }

    /// Top of the colour bar's area, in pixels (the packing lies above it).
    pub fn colorbar_top(&self) -> i64 {
        self.colorbar_top
    }
}

fn check(scene: &Scene, forces: &[Vec3], plane: Plane) -> Result<()> {
    if scene.grains.is_empty() {
        return Err(Error::Invalid("the scene has no grains to draw".into()));
    }
    if scene.dim == 2 && plane != Plane::XY {
        return Err(Error::Invalid(format!(
            "plane {} needs a 3D scene; this one is 2D (use xy)",
            plane.name()
        )));
    }
    if forces.len() != scene.contacts.len() {
        let detail = if forces.len() < scene.contacts.len() {
            format!("contact `{}` has none", scene.contacts[forces.len()].id)
        } else {
            "there are more forces than contacts".into()
        };
        return Err(Error::Invalid(format!(
            "{} forces for {} contacts: {detail}",
            forces.len(),
            scene.contacts.len()
        )));
    }
    if let Some((c, _)) = scene
        .contacts
        .iter()
        .zip(forces)
        .find(|(_, f)| f.iter().any(|x| !x.is_finite()))
    {
        return Err(Error::Invalid(format!(
            "the force of contact `{}` is not finite",
            c.id
        )));
    }
    Ok(())
}

/// The layout [`draw_force_chains`] uses for this scene and these options.
pub fn chain_layout(scene: &Scene, opts: &ForceChainOptions) -> Result<ChainLayout> {
    if scene.grains.is_empty() {
        return Err(Error::Invalid("the scene has no grains to draw".into()));
    }
    let axes = opts.plane.axes();
    let mut lo = (f64::INFINITY, f64::INFINITY);
    let mut hi = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    let mut include = |u: f64, v: f64, r: f64| {
        lo = (lo.0.min(u - r), lo.1.min(v - r));
        hi = (hi.0.max(u + r), hi.1.max(v + r));
    };
    for g in &scene.grains {
        let r = g.equivalent_radius(scene.dim);
        let r = if r.is_finite() { r.max(0.0) } else { 0.0 };
        include(g.position[axes.0], g.position[axes.1], r);
    }
    for c in &scene.contacts {
        include(c.point[axes.0], c.point[axes.1], 0.0);
    }
    let mut span = (hi.0 - lo.0, hi.1 - lo.1);
    // A single point or a line of points still needs an area to show.
    let largest = span.0.max(span.1);
    let fallback = if largest > 0.0 { largest } else { 1.0 };
    if span.0 <= 0.0 {
        span.0 = fallback;
    }
    if span.1 <= 0.0 {
        span.1 = fallback;
    }
    let centre = ((lo.0 + hi.0) / 2.0, (lo.1 + hi.1) / 2.0);

    let width = opts.width_px.clamp(64, 20_000);
    let text_scale = if width >= 600 { 2 } else { 1 };
    let (_, th) = text_size("0", text_scale);
    let th = th as i64;
    let margin = (width as i64 / 25).max(12) + 3 * th;
    let title_h = if opts.title.is_some() { th + th / 2 } else { 0 };
    let inner_w = (width as i64 - 2 * margin).max(16) as f64;
    let mut scale = inner_w / span.0;
    // Very tall packings: cap the height at three widths.
    let max_h = 3.0 * width as f64;
    if span.1 * scale > max_h {
        scale = max_h / span.1;
    }
    let inner_h = (span.1 * scale).max(16.0);
    let colorbar_h = 6 * th;
    let top = margin + title_h;
    let height = (top as f64 + inner_h + margin as f64 + colorbar_h as f64).ceil() as u32;
    Ok(ChainLayout {
        width,
        height,
        axes,
        centre,
        origin: (width as f64 / 2.0, top as f64 + inner_h / 2.0),
        scale,
        text_scale,
        colorbar_top: (top as f64 + inner_h) as i64 + margin,
        title_h,
        margin,
    })
}

/// Draws the force chains of one frame (`forces` in contact order).
pub fn draw_force_chains(
    scene: &Scene,
    forces: &[Vec3],
    opts: &ForceChainOptions,
) -> Result<RgbImage> {
    draw_force_chains_with_sd(scene, forces, None, opts)
}

/// The standard deviation of |f| from per-component ones, to first order
/// (components independent): √Σ (f_k/|f| · sd_k)².
pub(crate) fn magnitude_sd(f: Vec3, sd: Vec3) -> f64 {
    let m = norm(f);
    if m == 0.0 {
        return norm(sd);
    }
    (0..3)
        .map(|k| (f[k] / m * sd[k]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// As [`draw_force_chains`], with each force's ±1 sd (per component, contact
/// order) shown by width: a solid core as wide as |f| − sd would be drawn and a
/// pale band as wide as |f| + sd (colour still by |f|).
pub fn draw_force_chains_with_sd(
    scene: &Scene,
    forces: &[Vec3],
    sd: Option<&[Vec3]>,
    opts: &ForceChainOptions,
) -> Result<RgbImage> {
    check(scene, forces, opts.plane)?;
    if let Some(sd) = sd {
        if sd.len() != forces.len() {
            return Err(Error::Invalid(format!(
                "{} standard deviations for {} forces",
                sd.len(),
                forces.len()
            )));
        }
        if let Some((c, _)) = scene
            .contacts
            .iter()
            .zip(sd)
            .find(|(_, s)| s.iter().any(|x| !(x.is_finite() && *x >= 0.0)))
        {
            return Err(Error::Invalid(format!(
                "the standard deviation of contact `{}` is negative or not finite",
                c.id
            )));
        }
    }
    let layout = chain_layout(scene, opts)?;
    let mut img = RgbImage::from_pixel(layout.width, layout.height, WHITE);
    let radius_px = |i: usize| scene.grains[i].equivalent_radius(scene.dim).max(0.0) * layout.scale;
    let mean_radius_px =
        (0..scene.grains.len()).map(radius_px).sum::<f64>() / scene.grains.len() as f64;

    // Grains.
    for (i, g) in scene.grains.iter().enumerate() {
        let c = layout.to_pixel(g.position);
        let r = radius_px(i);
        if r >= 2.0 {
            ring(&mut img, c, r, (r / 30.0).clamp(1.0, 3.0), OUTLINE);
        } else {
            disk(&mut img, c, 1.0, OUTLINE);
        }
    }

    draw_walls(scene, &layout, &mut img);

    // Forces, weakest first so strong chains stay on top.
    let magnitudes: Vec<f64> = forces.iter().map(|f| norm(*f)).collect();
    let data_max = magnitudes.iter().cloned().fold(0.0, f64::max);
    let fmax = opts
        .max_force
        .filter(|m| m.is_finite() && *m > 0.0)
        .unwrap_or(data_max);
    let mut order: Vec<usize> = (0..forces.len()).collect();
    order.sort_by(|&a, &b| magnitudes[a].total_cmp(&magnitudes[b]));
    // The strongest force is drawn about a grain radius wide (a little less, to keep chains apart).
    let full_width = (0.75 * mean_radius_px).max(1.0);
    let ends = |c: usize| {
        let contact = &scene.contacts[c];
        let p = layout.to_pixel(scene.grains[contact.a].position);
        let q = match contact.b {
            Body::Grain(b) => layout.to_pixel(scene.grains[b].position),
            Body::Wall(_) => layout.to_pixel(contact.point),
        };
        (p, q)
    };
    // Bands first, all of them, so no band hides another contact's line.
    if let (Some(sd), true) = (sd, fmax > 0.0) {
        for &c in &order {
            let s = magnitude_sd(forces[c], sd[c]);
            if s <= 0.0 {
                continue;
            }
            let (p, q) = ends(c);
            let t = (magnitudes[c] / fmax).min(1.0);
            let width = ((magnitudes[c] + s) / fmax).min(1.5) * full_width;
            thick_line(&mut img, p, q, width, lighten(force_color(t), 0.65));
        }
    }
    for c in order {
        let (p, q) = ends(c);
        if magnitudes[c] == 0.0 || fmax == 0.0 {
            thick_line(&mut img, p, q, 0.6, ZERO_FORCE);
            continue;
        }
        let t = (magnitudes[c] / fmax).min(1.0);
        // With an sd the solid core is |f| − sd wide and the pale band |f| + sd.
        let core = match sd {
            Some(sd) => (magnitudes[c] - magnitude_sd(forces[c], sd[c])).max(0.0) / fmax,
            None => t,
        };
        thick_line(&mut img, p, q, (core * full_width).max(0.8), force_color(t));
    }

    if opts.show_ids {
        let s = 1;
        for g in &scene.grains {
            let (x, y) = layout.to_pixel(g.position);
            let (tw, th) = text_size(&g.id, s);
            draw_text(
                &mut img,
                snap(x) - tw as i64 / 2,
                snap(y) - th as i64 / 2,
                &g.id,
                s,
                Rgb([20, 60, 160]),
            );
        }
    }

    if let Some(title) = &opts.title {
        let (tw, _) = text_size(title, layout.text_scale);
        draw_text(
            &mut img,
            (layout.width as i64 / 2 - tw as i64 / 2).max(2),
            layout.margin / 2,
            title,
            layout.text_scale,
            BLACK,
        );
    }

    let units = opts.units.clone().unwrap_or_else(|| {
        if scene.dim == 2 {
            "N/m".into()
        } else {
            "N".into()
        }
    });
    let note = sd.map(|_| "line width: |f| - 1 sd (solid) to |f| + 1 sd (pale band)");
    draw_colorbar(&mut img, &layout, fmax, &units, forces.is_empty(), note);
    Ok(img)
}

/// A text position in whole pixels. The small bias keeps exact half-pixel
/// positions from flipping with rounding noise (e.g. after a shift of origin).
fn snap(v: f64) -> i64 {
    (v + 1e-3).round() as i64
}

/// Each wall as a line through its contact points, perpendicular to their mean
/// normal (as projected), spanning the packing.
fn draw_walls(scene: &Scene, layout: &ChainLayout, img: &mut RgbImage) {
    let (iu, iv) = layout.axes;
    for (w, wall) in scene.walls.iter().enumerate() {
        let contacts: Vec<_> = scene
            .contacts
            .iter()
            .filter(|c| c.b == Body::Wall(w))
            .collect();
        if contacts.is_empty() {
            continue;
        }
        let k = contacts.len() as f64;
        let mut n = [0.0; 3];
        let mut p = [0.0; 3];
        for c in &contacts {
            for i in 0..3 {
                n[i] += c.normal[i] / k;
                p[i] += c.point[i] / k;
            }
        }
        let n_len = norm(n);
        let (nu, nv) = (n[iu], n[iv]);
        let in_plane = (nu * nu + nv * nv).sqrt();
        // A wall facing the viewer covers everything; leave it out.
        if n_len == 0.0 || in_plane < 0.3 * n_len {
            continue;
        }
        // Pixel-space directions (v flips).
        let normal_px = (nu / in_plane, -nv / in_plane);
        let tangent_px = (-normal_px.1, normal_px.0);
        let anchor = layout.to_pixel(p);
        let (mut s_lo, mut s_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for g in &scene.grains {
            let c = layout.to_pixel(g.position);
            let r = g.equivalent_radius(scene.dim).max(0.0) * layout.scale;
            let s = (c.0 - anchor.0) * tangent_px.0 + (c.1 - anchor.1) * tangent_px.1;
            s_lo = s_lo.min(s - r);
            s_hi = s_hi.max(s + r);
        }
        let thickness = 3.0 * layout.text_scale as f64 / 2.0;
        // Shift by half the stroke so the line sits outside the grains.
        let shift = thickness / 2.0;
        let a = (
            anchor.0 + s_lo * tangent_px.0 + shift * normal_px.0,
            anchor.1 + s_lo * tangent_px.1 + shift * normal_px.1,
        );
        let b = (
            anchor.0 + s_hi * tangent_px.0 + shift * normal_px.0,
            anchor.1 + s_hi * tangent_px.1 + shift * normal_px.1,
        );
        thick_line(img, a, b, thickness, WALL);
        // Name beyond the wall, near its start.
        let (tw, th) = text_size(&wall.name, 1);
        let gap = 6.0 + th as f64;
        let lx = a.0 + gap * normal_px.0 - tw as f64 / 2.0 + 8.0 * tangent_px.0;
        let ly = a.1 + gap * normal_px.1 - th as f64 / 2.0 + 8.0 * tangent_px.1;
        let lx = lx.clamp(1.0, (layout.width as f64 - tw as f64 - 1.0).max(1.0));
        let ly = ly.clamp(1.0, (layout.height as f64 - th as f64 - 1.0).max(1.0));
        draw_text(img, snap(lx), snap(ly), &wall.name, 1, WALL);
    }
}

fn draw_colorbar(
    img: &mut RgbImage,
    layout: &ChainLayout,
    fmax: f64,
    units: &str,
    no_contacts: bool,
    note: Option<&str>,
) {
    let s = layout.text_scale;
    let (_, th) = text_size("0", s);
    let th = th as i64;
    let top = layout.colorbar_top;
    let left = layout.margin;
    let right = layout.width as i64 - layout.margin;
    let bar_h = 2 * th;
    if no_contacts || fmax == 0.0 {
        let msg = if no_contacts {
            "no contacts".to_owned()
        } else {
            format!("all contact forces are zero [{units}]")
        };
        let (tw, _) = text_size(&msg, s);
        draw_text(
            img,
            (layout.width as i64 - tw as i64) / 2,
            top,
            &msg,
            s,
            BLACK,
        );
        return;
    }
    let span = (right - left).max(1);
    for x in left..right {
        let t = (x - left) as f64 / span as f64;
        fill_rect(img, x, top, x + 1, top + bar_h, force_color(t));
    }
    rect_outline(img, left, top, right, top + bar_h, BLACK);
    let (ticks, step) = linear_ticks(0.0, fmax, 5);
    for v in ticks {
        let x = left as f64 + v / fmax * span as f64;
        thick_line(
            img,
            (x, (top + bar_h) as f64),
            (x, (top + bar_h + th / 2) as f64),
            1.0,
            BLACK,
        );
        let label = format_tick(v, step);
        let (tw, _) = text_size(&label, s);
        let lx = (snap(x) - tw as i64 / 2).clamp(0, (layout.width as i64 - tw as i64).max(0));
        draw_text(img, lx, top + bar_h + th / 2 + 2, &label, s, BLACK);
    }
    let title = format!(
        "contact force |f| [{units}], max {}",
        format_tick(fmax, fmax / 1000.0)
    );
    let (tw, _) = text_size(&title, s);
    draw_text(
        img,
        (layout.width as i64 - tw as i64) / 2,
        top + bar_h + 2 * th + 4,
        &title,
        s,
        BLACK,
    );
    if let Some(note) = note {
        // Small, on its own line: the colour bar area has room for it.
        let (nw, _) = text_size(note, 1);
        draw_text(
            img,
            ((layout.width as i64 - nw as i64) / 2).max(0),
            top + bar_h + 3 * th + 6,
            note,
            1,
            Rgb([80, 80, 80]),
        );
    }
}
