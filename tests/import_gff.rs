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

fn with_errors() -> Options {
    Options {
        errors: Some(fixture("grains_errors.gff")),
        ..Options::default()
    }
}

#[test]
fn maps_fitallb_columns_units_and_errors() {
    let s = import(
        &fixture("grains.gff"),
        &fixture("contacts.csv"),
        &with_errors(),
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
    // Standard errors from the errors file's sig*_s (sample frame).
    let sd = g.stress_sd.unwrap();
    assert!((sd[sym::ZZ] - 1.5e6).abs() < 1e-6 && (sd[sym::XX] - 0.8e6).abs() < 1e-6);
    // Grain 4 was not fitted (errors all 0): unknown, and said so.
    assert_eq!(f.grains[3].stress_sd, None);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].starts_with("1 grain(s) have a zero standard error in 6 column(s)"),
        "{}",
        s.warnings[0]
    );
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
        ..Options::default()
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
        &with_errors(),
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
    assert!(e.contains("bad.gff, line 6, column `z`"), "{e}");

    let no_sig = gff.replace(" sig33_s ", " sigma33_s ");
    std::fs::write(&p, no_sig).unwrap();
    let e = import(&p, &fixture("contacts.csv"), &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 5, column `sig33_s`"), "{e}");

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

// ---- Strain → stress (`--stiffness`), fixtures/import/gff/strain made by
// make_strain.py from a known sample-frame stress at known orientations.

use grainforce::import::stiffness::Stiffness;

fn strain(name: &str) -> PathBuf {
    fixture("strain").join(name)
}

/// id → (stress, sd) in Pa, [`sym`] order, from NAME_expected.csv (MPa).
fn expected(name: &str) -> Vec<(String, [f64; 6], [f64; 6])> {
    let text = std::fs::read_to_string(strain(&format!("{name}_expected.csv"))).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<&str> = l.split(',').collect();
            let v: Vec<f64> = c[1..]
                .iter()
                .map(|x| x.parse::<f64>().unwrap() * 1e6)
                .collect();
            let mut s = [0.0; 6];
            let mut sd = [0.0; 6];
            s.copy_from_slice(&v[..6]);
            sd.copy_from_slice(&v[6..]);
            (c[0].to_owned(), s, sd)
        })
        .collect()
}

fn strain_options(spec: &str, errors: bool, name: &str) -> Options {
    Options {
        stiffness: Some(Stiffness::parse(spec).unwrap()),
        tomography_grains: Some(strain("tomo_grains.csv")),
        errors: errors.then(|| strain(&format!("{name}_strain_errors.gff"))),
        ..Options::default()
    }
}

/// Largest |a − b| over all grains and components, relative to the largest |b|.
fn worst(pairs: impl Iterator<Item = ([f64; 6], [f64; 6])>) -> f64 {
    let mut err: f64 = 0.0;
    let mut size: f64 = 0.0;
    for (a, b) in pairs {
        for k in 0..6 {
            err = err.max((a[k] - b[k]).abs());
            size = size.max(b[k].abs());
        }
    }
    err / size
}

fn recovers(name: &str, spec: &str) {
    let truth = expected(name);
    for file in [
        format!("{name}_strain.gff"),
        format!("{name}_strain_sample.gff"),
    ] {
        let s = import(
            &strain(&file),
            &strain("contacts.csv"),
            &strain_options(spec, false, name),
        )
        .unwrap();
        let grains = &s.frames[0].grains;
        assert_eq!(grains.len(), truth.len());
        let e = worst(grains.iter().zip(&truth).map(|(g, t)| {
            assert_eq!(g.id, t.0);
            (g.stress, t.1)
        }));
        eprintln!("{file}: strain → stress relative error {e:.2e}");
        assert!(e < 1e-9, "{file}: {e}");
        assert!(s.warnings.is_empty(), "{:?}", s.warnings);
    }
    // Crystal-frame strain errors propagate to sd_s_*; grain 3 has none.
    let s = import(
        &strain(&format!("{name}_strain.gff")),
        &strain("contacts.csv"),
        &strain_options(spec, true, name),
    )
    .unwrap();
    let grains = &s.frames[0].grains;
    assert_eq!(grains[2].stress_sd, None);
    let e = worst(
        grains
            .iter()
            .zip(&truth)
            .filter(|(g, _)| g.id != "3")
            .map(|(g, t)| (g.stress_sd.unwrap(), t.2)),
    );
    eprintln!("{name}: propagated sd relative error {e:.2e}");
    assert!(e < 1e-9, "{e}");
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(s.warnings[0].contains("1 grain(s) have a zero standard error in 6 column(s)"));
}

