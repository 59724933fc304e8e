//! Contacts between detected disks, and between disks and walls, by a pixel
//! threshold on the gap between boundaries. The contact point lies on the line
//! of centres, in the middle of the gap (or overlap); the normal points from
//! the first body towards the second. All in pixel coordinates.

use super::detect::Disk;
use crate::error::{Error, Result};

/// A straight wall through two points [px]; a contact exists where a disk's
/// boundary comes within the threshold of the (infinite) line.
#[derive(Debug, Clone, PartialEq)]
pub struct WallLine {
    pub name: String,
    pub p0: [f64; 2],
    pub p1: [f64; 2],
}

impl WallLine {
    pub fn new(name: impl Into<String>, p0: [f64; 2], p1: [f64; 2]) -> Result<Self> {
        let name = name.into();
        let length = ((p1[0] - p0[0]).powi(2) + (p1[1] - p0[1]).powi(2)).sqrt();
        if !(length > 0.0 && length.is_finite()) || name.is_empty() {
            return Err(Error::Invalid(format!(
                "wall `{name}` needs a name and two distinct points"
            )));
        }
        Ok(WallLine { name, p0, p1 })
    }

    /// Parses `NAME=x0,y0,x1,y1` (pixels).
    pub fn parse(spec: &str) -> Result<Self> {
        let bad = || {
            Error::Invalid(format!(
                "wall `{spec}`: expected NAME=x0,y0,x1,y1 in pixels (or `edges`)"
            ))
        };
        let (name, coords) = spec.split_once('=').ok_or_else(bad)?;
        let v: Vec<f64> = coords
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| bad())?;
        if v.len() != 4 || v.iter().any(|x| !x.is_finite()) {
            return Err(bad());
        }
        WallLine::new(name.trim(), [v[0], v[1]], [v[2], v[3]])
    }

    /// A wall given in scene coordinates [m], placed in the image by `frame`.
    pub fn from_scene(
        name: impl Into<String>,
        p0: [f64; 2],
        p1: [f64; 2],
        frame: &super::PixelFrame,
    ) -> Result<Self> {
        WallLine::new(name, frame.to_pixel(p0), frame.to_pixel(p1))
    }

    /// Unit normal of the line and its offset: points q on it satisfy n·q = d.
    fn normal_form(&self) -> ([f64; 2], f64) {
        let t = [self.p1[0] - self.p0[0], self.p1[1] - self.p0[1]];
        let l = (t[0] * t[0] + t[1] * t[1]).sqrt();
        let n = [-t[1] / l, t[0] / l];
        (n, n[0] * self.p0[0] + n[1] * self.p0[1])
    }
}

/// Four walls along the bounding box of `disks` (`left`, `right`, `top`,
/// `bottom`, in the image's axes), each spanning it, at the second outermost
/// disk edge on each side: a wall the picture does not show is put where two
/// disks agree, so that one disk found larger or farther out (jlin-narrow21's
/// corner disk, 9 px beyond its column) does not move the wall off all the
/// others; the outermost one overlaps it, which counts as touching. None
/// without disks.
pub fn packing_box_walls(disks: &[Disk]) -> Vec<WallLine> {
    if disks.is_empty() {
        return Vec::new();
    }
    // The second smallest of the edges (the only one of one disk).
    let second = |mut edges: Vec<f64>| {
        edges.sort_by(f64::total_cmp);
        edges[1.min(edges.len() - 1)]
    };
    let (mut lo, mut hi) = ([0.0; 2], [0.0; 2]);
    for k in 0..2 {
        let centre = |d: &Disk| if k == 0 { d.x } else { d.y };
        lo[k] = second(disks.iter().map(|d| centre(d) - d.r).collect());
        hi[k] = -second(disks.iter().map(|d| -(centre(d) + d.r)).collect());
    }
    let wall = |name: &str, p0, p1| WallLine {
        name: name.into(),
        p0,
        p1,
    };
    vec![
        wall("left", [lo[0], lo[1]], [lo[0], hi[1]]),
        wall("right", [hi[0], lo[1]], [hi[0], hi[1]]),
        wall("top", [lo[0], lo[1]], [hi[0], lo[1]]),
        wall("bottom", [lo[0], hi[1]], [hi[0], hi[1]]),
    ]
}

