//! VTK export: written files are read back (a small XML reader below) and, when
//! ParaView's `pvpython` is installed, loaded by ParaView itself.

use grainforce::export::vtk::{write_frame, write_series, Encoding};
use grainforce::import::{lammps, net_forces, ImportedScene};
use grainforce::scene::{self, Body};
use std::path::Path;

fn lammps_run() -> ImportedScene {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/import/lammps");
    lammps::import(
        &dir.join("atoms.dump"),
        &dir.join("pairs.dump"),
        &lammps::Options::default(),
    )
    .unwrap()
}

/// The XML part of a `.vtp` file and, for appended raw data, the bytes after
/// the `_` marker.
fn split(file: &[u8]) -> (String, &[u8]) {
    let marker = b"<AppendedData encoding=\"raw\">";
    match file.windows(marker.len()).position(|w| w == marker) {
        Some(at) => {
            let underscore = at + file[at..].iter().position(|&b| b == b'_').unwrap();
            let tail = b"\n  </AppendedData>\n</VTKFile>\n";
            assert!(file.ends_with(tail), "appended block not closed");
            (
                String::from_utf8(file[..at].to_vec()).unwrap(),
                &file[underscore + 1..file.len() - tail.len()],
            )
        }
        None => (String::from_utf8(file.to_vec()).unwrap(), &[]),
    }
}

fn field<'a>(tag: &'a str, name: &str) -> Option<&'a str> {
    tag.split(&format!(" {name}=\"")).nth(1)?.split('"').next()
}

/// The numbers of a named DataArray, and its NumberOfComponents, read as a
/// VTK reader does: ASCII text, or a UInt64 byte count and little-endian
/// values at `offset` in the appended block.
fn data_array(file: &[u8], name: &str) -> (usize, Vec<f64>) {
    let (xml, appended) = split(file);
    let start = xml
        .find(&format!("Name=\"{name}\""))
        .unwrap_or_else(|| panic!("no array {name}"));
    let start = xml[..start].rfind('<').unwrap();
    let open_end = start + xml[start..].find('>').unwrap();
    let tag = &xml[start..open_end];
    let comps: usize = field(tag, "NumberOfComponents").unwrap().parse().unwrap();
    let values = match field(tag, "format").unwrap() {
        "ascii" => {
            let close = open_end + xml[open_end..].find("</DataArray>").unwrap();
            xml[open_end + 1..close]
                .split_whitespace()
                .map(|v| v.parse().unwrap())
                .collect()
        }
        "appended" => {
            assert!(tag.ends_with('/'), "an appended array has no body");
            let offset: usize = field(tag, "offset").unwrap().parse().unwrap();
            let len = u64::from_le_bytes(appended[offset..offset + 8].try_into().unwrap()) as usize;
            let bytes = &appended[offset + 8..offset + 8 + len];
            match field(tag, "type").unwrap() {
                "Float64" => bytes
                    .chunks_exact(8)
                    .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
                    .collect(),
                "Int64" => bytes
                    .chunks_exact(8)
                    .map(|b| i64::from_le_bytes(b.try_into().unwrap()) as f64)
                    .collect(),
                "Int32" => bytes
                    .chunks_exact(4)
                    .map(|b| i32::from_le_bytes(b.try_into().unwrap()) as f64)
                    .collect(),
                other => panic!("unexpected type {other}"),
            }
        }
        other => panic!("unexpected format {other}"),
    };
    (comps, values)
}

fn attribute(file: &[u8], name: &str) -> usize {
    field(&split(file).0, name).unwrap().parse().unwrap()
}

#[test]
fn grains_and_contacts_read_back_binary_and_ascii() {
    let mut sizes = Vec::new();
    for encoding in [Encoding::Binary, Encoding::Ascii] {
        sizes.push(read_back(encoding));
    }
    // Binary is the compact default.
    assert!(
        sizes[0] < sizes[1],
        "binary {} B, ascii {} B",
        sizes[0],
        sizes[1]
    );
}

