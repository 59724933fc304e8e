//! Force-network statistics on hand-built cases with known answers.

use grainforce::scene::{Body, Contact, Grain, Scene, Vec3};
use grainforce::stats::{distribution, frame_stats, Options};
use rand::SeedableRng;
use rand_distr::{Distribution, Exp};

fn disk(scene: &mut Scene, x: f64, y: f64) -> usize {
    let mut g = Grain::new(
        scene.grains.len().to_string(),
        [x, y, 0.0],
        std::f64::consts::PI,
        [0.0; 6],
    );
    g.radius = Some(1.0);
    scene.grains.push(g);
    scene.grains.len() - 1
}

/// A contact between two unit disks with normal force `f` (a push).
fn push(scene: &mut Scene, forces: &mut Vec<Vec3>, a: usize, b: usize, f: f64) {
    let (pa, pb) = (scene.grains[a].position, scene.grains[b].position);
    let d = [pb[0] - pa[0], pb[1] - pa[1], 0.0];
    let l = (d[0] * d[0] + d[1] * d[1]).sqrt();
    let n = [d[0] / l, d[1] / l, 0.0];
    scene.contacts.push(Contact {
        id: scene.contacts.len().to_string(),
        a,
        b: Body::Grain(b),
        point: [pa[0] + n[0], pa[1] + n[1], 0.0],
        normal: n,
        mu: None,
    });
    forces.push([-f * n[0], -f * n[1], 0.0]);
}

/// A hexagon-shaped patch of a triangular lattice under equal contact forces;
/// each missing neighbour of a boundary disk is a wall contact, so every disk
/// has six contacts. The hexagonal symmetry makes the fabric isotropic.
#[test]
fn hexagonal_packing_has_z_six_and_isotropic_fabric() {
    let mut s = Scene::new(2);
    let mut forces = Vec::new();
    let r = 3i32;
    let mut index = std::collections::HashMap::new();
    for i in -r..=r {
        for j in -r..=r {
            if (i + j).abs() <= r {
                let x = 2.0 * i as f64 + j as f64;
                let y = 3f64.sqrt() * j as f64;
                index.insert((i, j), disk(&mut s, x, y));
            }
        }
    }
    let wall = s.wall_or_insert("box");
    let dirs = [(1, 0), (0, 1), (-1, 1), (-1, 0), (0, -1), (1, -1)];
    let keys: Vec<(i32, i32)> = index.keys().copied().collect();
    for (i, j) in keys {
        let a = index[&(i, j)];
        for (k, (di, dj)) in dirs.iter().enumerate() {
            match index.get(&(i + di, j + dj)) {
                Some(&b) if k < 3 => push(&mut s, &mut forces, a, b, 2.0),
                Some(_) => {}
                None => {
                    let ang = k as f64 * std::f64::consts::PI / 3.0;
                    let n = [ang.cos(), ang.sin(), 0.0];
                    let p = s.grains[a].position;
                    s.contacts.push(Contact {
                        id: format!("w{}", s.contacts.len()),
                        a,
                        b: Body::Wall(wall),
                        point: [p[0] + n[0], p[1] + n[1], 0.0],
                        normal: n,
                        mu: None,
                    });
                    forces.push([-2.0 * n[0], -2.0 * n[1], 0.0]);
                }
            }
        }
    }
    let st = frame_stats(&s, &forces, &Options::default()).unwrap();
    assert_eq!(st.grains, 37);
    assert!(
        (st.coordination - 6.0).abs() < 1e-12,
        "Z = {}",
        st.coordination
    );
    assert!((st.coordination_without_rattlers - 6.0).abs() < 1e-12);
    assert_eq!(st.rattlers, 0);
    assert!((st.fabric[0] - 0.5).abs() < 1e-12 && (st.fabric[1] - 0.5).abs() < 1e-12);
    assert!(st.fabric[3].abs() < 1e-12);
    assert!(st.fabric_anisotropy < 1e-10, "a = {}", st.fabric_anisotropy);
    assert_eq!(st.mean_normal_force, 2.0);
    // Equal forces: nothing is above the mean, no chains.
    assert_eq!(st.strong_contact_share, 0.0);
    assert!(st.chain_lengths.is_empty());
    // Compression: negative, equal normal stresses.
    assert!(st.stress[0] < 0.0 && (st.stress[0] - st.stress[1]).abs() < 1e-9 * st.stress[0].abs());
}

/// Six disks in a row carrying force 1, four weak side contacts (0.1) and one
/// strong contact at right angles: one chain of five contacts.
fn chain_scene() -> (Scene, Vec<Vec3>) {
    let mut s = Scene::new(2);
    let mut f = Vec::new();
    let row: Vec<usize> = (0..6).map(|i| disk(&mut s, 2.0 * i as f64, 0.0)).collect();
    for w in row.windows(2) {
        push(&mut s, &mut f, w[0], w[1], 1.0);
    }
    for &i in &row[1..5] {
        let x = s.grains[i].position[0];
        let side = disk(&mut s, x, 2.0);
        push(&mut s, &mut f, i, side, 0.1);
    }
    let below = disk(&mut s, 6.0, -2.0);
    push(&mut s, &mut f, row[3], below, 1.0);
    (s, f)
}