/// The four image borders as walls named `left`, `right`, `top` and `bottom`
/// (the outer edges of the edge pixels).
pub fn edge_walls(width: u32, height: u32) -> Vec<WallLine> {
    let (r, b) = (width as f64 - 0.5, height as f64 - 0.5);
    vec![
        WallLine {
            name: "left".into(),
            p0: [-0.5, -0.5],
            p1: [-0.5, b],
        },
        WallLine {
            name: "right".into(),
            p0: [r, -0.5],
            p1: [r, b],
        },
        WallLine {
            name: "top".into(),
            p0: [-0.5, -0.5],
            p1: [r, -0.5],
        },
        WallLine {
            name: "bottom".into(),
            p0: [-0.5, b],
            p1: [r, b],
        },
    ]
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ContactBody {
    /// Index into the disks.
    Disk(usize),
    /// Index into the walls.
    Wall(usize),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PixelContact {
    /// Index of the first disk.
    pub a: usize,
    pub b: ContactBody,
    /// Contact point [px].
    pub point: [f64; 2],
    /// Unit normal from `a` towards `b` (pixel axes, y down).
    pub normal: [f64; 2],
    /// Boundary gap [px]; negative where the disks overlap.
    pub gap: f64,
}

/// Every pair of disks (a < b) whose boundaries are closer than `gap_px`, then
/// every disk within `gap_px` of a wall line. Sorted by a, then b.
pub fn find_contacts(disks: &[Disk], walls: &[WallLine], gap_px: f64) -> Vec<PixelContact> {
    let mut out = Vec::new();
    // Sweep along x so only disks that can touch are compared.
    let mut order: Vec<usize> = (0..disks.len()).collect();
    order.sort_by(|&i, &j| (disks[i].x - disks[i].r).total_cmp(&(disks[j].x - disks[j].r)));
    for (k, &i) in order.iter().enumerate() {
        let di = &disks[i];
        for &j in &order[k + 1..] {
            let dj = &disks[j];
            if dj.x - dj.r > di.x + di.r + gap_px {
                break;
            }
            let (a, b) = if i < j { (i, j) } else { (j, i) };
            let (da, db) = (&disks[a], &disks[b]);
            let d = [db.x - da.x, db.y - da.y];
            let dist = (d[0] * d[0] + d[1] * d[1]).sqrt();
            let gap = dist - da.r - db.r;
            if gap < gap_px && dist > 0.0 {
                let n = [d[0] / dist, d[1] / dist];
                let reach = da.r + 0.5 * gap;
                out.push(PixelContact {
                    a,
                    b: ContactBody::Disk(b),
                    point: [da.x + reach * n[0], da.y + reach * n[1]],
                    normal: n,
                    gap,
                });
            }
        }
    }
    for (w, wall) in walls.iter().enumerate() {
        let (n, offset) = wall.normal_form();
        for (a, disk) in disks.iter().enumerate() {
            let signed = offset - (n[0] * disk.x + n[1] * disk.y);
            let gap = signed.abs() - disk.r;
            if gap < gap_px {
                let s = if signed >= 0.0 { 1.0 } else { -1.0 };
                let normal = [s * n[0], s * n[1]];
                out.push(PixelContact {
                    a,
                    b: ContactBody::Wall(w),
                    // The wall surface; the gap is the wall's own position.
                    point: [disk.x + signed * n[0], disk.y + signed * n[1]],
                    normal,
                    gap,
                });
            }
        }
    }
    out.sort_by_key(|c| {
        (
            c.a,
            match c.b {
                ContactBody::Disk(b) => (0, b),
                ContactBody::Wall(w) => (1, w),
            },
        )
    });
    out
}

/// Wall `w`'s line read from its listed contacts in `scene`: their mean
/// point and their mean normal, made a unit vector (scene axes). None
/// without contacts, or where their normals cancel.
pub fn wall_line_of_contacts(
    scene: &crate::scene::Scene,
    w: usize,
) -> Option<([f64; 2], [f64; 2])> {
    use crate::scene::Body;
    let (mut point, mut normal, mut n) = ([0.0; 2], [0.0; 2], 0usize);
    for c in scene.contacts.iter().filter(|c| c.b == Body::Wall(w)) {
        for k in 0..2 {
            point[k] += c.point[k];
            normal[k] += c.normal[k];
        }
        n += 1;
    }
    let length = normal[0].hypot(normal[1]);
    if n == 0 || !(length.is_finite() && length > 0.0) {
        return None;
    }
    Some((
        [point[0] / n as f64, point[1] / n as f64],
        [normal[0] / length, normal[1] / length],
    ))
}

/// The wall lines implied by a scene's wall contacts (e.g. a DEM's): for each
/// wall, [`wall_line_of_contacts`] in the pixels of `frame`. Walls without
/// contacts are skipped.
pub fn walls_from_scene_contacts(
    scene: &crate::scene::Scene,
    frame: &super::PixelFrame,
) -> Vec<WallLine> {
    let mut out = Vec::new();
    for (w, wall) in scene.walls.iter().enumerate() {
        let Some((point, normal)) = wall_line_of_contacts(scene, w) else {
            continue;
        };
        let tangent = [-normal[1], normal[0]];
        let p0 = [point[0] - tangent[0], point[1] - tangent[1]];
        let p1 = [point[0] + tangent[0], point[1] + tangent[1]];
        if let Ok(line) = WallLine::from_scene(wall.name.clone(), p0, p1, frame) {
            out.push(line);
        }
    }
    out
}

// ---------------------------------------------------------------------------
// Contacts from image evidence (real photographs).
//
// A photoelastic disk shows a dark rim a few pixels wide inside its edge
// (refraction). The detector's circle follows the bright interior, so touching
// disks look 2·rim apart. Each disk's rim is measured from its own edge
// profile, the circle grown to the rim's outer edge, and a pair is a contact
// when (i) the outer edges meet within a tolerance that grows with the radius,
// (ii) no background shows between the rims along the line of centres, and/or
// (iii) the photoelastic signal G² (squared intensity gradient) is strong near
// the contact point on both disks. A confidence in [0, 1] says how sure.

use super::FloatImage;

/// What an edge profile says about a disk's rim.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rim {
    /// From the fitted circle to the rim's outer edge [px] (0 without a rim).
    pub width: f64,
    /// Mean intensity of the darkest part of the rim and of the background just outside.
    pub level: f64,
    pub background: f64,
}

/// G² over the floor on both sides from which a contact counts as carrying
/// force: above the level of the packing's unloaded disks (the floor, the
/// lower quartile of the disks' interior G²). On the five shared real
/// photographs this flags 49–78 % of PeGS's force-bearing contacts, and
/// 82–100 % of those it flags are PeGS's (docs/image.md).
pub const FORCE_G2: f64 = 1.0;

/// Settings of [`find_image_contacts`].
#[derive(Debug, Clone)]
pub struct ContactOptions {
    /// Tolerance on the gap between the disks' outer edges [px]: `base_px` plus
    /// `per_radius` times the smaller radius (fit error grows with the disk).
    pub base_px: f64,
    pub per_radius: f64,
    /// Pairs farther apart than this fraction of the smaller radius are never
    /// contacts, whatever the image says.
    pub search_per_radius: f64,
    /// Contacts with at least this confidence are written as contacts; those
    /// down to `doubtful` are reported with a flag.
    pub confident: f64,
    pub doubtful: f64,
    /// The outer part of each disk (a fraction of its radius) whose G² is
    /// not read (a real disk's dark outline has a gradient of its own).
    pub edge_margin: f64,
    /// A contact carries force when G² near it, over the packing's floor, is
    /// at least this on both disks (PeGS's rule, with a threshold relative
    /// to the image's own unloaded level instead of a fixed number).
    pub force_g2: f64,
}

impl Default for ContactOptions {
    fn default() -> Self {
        ContactOptions {
            base_px: 1.0,
            per_radius: 0.04,
            search_per_radius: 0.2,
            confident: 0.5,
            doubtful: 0.2,
            edge_margin: 0.0,
            force_g2: FORCE_G2,
        }
    }
}

/// The evidence behind one contact.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactEvidence {
    /// Gap between the outer edges of the rims [px] (negative: overlap).
    pub outer_gap: f64,
    /// Tolerance the gap was held to [px].
    pub tolerance: f64,
    /// Whether background shows between the rims; `None` when the rims are
    /// not darker than the background (nothing to tell them apart by).
    pub background_between: Option<bool>,
    /// G² near the contact on each disk over the packing's floor (its lower
    /// quartile of disk-interior G²); [a, b], b = 0 for walls.
    pub g2: [f64; 2],
    pub confidence: f64,
    /// G² is at least [`ContactOptions::force_g2`] on both sides (on the disk
    /// for a wall): the contact carries force by PeGS's rule.
    pub force_bearing: bool,
}

