//! `import imaged11`: stresses from ImageD11 grain maps, against the stresses
//! ImageD11's own functions compute from the same files
//! (fixtures/import/imaged11/make_fixtures.py wrote both).

mod common;

use common::run;
use grainforce::import::imaged11::{self, Options};
use grainforce::import::stiffness::Stiffness;
use std::path::{Path, PathBuf};

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/import/imaged11")
}

/// (grain, position µm, stress MPa in Sym order xx yy zz xy xz yz) from the
/// CSV `file` that make_fixtures.py wrote.
fn expected(file: &str) -> Vec<(usize, [f64; 3], [f64; 6])> {
    let text = std::fs::read_to_string(dir().join(file)).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let v: Vec<f64> = l.split(',').map(|x| x.parse().unwrap()).collect();
            (
                v[0] as usize,
                [v[1], v[2], v[3]],
                [v[4], v[5], v[6], v[7], v[8], v[9]],
            )
        })
        .collect()
}

fn cell(name: &str) -> [f64; 6] {
    match name {
        "zirconium" => [3.232, 3.232, 5.147, 90.0, 90.0, 120.0],
        _ => [4.9134, 4.9134, 5.4052, 90.0, 90.0, 120.0],
    }
}

fn options(name: &str) -> Options {
    Options {
        cell: cell(name),
        stiffness: Stiffness::parse(name).unwrap(),
        grain_volume: Some(1e-12),
        phase: None,
    }
}

/// The largest difference [MPa] between the imported grains and ImageD11's
/// stresses in `truth`; positions must agree to the last bit of µm → m.
fn largest_difference(file: &str, truth: &str, options: &Options) -> f64 {
    let out = imaged11::import(&dir().join(file), None, options).unwrap();
    let scene = &out.frames[0];
    let truth = expected(truth);
    assert_eq!(scene.grains.len(), truth.len());
    let mut worst: f64 = 0.0;
    for (g, (i, p, s)) in scene.grains.iter().zip(&truth) {
        assert_eq!(g.id, i.to_string());
        for k in 0..3 {
            assert!((g.position[k] - p[k] * 1e-6).abs() < 1e-15);
        }
        for k in 0..6 {
            worst = worst.max((g.stress[k] / 1e6 - s[k]).abs());
        }
    }
    eprintln!("{file}: largest difference from ImageD11 {worst:.2e} MPa");
    worst
}

#[test]
fn stresses_match_imaged11_within_a_kilopascal() {
    for name in ["zirconium", "quartz"] {
        let worst = largest_difference(
            &format!("{name}.map"),
            &format!("{name}_stress.csv"),
            &options(name),
        );
        assert!(worst <= 1e-3, "{name}: {worst} MPa");
    }
}

#[test]
fn hdf5_grain_files_match_imaged11_to_1e_8_mpa() {
    for name in ["zirconium", "quartz"] {
        let h5 = format!("{name}.h5");
        let worst = largest_difference(&h5, &format!("{name}_h5_stress.csv"), &options(name));
        assert!(worst <= 1e-8, "{name}: {worst} MPa");
        // The phase named explicitly reads the same group.
        let named = Options {
            phase: Some(name.into()),
            ..options(name)
        };
        assert_eq!(
            imaged11::import(&dir().join(&h5), None, &named)
                .unwrap()
                .frames[0]
                .grains,
            imaged11::import(&dir().join(&h5), None, &options(name))
                .unwrap()
                .frames[0]
                .grains
        );
        // The map's 9-digit UBIs describe the same grains.
        let map = imaged11::read_grains(&dir().join(format!("{name}.map")), None).unwrap();
        let full = imaged11::read_grains(&dir().join(&h5), None).unwrap();
        assert_eq!(map.len(), full.len());
        for (a, b) in map.iter().zip(&full) {
            assert_eq!(a.index, b.index);
            for (ra, rb) in a.ubi.iter().zip(&b.ubi) {
                for (x, y) in ra.iter().zip(rb) {
                    assert!((x - y).abs() <= 5e-9 * y.abs().max(1.0), "{x} vs {y}");
                }
            }
        }
    }
}

#[test]
fn hdf5_after_a_user_block_is_still_hdf5() {
    // The signature at byte 512 (h5py's userblock_size=512): read as HDF5,
    // not refused as a text map that is not UTF-8.
    let plain = imaged11::read_grains(&dir().join("quartz.h5"), None).unwrap();
    let behind = imaged11::read_grains(&dir().join("quartz_userblock.h5"), None).unwrap();
    assert_eq!(plain.len(), behind.len());
    for (a, b) in plain.iter().zip(&behind) {
        assert_eq!(
            (a.index, a.ubi, a.translation),
            (b.index, b.ubi, b.translation)
        );
    }
}

