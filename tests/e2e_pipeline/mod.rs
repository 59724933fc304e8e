//! The whole image chain on a DEM scene with exact forces: render → detect →
//! contacts → strain → stress → infer, each stage measured against the DEM.
//! Shared by `tests/image_end_to_end.rs` and `examples/image_end_to_end.rs`.
#![allow(dead_code)]

use grainforce::image::contacts::walls_from_scene_contacts;
use grainforce::image::dic::DicOptions;
use grainforce::image::{
    detect_disks, find_contacts, measure_stresses, render_scene, scene_from_detection,
    DetectOptions, Elasticity, PlaneCondition, RenderOptions, StrainOptions,
};
use grainforce::infer::{infer, InferOptions, Method};
use grainforce::report::metrics::relative_error;
use grainforce::scene::{read_forces, read_scene, Body, Scene, Vec3};
use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

pub const METHODS: [Method; 3] = [Method::Qs, Method::Tikhonov, Method::Scaled];

#[derive(Debug, Clone)]
pub struct Setup {
    /// Pixels per mean grain diameter.
    pub px_per_diameter: f64,
    /// A soft material, used both to draw and to measure, so grain strains are
    /// ~1e-2 and measurable; stresses (what inference sees) do not depend on it.
    pub elasticity: Elasticity,
    pub noise: f64,
    pub gap_px: f64,
    pub dic: DicOptions,
}

impl Setup {
    pub fn new(px_per_diameter: f64) -> Self {
        Setup {
            px_per_diameter,
            elasticity: Elasticity::new(5.5e6, 0.5, PlaneCondition::Stress).expect("valid"),
            noise: 0.005,
            gap_px: 2.0,
            dic: DicOptions::default(),
        }
    }
}

/// Stage by stage, how the chain did against the DEM.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub px_per_m: f64,
    pub image_size: (u32, u32),
    pub grains_truth: usize,
    pub disks_found: usize,
    /// Disks matched one-to-one to DEM grains.
    pub disks_matched: usize,
    pub worst_centre_px: f64,
    pub worst_radius_px: f64,
    pub contacts_truth: usize,
    pub contacts_found: usize,
    pub contacts_matched: usize,
    /// Largest angle [deg] between matched normals.
    pub worst_normal_deg: f64,
    /// ‖σ_measured − σ_DEM‖ / ‖σ_DEM‖ over all matched grains (xx, yy, xy).
    pub stress_relerr: f64,
    /// Inference on the detected geometry with the DEM's exact stresses (geometry error alone).
    pub geometry_only_relerr: Vec<(Method, f64)>,
    /// The full chain, over the matched contacts.
    pub relerr: Vec<(Method, f64)>,
    /// The full chain over every DEM contact (missed ones count as zero force).
    pub relerr_all: Vec<(Method, f64)>,
    /// ‖f on detected contacts the DEM lacks‖ / ‖f_DEM‖ (should be ~0).
    pub false_force: Vec<(Method, f64)>,
    pub seconds: [f64; 4],
}

impl Outcome {
    pub fn recall(&self) -> f64 {
        self.contacts_matched as f64 / self.contacts_truth as f64
    }
    pub fn precision(&self) -> f64 {
        self.contacts_matched as f64 / self.contacts_found as f64
    }
    pub fn relerr_of(&self, method: Method) -> f64 {
        lookup(&self.relerr, method)
    }
}

fn debug() -> bool {
    std::env::var_os("E2E_DEBUG").is_some()
}

fn lookup(v: &[(Method, f64)], method: Method) -> f64 {
    v.iter()
        .find(|(m, _)| *m == method)
        .map(|p| p.1)
        .unwrap_or(f64::NAN)
}

/// A contact's identity independent of order: the two grain ids, or a grain id and a wall name.
fn key(scene: &Scene, a: usize, b: &Body) -> (String, String) {
    let ida = scene.grains[a].id.clone();
    match b {
        Body::Grain(j) => {
            let idb = scene.grains[*j].id.clone();
            if ida <= idb {
                (ida, idb)
            } else {
                (idb, ida)
            }
        }
        Body::Wall(w) => (ida, format!("wall:{}", scene.walls[*w].name)),
    }
}

/// Whether the contact's (a, b) order is the reverse of its key's.
fn reversed(scene: &Scene, a: usize, b: &Body) -> bool {
    match b {
        Body::Grain(j) => scene.grains[a].id > scene.grains[*j].id,
        Body::Wall(_) => false,
    }
}

