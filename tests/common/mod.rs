//! Hand-built scenes with exact forces, built independently of the library's
//! assembler: a force field is made to satisfy momentum balance by a dense
//! least-change projection, and stresses follow from V σ = Σ sym(r ⊗ f).
#![allow(dead_code)]

use grainforce::scene::{self, read_forces, read_scene, Body, Contact, Grain, Scene, Vec3};
use std::path::Path;

/// Runs the grainforce binary: whether it succeeded, and its stderr.
pub fn run(args: &[&str]) -> (bool, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(args)
        .output()
        .expect("the binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs the grainforce binary: whether it succeeded, its stdout and its stderr.
pub fn grainforce(args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .args(args)
        .output()
        .expect("the binary runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A bundled scene under fixtures/ and its exact forces (forces.csv).
pub fn fixture(name: &str) -> (Scene, Vec<Vec3>) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name);
    let scene = read_scene(&dir).unwrap();
    let truth = read_forces(&dir.join("forces.csv"))
        .unwrap()
        .for_scene(&scene, &dir)
        .unwrap();
    (scene, truth)
}
use nalgebra::{DMatrix, DVector};

pub fn grain(id: &str, position: Vec3, radius: f64, dim: usize) -> Grain {
    let volume = if dim == 2 {
        std::f64::consts::PI * radius * radius
    } else {
        4.0 / 3.0 * std::f64::consts::PI * radius.powi(3)
    };
    let mut g = Grain::new(id, position, volume, [0.0; 6]);
    g.radius = Some(radius);
    g
}

/// Adds a grain–grain contact at the middle of the two surfaces.
pub fn touch(scene: &mut Scene, a: usize, b: usize, mu: Option<f64>) {
    let (pa, pb) = (scene.grains[a].position, scene.grains[b].position);
    let (ra, rb) = (
        scene.grains[a].radius.unwrap(),
        scene.grains[b].radius.unwrap(),
    );
    let d = scene::sub(pb, pa);
    let l = scene::norm(d);
    let n = [d[0] / l, d[1] / l, d[2] / l];
    let t = 0.5 * (l + ra - rb);
    let id = format!("c{}", scene.contacts.len());
    scene.contacts.push(Contact {
        id,
        a,
        b: Body::Grain(b),
        point: [pa[0] + t * n[0], pa[1] + t * n[1], pa[2] + t * n[2]],
        normal: n,
        mu,
    });
}

/// Adds a contact of grain `a` with a wall whose outward normal (from the grain) is `n`.
pub fn wall(scene: &mut Scene, a: usize, name: &str, n: Vec3, mu: Option<f64>) {
    let w = scene.wall_or_insert(name);
    let p = scene.grains[a].position;
    let r = scene.grains[a].radius.unwrap();
    let id = format!("c{}", scene.contacts.len());
    scene.contacts.push(Contact {
        id,
        a,
        b: Body::Wall(w),
        point: [p[0] + r * n[0], p[1] + r * n[1], p[2] + r * n[2]],
        normal: n,
        mu,
    });
}

/// The momentum matrix (force and moment per grain) over d components per contact.
/// Frictionless contacts get extra rows forcing their tangential part to zero.
fn momentum_matrix(scene: &Scene) -> DMatrix<f64> {
    let d = scene.dim;
    let rows_per = if d == 2 { 3 } else { 6 };
    let frictionless: Vec<usize> = (0..scene.contacts.len())
        .filter(|&c| scene.contacts[c].mu == Some(0.0))
        .collect();
    let base = rows_per * scene.grains.len();
    let mut m = DMatrix::zeros(
        base + (d - 1) * frictionless.len(),
        d * scene.contacts.len(),
    );
    for (k, &c) in frictionless.iter().enumerate() {
        let (t1, t2) = scene::tangents(d, scene.contacts[c].normal);
        for j in 0..d {
            m[(base + (d - 1) * k, d * c + j)] = t1[j];
            if d == 3 {
                m[(base + (d - 1) * k + 1, d * c + j)] = t2[j];
            }
        }
    }
    for (ci, c) in scene.contacts.iter().enumerate() {
        let mut sides = vec![(c.a, 1.0)];
        if let Body::Grain(b) = c.b {
            sides.push((b, -1.0));
        }
        for (p, s) in sides {
            let r = scene::sub(c.point, scene.grains[p].position);
            for k in 0..d {
                let mut e = [0.0; 3];
                e[k] = s;
                m[(rows_per * p + k, d * ci + k)] += s;
                let mom = scene::cross(r, e);
                if d == 2 {
                    m[(rows_per * p + 2, d * ci + k)] += mom[2];
                } else {
                    for j in 0..3 {
                        m[(rows_per * p + 3 + j, d * ci + k)] += mom[j];
                    }
                }
            }
        }
    }
    m
}

/// The force field closest to `guess` with zero net force and moment on every grain.
pub fn equilibrate(scene: &Scene, guess: &[Vec3]) -> Vec<Vec3> {
    let d = scene.dim;
    let m = momentum_matrix(scene);
    let f0 = DVector::from_iterator(d * guess.len(), guess.iter().flat_map(|f| f[..d].to_vec()));
    // f = f0 − Mᵀ (M Mᵀ)⁺ M f0
    let svd = (&m * m.transpose()).svd(true, true);
    let y = svd.solve(&(&m * &f0), 1e-12).unwrap();
    let f = &f0 - m.transpose() * y;
    let residual = (&m * &f).amax();
    assert!(
        residual < 1e-9 * f0.amax(),
        "equilibration failed: {residual}"
    );
    (0..guess.len())
        .map(|c| {
            let mut v = [0.0; 3];
            v[..d].copy_from_slice(&f.as_slice()[d * c..d * c + d]);
            v
        })
        .collect()
}

/// Sets every grain's stress from V σ = Σ sym(r ⊗ f) (tension positive).
pub fn set_stresses(scene: &mut Scene, forces: &[Vec3]) {
    let mut acc = vec![[0.0; 6]; scene.grains.len()];
    for (c, f) in scene.contacts.iter().zip(forces) {
        let mut sides = vec![(c.a, *f)];
        if let Body::Grain(b) = c.b {
            sides.push((b, [-f[0], -f[1], -f[2]]));
        }
        for (p, fp) in sides {
            let r = scene::sub(c.point, scene.grains[p].position);
            let t = scene::sym_outer(r, fp);
            for k in 0..6 {
                acc[p][k] += t[k];
            }
        }
    }
    for (g, s) in scene.grains.iter_mut().zip(acc) {
        for k in 0..6 {
            g.stress[k] = s[k] / g.volume;
        }
    }
}

/// Compressive normal forces of magnitude ~`p` with tangential parts of
/// relative size `shear` (deterministic pseudo-random), before equilibration.
pub fn compressive_guess(scene: &Scene, p: f64, shear: f64) -> Vec<Vec3> {
    scene
        .contacts
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let (t1, t2) = scene::tangents(scene.dim, c.normal);
            let s1 = shear * ((i as f64 * 12.9898).sin() * 43758.5453).fract();
            let s2 = shear * ((i as f64 * 78.233).sin() * 12543.531).fract();
            let mag = p * (1.0 + 0.3 * ((i as f64 * 3.7).sin()));
            let mut f = [0.0; 3];
            for k in 0..3 {
                f[k] = -mag * c.normal[k] + mag * (s1 * t1[k] + s2 * t2[k]);
            }
            if c.mu == Some(0.0) {
                let fn_ = scene::dot(f, c.normal);
                for k in 0..3 {
                    f[k] = fn_ * c.normal[k];
                }
            }
            f
        })
        .collect()
}

