//! The 3DXRD (.gff) + tomography contact-list importer, and the `sd_s_*`
//! standard-error columns it writes into grains.csv.

use grainforce::import::gff::{import, Options};
use grainforce::scene::{self, sym, Body};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/import/gff")
        .join(name)
}

#[test]
fn maps_fitallb_columns_units_and_errors() {
    let s = import(
        &fixture("grains.gff"),
        &fixture("contacts.csv"),
        &Options::default(),
    )
    .unwrap();
    assert!(s.forces.is_none());
    let f = &s.frames[0];
    assert_eq!(f.dim, 3);
    assert_eq!(f.grains.len(), 4);
    let g = &f.grains[0];
    assert_eq!(g.id, "1");
    // z = 0.25 mm; sig33 = −12.5 MPa → s_zz; sig23 = 0.4 → s_yz; sig12 = 0.2 → s_xy.
    assert!((g.position[2] - 0.25e-3).abs() < 1e-15);
    assert!((g.stress[sym::ZZ] + 12.5e6).abs() < 1e-6);
    assert!((g.stress[sym::YZ] - 0.4e6).abs() < 1e-6);
    assert!((g.stress[sym::XZ] + 0.3e6).abs() < 1e-6);
    assert!((g.stress[sym::XY] - 0.2e6).abs() < 1e-6);
    let sd = g.stress_sd.unwrap();
    assert!((sd[sym::ZZ] - 1.5e6).abs() < 1e-6 && (sd[sym::XX] - 0.8e6).abs() < 1e-6);
    // grainvolume 0.065450 mm³ → m³.
    assert!((g.volume - 0.065450e-9).abs() < 1e-18);
    assert_eq!(f.contacts.len(), 5);
    assert_eq!(f.contacts[3].b, Body::Wall(f.wall_index("bottom").unwrap()));
    // Compressed grains: negative normal stresses (tension positive).
    assert!(f
        .grains
        .iter()
        .all(|g| g.stress[0] < 0.0 && g.stress[2] < 0.0));
}

#[test]
fn units_and_tomography_volumes_are_options() {
    let options = Options {
        stress_unit: 1.0,
        length_unit: 1.0,
        tomography_grains: Some(fixture("tomo_grains.csv")),
    };
    let s = import(&fixture("grains.gff"), &fixture("contacts.csv"), &options).unwrap();
    let f = &s.frames[0];
    assert!((f.grains[0].stress[sym::ZZ] + 12.5).abs() < 1e-12);
    assert!((f.grains[0].position[2] - 0.25).abs() < 1e-12);
    assert_eq!(f.grains[2].volume, 7.0e-11, "tomography volume of grain 3");
    assert!((f.grains[1].volume - 0.065450).abs() < 1e-12);
}

/// The standard errors survive grains.csv: written as sd_s_* and read back into
/// Grain::stress_sd.
#[test]
fn standard_errors_round_trip_through_grains_csv() {
    let s = import(
        &fixture("grains.gff"),
        &fixture("contacts.csv"),
        &Options::default(),
    )
    .unwrap();
    let dir = tempfile::tempdir().unwrap();
    s.write(dir.path()).unwrap();
    let header = std::fs::read_to_string(dir.path().join("grains.csv")).unwrap();
    assert!(header.lines().next().unwrap().contains("sd_s_xx"));
    let back = scene::read_scene(dir.path()).unwrap();
    assert_eq!(back.grains, s.frames[0].grains);
    assert!(!dir.path().join("forces.csv").exists());
}

#[test]
fn stress_sd_columns_are_checked_when_read() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("contacts.csv"), "id,a,b,x,y,n_x,n_y\n").unwrap();
    let grains = |row: &str| {
        std::fs::write(
            dir.path().join("grains.csv"),
            format!("id,x,y,volume,s_xx,s_yy,s_xy,sd_s_xx,sd_s_yy,sd_s_xy\n{row}\n"),
        )
        .unwrap();
        scene::read_scene(dir.path())
    };
    let g = grains("1,0,0,1,-1,-2,0,0.1,0.2,0.3").unwrap();
    assert_eq!(g.grains[0].stress_sd, Some([0.1, 0.2, 0.0, 0.3, 0.0, 0.0]));
    assert_eq!(
        grains("1,0,0,1,-1,-2,0,,,").unwrap().grains[0].stress_sd,
        None
    );
    let e = grains("1,0,0,1,-1,-2,0,0.1,,0.3").unwrap_err().to_string();
    assert!(
        e.contains("line 2") && e.contains("some but not all"),
        "{e}"
    );
    let e = grains("1,0,0,1,-1,-2,0,0.1,-0.2,0.3")
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 2") && e.contains("sd_s_yy"), "{e}");
}

#[test]
fn malformed_inputs_give_located_errors() {
    let dir = tempfile::tempdir().unwrap();
    let gff = std::fs::read_to_string(fixture("grains.gff")).unwrap();
    let bad_value = gff.replacen("0.2500 0.1", "0.25x 0.1", 1);
    let p = dir.path().join("bad.gff");
    std::fs::write(&p, bad_value).unwrap();
    let e = import(&p, &fixture("contacts.csv"), &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("bad.gff, line 5, column `z`"), "{e}");

    let no_sig = gff.replace(" sig33 ", " sigma33 ");
    std::fs::write(&p, no_sig).unwrap();
    let e = import(&p, &fixture("contacts.csv"), &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 4, column `sig33`"), "{e}");

    let c = dir.path().join("c.csv");
    std::fs::write(
        &c,
        "a,b,x,y,z,n_x,n_y,n_z\n1,2,0,0,0,0,0,1\n1,9,0,0,0,0,0,1\n",
    )
    .unwrap();
    let e = import(&fixture("grains.gff"), &c, &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("c.csv, line 3, column `b`"), "{e}");
    std::fs::write(&c, "a,b,x,y,z,n_x,n_y,n_z\n1,2,0,0,0,0,0,2\n").unwrap();
    let e = import(&fixture("grains.gff"), &c, &Options::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("line 2, column `n_x`") && e.contains("unit"),
        "{e}"
    );
}