pub fn run(fixture: &Path, setup: &Setup) -> grainforce::Result<Outcome> {
    let dem = read_scene(fixture)?;
    let truth_file = fixture.join("forces.csv");
    let truth = read_forces(&truth_file)?.for_scene(&dem, &truth_file)?;
    let radii: Vec<f64> = dem.grains.iter().map(|g| g.equivalent_radius(2)).collect();
    let mean_diameter = 2.0 * radii.iter().sum::<f64>() / radii.len() as f64;
    let px_per_m = setup.px_per_diameter / mean_diameter;

    // 1. Draw the loaded packing and its unloaded reference.
    let t0 = Instant::now();
    let mut render = RenderOptions::new(px_per_m, setup.elasticity);
    render.noise = setup.noise;
    let images = render_scene(&dem, &render)?;
    let frame = images.frame;
    let t_render = t0.elapsed().as_secs_f64();

    // 2. Find the disks; match them to DEM grains by nearest centre.
    let t0 = Instant::now();
    let r_min = radii.iter().cloned().fold(f64::INFINITY, f64::min) * px_per_m;
    let r_max = radii.iter().cloned().fold(0.0, f64::max) * px_per_m;
    let disks = detect_disks(
        &images.deformed,
        &DetectOptions::new(0.85 * r_min, 1.15 * r_max),
    )?;
    let truth_px: Vec<[f64; 2]> = dem
        .grains
        .iter()
        .map(|g| frame.to_pixel([g.position[0], g.position[1]]))
        .collect();
    let mut ids = Vec::with_capacity(disks.len());
    let mut taken = vec![false; dem.grains.len()];
    let (mut worst_centre, mut worst_radius, mut matched) = (0.0f64, 0.0f64, 0);
    for (k, d) in disks.iter().enumerate() {
        let (best, dist) = truth_px
            .iter()
            .enumerate()
            .map(|(i, p)| (i, (p[0] - d.x).hypot(p[1] - d.y)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .expect("grains");
        if dist < 0.5 * radii[best] * px_per_m && !taken[best] {
            taken[best] = true;
            matched += 1;
            worst_centre = worst_centre.max(dist);
            worst_radius = worst_radius.max((d.r - radii[best] * px_per_m).abs());
            ids.push(dem.grains[best].id.clone());
        } else {
            ids.push(format!("extra{k}"));
        }
    }

    // 3. Contacts, with walls at the DEM's wall lines.
    let walls = walls_from_scene_contacts(&dem, &frame);
    let contacts = find_contacts(&disks, &walls, setup.gap_px);
    let mut scene = scene_from_detection(&disks, &ids, &contacts, &walls, &frame)?;
    scene.settings.mu = dem.settings.mu;
    scene.settings.thickness = dem.settings.thickness;
    for wall in &mut scene.walls {
        if let Some(w) = dem.walls.iter().find(|w| w.name == wall.name) {
            wall.measured_force = w.measured_force;
        }
    }
    let t_detect = t0.elapsed().as_secs_f64();

    // 4. Stresses by DIC.
    let t0 = Instant::now();
    let strain = StrainOptions {
        elasticity: setup.elasticity,
        dic: setup.dic.clone(),
    };
    measure_stresses(
        &images.reference,
        &images.deformed,
        &mut scene,
        &frame,
        &strain,
    )?;
    let t_strain = t0.elapsed().as_secs_f64();

    let dem_grain: HashMap<&str, usize> = dem
        .grains
        .iter()
        .enumerate()
        .map(|(i, g)| (g.id.as_str(), i))
        .collect();
    let (mut err2, mut ref2) = (0.0, 0.0);
    for g in &scene.grains {
        if let Some(&i) = dem_grain.get(g.id.as_str()) {
            for c in [0, 1, 3] {
                err2 += (g.stress[c] - dem.grains[i].stress[c]).powi(2);
                ref2 += dem.grains[i].stress[c].powi(2);
            }
        }
    }
    let stress_relerr = (err2 / ref2).sqrt();

    // 5. Match contacts by grain pair / wall name.
    let truth_index: HashMap<(String, String), usize> = dem
        .contacts
        .iter()
        .enumerate()
        .map(|(i, c)| (key(&dem, c.a, &c.b), i))
        .collect();
    let mut pairs = Vec::new(); // (detected contact, DEM contact, sign)
    for (k, c) in scene.contacts.iter().enumerate() {
        if let Some(&i) = truth_index.get(&key(&scene, c.a, &c.b)) {
            let d = &dem.contacts[i];
            let sign = if reversed(&scene, c.a, &c.b) == reversed(&dem, d.a, &d.b) {
                1.0
            } else {
                -1.0
            };
            pairs.push((k, i, sign));
        }
    }
    let worst_normal_deg = pairs
        .iter()
        .map(|&(k, i, s)| {
            let (n, m) = (scene.contacts[k].normal, dem.contacts[i].normal);
            (s * (n[0] * m[0] + n[1] * m[1]))
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .fold(0.0, f64::max);

    if debug() {
        for (k, c) in contacts.iter().enumerate() {
            let m = pairs.iter().any(|p| p.0 == k);
            if !m {
                eprintln!("extra contact {} {:?} gap {:.3}", c.a, c.b, c.gap);
            }
        }
        for (k, d) in disks.iter().enumerate() {
            if let Some(&i) = dem_grain.get(ids[k].as_str()) {
                let e = (truth_px[i][0] - d.x).hypot(truth_px[i][1] - d.y);
                if e > 0.5 {
                    eprintln!(
                        "disk {k} id {} at ({:.1},{:.1}) r {:.2} (true r {:.2}) off by {e:.2} px",
                        ids[k],
                        d.x,
                        d.y,
                        d.r,
                        radii[i] * px_per_m
                    );
                }
            }
        }
        for (i, c) in dem.contacts.iter().enumerate() {
            if !pairs.iter().any(|p| p.1 == i) {
                eprintln!("missed DEM contact {} {:?}", dem.grains[c.a].id, c.b);
            }
        }
    }

    // 6. Infer and compare.
    let t0 = Instant::now();
    let compare = |forces: &[Vec3]| -> (f64, f64) {
        let t: Vec<Vec3> = pairs.iter().map(|&(_, i, _)| truth[i]).collect();
        let f: Vec<Vec3> = pairs
            .iter()
            .map(|&(k, _, s)| forces[k].map(|x| s * x))
            .collect();
        let mut all = vec![[0.0; 3]; truth.len()];
        for (&(_, i, _), v) in pairs.iter().zip(&f) {
            all[i] = *v;
        }
        (relative_error(&t, &f), relative_error(&truth, &all))
    };
    let (mut relerr, mut relerr_all, mut geometry_only) = (Vec::new(), Vec::new(), Vec::new());
    let mut false_force = Vec::new();
    let mut exact = scene.clone();
    for g in &mut exact.grains {
        if let Some(&i) = dem_grain.get(g.id.as_str()) {
            g.stress = dem.grains[i].stress;
        }
    }
    for method in METHODS {
        let opts = InferOptions {
            method,
            ..InferOptions::default()
        };
        let r = infer(&scene, &opts)?;
        if debug() {
            let rep = &r.report;
            eprintln!(
                "{method}: modelled {}/{} clusters {} rattlers {} status {} warnings {:?}",
                rep.modelled_contacts,
                rep.contacts,
                rep.clusters,
                rep.rattlers,
                rep.solver_status,
                rep.warnings
            );
            let f = r.forces_or_zero();
            eprintln!(
                "  stress residual {:.3e} momentum residual {:.3e} force scale {:.3e} max |f| {:.3e} unique {:?}",
                rep.stress_residual,
                rep.momentum_residual,
                rep.force_scale,
                f.iter().map(|v| v[0].hypot(v[1])).fold(0.0, f64::max),
                rep.unique
            );
        }
        let (matched_err, all_err) = compare(&r.forces_or_zero());
        let f = r.forces_or_zero();
        let false_norm: f64 = (0..scene.contacts.len())
            .filter(|k| !pairs.iter().any(|p| p.0 == *k))
            .map(|k| f[k].iter().map(|x| x * x).sum::<f64>())
            .sum::<f64>()
            .sqrt();
        let truth_norm: f64 = truth.iter().flatten().map(|x| x * x).sum::<f64>().sqrt();
        false_force.push((method, false_norm / truth_norm));
        relerr.push((method, matched_err));
        relerr_all.push((method, all_err));
        let g = infer(&exact, &opts)?;
        geometry_only.push((method, compare(&g.forces_or_zero()).0));
    }
    let t_infer = t0.elapsed().as_secs_f64();

    Ok(Outcome {
        px_per_m,
        image_size: (frame.width, frame.height),
        grains_truth: dem.grains.len(),
        disks_found: disks.len(),
        disks_matched: matched,
        worst_centre_px: worst_centre,
        worst_radius_px: worst_radius,
        contacts_truth: dem.contacts.len(),
        contacts_found: scene.contacts.len(),
        contacts_matched: pairs.len(),
        worst_normal_deg,
        stress_relerr,
        geometry_only_relerr: geometry_only,
        relerr,
        relerr_all,
        false_force,
        seconds: [t_render, t_detect, t_strain, t_infer],
    })
}
