//! One scene from two instruments: stresses given in another frame (a
//! diffraction grain map's) attached to a label volume's grains by position,
//! with the rigid transform between the frames fitted (`import::register`,
//! `import labels --stresses`). Checked on DEM packings moved by known
//! transforms, with grains missing on each side and noisy positions.

mod common;

use common::{fixture, run};
use grainforce::import::labels::{self, synth, Options};
use grainforce::import::register::{
    self, attach_stresses, register, rotate_stress, MatchOptions, StressedGrain, TransformModel,
};
use grainforce::scene::{self, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::collections::HashSet;

/// The rotation by `angle` degrees about `axis`.
fn rotation(axis: Vec3, angle: f64) -> [[f64; 3]; 3] {
    let l = scene::norm(axis);
    let [x, y, z] = axis.map(|v| v / l);
    let (s, c) = angle.to_radians().sin_cos();
    let t = 1.0 - c;
    [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
}

fn mul(r: &[[f64; 3]; 3], v: Vec3) -> Vec3 {
    [0, 1, 2].map(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
}

fn transpose(r: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    [0, 1, 2].map(|i| [0, 1, 2].map(|j| r[j][i]))
}

/// Angle between two rotations [degrees].
fn angle_between(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> f64 {
    // trace(Aᵀ B) = 1 + 2 cos θ.
    let mut tr = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            tr += a[i][j] * b[i][j];
        }
    }
    ((tr - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees()
}

/// The second instrument's view of `positions`: each point q with
/// p = R q + t, `noise` (Gaussian, per coordinate, m) added, the `missing`
/// indices left out; returns (points, their index in `positions`).
fn moved(
    positions: &[Vec3],
    r: &[[f64; 3]; 3],
    t: Vec3,
    noise: f64,
    missing: &HashSet<usize>,
    seed: u64,
) -> (Vec<Vec3>, Vec<usize>) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let normal = Normal::new(0.0, noise.max(1e-300)).unwrap();
    let rt = transpose(r);
    let mut out = Vec::new();
    let mut index = Vec::new();
    for (i, &p) in positions.iter().enumerate() {
        if missing.contains(&i) {
            continue;
        }
        let mut q = mul(&rt, scene::sub(p, t));
        if noise > 0.0 {
            for x in &mut q {
                *x += normal.sample(&mut rng);
            }
        }
        out.push(q);
        index.push(i);
    }
    (out, index)
}

fn pick(n: usize, count: usize, seed: u64) -> HashSet<usize> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut set = HashSet::new();
    while set.len() < count {
        set.insert(rng.gen_range(0..n));
    }
    set
}

fn median_spacing(p: &[Vec3]) -> f64 {
    let mut d: Vec<f64> = p
        .iter()
        .enumerate()
        .map(|(i, &a)| {
            p.iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, &b)| scene::norm(scene::sub(a, b)))
                .fold(f64::INFINITY, f64::min)
        })
        .collect();
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

/// 1000 grains of a sheared DEM packing, 5 % missing on each side (not the
/// same ones), noise 3 % of the spacing, under four transforms including a
/// half turn: the transform, every pair and every unmatched grain recovered.
#[test]
fn known_transforms_are_recovered_with_missing_grains_and_noise() {
    let (dem, _) = fixture("regression/box3d_sheared");
    let all: Vec<Vec3> = dem.grains.iter().map(|g| g.position).collect();
    let n = all.len();
    let spacing = median_spacing(&all);
    let transforms = [
        (rotation([0.0, 0.0, 1.0], 0.0), [0.0; 3]),
        (rotation([0.0, 0.0, 1.0], 90.0), [0.01, -0.02, 0.003]),
        (rotation([0.3, -0.5, 0.8], 137.0), [-0.004, 0.05, 0.1]),
        (rotation([1.0, 1.0, 0.0], 180.0), [0.002, 0.0, -0.007]),
    ];
    for (case, (r, t)) in transforms.iter().enumerate() {
        let seed = case as u64;
        let missing_ct = pick(n, n / 20, 100 + seed);
        let missing_xrd = pick(n, n / 20, 200 + seed);
        let (first, first_index) = moved(
            &all,
            &rotation([1.0, 0.0, 0.0], 0.0),
            [0.0; 3],
            0.0,
            &missing_ct,
            0,
        );
        let (second, second_index) = moved(&all, r, *t, 0.03 * spacing, &missing_xrd, 300 + seed);
        let reg = register(&first, &second, &MatchOptions::default()).unwrap();
        let angle = angle_between(&reg.rotation, r);
        // The translation alone mixes in the rotation's error times the
        // distance from the origin: compare where the sample's centre lands.
        let centre = all
            .iter()
            .fold([0.0; 3], |c, p| [0, 1, 2].map(|k| c[k] + p[k] / n as f64));
        let seen_there = mul(&transpose(r), scene::sub(centre, *t));
        let shift = scene::norm(scene::sub(reg.apply(seen_there), centre));
        eprintln!(
            "case {case}: {} pairs, rms {:.4} spacing, rotation off {angle:.4}°, centre off \
             {:.4} spacing",
            reg.pairs.len(),
            reg.rms / spacing,
            shift / spacing
        );
        // Noise σ = 0.03 spacing over ~900 pairs some 10 spacings across:
        // the rotation is known to a few hundredths of a degree.
        assert!(angle < 0.05, "case {case}: rotation off by {angle}°");
        assert!(shift < 0.02 * spacing, "case {case}: centre off by {shift}");
        // Three noisy coordinates of σ = 0.03 spacing: rms distance √3 σ.
        assert!(
            (reg.rms / spacing - 0.052).abs() < 0.01,
            "rms {}",
            reg.rms / spacing
        );
        let both: Vec<usize> = (0..n)
            .filter(|i| !missing_ct.contains(i) && !missing_xrd.contains(i))
            .collect();
        assert_eq!(reg.pairs.len(), both.len(), "case {case}");
        for &(f, s) in &reg.pairs {
            assert_eq!(first_index[f], second_index[s], "case {case}: wrong pair");
        }
        let unmatched: HashSet<usize> = reg
            .unmatched_first
            .iter()
            .map(|&f| first_index[f])
            .collect();
        let expected: HashSet<usize> = missing_xrd.difference(&missing_ct).copied().collect();
        assert_eq!(unmatched, expected, "case {case}");
        let unmatched: HashSet<usize> = reg
            .unmatched_second
            .iter()
            .map(|&s| second_index[s])
            .collect();
        let expected: HashSet<usize> = missing_ct.difference(&missing_xrd).copied().collect();
        assert_eq!(unmatched, expected, "case {case}");
    }
}

/// A small packing (60 grains, 4 missing on each side) is matched too.
#[test]
fn a_small_packing_is_matched() {
    let (dem, _) = fixture("regression/box3d_gated");
    let all: Vec<Vec3> = dem.grains.iter().map(|g| g.position).collect();
    let spacing = median_spacing(&all);
    let r = rotation([-0.2, 0.9, 0.4], 71.0);
    let t = [0.003, 0.001, -0.002];
    let none = HashSet::new();
    let (first, first_index) = moved(
        &all,
        &rotation([0.0, 0.0, 1.0], 0.0),
        [0.0; 3],
        0.0,
        &pick(60, 4, 1),
        0,
    );
    let (second, second_index) = moved(&all, &r, t, 0.02 * spacing, &pick(60, 4, 2), 3);
    let reg = register(&first, &second, &MatchOptions::default()).unwrap();
    assert!(angle_between(&reg.rotation, &r) < 0.5);
    for &(f, s) in &reg.pairs {
        assert_eq!(first_index[f], second_index[s]);
    }
    let both = (0..60)
        .filter(|i| !pick(60, 4, 1).contains(i) && !pick(60, 4, 2).contains(i))
        .count();
    assert_eq!(reg.pairs.len(), both);
    // The same frame, no transform fitted: nearest neighbours only.
    let (same, _) = moved(
        &all,
        &rotation([0.0, 0.0, 1.0], 0.0),
        [0.0; 3],
        0.02 * spacing,
        &none,
        4,
    );
    let options = MatchOptions {
        transform: TransformModel::Identity,
        ..MatchOptions::default()
    };
    let reg = register(&all, &same, &options).unwrap();
    assert_eq!(reg.pairs.len(), 60);
    assert!(reg.pairs.iter().all(|&(f, s)| f == s));
    assert_eq!(reg.rotation, rotation([0.0, 0.0, 1.0], 0.0));
}

#[test]
fn stresses_and_their_errors_rotate_with_the_frame() {
    let r = rotation([0.4, 0.1, -0.7], 33.0);
    let s = [1.0, -2.0, 3.0, 0.5, -0.25, 0.75];
    // As full tensors: R S Rᵀ.
    let full = |s: &[f64; 6]| [[s[0], s[3], s[4]], [s[3], s[1], s[5]], [s[4], s[5], s[2]]];
    let m = full(&s);
    let (out, sd) = rotate_stress(&r, &s, Some(&[0.1; 6]));
    let got = full(&out);
    for i in 0..3 {
        for j in 0..3 {
            let mut want = 0.0;
            for p in 0..3 {
                for q in 0..3 {
                    want += r[i][p] * m[p][q] * r[j][q];
                }
            }
            assert!((got[i][j] - want).abs() < 1e-12);
        }
    }
    // Back again is the identity; the invariant trace is kept.
    let (back, _) = rotate_stress(&transpose(&r), &out, None);
    for k in 0..6 {
        assert!((back[k] - s[k]).abs() < 1e-12);
    }
    // Independent errors of 0.1: the normal components' variances sum to
    // 0.01 · Σ_pq (R_ip R_iq)² weighted once per component.
    let sd = sd.unwrap();
    assert!(sd.iter().all(|&x| x > 0.0 && x < 0.2));
    assert_eq!(rotate_stress(&r, &s, None).1, None);
}

/// The regression DEM box voxelised at `per_diameter` voxels per mean grain
/// diameter: (scene, that diameter, voxel size, grid, labels).
fn voxelised_box(per_diameter: f64) -> (scene::Scene, f64, f64, synth::Grid, Vec<u32>) {
    let (dem, _) = fixture("regression/box3d_gated");
    let (grains, _) = synth::spheres_of(&dem);
    let diameter = 2.0
        * dem
            .grains
            .iter()
            .map(|g| g.equivalent_radius(3))
            .sum::<f64>()
        / dem.grains.len() as f64;
    let voxel = diameter / per_diameter;
    let grid = synth::Grid::around(&grains, voxel, 3.0);
    let (volume, _) = synth::voxelise(&grains, &grid);
    (dem, diameter, voxel, grid, volume)
}

/// The DEM's 60 grains voxelised (15 voxels per diameter) and imported; the
/// DEM's stresses seen from another frame (turned 120° about a tilted axis,
/// shifted, noisy positions, 3 grains missing) come back onto the right
/// labels, rotated into the CT frame.
#[test]
fn diffraction_stresses_land_on_the_label_grains() {
    let (dem, d, voxel, grid, volume) = voxelised_box(15.0);
    let options = Options {
        voxel_size: voxel,
        origin: grid.origin,
        ..Options::default()
    };
    let mut imported = labels::import_array(&volume, grid.shape, None, &options).unwrap();
    let r = rotation([0.5, 0.5, 1.0], 120.0);
    let t = [0.02, -0.01, 0.005];
    let missing = pick(60, 3, 9);
    let all: Vec<Vec3> = dem.grains.iter().map(|g| g.position).collect();
    let (positions, index) = moved(&all, &r, t, 0.01 * d, &missing, 5);
    let rt = transpose(&r);
    let source: Vec<StressedGrain> = positions
        .iter()
        .zip(&index)
        .map(|(&p, &i)| StressedGrain {
            id: format!("xrd{i}"),
            position: p,
            // The stress as the diffraction frame sees it: Rᵀ σ R.
            stress: rotate_stress(&rt, &dem.grains[i].stress, None).0,
            stress_sd: None,
        })
        .collect();
    let m = attach_stresses(&mut imported.scene, &source, &MatchOptions::default()).unwrap();
    assert_eq!(m.matches.len(), 57);
    assert_eq!(m.unmatched_scene.len(), 3);
    assert!(m.unmatched_source.is_empty());
    assert!(angle_between(&m.registration.rotation, &r) < 0.5);
    for (label, xrd, _) in &m.matches {
        // Labels are DEM index + 1.
        let i: usize = label.parse::<usize>().unwrap() - 1;
        assert_eq!(xrd, &format!("xrd{i}"));
        let g = imported
            .scene
            .grains
            .iter()
            .find(|g| &g.id == label)
            .unwrap();
        let truth = dem.grains[i].stress;
        let scale = truth.iter().map(|x| x.abs()).fold(0.0, f64::max);
        // The fitted rotation is off by ≲ 0.1°: ≲ 0.2 % of the stress.
        for k in 0..6 {
            assert!(
                (g.stress[k] - truth[k]).abs() <= 5e-3 * scale,
                "grain {label} component {k}: {} vs {}",
                g.stress[k],
                truth[k]
            );
        }
    }
    for id in &m.unmatched_scene {
        let i: usize = id.parse::<usize>().unwrap() - 1;
        assert!(missing.contains(&i));
        let g = imported.scene.grains.iter().find(|g| &g.id == id).unwrap();
        assert_eq!(g.stress, [0.0; 6]);
    }
}

#[test]
fn the_cli_attaches_stresses_and_refuses_bad_files() {
    let (dem, _, voxel, grid, volume) = voxelised_box(12.0);
    let volume: Vec<u16> = volume.iter().map(|&l| l as u16).collect();
    let dir = tempfile::tempdir().unwrap();
    let npy = dir.path().join("labels.npy");
    labels::volume::write_npy(&npy, &volume, grid.shape).unwrap();
    // A grain map in a frame turned 90° about z (the diffraction sample frame).
    let r = rotation([0.0, 0.0, 1.0], 90.0);
    let rt = transpose(&r);
    let mut text = String::from("id,x,y,z,s_xx,s_yy,s_zz,s_xy,s_xz,s_yz\n");
    for (i, g) in dem.grains.iter().enumerate().skip(2) {
        let p = mul(&rt, g.position);
        let s = rotate_stress(&rt, &g.stress, None).0;
        text.push_str(&format!(
            "g{i},{},{},{},{},{},{},{},{},{}\n",
            p[0], p[1], p[2], s[0], s[1], s[2], s[3], s[4], s[5]
        ));
    }
    let stresses = dir.path().join("grains_xrd.csv");
    std::fs::write(&stresses, &text).unwrap();
    let out = dir.path().join("scene");
    let origin = format!("{},{},{}", grid.origin[0], grid.origin[1], grid.origin[2]);
    let voxel_text = voxel.to_string();
    let args = |stress: &str, out: &str| {
        vec![
            "import".to_owned(),
            "labels".to_owned(),
            npy.to_str().unwrap().to_owned(),
            "-o".to_owned(),
            out.to_owned(),
            "--voxel-size".to_owned(),
            voxel_text.clone(),
            "--origin".to_owned(),
            origin.clone(),
            "--stresses".to_owned(),
            stress.to_owned(),
        ]
    };
    let a = args(stresses.to_str().unwrap(), out.to_str().unwrap());
    let (ok, err) = run(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(ok, "{err}");
    assert!(err.contains("58 grains matched"), "{err}");
    assert!(err.contains("2 label grain(s)"), "{err}");
    let scene = scene::read_scene(&out).unwrap();
    let g = scene.grains.iter().find(|g| g.id == "10").unwrap();
    let truth = dem.grains[9].stress;
    assert!((g.stress[0] - truth[0]).abs() < 5e-3 * truth[0].abs().max(truth[1].abs()));
    let csv = std::fs::read_to_string(out.join("stress_match.csv")).unwrap();
    assert!(csv.starts_with("grain,source,distance\n3,g2,"), "{csv}");
    assert!(csv.contains("\n10,g9,"), "{csv}");
    assert!(csv.contains("\n1,,\n") && csv.contains("\n2,,\n"), "{csv}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("stress_match.json")).unwrap())
            .unwrap();
    assert_eq!(json["matched"], 58);
    assert!((json["rotation_angle_degrees"].as_f64().unwrap() - 90.0).abs() < 0.5);

    // A bad cell: the file, the line and the column named; nothing written.
    let bad = dir.path().join("bad.csv");
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    let mut cells: Vec<String> = lines[3].split(',').map(str::to_owned).collect();
    cells[7] = "oops".into();
    lines[3] = cells.join(",");
    std::fs::write(&bad, lines.join("\n")).unwrap();
    let out2 = dir.path().join("scene2");
    let a = args(bad.to_str().unwrap(), out2.to_str().unwrap());
    let (ok, err) = run(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!ok);
    assert!(
        err.contains("bad.csv") && err.contains("line 4") && err.contains("s_xy"),
        "{err}"
    );
    assert!(!out2.exists());
    // Positions in millimetres: nothing matches, and the message says why.
    let mm = dir.path().join("mm.csv");
    let mut text_mm = String::from("id,x,y,z,s_xx,s_yy,s_zz,s_xy,s_xz,s_yz\n");
    for (i, g) in dem.grains.iter().enumerate() {
        let p = g.position.map(|x| x * 1e3);
        text_mm.push_str(&format!("g{i},{},{},{},1,1,1,0,0,0\n", p[0], p[1], p[2]));
    }
    std::fs::write(&mm, text_mm).unwrap();
    let a = args(mm.to_str().unwrap(), out2.to_str().unwrap());
    let (ok, err) = run(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(!ok);
    assert!(err.contains("length unit"), "{err}");
    assert!(!out2.exists());
    let _ = register::read_stressed_grains(&stresses).unwrap();
}
