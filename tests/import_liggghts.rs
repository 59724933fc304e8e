//! The LIGGGHTS importer on a real LIGGGHTS 3.8 run (fixtures/import/liggghts,
//! made by `liggghts -in in.settle`): 20 spheres settled on a floor.

use grainforce::import::liggghts::{import, Options};
use grainforce::import::{net_forces, ImportedScene};
use grainforce::scene::{self, Body};
use std::path::{Path, PathBuf};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/import/liggghts")
        .join(name)
}

fn imported(options: &Options) -> ImportedScene {
    import(&fixture("atoms.dump"), &fixture("pairs.dump"), options).unwrap()
}

fn with_gravity() -> Options {
    Options {
        gravity: Some([0.0, 0.0, -9.81]),
        ..Options::default()
    }
}

#[test]
fn reads_grains_contacts_and_a_force_by_hand() {
    let s = imported(&with_gravity());
    let f = &s.frames[0];
    assert_eq!((f.dim, f.grains.len(), f.contacts.len()), (3, 20, 14));
    // First entry: atoms 11 and 20, force on 11 by 20.
    assert_eq!(f.contacts[0].id, "11-20");
    assert_eq!(f.grains[f.contacts[0].a].id, "11");
    assert_eq!(
        s.forces.as_ref().unwrap()[0][0],
        [-0.0001486969736, 5.344456431e-05, -7.798604476e-05]
    );
    // Explicit keywords give the same scene.
    let explicit = Options {
        keywords: Some(vec!["pos".into(), "id".into(), "force".into()]),
        ..with_gravity()
    };
    assert_eq!(imported(&explicit), s);
}

/// Grains clear of the walls (whose forces LIGGGHTS' pair dump lacks) balance:
/// Σ contact forces = m (a − g) with a = f/m from the per-atom force.
#[test]
fn grains_away_from_walls_balance() {
    let s = imported(&with_gravity());
    let (frame, forces) = (&s.frames[0], &s.forces.as_ref().unwrap()[0]);
    let net = net_forces(frame, forces);
    let mean = forces.iter().map(|f| scene::norm(*f)).sum::<f64>() / forces.len() as f64;
    let mut checked = Vec::new();
    for (i, (g, n)) in frame.grains.iter().zip(&net).enumerate() {
        let (p, r) = (g.position, g.radius.unwrap());
        let clear = p[2] > r && (0..2).all(|k| p[k] > r && p[k] < 0.02 - r);
        let has_contacts = frame
            .contacts
            .iter()
            .any(|c| c.a == i || c.b == Body::Grain(i));
        if !clear || !has_contacts {
            continue;
        }
        let (target, _) = frame.momentum_target(g);
        assert!(
            scene::norm(scene::sub(*n, target)) < 1e-6 * mean,
            "grain {}",
            g.id
        );
        checked.push(i);
    }
    // The run is nearly a monolayer: most grains touch the floor.
    assert!(!checked.is_empty(), "no grain clear of the walls");
    // The sign matters: reversed forces would not balance.
    let reversed: Vec<_> = forces.iter().map(|f| f.map(|x| -x)).collect();
    let net = net_forces(frame, &reversed);
    let worst = checked
        .iter()
        .map(|&i| {
            scene::norm(scene::sub(
                net[i],
                frame.momentum_target(&frame.grains[i]).0,
            ))
        })
        .fold(0.0, f64::max);
    assert!(worst > 0.1 * mean);
}

#[test]
fn contacts_push_and_stresses_are_compressive() {
    let s = imported(&Options::default());
    let (frame, forces) = (&s.frames[0], &s.forces.as_ref().unwrap()[0]);
    for (c, f) in frame.contacts.iter().zip(forces) {
        assert!(scene::dot(*f, c.normal) < 0.0, "contact {}", c.id);
    }
    for g in &frame.grains {
        let tr = g.stress[0] + g.stress[1] + g.stress[2];
        assert!(tr <= 0.0, "grain {}", g.id);
    }
}

#[test]
fn wrong_keywords_are_reported() {
    let bad = Options {
        keywords: Some(vec!["id".into(), "force".into()]),
        ..Options::default()
    };
    let e = import(&fixture("atoms.dump"), &fixture("pairs.dump"), &bad)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("pairs.dump, line 9") && e.contains("make 6 columns"),
        "{e}"
    );
    let unknown = Options {
        keywords: Some(vec!["pos".into(), "ids".into(), "force".into()]),
        ..Options::default()
    };
    let e = import(&fixture("atoms.dump"), &fixture("pairs.dump"), &unknown)
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown pair/gran/local keyword `ids`"), "{e}");
}
