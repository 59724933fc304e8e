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

// ---- A `Wall` floor (fixtures/import/yade/wall, made by make_wall.py with
// YADE's geometry and law conventions; see that script).

fn wall_fixture(name: &str) -> PathBuf {
    fixture("wall").join(name)
}

fn wall_import(bodies: &Path, interactions: &Path) -> ImportedScene {
    import(bodies, interactions, &Options::default()).unwrap()
}

/// Largest per-sphere |Σ r × f − τ| relative to the mean |f|·R.
fn worst_torque_mismatch(s: &ImportedScene, bodies: &Path) -> f64 {
    let frame = &s.frames[0];
    let text = std::fs::read_to_string(bodies).unwrap();
    let mut torques = vec![None; frame.grains.len()];
    for line in text.lines().skip(1) {
        let cells: Vec<&str> = line.split(',').collect();
        if let Some(i) = frame.grains.iter().position(|g| g.id == cells[0]) {
            let t: Vec<f64> = cells[10..13].iter().map(|x| x.parse().unwrap()).collect();
            torques[i] = Some([t[0], t[1], t[2]]);
        }
    }
    grainforce::import::yade::torque_mismatch(frame, &s.forces.as_ref().unwrap()[0], &torques)
        .into_iter()
        .map(|m| m.unwrap())
        .fold(0.0, f64::max)
}

/// The same export as YADE's raw contact points would give it: no `depth`
/// column and the floor's kind renamed, so nothing moves the floor contacts
/// off the plane (the importer before issue 23).
fn on_the_plane(dir: &Path) -> (PathBuf, PathBuf) {
    let bodies = std::fs::read_to_string(wall_fixture("bodies.csv")).unwrap();
    let b = dir.join("bodies.csv");
    std::fs::write(&b, bodies.replace(",Wall,", ",Floor,")).unwrap();
    let inter = std::fs::read_to_string(wall_fixture("interactions.csv")).unwrap();
    let i = dir.join("interactions.csv");
    let no_depth: Vec<String> = inter
        .lines()
        .map(|l| {
            let mut c: Vec<&str> = l.split(',').collect();
            c.remove(8);
            c.join(",")
        })
        .collect();
    std::fs::write(&i, no_depth.join("\n")).unwrap();
    (b, i)
}

fn qs_relerr(s: &ImportedScene) -> f64 {
    use grainforce::infer::{infer, InferOptions, Method};
    let mut frame = s.frames[0].clone();
    frame.settings.mu = Some(0.5_f64.tan()); // the run's friction angle, 0.5 rad
    let opts = InferOptions {
        method: Method::Qs,
        ..InferOptions::default()
    };
    let r = infer(&frame, &opts).unwrap();
    grainforce::report::metrics::relative_error(&s.forces.as_ref().unwrap()[0], &r.forces_or_zero())
}

#[test]
fn wall_floor_contacts_sit_where_yade_applies_the_force() {
    let s = wall_import(
        &wall_fixture("bodies.csv"),
        &wall_fixture("interactions.csv"),
    );
    let f = &s.frames[0];
    assert_eq!(f.grains.len(), 27);
    let floor = f.wall_index("Wall0").expect("the Wall floor");
    let inter = std::fs::read_to_string(wall_fixture("interactions.csv")).unwrap();
    let mut seen = 0;
    for line in inter.lines().skip(1) {
        let c: Vec<f64> = line.split(',').map(|x| x.parse().unwrap()).collect();
        if c[0] != 0.0 {
            continue;
        }
        let id = format!("{}-0", c[1]);
        let k = f.contacts.iter().position(|x| x.id == id).unwrap();
        let contact = &f.contacts[k];
        assert_eq!(contact.b, Body::Wall(floor));
        assert_eq!(contact.normal, [0.0, 0.0, -1.0]);
        let g = &f.grains[contact.a];
        let depth = c[8];
        // YADE's contactPoint is on the plane (z = 0); the law acts δ/2 below it.
        assert_eq!(c[4], 0.0);
        let expected = g.position[2] - (g.radius.unwrap() - 0.5 * depth);
        assert!((contact.point[2] - expected).abs() < 1e-18);
        assert!((contact.point[2] + 0.5 * depth).abs() < 1e-15);
        assert_eq!(&contact.point[..2], &c[2..4]);
        seen += 1;
    }
    assert!(seen >= 5, "{seen} floor contacts");
    assert_eq!(s.warnings, Vec::<String>::new());
}

