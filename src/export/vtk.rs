//! VTK XML PolyData for ParaView.
//!
//! Each frame gives two `.vtp` files, their arrays appended as raw binary
//! (little-endian, UInt64 size headers: compact and bit-exact) by default or
//! as ASCII text on request ([`Encoding`]):
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
use std::path::{Path, PathBuf};

/// The two files written for one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameFiles {
    pub grains: PathBuf,
    pub contacts: PathBuf,
}

fn write_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(dir) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    crate::scene::write_file_atomically(path, bytes)
}

fn contacts_path(grains: &Path) -> PathBuf {
    let stem = grains
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("scene");
    grains.with_file_name(format!("{stem}_contacts.vtp"))
}

/// How the data arrays are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Encoding {
    /// Raw little-endian bytes appended after the XML (VTK's "appended raw").
    #[default]
    Binary,
    /// Numbers as text inside each `<DataArray>`.
    Ascii,
}

enum Values {
    F64(Vec<f64>),
    I64(Vec<i64>),
    I32(Vec<i32>),
}

impl Values {
    fn type_name(&self) -> &'static str {
        match self {
            Values::F64(_) => "Float64",
            Values::I64(_) => "Int64",
            Values::I32(_) => "Int32",
        }
    }

    fn text(&self) -> String {
        fn join<T: std::fmt::Display>(v: &[T], f: impl Fn(&T) -> String) -> String {
            v.iter().map(f).collect::<Vec<_>>().join(" ")
        }
        match self {
            // `{:e}` prints the shortest digits that read back to the same f64.
            Values::F64(v) => join(v, |x| format!("{x:e}")),
            Values::I64(v) => join(v, |x| x.to_string()),
            Values::I32(v) => join(v, |x| x.to_string()),
        }
    }

    fn bytes(&self) -> Vec<u8> {
        match self {
            Values::F64(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Values::I64(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Values::I32(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
        }
    }
}

/// One `.vtp` file being built: the XML, and the appended block in binary.
struct Document {
    xml: String,
    appended: Vec<u8>,
    encoding: Encoding,
}

impl Document {
    fn new(encoding: Encoding) -> Self {
        Document {
            xml: "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n  <PolyData>\n".to_owned(),
            appended: Vec::new(),
            encoding,
        }
    }

    fn array(&mut self, name: &str, components: usize, values: Values) {
        let ty = values.type_name();
        let open = format!(
            "        <DataArray type=\"{ty}\" Name=\"{name}\" NumberOfComponents=\"{components}\""
        );
        match self.encoding {
            Encoding::Ascii => {
                let _ = writeln!(
                    self.xml,
                    "{open} format=\"ascii\">{}</DataArray>",
                    values.text()
                );
            }
            Encoding::Binary => {
                let offset = self.appended.len();
                let _ = writeln!(self.xml, "{open} format=\"appended\" offset=\"{offset}\"/>");
                let bytes = values.bytes();
                self.appended.extend((bytes.len() as u64).to_le_bytes());
                self.appended.extend(bytes);
            }
        }
    }

    fn finish(mut self) -> Vec<u8> {
        self.xml.push_str("    </Piece>\n  </PolyData>\n");
        let mut out = match self.encoding {
            Encoding::Ascii => self.xml.into_bytes(),
            Encoding::Binary => {
                self.xml.push_str("  <AppendedData encoding=\"raw\">\n   _");
                let mut out = self.xml.into_bytes();
                out.extend(self.appended);
                out.extend(b"\n  </AppendedData>\n");
                out
            }
        };
        out.extend(b"</VTKFile>\n");
        out
    }
}

fn vector_values(v: impl Iterator<Item = Vec3>) -> Values {
    Values::F64(v.flatten().collect())
}

fn indices(v: impl Iterator<Item = usize>) -> Values {
    Values::I64(v.map(|i| i as i64).collect())
}

/// The grains file: grains as vertices at their centroids.
pub(crate) fn grains_vtp(scene: &Scene, forces: Option<&[Vec3]>, encoding: Encoding) -> Vec<u8> {
    let n = scene.grains.len();
    let g = &scene.grains;
    let mut doc = Document::new(encoding);
    let _ = writeln!(
        doc.xml,
        "    <Piece NumberOfPoints=\"{n}\" NumberOfVerts=\"{n}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">"
    );
    doc.xml
        .push_str("      <PointData Scalars=\"radius\" Tensors=\"stress\">\n");
    let radius = g.iter().map(|g| g.equivalent_radius(scene.dim)).collect();
    doc.array("radius", 1, Values::F64(radius));
    doc.array(
        "volume",
        1,
        Values::F64(g.iter().map(|g| g.volume).collect()),
    );
    // Row-major full tensor from xx, yy, zz, xy, xz, yz.
    let stress = g
        .iter()
        .flat_map(|g| {
            let s = g.stress;
            [s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2]]
        })
        .collect();
    doc.array("stress", 9, Values::F64(stress));
    doc.array("grain_index", 1, indices(0..n));
    if let Some(f) = forces {
        let net = crate::import::net_forces(scene, f);
        doc.array("net_force", 3, vector_values(net.into_iter()));
    }
    doc.xml.push_str("      </PointData>\n      <Points>\n");
    doc.array("Points", 3, vector_values(g.iter().map(|g| g.position)));
    doc.xml.push_str("      </Points>\n      <Verts>\n");
    doc.array("connectivity", 1, indices(0..n));
    doc.array("offsets", 1, indices(1..=n));
    doc.xml.push_str("      </Verts>\n");
    doc.finish()
}

/// The contacts file: contacts as lines between centroids (or to the
/// contact point on a wall).
pub(crate) fn contacts_vtp(scene: &Scene, forces: Option<&[Vec3]>, encoding: Encoding) -> Vec<u8> {
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
    let cs = &scene.contacts;
    let mut doc = Document::new(encoding);
    let _ = writeln!(
        doc.xml,
        "    <Piece NumberOfPoints=\"{}\" NumberOfVerts=\"0\" NumberOfLines=\"{m}\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">",
        points.len()
    );
    let scalars = if forces.is_some() {
        "force_magnitude"
    } else {
        "is_wall"
    };
    let _ = writeln!(doc.xml, "      <CellData Scalars=\"{scalars}\">");
    doc.array("normal", 3, vector_values(cs.iter().map(|c| c.normal)));
    let is_wall = cs
        .iter()
        .map(|c| i32::from(matches!(c.b, Body::Wall(_))))
        .collect();
    doc.array("is_wall", 1, Values::I32(is_wall));
    if let Some(f) = forces {
        doc.array("force", 3, vector_values(f.iter().copied()));
        let magnitude = f.iter().map(|v| scene::norm(*v)).collect();
        doc.array("force_magnitude", 1, Values::F64(magnitude));
        let normal = cs.iter().zip(f).map(|(c, v)| -scene::dot(*v, c.normal));
        doc.array("normal_force", 1, Values::F64(normal.collect()));
        let tangential = cs.iter().zip(f).map(|(c, v)| {
            let fn_ = scene::dot(*v, c.normal);
            scene::norm([
                v[0] - fn_ * c.normal[0],
                v[1] - fn_ * c.normal[1],
                v[2] - fn_ * c.normal[2],
            ])
        });
        doc.array("tangential_force", 1, Values::F64(tangential.collect()));
    }
    doc.xml.push_str("      </CellData>\n      <Points>\n");
    doc.array("Points", 3, vector_values(points.into_iter()));
    doc.xml.push_str("      </Points>\n      <Lines>\n");
    doc.array("connectivity", 1, indices(connectivity.into_iter()));
    doc.array("offsets", 1, indices((1..=m).map(|i| 2 * i)));
    doc.xml.push_str("      </Lines>\n");
    doc.finish()
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
pub fn write_frame(
    path: &Path,
    scene: &Scene,
    forces: Option<&[Vec3]>,
    encoding: Encoding,
) -> Result<FrameFiles> {
    check_forces(scene, forces)?;
    let contacts = contacts_path(path);
    write_atomically(path, &grains_vtp(scene, forces, encoding))?;
    write_atomically(&contacts, &contacts_vtp(scene, forces, encoding))?;
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
    encoding: Encoding,
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
        let written = write_frame(&path, scene, f, encoding)?;
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
    write_atomically(pvd, index.as_bytes())?;
    Ok(files)
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