/// A candidate contact and whether it is doubtful (below the confidence to be
/// written as a contact, but not negligible).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageContact {
    pub contact: PixelContact,
    pub evidence: ContactEvidence,
    pub doubtful: bool,
}

fn sample(image: &FloatImage, x: f64, y: f64) -> Option<f64> {
    super::detect::Plane::whole(image).sample(x, y)
}

/// Measures each disk's rim from its mean radial profile over the rays that do
/// not run into a neighbour: the darkest point just outside the fitted circle,
/// then the half-way rise to the background. `None` where no darker rim shows
/// (the background is as dark as the rim, or the disk has no free side).
pub(crate) fn measure_rims(image: &FloatImage, disks: &[Disk]) -> Vec<Option<Rim>> {
    use rayon::prelude::*;
    disks
        .par_iter()
        .enumerate()
        .map(|(k, d)| {
            let reach = (0.25 * d.r).clamp(4.0, 20.0);
            let (lo, step) = (d.r - 3.0, 0.25);
            let n = ((reach + 3.0) / step) as usize + 1;
            let rays = ((std::f64::consts::TAU * d.r / 2.0) as usize).clamp(32, 720);
            let mut sum = vec![0.0; n];
            let mut used = 0usize;
            let neighbours: Vec<&Disk> = disks
                .iter()
                .enumerate()
                .filter(|(j, e)| {
                    *j != k && (e.x - d.x).hypot(e.y - d.y) < d.r + 1.25 * e.r + reach + 4.0
                })
                .map(|(_, e)| e)
                .collect();
            let mut profile = vec![0.0; n];
            'ray: for t in 0..rays {
                let a = std::f64::consts::TAU * t as f64 / rays as f64;
                let (ca, sa) = (a.cos(), a.sin());
                for (m, p) in profile.iter_mut().enumerate() {
                    let rho = lo + step * m as f64;
                    let (x, y) = (d.x + rho * ca, d.y + rho * sa);
                    if rho > d.r
                        && neighbours
                            .iter()
                            .any(|e| (x - e.x).hypot(y - e.y) < e.r + (0.25 * e.r).max(4.0))
                    {
                        continue 'ray;
                    }
                    match sample(image, x, y) {
                        Some(v) => *p = v,
                        None => continue 'ray,
                    }
                }
                used += 1;
                for (s, p) in sum.iter_mut().zip(&profile) {
                    *s += p;
                }
            }
            if used < 8 {
                return None;
            }
            let mean: Vec<f64> = sum.iter().map(|s| s / used as f64).collect();
            let first_out = (3.0 / step) as usize; // ρ = r
                                                   // The darkest point within the rim's reach, then the background level
                                                   // beyond it: the mean of the profile's last 2 px.
            let search_end = n - (2.0 / step) as usize;
            let (dark_at, &dark) = mean[first_out.saturating_sub(4)..search_end]
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))?;
            let dark_at = dark_at + first_out.saturating_sub(4);
            let tail = &mean[search_end..];
            let background = tail.iter().sum::<f64>() / tail.len() as f64;
            // A rim must be clearly darker than the background (five grey
            // levels of an 8-bit image; the mean over the rays is smooth).
            if background - dark < 0.02 {
                return None;
            }
            let half = 0.5 * (dark + background);
            let rise = (dark_at..n - 1).find(|&m| mean[m + 1] >= half)?;
            let f = (half - mean[rise]) / (mean[rise + 1] - mean[rise]).max(1e-12);
            let outer = lo + step * (rise as f64 + f.clamp(0.0, 1.0));
            Some(Rim {
                width: (outer - d.r).max(0.0),
                level: dark,
                background,
            })
        })
        .collect()
}

