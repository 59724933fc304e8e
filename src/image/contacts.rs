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

/// The wall lines implied by a scene's wall contacts (e.g. a DEM's): for each
/// wall, the line through its mean contact point, perpendicular to its mean
/// normal, in the pixels of `frame`. Walls without contacts are skipped.
pub fn walls_from_scene_contacts(
    scene: &crate::scene::Scene,
    frame: &super::PixelFrame,
) -> Vec<WallLine> {
    use crate::scene::Body;
    let mut out = Vec::new();
    for (w, wall) in scene.walls.iter().enumerate() {
        let (mut point, mut normal, mut n) = ([0.0; 2], [0.0; 2], 0usize);
        for c in scene.contacts.iter().filter(|c| c.b == Body::Wall(w)) {
            for k in 0..2 {
                point[k] += c.point[k];
                normal[k] += c.normal[k];
            }
            n += 1;
        }
        if n == 0 {
            continue;
        }
        let point = [point[0] / n as f64, point[1] / n as f64];
        let length = normal[0].hypot(normal[1]);
        if length == 0.0 {
            continue;
        }
        let tangent = [-normal[1] / length, normal[0] / length];
        let p0 = [point[0] - tangent[0], point[1] - tangent[1]];
        let p1 = [point[0] + tangent[0], point[1] + tangent[1]];
        if let Ok(line) = WallLine::from_scene(wall.name.clone(), p0, p1, frame) {
            out.push(line);
        }
    }
    out
}