#[test]
fn zirconium_strains_give_the_known_stress() {
    recovers("zirconium", "zirconium");
    recovers("zirconium", "hexagonal:143.4,72.8,65.3,164.8,32.0");
}

#[test]
fn quartz_strains_give_the_known_stress() {
    recovers("quartz", "quartz");
    recovers("quartz", "trigonal:86.74,6.99,11.91,-17.91,107.2,57.94");
}

fn rotation(axis: [f64; 3], angle: f64) -> [[f64; 3]; 3] {
    let n = (axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]).sqrt();
    let [x, y, z] = axis.map(|v| v / n);
    let (s, c) = angle.sin_cos();
    let k = 1.0 - c;
    [
        [c + x * x * k, x * y * k - z * s, x * z * k + y * s],
        [y * x * k + z * s, c + y * y * k, y * z * k - x * s],
        [z * x * k - y * s, z * y * k + x * s, c + z * z * k],
    ]
}

/// A cubic crystal with C44 = (C11 − C12)/2 is isotropic: σ = λ tr ε I + 2 μ ε
/// (λ = C12, μ = C44) whatever the orientation, shear factor 2 included.
#[test]
fn isotropic_cubic_is_hookes_law() {
    let (c11, c12) = (200.0, 80.0);
    let c = Stiffness::parse(&format!("cubic:{c11},{c12},{}", 0.5 * (c11 - c12))).unwrap();
    let (lambda, mu) = (c12 * 1e9, 0.5 * (c11 - c12) * 1e9);
    let eps = [1e-3, -2e-4, 5e-4, 3e-4, -1e-4, 2e-4];
    for (axis, angle) in [
        ([1.0, 2.0, 3.0], 0.7),
        ([0.0, 0.0, 1.0], 0.0),
        ([-1.0, 0.5, 0.2], 2.5),
    ] {
        let sigma = c.stress(&rotation(axis, angle), &eps);
        let trace = eps[sym::XX] + eps[sym::YY] + eps[sym::ZZ];
        for k in 0..6 {
            let diagonal = [sym::XX, sym::YY, sym::ZZ].contains(&k);
            let hooke = 2.0 * mu * eps[k] + if diagonal { lambda * trace } else { 0.0 };
            assert!(
                (sigma[k] - hooke).abs() < 1e-12 * 1e9 * 1e-3,
                "{k}: {} vs {hooke}",
                sigma[k]
            );
        }
    }
    // Anisotropic cubic: a rotation about z by 45° changes the xx response.
    let c = Stiffness::parse("cubic:168,121,75").unwrap(); // copper-like
    let uniaxial = [1e-3, 0.0, 0.0, 0.0, 0.0, 0.0];
    let a = c.stress(&rotation([0.0, 0.0, 1.0], 0.0), &uniaxial)[sym::XX];
    let b = c.stress(
        &rotation([0.0, 0.0, 1.0], std::f64::consts::FRAC_PI_4),
        &uniaxial,
    )[sym::XX];
    assert!((a - 168e6).abs() < 1e-3 && (b - a).abs() > 1e6, "{a} {b}");
}