/// Mean G² (squared central-difference gradient) over the pixels of disk `d`'s
/// interior (inside `inner` px of the centre) within `radius` of `at`.
fn mean_g2(image: &FloatImage, d: &Disk, inner: f64, at: [f64; 2], radius: f64) -> f64 {
    let (w, h) = (image.width() as i64, image.height() as i64);
    let (mut sum, mut count) = (0.0, 0usize);
    let y0 = ((at[1] - radius).floor() as i64).max(1);
    let y1 = ((at[1] + radius).ceil() as i64).min(h - 2);
    let x0 = ((at[0] - radius).floor() as i64).max(1);
    let x1 = ((at[0] + radius).ceil() as i64).min(w - 2);
    for i in y0..=y1 {
        for j in x0..=x1 {
            let (x, y) = (j as f64, i as f64);
            if (x - at[0]).hypot(y - at[1]) > radius || (x - d.x).hypot(y - d.y) > inner {
                continue;
            }
            let v = |dx: i64, dy: i64| image.get_pixel((j + dx) as u32, (i + dy) as u32)[0] as f64;
            let gx = 0.5 * (v(1, 0) - v(-1, 0));
            let gy = 0.5 * (v(0, 1) - v(0, -1));
            sum += gx * gx + gy * gy;
            count += 1;
        }
    }
    if count == 0 {
        0.0
    } else {
        sum / count as f64
    }
}

