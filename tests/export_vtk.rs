//! VTK export: written files are read back (a small XML reader below) and, when
//! ParaView's `pvpython` is installed, loaded by ParaView itself.

use grainforce::export::vtk::{write_frame, write_series};
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

/// The numbers of a named DataArray, and its NumberOfComponents.
fn data_array(xml: &str, name: &str) -> (usize, Vec<f64>) {
    let tag = format!("Name=\"{name}\"");
    let start = xml.find(&tag).unwrap_or_else(|| panic!("no array {name}"));
    let open_end = start + xml[start..].find('>').unwrap();
    let comps: usize = xml[start..open_end]
        .split("NumberOfComponents=\"")
        .nth(1)
        .unwrap()
        .split('"')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    let close = open_end + xml[open_end..].find("</DataArray>").unwrap();
    let values = xml[open_end + 1..close]
        .split_whitespace()
        .map(|v| v.parse().unwrap())
        .collect();
    (comps, values)
}

fn attribute(xml: &str, name: &str) -> usize {
    xml.split(&format!("{name}=\""))
        .nth(1)
        .unwrap()
        .split('"')
        .next()
        .unwrap()
        .parse()
        .unwrap()
}

#[test]
fn grains_and_contacts_read_back() {
    let run = lammps_run();
    let (frame, forces) = (&run.frames[0], &run.forces.as_ref().unwrap()[0]);
    let dir = tempfile::tempdir().unwrap();
    let files = write_frame(&dir.path().join("out.vtp"), frame, Some(forces)).unwrap();
    assert_eq!(files.contacts, dir.path().join("out_contacts.vtp"));

    let grains = std::fs::read_to_string(&files.grains).unwrap();
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

    let contacts = std::fs::read_to_string(&files.contacts).unwrap();
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
}

#[test]
fn a_sequence_gets_a_pvd_index() {
    let run = lammps_run();
    let dir = tempfile::tempdir().unwrap();
    let pvd = dir.path().join("run.pvd");
    let files = write_series(&pvd, &run.frames, run.forces.as_deref()).unwrap();
    assert_eq!(files.len(), 2);
    let index = std::fs::read_to_string(&pvd).unwrap();
    assert_eq!(index.matches("<DataSet").count(), 4);
    assert!(index.contains("timestep=\"120000\" part=\"1\" file=\"run_120000_contacts.vtp\""));
    for f in &files {
        assert!(f.grains.exists() && f.contacts.exists());
    }
    // A force set per frame is required.
    assert!(write_series(&pvd, &run.frames, Some(&run.forces.as_ref().unwrap()[..1])).is_err());
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
    let files = write_frame(&dir.path().join("out.vtp"), frame, Some(forces)).unwrap();
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