#[test]
fn stiffness_specs_and_files() {
    let hex = Stiffness::parse("hexagonal:143.4,72.8,65.3,164.8,32.0").unwrap();
    assert_eq!(Stiffness::parse("Zirconium").unwrap().voigt, hex.voigt);
    // Hexagonal constants are invariant about c: a 6×6 file of them, unrotated,
    // gives the same stresses as the symbolic form.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("zr.txt");
    let rows: Vec<String> = hex
        .voigt
        .iter()
        .map(|r| {
            r.iter()
                .map(|x| (x / 1e9).to_string())
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect();
    std::fs::write(&p, format!("# zirconium, GPa\n{}\n", rows.join("\n"))).unwrap();
    let file = Stiffness::parse(p.to_str().unwrap()).unwrap();
    let u = rotation([0.3, -1.0, 0.4], 1.1);
    let eps = [1e-3, -2e-4, 5e-4, 3e-4, -1e-4, 2e-4];
    let (a, b) = (file.stress(&u, &eps), hex.stress(&u, &eps));
    assert!((0..6).all(|k| (a[k] - b[k]).abs() < 1e-6), "{a:?} {b:?}");

    for (spec, msg) in [
        ("cubic:1,2", "needs 3 constants"),
        ("cubic:100,x,50", "`x` is not a number"),
        ("tetragonal:1,2,3,4,5,6", "unknown symmetry"),
        ("cubic:100,150,50", "not positive definite"),
    ] {
        let e = Stiffness::parse(spec).unwrap_err().to_string();
        assert!(e.contains(msg), "{spec}: {e}");
    }
    std::fs::write(&p, "1 2 3\n").unwrap();
    let e = Stiffness::parse(p.to_str().unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.contains("36 numbers, found 3"), "{e}");
    let mut m = rows.clone();
    m[1] = m[1].replacen("72.8", "70", 1);
    std::fs::write(&p, m.join("\n")).unwrap();
    let e = Stiffness::parse(p.to_str().unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("zr.txt, line 2") && e.contains("not symmetric"),
        "{e}"
    );
    std::fs::write(&p, "1 2 oops\n").unwrap();
    let e = Stiffness::parse(p.to_str().unwrap())
        .unwrap_err()
        .to_string();
    assert!(e.contains("zr.txt, line 1") && e.contains("`oops`"), "{e}");
}

#[test]
fn strain_only_files_need_a_stiffness() {
    let e = import(
        &strain("zirconium_strain.gff"),
        &strain("contacts.csv"),
        &Options::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("column `sig11_s`") && e.contains("--stiffness"),
        "{e}"
    );
    // --stiffness on a file without strains.
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.gff");
    std::fs::write(&p, "# grainno x y z grainvolume sig11_s sig22_s sig33_s sig23_s sig13_s sig12_s\n1 0 0 0 1 1 1 1 0 0 0\n").unwrap();
    let e = import(
        &p,
        &strain("contacts.csv"),
        &Options {
            stiffness: Some(Stiffness::parse("quartz").unwrap()),
            ..Options::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("column `eps11`"), "{e}");
}

/// sig* without sig*_s: rotated to the sample frame by U; sig*_s that is not
/// sig* rotated (another convention, e.g. `_s` = standard error) is reported;
/// all-zero rows (FitAllB's unrefined strain) too; U must be a rotation.
#[test]
fn crystal_frame_stress_and_doubtful_files() {
    let dir = tempfile::tempdir().unwrap();
    let c = dir.path().join("c.csv");
    std::fs::write(&c, "a,b,x,y,z,n_x,n_y,n_z\n1,2,0,0,0,1,0,0\n").unwrap();
    let p = dir.path().join("g.gff");
    let head = "# grainno x y z grainvolume U11 U12 U13 U21 U22 U23 U31 U32 U33 sig11 sig22 sig33 sig23 sig13 sig12";
    // U: 90° about z, crystal x → sample y.
    std::fs::write(&p, format!("{head}\n1 0 0 0 1 0 -1 0 1 0 0 0 0 1 10 0 0 0 0 4\n2 0 0 0 1 1 0 0 0 1 0 0 0 1 0 0 0 0 0 0\n")).unwrap();
    let s = import(&p, &c, &Options::default()).unwrap();
    let g = &s.frames[0].grains[0];
    assert!((g.stress[sym::YY] - 10e6).abs() < 1e-6 && g.stress[sym::XX].abs() < 1e-6);
    assert!((g.stress[sym::XY] + 4e6).abs() < 1e-6, "{:?}", g.stress);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(s.warnings[0].starts_with("1 grain(s)") && s.warnings[0].contains("equal to 0"));

    let both = format!("{head} sig11_s sig22_s sig33_s sig23_s sig13_s sig12_s");
    std::fs::write(&p, format!("{both}\n1 0 0 0 1 0 -1 0 1 0 0 0 0 1 10 0 0 0 0 4 0 10 0 0 0 -4\n2 0 0 0 1 1 0 0 0 1 0 0 0 1 -5 -6 -7 1 1 1 0.5 0.6 0.7 0.1 0.1 0.1\n")).unwrap();
    let s = import(&p, &c, &Options::default()).unwrap();
    assert!((s.frames[0].grains[0].stress[sym::YY] - 10e6).abs() < 1e-6);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].contains("1 grain(s)") && s.warnings[0].contains("first on line 3"),
        "{}",
        s.warnings[0]
    );

    std::fs::write(
        &p,
        format!("{head}\n1 0 0 0 1 1 0 0 0 2 0 0 0 1 10 0 0 0 0 4\n"),
    )
    .unwrap();
    let e = import(&p, &c, &Options::default()).unwrap_err().to_string();
    assert!(
        e.contains("g.gff, line 2, column `U11`") && e.contains("not a rotation"),
        "{e}"
    );
    let no_u =
        "# grainno x y z grainvolume sig11 sig22 sig33 sig23 sig13 sig12\n1 0 0 0 1 1 1 1 0 0 0\n";
    std::fs::write(&p, no_u).unwrap();
    let e = import(&p, &c, &Options::default()).unwrap_err().to_string();
    assert!(
        e.contains("column `U11` is missing") && e.contains("crystal frame"),
        "{e}"
    );
}