/// The gap between touching disks' outlines: the lower quartile, over the
/// disks with a neighbour within `search_per_radius` of the smaller radius,
/// of the gap to the nearest one (0 when outlines overlap). Where a dark rim
/// is as dark as the background (a dark field) the outline found is the
/// bright interior's, and touching disks' outlines stop short of each other
/// by two rims; most disks of a packing touch their nearest neighbour, and
/// the lower quartile leaves out those that do not.
pub fn touching_gap(disks: &[Disk], search_per_radius: f64) -> f64 {
    let mut gaps: Vec<f64> = disks
        .iter()
        .enumerate()
        .filter_map(|(i, a)| {
            disks
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, b)| ((a.x - b.x).hypot(a.y - b.y) - a.r - b.r, a.r.min(b.r)))
                .filter(|&(gap, small)| gap <= search_per_radius * small)
                .map(|(gap, _)| gap)
                .min_by(f64::total_cmp)
        })
        .collect();
    if gaps.is_empty() {
        return 0.0;
    }
    let k = gaps.len() / 4;
    gaps.select_nth_unstable_by(k, f64::total_cmp).1.max(0.0)
}

/// The outer circles: each detected circle grown by its rim (measured, or the
/// median of the measured ones where its own does not show).
pub fn outer_disks(disks: &[Disk], rims: &[Option<Rim>]) -> Vec<Disk> {
    let mut widths: Vec<f64> = rims.iter().flatten().map(|r| r.width).collect();
    widths.sort_by(f64::total_cmp);
    let typical = widths.get(widths.len() / 2).copied().unwrap_or(0.0);
    disks
        .iter()
        .zip(rims)
        .map(|(d, rim)| Disk {
            r: d.r + rim.map_or(typical, |r| r.width),
            ..*d
        })
        .collect()
}

