//! VTK XML PolyData for ParaView.
//!
//! Each frame gives two ASCII `.vtp` files:
//! - `NAME.vtp`: grains as points (vertex cells) at their centroids, with point
//!   data `radius`, `volume`, `stress` (9 components, row-major xx xy xz yx …,
//!   tension positive, Pa), `grain_index` and, with forces, `net_force` (sum of
//!   the contact forces on the grain, N or N/m in 2D);
//! - `NAME_contacts.vtp`: contacts as line cells between the two centroids (a
//!   wall contact: from the centroid to the contact point), with cell data
//!   `normal` (from a towards b), `is_wall`, and with forces `force` (on a by
//!   b), `force_magnitude`, `normal_force` = −f·n (compression positive) and
//!   `tangential_force` = |f − (f·n) n|.
//!
//! A sequence is written as `NAME_<frame>.vtp` / `NAME_<frame>_contacts.vtp`
//! plus `NAME.pvd`, a collection ParaView opens as a time series (frame number
//! as time; part 0 = grains, part 1 = contacts). Every file is written to a
//! temporary file and renamed into place.

use crate::error::{Error, Result};
use crate::scene::{self, Body, Scene, Vec3};
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};

/// The two files written for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFiles {
    pub grains: PathBuf,
    pub contacts: PathBuf,
}

fn write_atomically(path: &Path, text: &str) -> Result<()> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut tmp = tempfile::NamedTempFile::new_in(dir).map_err(|e| Error::io(dir, e))?;
    tmp.write_all(text.as_bytes())
        .map_err(|e| Error::io(path, e))?;
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

fn contacts_path(grains: &Path) -> PathBuf {
    let stem = grains
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("scene");
    grains.with_file_name(format!("{stem}_contacts.vtp"))
}

fn array(
    out: &mut String,
    ty: &str,
    name: &str,
    components: usize,
    values: impl Iterator<Item = String>,
) {
    let _ = write!(
        out,
        "        <DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{components}\" format=\"ascii\">"
    );
    for (i, v) in values.enumerate() {
        out.push_str(if i == 0 { "" } else { " " });
        out.push_str(&v);
    }
    out.push_str("</DataArray>\n");
}

fn num(x: f64) -> String {
    format!("{x:e}")
}

fn header(out: &mut String) {
    out.push_str("<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <PolyData>\n");
}

fn footer(out: &mut String) {
    out.push_str("    </Piece>\n  </PolyData>\n</VTKFile>\n");
}

/// XML text of the grains file.
pub fn grains_vtp(scene: &Scene, forces: Option<&[Vec3]>) -> String {
    let n = scene.grains.len();
    let mut out = String::new();
    header(&mut out);
    let _ = writeln!(
        out,
        "    <Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">"
    );
    out.push_str("      <PointData Scalars=\"radius\" Tensors=\"stress\">\n");
    let g = &scene.grains;
    array(
        &mut out,
        "Float64",
        "radius",
        1,
        g.iter().map(|g| num(g.equivalent_radius(scene.dim))),
    );
    array(
        &mut out,
        "Float64",
        "volume",
        1,
        g.iter().map(|g| num(g.volume)),
    );
    array(
        &mut out,
        "Float64",
        "stress",
        9,
        g.iter().flat_map(|g| {
            let s = g.stress;
            // Row-major full tensor from xx, yy, zz, xy, xz, yz.
            [s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2]].map(num)
        }),
    );
    array(
        &mut out,
        "Int64",
        "grain_index",
        1,
        (0..n).map(|i| i.to_string()),
    );
    if let Some(f) = forces {
        let net = crate::import::net_forces(scene, f);
        array(
            &mut out,
            "Float64",
            "net_force",
            3,
            net.iter().flat_map(|v| v.map(num)),
        );
    }
    out.push_str("      </PointData>\n      <Points>\n");
    array(
        &mut out,
        "Float64",
        "Points",
        3,
        g.iter().flat_map(|g| g.position.map(num)),
    );
    out.push_str("      </Points>\n      <Verts>\n");
    array(
        &mut out,
        "Int64",
        "connectivity",
        1,
        (0..n).map(|i| i.to_string()),
    );
    array(
        &mut out,
        "Int64",
        "offsets",
        1,
        (1..=n).map(|i| i.to_string()),
    );
    out.push_str("      </Verts>\n");
    footer(&mut out);
    out
}

