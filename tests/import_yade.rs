//! The YADE importer on a real YADE run (fixtures/import/yade, made by
//! `yade -n -x settle.py` with the export recipe grainforce_export.py).

use grainforce::import::yade::{import, Options};
use grainforce::import::ImportedScene;
use grainforce::scene::{self, Body};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/import/yade")
        .join(name)
}

fn imported() -> ImportedScene {
    let options = Options {
        gravity: Some([0.0, 0.0, -9.81]),
        ..Options::default()
    };
    import(
        &fixture("bodies.csv"),
        &fixture("interactions.csv"),
        &options,
    )
    .unwrap()
}

#[test]
fn spheres_are_grains_and_boxes_are_walls() {
    let s = imported();
    let f = &s.frames[0];
    assert_eq!(f.dim, 3);
    assert_eq!(f.grains.len(), 20);
    assert_eq!(f.contacts.len(), 48);
    assert!(f.wall_index("Box4").is_some(), "bottom box");
    let g = &f.grains[0];
    let r = g.radius.unwrap();
    assert!((g.volume - 4.0 / 3.0 * std::f64::consts::PI * r.powi(3)).abs() < 1e-20);
}

/// The first interaction has the bottom box (id 4) first: the contact is
/// sphere 8 on Box4, the force on the sphere +(fn + fs), the normal reversed.
#[test]
fn wall_first_interaction_is_swapped_by_hand() {
    let s = imported();
    let f = &s.frames[0];
    let c = f.contacts.iter().position(|c| c.id == "8-4").unwrap();
    assert_eq!(f.grains[f.contacts[c].a].id, "8");
    assert_eq!(f.contacts[c].b, Body::Wall(f.wall_index("Box4").unwrap()));
    assert_eq!(f.contacts[c].normal, [0.0, 0.0, -1.0]);
    let force = s.forces.as_ref().unwrap()[0][c];
    assert_eq!(
        force,
        [
            2.917166871932486e-05,
            -0.001197693419273623,
            0.006857113846439162
        ]
    );
}

/// Σ f over a sphere's contacts equals YADE's O.forces.f (stored as m (a − g)),
/// and Σ r × f equals O.forces.t: signs, swapping and contact points agree.
#[test]
fn forces_and_moments_balance_yade_totals() {
    let s = imported();
    let residual = s.momentum_residual().unwrap();
    assert!(residual < 1e-9, "momentum residual {residual}");
    let (frame, forces) = (&s.frames[0], &s.forces.as_ref().unwrap()[0]);
    let mut m = vec![[0.0; 3]; frame.grains.len()];
    let mut scale: f64 = 0.0;
    for (c, f) in frame.contacts.iter().zip(forces) {
        let r = scene::sub(c.point, frame.grains[c.a].position);
        let t = scene::cross(r, *f);
        scale = scale.max(scene::norm(t));
        (0..3).for_each(|k| m[c.a][k] += t[k]);
        if let Body::Grain(b) = c.b {
            let t = scene::cross(scene::sub(c.point, frame.grains[b].position), *f);
            (0..3).for_each(|k| m[b][k] -= t[k]);
        }
    }
    for (g, mg) in frame.grains.iter().zip(&m) {
        let (_, target) = frame.momentum_target(g);
        assert!(
            scene::norm(scene::sub(*mg, target)) < 1e-9 * scale,
            "grain {}",
            g.id
        );
    }
}

#[test]
fn settled_spheres_are_compressed_and_stress_is_consistent() {
    let s = imported();
    let dir = tempfile::tempdir().unwrap();
    s.write(dir.path()).unwrap();
    let back = scene::read_scene(dir.path()).unwrap();
    assert_eq!(back.settings.gravity, Some(vec![0.0, 0.0, -9.81]));
    for g in &back.grains {
        assert!(
            g.stress[0] + g.stress[1] + g.stress[2] < 0.0,
            "grain {}",
            g.id
        );
    }
}

#[test]
fn malformed_inputs_give_located_errors() {
    let dir = tempfile::tempdir().unwrap();
    let bodies = std::fs::read_to_string(fixture("bodies.csv")).unwrap();
    let p = dir.path().join("bodies.csv");
    let mut lines: Vec<String> = bodies.lines().map(str::to_owned).collect();
    lines[8] = lines[8].replacen(",Sphere,", ",Sphere,oops", 1);
    std::fs::write(&p, lines.join("\n")).unwrap();
    let e = import(&p, &fixture("interactions.csv"), &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("bodies.csv, line 9, column `x`"), "{e}");

    let i = dir.path().join("interactions.csv");
    std::fs::write(&i, "id1,id2,cp_x,cp_y,cp_z,n_x,n_y,n_z,fn_x,fn_y,fn_z,fs_x,fs_y,fs_z\n6,99,0,0,0,1,0,0,0,0,0,0,0,0\n").unwrap();
    let e = import(&fixture("bodies.csv"), &i, &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("interactions.csv, line 2, column `id2`"), "{e}");
}