/// Writes the LAMMPS frame, checks every array, returns the contacts file's size.
fn read_back(encoding: Encoding) -> usize {
    let run = lammps_run();
    let (frame, forces) = (&run.frames[0], &run.forces.as_ref().unwrap()[0]);
    let dir = tempfile::tempdir().unwrap();
    let files = write_frame(&dir.path().join("out.vtp"), frame, Some(forces), encoding).unwrap();
    assert_eq!(files.contacts, dir.path().join("out_contacts.vtp"));

    let grains = std::fs::read(&files.grains).unwrap();
    assert_eq!(attribute(&grains, "NumberOfPoints"), 40);
    let (c, radius) = data_array(&grains, "radius");
    assert_eq!((c, radius.len()), (1, 40));
    assert_eq!(radius[0], frame.grains[0].radius.unwrap());
    let (c, stress) = data_array(&grains, "stress");
    assert_eq!((c, stress.len()), (9, 360));
    let s = frame.grains[5].stress;
    assert_eq!(
        &stress[45..54],
        &[s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2]]
    );
    let (_, net) = data_array(&grains, "net_force");
    let expected = net_forces(frame, forces);
    for (g, e) in expected.iter().enumerate() {
        for k in 0..3 {
            assert!((net[3 * g + k] - e[k]).abs() <= 1e-15 * e[k].abs().max(1e-300) + 1e-300);
        }
    }

    let contacts = std::fs::read(&files.contacts).unwrap();
    let walls = frame
        .contacts
        .iter()
        .filter(|c| matches!(c.b, Body::Wall(_)))
        .count();
    assert!(walls > 0);
    assert_eq!(attribute(&contacts, "NumberOfLines"), frame.contacts.len());
    assert_eq!(attribute(&contacts, "NumberOfPoints"), 40 + walls);
    let (_, conn) = data_array(&contacts, "connectivity");
    let (_, f) = data_array(&contacts, "force");
    let (_, fnorm) = data_array(&contacts, "normal_force");
    let (_, ftan) = data_array(&contacts, "tangential_force");
    let (_, points) = data_array(&contacts, "Points");
    for (i, c) in frame.contacts.iter().enumerate() {
        assert_eq!(conn[2 * i] as usize, c.a);
        let end = conn[2 * i + 1] as usize;
        match c.b {
            Body::Grain(b) => assert_eq!(end, b),
            Body::Wall(_) => assert_eq!(&points[3 * end..3 * end + 3], &c.point),
        }
        assert_eq!(&f[3 * i..3 * i + 3], &forces[i]);
        let n = -scene::dot(forces[i], c.normal);
        assert!((fnorm[i] - n).abs() <= 1e-12 * scene::norm(forces[i]));
        // |f|² = f_n² + f_t²
        let m = scene::norm(forces[i]);
        assert!((fnorm[i].powi(2) + ftan[i].powi(2) - m * m).abs() <= 1e-9 * m * m);
    }
    contacts.len()
}

#[test]
fn a_sequence_gets_a_pvd_index() {
    let run = lammps_run();
    let dir = tempfile::tempdir().unwrap();
    let pvd = dir.path().join("run.pvd");
    let files = write_series(&pvd, &run.frames, run.forces.as_deref(), Encoding::Binary).unwrap();
    assert_eq!(files.len(), 2);
    let index = std::fs::read_to_string(&pvd).unwrap();
    assert_eq!(index.matches("<DataSet").count(), 4);
    assert!(index.contains("timestep=\"120000\" part=\"1\" file=\"run_120000_contacts.vtp\""));
    for f in &files {
        assert!(f.grains.exists() && f.contacts.exists());
    }
    // A force set per frame is required.
    assert!(write_series(
        &pvd,
        &run.frames,
        Some(&run.forces.as_ref().unwrap()[..1]),
        Encoding::Binary
    )
    .is_err());
}

/// ParaView reads the files and finds the same counts and a force value.
#[test]
fn paraview_loads_the_files_when_installed() {
    if std::process::Command::new("pvpython")
        .arg("--version")
        .output()
        .is_err()
    {
        eprintln!("pvpython not installed: ParaView check skipped");
        return;
    }
    let run = lammps_run();
    let (frame, forces) = (&run.frames[0], &run.forces.as_ref().unwrap()[0]);
    let dir = tempfile::tempdir().unwrap();
    let files = write_frame(
        &dir.path().join("out.vtp"),
        frame,
        Some(forces),
        Encoding::Binary,
    )
    .unwrap();
    let script = format!(
        "from paraview.simple import *\n\
         from paraview import servermanager as sm\n\
         g = sm.Fetch(XMLPolyDataReader(FileName=[r'{}']))\n\
         c = sm.Fetch(XMLPolyDataReader(FileName=[r'{}']))\n\
         print(g.GetNumberOfPoints(), c.GetNumberOfCells(), repr(c.GetCellData().GetArray('force').GetTuple3(0)[1]))\n",
        files.grains.display(),
        files.contacts.display()
    );
    let out = std::process::Command::new("pvpython")
        .arg("--force-offscreen-rendering")
        .arg("-c")
        .arg(&script)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let last = text.lines().last().unwrap_or_default().to_owned();
    let v: Vec<&str> = last.split_whitespace().collect();
    assert_eq!(
        v.len(),
        3,
        "pvpython said: {text} {}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(v[0].parse::<usize>().unwrap(), 40);
    assert_eq!(v[1].parse::<usize>().unwrap(), frame.contacts.len());
    assert_eq!(v[2].parse::<f64>().unwrap(), forces[0][1]);
}