/// Checks compressive and Coulomb-admissible forces (for building valid truth).
pub fn admissible(scene: &Scene, forces: &[Vec3]) -> bool {
    scene.contacts.iter().zip(forces).all(|(c, f)| {
        let fn_ = -scene::dot(*f, c.normal);
        let ft = scene::norm([
            f[0] + fn_ * c.normal[0],
            f[1] + fn_ * c.normal[1],
            f[2] + fn_ * c.normal[2],
        ]);
        let mu = c.mu.or(scene.settings.mu).unwrap_or(f64::INFINITY);
        fn_ > 0.0 && ft <= mu * fn_ * (1.0 + 1e-12) + 1e-9 * fn_
    })
}

pub fn relerr(truth: &[Vec3], inferred: &[Vec3]) -> f64 {
    let (mut e, mut n) = (0.0, 0.0);
    for (t, f) in truth.iter().zip(inferred) {
        for k in 0..3 {
            e += (t[k] - f[k]).powi(2);
            n += t[k] * t[k];
        }
    }
    (e / n).sqrt()
}

/// The relative error of 2D forces (x, y per contact) against the truth.
pub fn relerr_2d(fit: &[[f64; 2]], truth: &[[f64; 2]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (f, t) in fit.iter().zip(truth) {
        num += (f[0] - t[0]).powi(2) + (f[1] - t[1]).powi(2);
        den += t[0] * t[0] + t[1] * t[1];
    }
    (num / den).sqrt()
}

/// A frictional 2D packing: `nx` × `ny` disks on a triangular lattice between
/// four frictionless walls, with exact forces.
pub fn lattice_2d(nx: usize, ny: usize, mu: f64) -> (Scene, Vec<Vec3>) {
    packing_2d(nx, ny, mu, true)
}

/// As [`lattice_2d`] on a square lattice (coordination 4).
pub fn square_2d(nx: usize, ny: usize, mu: f64) -> (Scene, Vec<Vec3>) {
    packing_2d(nx, ny, mu, false)
}

fn packing_2d(nx: usize, ny: usize, mu: f64, triangular: bool) -> (Scene, Vec<Vec3>) {
    let mut s = Scene::new(2);
    let r = 0.004;
    let h = if triangular { r * 3f64.sqrt() } else { 2.0 * r };
    for j in 0..ny {
        for i in 0..nx {
            let shifted = triangular && j % 2 == 1;
            if shifted && i == nx - 1 {
                continue;
            }
            let x = r + 2.0 * r * i as f64 + if shifted { r } else { 0.0 };
            s.grains.push(grain(
                &format!("{}", s.grains.len()),
                [x, r + h * j as f64, 0.0],
                r,
                2,
            ));
        }
    }
    let ng = s.grains.len();
    for a in 0..ng {
        for b in a + 1..ng {
            let d = scene::norm(scene::sub(s.grains[a].position, s.grains[b].position));
            if d < 2.0 * r * 1.0001 {
                touch(&mut s, a, b, Some(mu));
            }
        }
    }
    let width = 2.0 * r * nx as f64;
    let top = s.grains.iter().map(|g| g.position[1]).fold(0.0, f64::max);
    for a in 0..ng {
        let p = s.grains[a].position;
        if p[1] < 1.5 * r {
            wall(&mut s, a, "bottom", [0.0, -1.0, 0.0], Some(0.0));
        }
        if p[1] > top - 0.5 * r {
            wall(&mut s, a, "top", [0.0, 1.0, 0.0], Some(0.0));
        }
        if p[0] < 1.5 * r {
            wall(&mut s, a, "left", [-1.0, 0.0, 0.0], Some(0.0));
        }
        if p[0] > width - 1.5 * r {
            wall(&mut s, a, "right", [1.0, 0.0, 0.0], Some(0.0));
        }
    }
    let guess = compressive_guess(&s, 100.0, 0.2);
    let forces = equilibrate(&s, &guess);
    // Where the exact field needs more friction than `mu`, that contact gets a
    // larger μ of its own (still a valid per-contact coefficient).
    for (c, f) in s.contacts.iter_mut().zip(&forces) {
        if let Some(m) = c.mu.filter(|&m| m > 0.0) {
            let fn_ = -scene::dot(*f, c.normal);
            let ft = scene::norm([f[0] + fn_ * c.normal[0], f[1] + fn_ * c.normal[1], 0.0]);
            c.mu = Some(m.max(1.25 * ft / fn_));
        }
    }
    assert!(
        admissible(&s, &forces),
        "lattice truth is not admissible: {:?}",
        admissibility(&s, &forces)
    );
    set_stresses(&mut s, &forces);
    (s, forces)
}

/// Measured wall loads from exact forces.
pub fn set_wall_loads(scene: &mut Scene, forces: &[Vec3]) {
    let mut totals = vec![[0.0; 3]; scene.walls.len()];
    for (c, f) in scene.contacts.iter().zip(forces) {
        if let Body::Wall(w) = c.b {
            for k in 0..3 {
                totals[w][k] += f[k];
            }
        }
    }
    for (w, t) in scene.walls.iter_mut().zip(totals) {
        w.measured_force = Some(t);
    }
}

/// Worst normal force and worst |f_t|/f_n, for diagnosing a truth that is not admissible.
pub fn admissibility(scene: &Scene, forces: &[Vec3]) -> (f64, f64) {
    let mut min_fn = f64::INFINITY;
    let mut max_ratio: f64 = 0.0;
    for (c, f) in scene.contacts.iter().zip(forces) {
        let fn_ = -scene::dot(*f, c.normal);
        let ft = scene::norm([
            f[0] + fn_ * c.normal[0],
            f[1] + fn_ * c.normal[1],
            f[2] + fn_ * c.normal[2],
        ]);
        min_fn = min_fn.min(fn_);
        max_ratio = max_ratio.max(ft / fn_.abs());
    }
    (min_fn, max_ratio)
}

/// A 2×2×2 simple-cubic stack of spheres in a box of six frictionless walls.
pub fn cubic_stack(mu: f64) -> (Scene, Vec<[f64; 3]>) {
    let mut s = Scene::new(3);
    let r = 0.0006;
    for k in 0..2 {
        for j in 0..2 {
            for i in 0..2 {
                let id = format!("{}", s.grains.len());
                s.grains.push(grain(
                    &id,
                    [
                        r + 2.0 * r * i as f64,
                        r + 2.0 * r * j as f64,
                        r + 2.0 * r * k as f64,
                    ],
                    r,
                    3,
                ));
            }
        }
    }
    for a in 0..8 {
        for b in a + 1..8 {
            let d = scene::norm(scene::sub(s.grains[a].position, s.grains[b].position));
            if d < 2.0 * r * 1.0001 {
                touch(&mut s, a, b, Some(mu));
            }
        }
    }
    let names = [
        ("left", 0, -1.0),
        ("right", 0, 1.0),
        ("bottom", 1, -1.0),
        ("top", 1, 1.0),
        ("back", 2, -1.0),
        ("front", 2, 1.0),
    ];
    for a in 0..8 {
        let p = s.grains[a].position;
        for &(name, axis, sign) in &names {
            let low = p[axis] < 1.5 * r;
            if (sign < 0.0) == low {
                let mut n = [0.0; 3];
                n[axis] = sign;
                wall(&mut s, a, name, n, Some(0.0));
            }
        }
    }
    let guess = compressive_guess(&s, 70.0, 0.2);
    let forces = equilibrate(&s, &guess);
    assert!(admissible(&s, &forces), "{:?}", admissibility(&s, &forces));
    set_stresses(&mut s, &forces);
    (s, forces)
}

/// The `impact` preset (2D, DEM seed 1) with 0.1 % of a diameter position
/// noise (draw `seed`), also written as a sequence folder `impact` in a
/// temporary directory (kept alive by `dir`).
pub struct NoisyImpact {
    pub run: grainforce::dem::DemRun,
    pub noisy: Vec<Scene>,
    pub dir: tempfile::TempDir,
    pub scene: std::path::PathBuf,
    /// The preset's frame rate [1/s].
    pub fps: f64,
}

impl NoisyImpact {
    /// `grainforce infer` on the noisy tracks at the preset's frame rate,
    /// accelerations derived from the tracks, then `args` (the method too).
    pub fn infer_from_tracks(&self, args: &[&str]) -> std::process::Output {
        let fps = self.fps.to_string();
        let mut all = vec!["--fps", &fps, "--derive-accelerations"];
        all.extend(args);
        grainforce_infer(&self.scene, &all)
    }
}

pub fn noisy_impact_on_disk(seed: u64) -> NoisyImpact {
    use grainforce::dem::perturb::{perturb, PerturbConfig};
    use grainforce::dem::{simulate, DemConfig, Preset};
    let config = DemConfig::preset(Preset::Impact, 2).seed(1);
    let fps = config.frame_rate;
    let run = simulate(&config).unwrap();
    let diameter = 2.0 * run.frames[0].grains[0].radius.unwrap();
    let config = PerturbConfig {
        position_noise: 1e-3 * diameter,
        seed,
        ..Default::default()
    };
    let noisy = perturb(&run.frames, &config).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("impact");
    scene::write_sequence(&scene, &noisy).unwrap();
    NoisyImpact {
        run,
        noisy,
        dir,
        scene,
        fps,
    }
}

/// `grainforce infer SCENE ARGS…`, its output captured.
pub fn grainforce_infer<S: AsRef<std::ffi::OsStr>>(
    scene: &std::path::Path,
    args: &[S],
) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_grainforce"))
        .arg("infer")
        .arg(scene)
        .args(args)
        .output()
        .unwrap()
}