#[test]
fn bad_hdf5_grain_files_are_named_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let quartz = dir().join("quartz.h5");
    let e = imaged11::read_grains(&quartz, Some("zircon"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("quartz.h5") && e.contains("no group `zircon`") && e.contains("quartz"),
        "{e}"
    );
    // --phase is for HDF5 files only.
    let e = imaged11::read_grains(&dir().join("quartz.map"), Some("quartz"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("quartz.map") && e.contains("HDF5"), "{e}");
    // A file cut short, or the signature followed by garbage: an error, no panic.
    let bytes = std::fs::read(&quartz).unwrap();
    let cut = tmp.path().join("cut.h5");
    for keep in [8, 100, 1000, bytes.len() / 2] {
        std::fs::write(&cut, &bytes[..keep]).unwrap();
        let e = imaged11::read_grains(&cut, None).unwrap_err().to_string();
        assert!(e.contains("cut.h5"), "{keep} bytes: {e}");
    }
    // The CLI: a missing phase fails without output.
    let out = tmp.path().join("scene");
    let (ok, err) = run(&[
        "import",
        "imaged11",
        quartz.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--cell",
        "4.9134,4.9134,5.4052,90,90,120",
        "--stiffness",
        "quartz",
        "--grain-volume",
        "1e-12",
        "--phase",
        "zircon",
    ]);
    assert!(!ok && err.contains("no group `zircon`"), "{err}");
    assert!(!out.exists());
}

#[test]
fn each_convention_matters() {
    // The Busing–Levy U in place of the polar rotation, or Green–Lagrange in
    // place of Biot, or constants left in the IEEE axes, move the stresses by
    // more than the 1e-3 MPa tolerance: the test above can tell them apart.
    let name = "quartz";
    let grains = imaged11::read_map(&dir().join("quartz.map")).unwrap();
    let b0 = imaged11::b_matrix(cell(name)).unwrap();
    let truth = expected(&format!("{name}_stress.csv"));
    let rotated = Stiffness::parse("quartz").unwrap();
    let mut ieee = rotated.clone();
    ieee.constants_to_crystal = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let (mut d_ieee, mut d_u, mut d_gl): (f64, f64, f64) = (0.0, 0.0, 0.0);
    for (g, (_, _, s)) in grains.iter().zip(&truth) {
        let st = imaged11::grain_strain(&g.ubi, &b0).unwrap();
        let a = ieee.stress(&st.rotation, &st.strain_sample);
        // Busing–Levy U = (B0 UBI)ᵀ.
        let mut u = [[0.0; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                u[j][i] = (0..3).map(|k| b0[i][k] * g.ubi[k][j]).sum();
            }
        }
        let b = rotated.stress(&u, &st.strain_sample);
        // Green–Lagrange: ½(V² − I) = e + e²/2 with e = V − I.
        let e = st.strain_sample;
        let t = [[e[0], e[3], e[4]], [e[3], e[1], e[5]], [e[4], e[5], e[2]]];
        let mut gl = e;
        for (k, &(i, j)) in [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)]
            .iter()
            .enumerate()
        {
            gl[k] += 0.5 * (0..3).map(|m| t[i][m] * t[m][j]).sum::<f64>();
        }
        let c = rotated.stress(&st.rotation, &gl);
        for k in 0..6 {
            d_ieee = d_ieee.max((a[k] / 1e6 - s[k]).abs());
            d_u = d_u.max((b[k] / 1e6 - s[k]).abs());
            d_gl = d_gl.max((c[k] / 1e6 - s[k]).abs());
        }
    }
    eprintln!(
        "IEEE axes {d_ieee:.3} MPa, Busing–Levy U {d_u:.3} MPa, Green–Lagrange {d_gl:.3} MPa"
    );
    assert!(
        d_ieee > 1.0 && d_u > 1e-2 && d_gl > 1e-2,
        "{d_ieee} {d_u} {d_gl}"
    );
}

#[test]
fn cli_writes_grains_and_reads_contacts() {
    let tmp = tempfile::tempdir().unwrap();
    let contacts = tmp.path().join("contacts.csv");
    std::fs::write(
        &contacts,
        "a,b,x,y,z,n_x,n_y,n_z\n0,1,0,0,0,1,0,0\n2,top,0,0,0,0,0,1\n",
    )
    .unwrap();
    let out = tmp.path().join("scene");
    let map = dir().join("zirconium.map");
    let (ok, err) = run(&[
        "import",
        "imaged11",
        map.to_str().unwrap(),
        contacts.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--cell",
        "3.232,3.232,5.147,90,90,120",
        "--stiffness",
        "zirconium",
        "--grain-volume",
        "1e-12",
    ]);
    assert!(ok, "{err}");
    let scene = grainforce::scene::read_scene(&out).unwrap();
    assert_eq!((scene.grains.len(), scene.contacts.len()), (12, 2));
    // Without --grain-volume: a clear error, nothing written.
    let out2 = tmp.path().join("scene2");
    let (ok, err) = run(&[
        "import",
        "imaged11",
        map.to_str().unwrap(),
        "-o",
        out2.to_str().unwrap(),
        "--cell",
        "3.232,3.232,5.147,90,90,120",
        "--stiffness",
        "zirconium",
    ]);
    assert!(!ok && err.contains("--grain-volume"), "{err}");
    assert!(!out2.exists());
    // A broken UBI row names the file and line.
    let bad = tmp.path().join("bad.map");
    std::fs::write(&bad, "#translation: 1 2 3\n#UBI:\n1 0 0\n0 1 x\n0 0 1\n").unwrap();
    let e = imaged11::read_map(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.map") && e.contains("line 4"), "{e}");
    // Rows are exactly three finite numbers; a translation too.
    for (text, line) in [
        ("#UBI:\n1 0 0\n0 1 0 7\n0 0 1\n", "line 3"),
        ("#UBI:\n1 0 0\n0 1 0\n0 0 inf\n", "line 4"),
        ("#translation: 1 2\n#UBI:\n1 0 0\n0 1 0\n0 0 1\n", "line 1"),
    ] {
        std::fs::write(&bad, text).unwrap();
        let e = imaged11::read_map(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.map") && e.contains(line), "{text:?}: {e}");
    }
}
