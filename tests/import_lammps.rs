//! The LAMMPS importer on a real LAMMPS run (fixtures/import/lammps, made by
//! `lmp -in in.settle`): 40 disks settled under gravity between three walls.

use grainforce::import::lammps::{import, LocalColumns, Options};
use grainforce::import::{net_forces, ImportedScene};
use grainforce::scene::{self, Body};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/import/lammps")
        .join(name)
}

fn imported() -> ImportedScene {
    let options = Options {
        gravity: Some([0.0, -9.81, 0.0]),
        ..Options::default()
    };
    import(&fixture("atoms.dump"), &fixture("pairs.dump"), &options).unwrap()
}

#[test]
fn reads_both_snapshots_as_a_2d_sequence() {
    let s = imported();
    assert_eq!(s.frames.len(), 2);
    for f in &s.frames {
        assert_eq!(f.dim, 2);
        assert_eq!(f.grains.len(), 40);
        assert!(f.contacts.len() > 40, "{} contacts", f.contacts.len());
        let walls: Vec<&str> = f.walls.iter().map(|w| w.name.as_str()).collect();
        assert!(
            walls.contains(&"bottom") && walls.contains(&"left"),
            "{walls:?}"
        );
    }
    assert_eq!(s.frames[0].frame, Some(100000));
    assert_eq!(s.frames[1].frame, Some(120000));
    // 2D volume is π R² per unit thickness.
    let g = &s.frames[0].grains[0];
    let r = g.radius.unwrap();
    assert!((g.volume - std::f64::consts::PI * r * r).abs() < 1e-15);
}

/// The first pair of the first snapshot, read straight from the file: the force
/// on i by j is pair/local fx..fz plus p1..p3.
#[test]
fn a_force_value_matches_the_dump_line() {
    let text = std::fs::read_to_string(fixture("pairs.dump")).unwrap();
    let line = text.lines().nth(9).unwrap();
    let v: Vec<f64> = line
        .split_whitespace()
        .map(|x| x.parse().unwrap())
        .collect();
    let (i, j) = (v[1] as i64, v[2] as i64);
    let expected = [v[3] + v[6], v[4] + v[7]];
    let s = imported();
    let frame = &s.frames[0];
    let c = frame
        .contacts
        .iter()
        .position(|c| c.id == format!("{i}-{j}"))
        .unwrap();
    let f = s.forces.as_ref().unwrap()[0][c];
    assert_eq!([f[0], f[1]], expected);
    assert_eq!(frame.grains[frame.contacts[c].a].id, i.to_string());
}

/// Every grain's contact forces (pairs and walls) balance m (a − g) with a = f/m
/// from the per-atom force: this pins the sign of pair/local, the inclusion of
/// the tangential part and the wall forces.
#[test]
fn contact_forces_balance_each_grain() {
    let s = imported();
    let residual = s.momentum_residual().unwrap();
    assert!(residual < 1e-6, "relative momentum residual {residual}");
    // Without gravity the same data must not balance (the check can fail).
    let mut no_g = s.clone();
    for f in &mut no_g.frames {
        f.settings.gravity = None;
    }
    assert!(no_g.momentum_residual().unwrap() > 0.1);
}

#[test]
fn contacts_push_and_normals_point_from_a_to_b() {
    let s = imported();
    for (frame, forces) in s.frames.iter().zip(s.forces.as_ref().unwrap()) {
        let mean = forces.iter().map(|f| scene::norm(*f)).sum::<f64>() / forces.len() as f64;
        for (c, f) in frame.contacts.iter().zip(forces) {
            let towards = match c.b {
                Body::Grain(b) => scene::sub(frame.grains[b].position, frame.grains[c.a].position),
                Body::Wall(_) => scene::sub(c.point, frame.grains[c.a].position),
            };
            assert!(scene::dot(towards, c.normal) > 0.0, "contact {}", c.id);
            assert!(
                scene::dot(*f, c.normal) < 1e-6 * mean,
                "contact {} pulls",
                c.id
            );
        }
    }
}