#[test]
fn straight_chain_is_one_chain_and_shares_are_as_computed_by_hand() {
    let (s, f) = chain_scene();
    let st = frame_stats(&s, &f, &Options::default()).unwrap();
    assert_eq!(st.chain_lengths, vec![5]);
    assert!((st.mean_normal_force - 0.64).abs() < 1e-12);
    assert!((st.strong_contact_share - 0.6).abs() < 1e-12);
    // Pressure shares: strong Σ f·|d| = 5·2 + 2 = 12 of 12 + 4·0.2 = 12.8.
    assert!(
        (st.strong_stress_share - 12.0 / 12.8).abs() < 1e-12,
        "{}",
        st.strong_stress_share
    );
    // Z = 2·10/11; removing rattlers iteratively leaves nothing.
    assert!((st.coordination - 20.0 / 11.0).abs() < 1e-12);
    assert_eq!(st.rattlers, 11);
    assert_eq!(st.coordination_without_rattlers, 0.0);
}

#[test]
fn chains_bend_only_within_the_tolerance() {
    let mut s = Scene::new(2);
    let mut f = Vec::new();
    let a = disk(&mut s, 0.0, 0.0);
    let b = disk(&mut s, 2.0, 0.0);
    let c = disk(&mut s, 4.0, 0.0);
    let t = 30f64.to_radians();
    let d = disk(&mut s, 4.0 + 2.0 * t.cos(), 2.0 * t.sin());
    push(&mut s, &mut f, a, b, 1.0);
    push(&mut s, &mut f, b, c, 1.0);
    push(&mut s, &mut f, c, d, 1.0);
    for &g in &[a, b] {
        let x = s.grains[g].position[0];
        let side = disk(&mut s, x, -2.0);
        push(&mut s, &mut f, g, side, 0.1);
    }
    let wide = frame_stats(&s, &f, &Options::default()).unwrap();
    assert_eq!(wide.chain_lengths, vec![3]);
    let narrow = Options {
        chain_angle_deg: 20.0,
        ..Options::default()
    };
    assert_eq!(frame_stats(&s, &f, &narrow).unwrap().chain_lengths, vec![2]);
}

#[test]
fn exponential_tail_rate_is_recovered() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    // f = 0.5 + Exp(2): mean 1, P(f/<f>) ∝ exp(−2 x) above the mean.
    let exp2 = Exp::new(2.0).unwrap();
    let f: Vec<f64> = (0..20000).map(|_| 0.5 + exp2.sample(&mut rng)).collect();
    let mean = f.iter().sum::<f64>() / f.len() as f64;
    let x: Vec<f64> = f.iter().map(|v| v / mean).collect();
    let (hist, tail) = distribution(&x, 0.2);
    let rate = tail.unwrap().rate;
    assert!((rate - 2.0).abs() < 0.1, "rate {rate}");
    let total: f64 = hist.density.iter().sum::<f64>() * 0.2;
    assert!((total - 1.0).abs() < 1e-12);
    // A plain exponential has rate 1 in units of its mean.
    let exp1 = Exp::new(3.0).unwrap();
    let g: Vec<f64> = (0..20000).map(|_| exp1.sample(&mut rng)).collect();
    let m = g.iter().sum::<f64>() / g.len() as f64;
    let (_, tail) = distribution(&g.iter().map(|v| v / m).collect::<Vec<_>>(), 0.2);
    let rate = tail.unwrap().rate;
    assert!((rate - 1.0).abs() < 0.06, "rate {rate}");
}

#[test]
fn mismatched_forces_are_an_error() {
    let (s, f) = chain_scene();
    assert!(frame_stats(&s, &f[1..], &Options::default()).is_err());
}

/// A frictional DEM packing: a grain held by two collinear contacts is not a
/// rattler; only the six grains without any contact are (as inference finds).
#[test]
fn frictional_packing_rattlers_are_the_unloaded_grains() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/oedometer");
    let scene = grainforce::scene::read_scene(&dir).unwrap();
    let forces = grainforce::scene::read_forces(&dir.join("forces.csv"))
        .unwrap()
        .for_scene(&scene, &dir)
        .unwrap();
    let st = frame_stats(&scene, &forces, &Options::default()).unwrap();
    let contactless = (0..scene.grains.len())
        .filter(|&g| {
            !scene
                .contacts
                .iter()
                .any(|c| c.a == g || c.b == Body::Grain(g))
        })
        .count();
    assert_eq!(contactless, 6);
    assert_eq!(st.rattlers, contactless);
    assert_eq!(st.rattler_min_contacts, 2);
    assert!(st.coordination_without_rattlers > st.coordination);
}