/// Contacts between the outer circles `outer` (see [`outer_disks`]) and with
/// walls, judged by the image: geometry within a tolerance that scales with
/// the radius, background between the rims, and G² on both sides. Every
/// candidate with at least `doubtful` confidence is returned; sorted as
/// [`find_contacts`].
pub fn find_image_contacts(
    image: &FloatImage,
    outer: &[Disk],
    rims: &[Option<Rim>],
    walls: &[WallLine],
    options: &ContactOptions,
) -> Vec<ImageContact> {
    let o = options;
    // The packing's G² floor: lower quartile of the disks' interior means.
    let interior = |d: &Disk, k: usize| {
        let width = rims[k].map_or(0.0, |r| r.width).max(o.edge_margin * d.r);
        (d.r - width - 1.5).max(1.0)
    };
    let mut floors: Vec<f64> = outer
        .iter()
        .enumerate()
        .map(|(k, d)| mean_g2(image, d, interior(d, k), [d.x, d.y], d.r))
        .collect();
    floors.sort_by(f64::total_cmp);
    let floor = floors
        .get(floors.len() / 4)
        .copied()
        .unwrap_or(0.0)
        .max(1e-9);
    let g2_near = |k: usize, n: [f64; 2]| {
        let d = &outer[k];
        let inner = interior(d, k);
        let reach = 0.25 * d.r;
        let at = [d.x + (inner - reach) * n[0], d.y + (inner - reach) * n[1]];
        mean_g2(image, d, inner, at, reach) / floor
    };
    let mut widths: Vec<f64> = rims.iter().flatten().map(|r| r.width).collect();
    widths.sort_by(f64::total_cmp);
    let typical = widths.get(widths.len() / 2).copied().unwrap_or(0.0);
    // Strong G²: four times the floor on a side counts as fully loaded.
    let loaded = |g: f64| ((g - 1.0) / 3.0).clamp(0.0, 1.0);
    let mut out = Vec::new();
    let mut order: Vec<usize> = (0..outer.len()).collect();
    order.sort_by(|&i, &j| (outer[i].x - outer[i].r).total_cmp(&(outer[j].x - outer[j].r)));
    let largest = outer.iter().map(|d| d.r).fold(0.0, f64::max);
    for (k, &i) in order.iter().enumerate() {
        for &j in &order[k + 1..] {
            if outer[j].x - outer[j].r > outer[i].x + outer[i].r + o.search_per_radius * largest {
                break;
            }
            let (a, b) = (i.min(j), i.max(j));
            let (da, db) = (&outer[a], &outer[b]);
            let d = [db.x - da.x, db.y - da.y];
            let dist = d[0].hypot(d[1]);
            let small = da.r.min(db.r);
            let gap = dist - da.r - db.r;
            if dist <= 0.0 || gap > o.search_per_radius * small {
                continue;
            }
            let n = [d[0] / dist, d[1] / dist];
            let tolerance = o.base_px + o.per_radius * small;
            let background_between = match (rims[a], rims[b]) {
                (None, None) => None,
                (ra, rb) => {
                    let known: Vec<Rim> = [ra, rb].into_iter().flatten().collect();
                    let level = known.iter().map(|r| r.level).sum::<f64>() / known.len() as f64;
                    let bg = known.iter().map(|r| r.background).sum::<f64>() / known.len() as f64;
                    // Along the line of centres from inside one rim to inside
                    // the other: an open gap shows as a bump of background
                    // between the two rims' dark minima; touching rims make
                    // one dark band.
                    let width = |r: Option<Rim>| r.map_or(typical, |r| r.width);
                    let from = da.r - width(ra) - 1.0;
                    let to = dist - db.r + width(rb) + 1.0;
                    bump_between(image, [da.x, da.y], n, from, to)
                        .map(|(peak, dark)| peak > dark + 0.5 * (bg - dark.min(level)))
                }
            };
            let g2 = [g2_near(a, n), g2_near(b, [-n[0], -n[1]])];
            let evidence = loaded(g2[0].min(g2[1]));
            // Where the outer edges overlap, light between them is leakage
            // (blur, compression) from the bright interiors, not a gap.
            let open = background_between == Some(true) && gap > 0.0;
            let confidence = if open {
                // Strong G² on both sides keeps it as a doubtful contact
                // (flagged for a look), never a confident one.
                0.35 * evidence
            } else if gap <= tolerance {
                // Edges meet and nothing shows between them; G² adds certainty.
                let base = if background_between.is_some() {
                    0.7
                } else {
                    0.55
                };
                base + (1.0 - base) * evidence
            } else {
                // Farther than the geometry allows: only strong G² on both
                // sides makes it a contact, fading with the distance.
                let beyond = (gap - tolerance) / (o.search_per_radius * small - tolerance);
                evidence * (1.0 - 0.6 * beyond.clamp(0.0, 1.0)) * 0.8
            };
            if confidence < o.doubtful {
                continue;
            }
            let reach = da.r + 0.5 * gap;
            out.push(ImageContact {
                contact: PixelContact {
                    a,
                    b: ContactBody::Disk(b),
                    point: [da.x + reach * n[0], da.y + reach * n[1]],
                    normal: n,
                    gap,
                },
                evidence: ContactEvidence {
                    outer_gap: gap,
                    tolerance,
                    background_between,
                    g2,
                    confidence,
                    force_bearing: g2[0].min(g2[1]) >= o.force_g2,
                },
                doubtful: confidence < o.confident,
            });
        }
    }
    for (w, wall) in walls.iter().enumerate() {
        let (n, offset) = wall.normal_form();
        for (a, disk) in outer.iter().enumerate() {
            let signed = offset - (n[0] * disk.x + n[1] * disk.y);
            let gap = signed.abs() - disk.r;
            let tolerance = o.base_px + o.per_radius * disk.r;
            if gap > o.search_per_radius * disk.r {
                continue;
            }
            let s = if signed >= 0.0 { 1.0 } else { -1.0 };
            let normal = [s * n[0], s * n[1]];
            let g = g2_near(a, normal);
            let evidence = loaded(g);
            let confidence = if gap <= tolerance {
                0.55 + 0.45 * evidence
            } else {
                let beyond = (gap - tolerance) / (o.search_per_radius * disk.r - tolerance);
                evidence * (1.0 - 0.6 * beyond.clamp(0.0, 1.0)) * 0.8
            };
            if confidence < o.doubtful {
                continue;
            }
            out.push(ImageContact {
                contact: PixelContact {
                    a,
                    b: ContactBody::Wall(w),
                    point: [disk.x + signed * n[0], disk.y + signed * n[1]],
                    normal,
                    gap,
                },
                evidence: ContactEvidence {
                    outer_gap: gap,
                    tolerance,
                    background_between: None,
                    g2: [g, 0.0],
                    confidence,
                    force_bearing: g >= o.force_g2,
                },
                doubtful: confidence < o.confident,
            });
        }
    }
    out.sort_by_key(|c| {
        (
            c.contact.a,
            match c.contact.b {
                ContactBody::Disk(b) => (0, b),
                ContactBody::Wall(w) => (1, w),
            },
        )
    });
    out
}