/// Σ r × f per sphere equals YADE's torques to 1e-9 of the mean |f|·R, and
/// forces sum to O.forces.f; on the plane the moments are off and the
/// importer names the bodies.
#[test]
fn wall_floor_moments_match_yade_torques() {
    let bodies = wall_fixture("bodies.csv");
    let s = wall_import(&bodies, &wall_fixture("interactions.csv"));
    let after = worst_torque_mismatch(&s, &bodies);
    assert!(after < 1e-9, "moment mismatch {after}");
    assert!(s.momentum_residual().unwrap() < 1e-9);
    // Without depth the `Wall` kind alone is enough: δ = R − |c − cp|.
    let dir = tempfile::tempdir().unwrap();
    let (_, no_depth) = on_the_plane(dir.path());
    let s2 = wall_import(&bodies, &no_depth);
    let derived = worst_torque_mismatch(&s2, &bodies);
    assert!(derived < 1e-9, "moment mismatch without depth {derived}");

    let (b, i) = on_the_plane(dir.path());
    let before = wall_import(&b, &i);
    let mismatch = worst_torque_mismatch(&before, &b);
    eprintln!("moment mismatch: on the plane {mismatch:.3e}, at R − δ/2 {after:.3e}");
    assert!(mismatch > 1e-5, "{mismatch}");
    assert_eq!(before.warnings.len(), 1, "{:?}", before.warnings);
    let w = &before.warnings[0];
    assert!(
        w.contains("differ from YADE's torques") && w.contains("bodies "),
        "{w}"
    );
    // Exactly the spheres with a sheared floor contact are named (a purely
    // normal force has no moment about a point on its own line).
    let floor = before.frames[0].wall_index("Floor0").unwrap();
    let forces = &before.forces.as_ref().unwrap()[0];
    for (k, g) in before.frames[0].grains.iter().enumerate() {
        let on_floor = before.frames[0]
            .contacts
            .iter()
            .zip(forces)
            .any(|(c, f)| c.a == k && c.b == Body::Wall(floor) && f[0].hypot(f[1]) > 1e-9);
        let named = w
            .split("bodies ")
            .nth(1)
            .unwrap()
            .split(['.', ','])
            .any(|x| x.trim() == g.id);
        assert_eq!(on_floor, named, "sphere {}", g.id);
    }
}

#[test]
fn qs_recovers_the_wall_run_forces() {
    let s = wall_import(
        &wall_fixture("bodies.csv"),
        &wall_fixture("interactions.csv"),
    );
    let after = qs_relerr(&s);
    let dir = tempfile::tempdir().unwrap();
    let (b, i) = on_the_plane(dir.path());
    let before = qs_relerr(&wall_import(&b, &i));
    eprintln!("qs relerr: contact points on the plane {before:.3e}, at R − δ/2 {after:.3e}");
    assert!(after < 1e-9, "qs relerr {after}");
    assert!(before > 1e-6, "{before}");
}

#[test]
fn gravity_comes_from_the_export_and_is_missed_when_absent() {
    let bodies = wall_fixture("bodies.csv");
    let s = wall_import(&bodies, &wall_fixture("interactions.csv"));
    assert_eq!(s.frames[0].settings.gravity, Some(vec![0.0, 0.0, -9.81]));
    assert_eq!(s.gravity_like_load(), None);
    // --gravity overrides the export.
    let over = import(
        &bodies,
        &wall_fixture("interactions.csv"),
        &Options {
            gravity: Some([0.0, 0.0, -9.8]),
            ..Options::default()
        },
    )
    .unwrap();
    assert_eq!(over.frames[0].settings.gravity, Some(vec![0.0, 0.0, -9.8]));

    // An export without the gravity columns: the settled bed looks gravity-loaded.
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(&bodies).unwrap();
    let cut: Vec<String> = text
        .lines()
        .map(|l| l.split(',').take(13).collect::<Vec<_>>().join(","))
        .collect();
    let b = dir.path().join("bodies.csv");
    std::fs::write(&b, cut.join("\n")).unwrap();
    let s = wall_import(&b, &wall_fixture("interactions.csv"));
    assert_eq!(s.frames[0].settings.gravity, None);
    let u = s.gravity_like_load().expect("looks gravity-loaded");
    assert!(
        (u[2] - 9.81).abs() < 0.5 && u[0].abs() < 0.5 && u[1].abs() < 0.5,
        "{u:?}"
    );
    let w = grainforce::import::gravity_like_warning(u, 3);
    assert!(w.contains("--gravity") && w.contains("-9.8"), "{w}");
    // The Box-walled fixture with gravity given does not trigger it, nor do
    // forces that are not a uniform load.
    assert_eq!(imported().gravity_like_load(), None);
    let mut shuffled = s.clone();
    for (k, f) in shuffled.forces.as_mut().unwrap()[0].iter_mut().enumerate() {
        if k % 2 == 0 {
            *f = f.map(|x| -x);
        }
    }
    assert_eq!(shuffled.gravity_like_load(), None);
}

#[test]
fn inconsistent_gravity_rows_are_located() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(wall_fixture("bodies.csv")).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    lines[4] = lines[4].replace(",-9.81", ",-9.8");
    let b = dir.path().join("bodies.csv");
    std::fs::write(&b, lines.join("\n")).unwrap();
    let e = import(&b, &wall_fixture("interactions.csv"), &Options::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("bodies.csv, line 5, column `gravity_x`"), "{e}");
}