/// Written files are self-consistent: V σ = Σ sym(r ⊗ f) from what is read
/// back, and squeezed grains have negative stress (tension positive).
#[test]
fn written_scene_is_self_consistent_and_compressive() {
    let s = imported();
    let dir = tempfile::tempdir().unwrap();
    s.write(dir.path()).unwrap();
    let frames = scene::read_sequence(dir.path()).unwrap();
    let forces = scene::read_forces(&dir.path().join("forces.csv")).unwrap();
    assert_eq!(frames.len(), 2);
    assert_eq!(frames[0].settings.gravity, Some(vec![0.0, -9.81]));
    for frame in &frames {
        let f = forces
            .for_scene(frame, &dir.path().join("forces.csv"))
            .unwrap();
        let mut sums = vec![[0.0; 6]; frame.grains.len()];
        for (c, fc) in frame.contacts.iter().zip(&f) {
            let t = scene::sym_outer(scene::sub(c.point, frame.grains[c.a].position), *fc);
            (0..6).for_each(|k| sums[c.a][k] += t[k]);
            if let Body::Grain(b) = c.b {
                let t = scene::sym_outer(scene::sub(c.point, frame.grains[b].position), *fc);
                (0..6).for_each(|k| sums[b][k] -= t[k]);
            }
        }
        let scale = frame
            .grains
            .iter()
            .map(|g| g.stress[0].abs())
            .fold(0.0, f64::max);
        for (g, s) in frame.grains.iter().zip(&sums) {
            for &k in scene::sym::components(2) {
                assert!(
                    (g.stress[k] - s[k] / g.volume).abs() <= 1e-9 * scale,
                    "grain {}",
                    g.id
                );
            }
            assert!(
                g.stress[0] + g.stress[1] < 0.0,
                "grain {} is not compressed",
                g.id
            );
        }
        let net = net_forces(frame, &f);
        assert_eq!(net.len(), 40);
    }
}

#[test]
fn explicit_columns_give_the_same_result_and_bad_names_are_located() {
    let cols = LocalColumns::parse(
        "i=c_ids[1],j=c_ids[2],fx=c_pair[1],fy=c_pair[2],fz=c_pair[3],tx=c_pair[4],ty=c_pair[5],tz=c_pair[6]",
    )
    .unwrap();
    let options = Options {
        columns: Some(cols),
        gravity: Some([0.0, -9.81, 0.0]),
        ..Options::default()
    };
    let s = import(&fixture("atoms.dump"), &fixture("pairs.dump"), &options).unwrap();
    assert_eq!(s, imported());

    let bad = Options {
        columns: Some(
            LocalColumns::parse("i=c_ids[1],j=c_ids[2],fx=c_pl[1],fy=c_pl[2],fz=c_pl[3]").unwrap(),
        ),
        ..Options::default()
    };
    let e = import(&fixture("atoms.dump"), &fixture("pairs.dump"), &bad)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("pairs.dump") && e.contains("line 9") && e.contains("c_pl[1]"),
        "{e}"
    );
    assert!(LocalColumns::parse("i=a,j=b,fx=c").is_err());
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const LOCAL: &str = "ITEM: TIMESTEP\n5\nITEM: NUMBER OF ENTRIES\n1\nITEM: BOX BOUNDS ff ff pp\n0 1\n0 1\n-0.1 0.1\nITEM: ENTRIES index c_1[1] c_1[2] c_2[1] c_2[2] c_2[3]\n1 1 2 -1.5 0 0\n";

#[test]
fn two_disks_by_hand() {
    // Two disks of radius 0.5 with centres 0.9 apart: overlap 0.1, contact
    // point 0.45 from the first. Force on 1 by 2 is −1.5 x (a push).
    let dir = tempfile::tempdir().unwrap();
    let atoms = write(
        dir.path(),
        "a.dump",
        "ITEM: TIMESTEP\n5\nITEM: NUMBER OF ATOMS\n2\nITEM: BOX BOUNDS ff ff pp\n0 1\n0 1\n-0.1 0.1\nITEM: ATOMS id x y z radius\n1 0 0 0 0.5\n2 0.9 0 0 0.5\n",
    );
    let local = write(dir.path(), "l.dump", LOCAL);
    let s = import(&atoms, &local, &Options::default()).unwrap();
    let f = &s.frames[0];
    assert_eq!(f.frame, None);
    assert_eq!(f.contacts.len(), 1);
    assert!((f.contacts[0].point[0] - 0.45).abs() < 1e-15);
    assert_eq!(f.contacts[0].normal, [1.0, 0.0, 0.0]);
    // σ_xx of disk 1: r_x f_x / V = 0.45 · (−1.5) / (π 0.25) < 0.
    let expected = 0.45 * -1.5 / (std::f64::consts::PI * 0.25);
    assert!((f.grains[0].stress[0] - expected).abs() < 1e-12);
    assert!((f.grains[1].stress[0] - expected).abs() < 1e-12);
}