/// XML text of the contacts file.
pub fn contacts_vtp(scene: &Scene, forces: Option<&[Vec3]>) -> String {
    let mut points: Vec<Vec3> = scene.grains.iter().map(|g| g.position).collect();
    let mut connectivity = Vec::new();
    for c in &scene.contacts {
        connectivity.push(c.a);
        match c.b {
            Body::Grain(b) => connectivity.push(b),
            Body::Wall(_) => {
                points.push(c.point);
                connectivity.push(points.len() - 1);
            }
        }
    }
    let m = scene.contacts.len();
    let mut out = String::new();
    header(&mut out);
    let _ = writeln!(
        out,
        "    <Piece NumberOfPoints=\"{}\" NumberOfVerts=\"0\" NumberOfLines=\"{m}\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">",
        points.len()
    );
    let scalars = if forces.is_some() {
        "force_magnitude"
    } else {
        "is_wall"
    };
    let _ = writeln!(out, "      <CellData Scalars=\"{scalars}\">");
    let cs = &scene.contacts;
    array(
        &mut out,
        "Float64",
        "normal",
        3,
        cs.iter().flat_map(|c| c.normal.map(num)),
    );
    array(
        &mut out,
        "Int32",
        "is_wall",
        1,
        cs.iter()
            .map(|c| u8::from(matches!(c.b, Body::Wall(_))).to_string()),
    );
    if let Some(f) = forces {
        array(
            &mut out,
            "Float64",
            "force",
            3,
            f.iter().flat_map(|v| v.map(num)),
        );
        array(
            &mut out,
            "Float64",
            "force_magnitude",
            1,
            f.iter().map(|v| num(scene::norm(*v))),
        );
        array(
            &mut out,
            "Float64",
            "normal_force",
            1,
            cs.iter()
                .zip(f)
                .map(|(c, v)| num(-scene::dot(*v, c.normal))),
        );
        array(
            &mut out,
            "Float64",
            "tangential_force",
            1,
            cs.iter().zip(f).map(|(c, v)| {
                let fn_ = scene::dot(*v, c.normal);
                num(scene::norm([
                    v[0] - fn_ * c.normal[0],
                    v[1] - fn_ * c.normal[1],
                    v[2] - fn_ * c.normal[2],
                ]))
            }),
        );
    }
    out.push_str("      </CellData>\n      <Points>\n");
    array(
        &mut out,
        "Float64",
        "Points",
        3,
        points.iter().flat_map(|p| p.map(num)),
    );
    out.push_str("      </Points>\n      <Lines>\n");
    array(
        &mut out,
        "Int64",
        "connectivity",
        1,
        connectivity.iter().map(|i| i.to_string()),
    );
    array(
        &mut out,
        "Int64",
        "offsets",
        1,
        (1..=m).map(|i| (2 * i).to_string()),
    );
    out.push_str("      </Lines>\n");
    footer(&mut out);
    out
}

fn check_forces(scene: &Scene, forces: Option<&[Vec3]>) -> Result<()> {
    match forces {
        Some(f) if f.len() != scene.contacts.len() => Err(Error::Invalid(format!(
            "{} forces for {} contacts",
            f.len(),
            scene.contacts.len()
        ))),
        _ => Ok(()),
    }
}

/// Writes one frame: `path` (grains) and `<stem>_contacts.vtp` beside it.
pub fn write_frame(path: &Path, scene: &Scene, forces: Option<&[Vec3]>) -> Result<FrameFiles> {
    check_forces(scene, forces)?;
    let contacts = contacts_path(path);
    write_atomically(path, &grains_vtp(scene, forces))?;
    write_atomically(&contacts, &contacts_vtp(scene, forces))?;
    Ok(FrameFiles {
        grains: path.to_owned(),
        contacts,
    })
}

/// Writes a sequence: one pair of `.vtp` files per frame next to `pvd` and the
/// `.pvd` collection indexing them by frame number.
pub fn write_series(
    pvd: &Path,
    frames: &[Scene],
    forces: Option<&[Vec<Vec3>]>,
) -> Result<Vec<FrameFiles>> {
    if let Some(f) = forces {
        if f.len() != frames.len() {
            return Err(Error::Invalid(format!(
                "{} force sets for {} frames",
                f.len(),
                frames.len()
            )));
        }
    }
    let stem = pvd
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("scene")
        .to_owned();
    let mut files = Vec::new();
    let mut index = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"1.0\" byte_order=\"LittleEndian\">\n  <Collection>\n",
    );
    for (i, scene) in frames.iter().enumerate() {
        let number = scene.frame.unwrap_or(i as i64);
        let path = pvd.with_file_name(format!("{stem}_{number}.vtp"));
        let f = forces.map(|f| f[i].as_slice());
        let written = write_frame(&path, scene, f)?;
        for (part, file) in [&written.grains, &written.contacts].iter().enumerate() {
            let name = file
                .file_name()
                .and_then(|s| s.to_str())
                .unwrap_or_default();
            let _ = writeln!(
                index,
                "    <DataSet timestep=\"{number}\" part=\"{part}\" file=\"{}\"/>",
                xml_escape(name)
            );
        }
        files.push(written);
    }
    index.push_str("  </Collection>\n</VTKFile>\n");
    write_atomically(pvd, &index)?;
    Ok(files)
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