/// The DEM oedometer and its exact forces in contact order.
pub fn oedometer() -> (Scene, Vec<[f64; 2]>) {
    let dir = Path::new("fixtures/oedometer");
    let scene = read_scene(dir).unwrap();
    let rows = read_forces(&dir.join("forces.csv")).unwrap().rows;
    let forces = scene
        .contacts
        .iter()
        .map(|c| {
            let r = rows.iter().find(|r| r.contact == c.id).unwrap();
            [r.force[0], r.force[1]]
        })
        .collect();
    (scene, forces)
}

/// The `count` grains nearest grain `centre`, with every contact that touches
/// them: inside pairs as they are, the others as loads from a body
/// "outside" (the inside grain as `a`).
pub fn cluster(
    scene: &Scene,
    forces: &[[f64; 2]],
    centre: usize,
    count: usize,
) -> (Scene, Vec<[f64; 2]>) {
    let c0 = scene.grains[centre].position;
    let mut order: Vec<usize> = (0..scene.grains.len()).collect();
    let d = |g: usize| {
        let p = scene.grains[g].position;
        (p[0] - c0[0]).hypot(p[1] - c0[1])
    };
    order.sort_by(|a, b| d(*a).total_cmp(&d(*b)));
    let chosen: Vec<usize> = order[..count].to_vec();
    let index = |g: usize| chosen.iter().position(|&k| k == g);
    let mut out = Scene::new(2);
    out.settings = scene.settings.clone();
    out.grains = chosen.iter().map(|&g| scene.grains[g].clone()).collect();
    let mut truth = Vec::new();
    for (c, f) in scene.contacts.iter().zip(forces) {
        let b = match c.b {
            Body::Grain(b) => index(b),
            Body::Wall(_) => None,
        };
        let (a, b, n, f) = match (index(c.a), b) {
            (Some(a), Some(b)) => (a, Body::Grain(b), c.normal, *f),
            (Some(a), None) => {
                let name = match c.b {
                    Body::Wall(w) => scene.walls[w].name.clone(),
                    Body::Grain(_) => "outside".to_string(),
                };
                (a, Body::Wall(out.wall_or_insert(&name)), c.normal, *f)
            }
            (None, Some(b)) => {
                let w = out.wall_or_insert("outside");
                let n = c.normal;
                (b, Body::Wall(w), [-n[0], -n[1], -n[2]], [-f[0], -f[1]])
            }
            (None, None) => continue,
        };
        out.contacts.push(Contact {
            id: c.id.clone(),
            a,
            b,
            point: c.point,
            normal: n,
            mu: c.mu,
        });
        truth.push(f);
    }
    (out, truth)
}