#[test]
fn malformed_dumps_give_located_errors() {
    let dir = tempfile::tempdir().unwrap();
    let local = write(dir.path(), "l.dump", LOCAL);
    let header = "ITEM: TIMESTEP\n5\nITEM: NUMBER OF ATOMS\n2\nITEM: BOX BOUNDS ff ff pp\n0 1\n0 1\n-0.1 0.1\n";
    let cases = [
        (
            "ITEM: ATOMS id x y z radius\n1 0 0 0 0.5\n2 0.9 zero 0 0.5\n",
            "line 11, column `y`",
        ),
        (
            "ITEM: ATOMS id x y z radius\n1 0 0 0 0.5\n2 0.9 0 0\n",
            "line 11",
        ),
        (
            "ITEM: ATOMS id x y z\n1 0 0 0\n2 0.9 0 0\n",
            "column `radius`",
        ),
        (
            "ITEM: ATOMS id x y z radius\n1 0 0 0 0.5\n2 0.9 0 0 -1\n",
            "line 11, column `radius`",
        ),
        (
            "ITEM: ATOMS id x y z radius\n1 0 0 0 0.5\n3 0.9 0 0 0.5\n",
            "atom 2 is not in",
        ),
    ];
    for (body, expected) in cases {
        let atoms = write(dir.path(), "a.dump", &format!("{header}{body}"));
        let e = import(&atoms, &local, &Options::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains(expected), "expected `{expected}` in: {e}");
    }
    let periodic = header.replace("ff ff pp", "pp ff pp")
        + "ITEM: ATOMS id x y z radius\n1 0 0 0 0.5\n2 0.9 0 0 0.5\n";
    let atoms = write(dir.path(), "a.dump", &periodic);
    let e = import(&atoms, &local, &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("periodic in x"), "{e}");
    // Swapped files are named as such.
    let e = import(&local, &local, &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("swapped"), "{e}");
}

/// Σ r × f over a grain's contacts (contact points in the middle of the
/// overlap) equals I α from the dumped torque.
#[test]
fn contact_moments_balance_the_dumped_torque() {
    let s = imported();
    let mut worst: f64 = 0.0;
    let mut scale: f64 = 0.0;
    for (frame, forces) in s.frames.iter().zip(s.forces.as_ref().unwrap()) {
        let mut m = vec![0.0; frame.grains.len()];
        for (c, f) in frame.contacts.iter().zip(forces) {
            let ra = scene::sub(c.point, frame.grains[c.a].position);
            m[c.a] += scene::cross(ra, *f)[2];
            scale = scale.max(scene::norm(*f) * scene::norm(ra));
            if let Body::Grain(b) = c.b {
                let rb = scene::sub(c.point, frame.grains[b].position);
                m[b] -= scene::cross(rb, *f)[2];
            }
        }
        for (g, mz) in frame.grains.iter().zip(&m) {
            let (_, target) = frame.momentum_target(g);
            worst = worst.max((mz - target[2]).abs());
        }
    }
    assert!(
        worst < 1e-6 * scale,
        "moment residual {worst} (scale {scale})"
    );
}

/// `fix gravity` read from input scripts, as LAMMPS's FixGravity computes it.
#[test]
fn gravity_is_read_from_the_input_script() {
    use grainforce::import::lammps::gravity_from_script;
    let (g, notes) = gravity_from_script(&fixture("in.settle")).unwrap();
    assert_eq!(g, Some([0.0, -9.81, 0.0]));
    assert!(notes.is_empty());
    let dir = tempfile::tempdir().unwrap();
    let script = |text: &str| {
        let p = dir.path().join("in.test");
        std::fs::write(&p, text).unwrap();
        gravity_from_script(&p)
    };
    let close = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-12);
    // 3D chute of 30°: g = 9.81 (sin 30°, 0, −cos 30°).
    let (g, _) = script("fix g all gravity 9.81 chute 30.0\n").unwrap();
    let s = 30f64.to_radians();
    assert!(
        close(g.unwrap(), [9.81 * s.sin(), 0.0, -9.81 * s.cos()]),
        "{g:?}"
    );
    // spherical φ = 90°, θ = 180°: straight down; vector is normalised; `&`
    // continues a line; `unfix` drops a fix; comments are ignored.
    let (g, _) = script(
        "fix a all gravity 2.0 spherical 90.0 180.0 # down\n\
         fix b all gravity 1.0 vector &\n 3 0 4\nunfix a\n",
    )
    .unwrap();
    assert!(close(g.unwrap(), [0.6, 0.0, 0.8]), "{g:?}");
    let (g, _) = script("dimension 2\nfix b all gravity 1.0 vector 3 4 5\n").unwrap();
    assert!(close(g.unwrap(), [0.6, 0.8, 0.0]), "{g:?}");
    // Not read, and said so.
    let (g, notes) =
        script("fix a all gravity v_g vector 0 0 -1\nfix b grains gravity 9.81 vector 0 0 -1\n")
            .unwrap();
    assert_eq!(g, None);
    assert!(
        notes[0].contains("variable") && notes[0].contains("line 1"),
        "{notes:?}"
    );
    assert!(notes[1].contains("group `grains`"), "{notes:?}");
    let e = script("fix a all gravity 9.81 vector 0 0 zero\n")
        .unwrap_err()
        .to_string();
    assert!(e.contains("in.test, line 1") && e.contains("zero"), "{e}");
}