/// The profile along `n` from `c` between distances `from` and `to` (each
/// point the mean of three samples across the line, ±1 px, then of 1.25 px
/// along it, so noise does not open a gap): the darkest point of each half, and the brightest
/// point between those two. Returns (brightest, mean of the two darkest);
/// `None` when the span is too short to hold two rims.
fn bump_between(
    image: &FloatImage,
    c: [f64; 2],
    n: [f64; 2],
    from: f64,
    to: f64,
) -> Option<(f64, f64)> {
    let t = [-n[1], n[0]];
    let step = 0.25;
    let count = ((to - from) / step).floor() as usize + 1;
    if count < 8 {
        return None;
    }
    let profile: Vec<f64> = (0..count)
        .map(|k| {
            let rho = from + step * k as f64;
            let p = [c[0] + rho * n[0], c[1] + rho * n[1]];
            let values: Vec<f64> = [-1.0, 0.0, 1.0]
                .iter()
                .filter_map(|&s| sample(image, p[0] + s * t[0], p[1] + s * t[1]))
                .collect();
            if values.is_empty() {
                f64::NAN
            } else {
                values.iter().sum::<f64>() / values.len() as f64
            }
        })
        .collect();
    if profile.iter().any(|v| v.is_nan()) {
        return None;
    }
    // A 1.25 px running mean along the line: noise must not make a bump.
    let profile: Vec<f64> = (0..count)
        .map(|k| {
            let window = &profile[k.saturating_sub(2)..(k + 3).min(count)];
            window.iter().sum::<f64>() / window.len() as f64
        })
        .collect();
    let darkest = |range: std::ops::Range<usize>| {
        range
            .map(|k| (k, profile[k]))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("non-empty half")
    };
    let (first, second) = (darkest(0..count / 2), darkest(count / 2..count));
    let peak = profile[first.0..=second.0]
        .iter()
        .fold(f64::NEG_INFINITY, |m, &v| m.max(v));
    Some((peak, 0.5 * (first.1 + second.1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A column of disks along an unseen left wall, one of them found 9 px
    /// farther out than the rest (as jlin-narrow21's corner disk is once
    /// its circle reaches the outline): every disk of the column touches
    /// the box wall, not only the outermost.
    #[test]
    fn one_disk_farther_out_does_not_move_the_box_wall_off_the_others() {
        let disk = |x: f64, y: f64, r: f64| Disk {
            x,
            y,
            r,
            support: 1.0,
            visible: 1.0,
            contrast: 1.0,
            rms: 0.0,
        };
        // Left edges at 100, 100.5, 101.5 and 91 px.
        let disks = [
            disk(165.0, 100.0, 65.0),
            disk(166.5, 240.0, 66.0),
            disk(166.5, 380.0, 65.0),
            disk(161.0, 520.0, 70.0),
        ];
        let walls = packing_box_walls(&disks);
        let image = FloatImage::new(400, 700);
        let rims = vec![None; disks.len()];
        let found = find_image_contacts(&image, &disks, &rims, &walls, &ContactOptions::default());
        let left = walls.iter().position(|w| w.name == "left").unwrap();
        let touching: Vec<usize> = found
            .iter()
            .filter(|c| !c.doubtful && c.contact.b == ContactBody::Wall(left))
            .map(|c| c.contact.a)
            .collect();
        assert_eq!(touching, vec![0, 1, 2, 3], "{:?}", walls[left]);
    }
}
