//! The presets: their default parameters, initial placement, preparation
//! (servo compression or gravity settling, then relaxation to the gate) and,
//! for the dynamic ones, the recorded impact.

use super::law::{damping_for_restitution, effective_shear, effective_young, Interaction};
use super::output::{balance_residuals, snapshot};
use super::sim::{Motion, System, WallShape};
use super::{
    ContactLaw, DemConfig, DemProgress, DemRun, GateReport, Material, Preset, SizeDistribution,
};
use crate::error::{Error, Result};
use crate::scene::{Scene, Settings, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::f64::consts::PI;

const QUARTZ: (f64, f64) = (95e9, 0.08);

pub(super) fn defaults(preset: Preset, dim: usize) -> DemConfig {
    let stiff = 67.5e6; // 67.5 kN/mm
    let mut c = DemConfig {
        preset,
        dim,
        grains: 58,
        seed: 1,
        gate: 1e-4,
        law: ContactLaw::Linear,
        thickness: 1.0,
        sizes: SizeDistribution::Uniform {
            min: 2.5e-3,
            max: 4e-3,
        },
        density: 2650.0,
        grain: Material {
            kn: stiff,
            kt: stiff,
            young: QUARTZ.0,
            poisson: QUARTZ.1,
            restitution: 0.5,
            mu: 0.5,
            tangential_damping: 0.0,
        },
        wall: rigid(stiff, stiff, 0.5, 0.0),
        pressure: 30e3,
        deviator: 1.0,
        gravity: None,
        safety: 0.1,
        overlap_ref: 0.01,
        local_damping: 0.7,
        stress_tolerance: 1e-2,
        max_steps: 5_000_000,
        duration: 0.0,
        frame_rate: 1.0,
        frames_every: None,
        impact_velocity: [0.0; 3],
        impactor_radius: 1.0,
        impactor_mass: 1.0,
        verbose: false,
    };
    let three_d = dim == 3;
    match preset {
        Preset::Oedometer | Preset::Box => {
            if three_d {
                // Quartz-like sand, ~0.6 mm radius; the oedometer carries 70 N
                // on its 5 mm × 5 mm cross-section.
                c.grains = 77;
                c.sizes = SizeDistribution::Uniform {
                    min: 0.55e-3,
                    max: 0.65e-3,
                };
                c.pressure = 70.0 / (5e-3 * 5e-3);
            }
            if preset == Preset::Box {
                c.grains = 1000;
                if three_d {
                    c.pressure = 1e6;
                }
            }
        }
        Preset::Impact => {
            // Polyurethane disks Ø 44.45 mm × 6.35 mm, E = 5.85 MPa.
            let r = 0.044_45 / 2.0;
            c.grains = 6;
            c.sizes = SizeDistribution::Uniform { min: r, max: r };
            c.density = 1250.0;
            let kn = linear_equivalent(5.85e6, 0.49, r / 2.0, 0.05 * r);
            hertz_disks_under_gravity(&mut c, 5.85e6, 0.49, kn, 0.6);
            c.duration = 0.028;
            c.frame_rate = 5000.0;
            c.impact_velocity = [-1.141, -0.66, 0.0];
            c.impactor_radius = 0.0127;
            // A heavy striker: twenty disks' worth (per unit thickness).
            c.impactor_mass = 20.0 * c.density * PI * r * r;
        }
        Preset::BedImpact => {
            // Bidisperse Ø 2.54 / 3.175 cm disks, E = 12 MPa, μ = 0.6.
            c.grains = 400;
            c.sizes = SizeDistribution::Bidisperse {
                small: 0.0254 / 2.0,
                large: 0.03175 / 2.0,
                fraction_small: 0.5,
            };
            c.density = 1200.0;
            let kn = linear_equivalent(12e6, 0.45, 0.0127 / 2.0, 0.05 * 0.0127);
            hertz_disks_under_gravity(&mut c, 12e6, 0.45, kn, 0.5);
            c.duration = 0.03;
            c.frame_rate = 4500.0;
            c.impact_velocity = [0.0, -2.4, 0.0];
            // A steel disk Ø 20 cm of the same thickness (per unit thickness).
            c.impactor_radius = 0.1;
            c.impactor_mass = 7850.0 * PI * 0.1 * 0.1;
        }
    }
    c
}

/// Linear stiffness equal to the Hertz tangent stiffness 2 E* √(R* δ) at overlap δ.
fn linear_equivalent(young: f64, poisson: f64, rstar: f64, delta: f64) -> f64 {
    2.0 * effective_young(young, poisson, young, poisson) * (rstar * delta).sqrt()
}

/// Per-unit-thickness scale of the laws: 1/T in 2D, 1 in 3D.
/// A wall of infinite Young's modulus with these linear constants.
fn rigid(kn: f64, kt: f64, restitution: f64, mu: f64) -> Material {
    Material {
        kn,
        kt,
        young: f64::INFINITY,
        poisson: 0.0,
        restitution,
        mu,
        tangential_damping: 0.0,
    }
}

/// The impact experiments' photoelastic disks (6.35 mm thick, μ = 0.6, Hertz
/// contacts of linear equivalent `kn`) between rigid walls, under gravity.
fn hertz_disks_under_gravity(
    c: &mut DemConfig,
    young: f64,
    poisson: f64,
    kn: f64,
    restitution: f64,
) {
    c.law = ContactLaw::Hertz;
    c.thickness = 6.35e-3;
    c.grain = Material {
        kn,
        kt: kn * 2.0 / 3.0,
        young,
        poisson,
        restitution,
        mu: 0.6,
        tangential_damping: 0.0,
    };
    c.wall = rigid(2.0 * kn, 4.0 / 3.0 * kn, restitution, 0.6);
    c.gravity = Some([0.0, -9.81, 0.0]);
    c.overlap_ref = 0.05;
}

fn law_scale(c: &DemConfig) -> f64 {
    if c.dim == 2 {
        1.0 / c.thickness
    } else {
        1.0
    }
}

/// The law between a grain and a body of material `wall` (a grain's own
/// material for grain–grain contacts).
fn interaction(c: &DemConfig, wall: &Material) -> Interaction {
    let s = law_scale(c);
    let g = &c.grain;
    let damp_n = damping_for_restitution(c.law, wall.restitution);
    let (normal, tangential) = match c.law {
        ContactLaw::Linear => (wall.kn * s, wall.kt * s),
        ContactLaw::Hertz => (
            effective_young(g.young, g.poisson, wall.young, wall.poisson) * s,
            effective_shear(g.young, g.poisson, wall.young, wall.poisson) * s,
        ),
    };
    Interaction {
        law: c.law,
        normal,
        tangential,
        damp_n,
        damp_t: wall.tangential_damping * damp_n,
        mu: wall.mu,
    }
}

/// Largest contact stiffness to expect: the linear constants, or the Hertz
/// tangent stiffnesses at the reference overlap `delta`.
fn max_stiffness(c: &DemConfig, grain: &Interaction, wall: &Interaction, delta: f64) -> f64 {
    let rmin = c.sizes.min_radius();
    let k = |it: &Interaction, rstar: f64| match it.law {
        ContactLaw::Linear => it.normal.max(it.tangential),
        ContactLaw::Hertz => {
            let s = (rstar * delta).sqrt();
            (2.0 * it.normal * s).max(8.0 * it.tangential * s)
        }
    };
    k(grain, 0.5 * rmin).max(k(wall, rmin))
}

fn grain_mass(c: &DemConfig, r: f64) -> f64 {
    if c.dim == 2 {
        c.density * PI * r * r
    } else {
        c.density * 4.0 / 3.0 * PI * r * r * r
    }
}

/// Places grains row by row (x), rows across z in 3D, then layers up y, inside
/// lateral extents `width` (x) and `depth` (z), starting at y = 0; returns the
/// positions and the height used.
fn row_pack(
    c: &DemConfig,
    radii: &[f64],
    width: f64,
    depth: f64,
    rng: &mut ChaCha8Rng,
) -> (Vec<Vec3>, f64) {
    let gap = 0.02;
    let mut pos = Vec::with_capacity(radii.len());
    let rmax = c.sizes.max_radius();
    let (mut x, mut z, mut y) = (0.0f64, 0.0f64, 0.0f64);
    let row_depth = 2.0 * rmax * (1.0 + gap);
    let layer_height = 2.0 * rmax * (1.0 + gap);
    for &r in radii {
        let d = 2.0 * r * (1.0 + gap);
        if x + d > width {
            x = 0.0;
            if c.dim == 3 && z + 2.0 * row_depth <= depth {
                z += row_depth;
            } else {
                z = 0.0;
                y += layer_height;
            }
        }
        // Random offsets inside the slack of the row/layer keep the packing disordered.
        let slack = 0.5 * (layer_height - 2.0 * r);
        let py = y + 0.5 * layer_height + rng.gen_range(-1.0..=1.0) * 0.9 * slack;
        let pz = if c.dim == 3 {
            z + 0.5 * row_depth + rng.gen_range(-1.0..=1.0) * 0.9 * slack
        } else {
            0.0
        };
        pos.push([x + 0.5 * d, py, pz]);
        x += d;
    }
    (pos, y + layer_height)
}

fn radii(c: &DemConfig, rng: &mut ChaCha8Rng) -> Vec<f64> {
    (0..c.grains)
        .map(|_| c.sizes.sample(rng.gen::<f64>()))
        .collect()
}

fn axis(k: usize, sign: f64) -> Vec3 {
    let mut v = [0.0; 3];
    v[k] = sign;
    v
}

/// Mean grain volume (area in 2D) of the configured size distribution, estimated from the draws.
fn mean_volume(c: &DemConfig, radii: &[f64]) -> f64 {
    radii
        .iter()
        .map(|&r| {
            if c.dim == 2 {
                PI * r * r
            } else {
                4.0 / 3.0 * PI * r * r * r
            }
        })
        .sum::<f64>()
        / radii.len() as f64
}

/// A plane wall to add: name, axis, position along it, normal sign, servo-controlled.
type PlaneSpec = (&'static str, usize, f64, f64, bool);

struct Built {
    sys: System,
    /// √(m_min / k_max): the time scale the step is a fraction of.
    tc: f64,
    /// Steps per frame for dynamic presets.
    frame_steps: u64,
}

fn build(c: &DemConfig) -> Result<Built> {
    let mut rng = ChaCha8Rng::seed_from_u64(c.seed);
    let radii = radii(c, &mut rng);
    let rmin = radii.iter().cloned().fold(f64::INFINITY, f64::min);
    let grain = interaction(c, &c.grain);
    let wall = interaction(c, &c.wall);
    let mut delta = c.overlap_ref * rmin;
    if c.preset.is_dynamic() && c.law == ContactLaw::Hertz {
        // Hertz overlap of the impactor on the lightest grain at the impact speed.
        let m = grain_mass(c, rmin);
        let mstar = m * c.impactor_mass / (m + c.impactor_mass);
        let rstar = rmin * c.impactor_radius / (rmin + c.impactor_radius);
        let v2 = c.impact_velocity.iter().map(|x| x * x).sum::<f64>();
        let impact = (15.0 * mstar * v2 / (16.0 * wall.normal * rstar.sqrt())).powf(0.4);
        delta = delta.max(impact);
    }
    let kmax = max_stiffness(c, &grain, &wall, delta);
    let mmin = grain_mass(c, rmin);
    let tc = (mmin / kmax).sqrt();
    let mut dt = c.safety * tc;
    let mut frame_steps = 1;
    if c.preset.is_dynamic() {
        let interval = 1.0 / c.frame_rate;
        match c.frames_every {
            Some(k) => frame_steps = k,
            None => {
                frame_steps = (interval / dt).ceil().max(1.0) as u64;
                dt = interval / frame_steps as f64;
            }
        }
    }
    let gravity = c.gravity.unwrap_or([0.0; 3]);
    let skin = 0.3 * c.sizes.max_radius();
    // Walls move slowly enough that the packing stays quasi-static: the
    // inertial stress ρ v² stays well below the target pressure, and an impact
    // at that speed overlaps by at most 2 % of the smallest radius.
    let servo_speed = (0.02 * rmin / tc).min(0.1 * (c.pressure / c.density).sqrt());
    let mean_v = mean_volume(c, &radii);
    let (positions, walls): (Vec<Vec3>, Vec<PlaneSpec>) = match c.preset {
        Preset::Oedometer | Preset::Box => {
            // Lateral size: the oedometer keeps the original's aspect (58
            // disks in 39 mm, 77 spheres in 5 mm × 5 mm); the box starts
            // as a cube holding the grains at a loose packing fraction.
            let width = match (c.preset, c.dim) {
                (Preset::Oedometer, 2) => 0.039 * (c.grains as f64 / 58.0).sqrt(),
                (Preset::Oedometer, _) => 5e-3 * (c.grains as f64 / 77.0).cbrt(),
                (_, 2) => (c.grains as f64 * mean_v / 0.6).sqrt(),
                _ => (c.grains as f64 * mean_v / 0.4).cbrt(),
            };
            let width = width.max(2.0 * 2.0 * c.sizes.max_radius() * 1.05);
            let (pos, height) = row_pack(c, &radii, width, width, &mut rng);
            let servo_all = c.preset == Preset::Box;
            let mut w = vec![
                ("left", 0, 0.0, 1.0, servo_all),
                ("right", 0, width, -1.0, servo_all),
                ("bottom", 1, 0.0, 1.0, servo_all),
                ("top", 1, height, -1.0, true),
            ];
            if c.dim == 3 {
                w.push(("back", 2, 0.0, 1.0, servo_all));
                w.push(("front", 2, width, -1.0, servo_all));
            }
            (pos, w)
        }
        Preset::Impact => {
            // Rows of three touching disks in the corner of the left and bottom walls.
            let pos = radii
                .iter()
                .enumerate()
                .map(|(k, &r)| {
                    let (row, col) = (k / 3, k % 3);
                    [r + 2.0 * r * col as f64, r + 2.0 * r * row as f64, 0.0]
                })
                .collect();
            (
                pos,
                vec![("left", 0, 0.0, 1.0, false), ("bottom", 1, 0.0, 1.0, false)],
            )
        }
        Preset::BedImpact => {
            let width = 1.22;
            if 2.0 * c.sizes.max_radius() * 1.05 > width {
                return Err(Error::Invalid("grains wider than the bed".into()));
            }
            let (pos, _) = row_pack(c, &radii, width, width, &mut rng);
            (
                pos,
                vec![
                    ("left", 0, 0.0, 1.0, false),
                    ("right", 0, width, -1.0, false),
                    ("bottom", 1, 0.0, 1.0, false),
                ],
            )
        }
    };
    let mut sys = System::new(c.dim, positions, radii, c.density, grain, gravity, dt, skin);
    if c.preset == Preset::Box {
        // Compressing a loose box to the target flows plastically, and the
        // stiffness-scaled servo creeps there at 1 % of the error per step:
        // 5 % halves the steps to the gate (1000 grains: 3D 1.77·10⁶ →
        // 0.84·10⁶, 2D 2.5·10⁵ → 1.4·10⁵); 20 % oscillates.
        sys.servo_gain = 0.05;
    }
    for (name, k, at, sign, servo) in walls {
        // The axial walls of the box carry the deviatoric load.
        let axial = c.preset == Preset::Box && k == 1;
        let motion = if servo {
            Motion::Servo {
                stress: if axial {
                    c.deviator * c.pressure
                } else {
                    c.pressure
                },
            }
        } else {
            Motion::Prescribed
        };
        sys.add_wall(
            name,
            WallShape::Plane {
                normal: axis(k, sign),
            },
            axis(k, at),
            [0.0; 3],
            motion,
            wall,
            servo_speed,
        );
    }
    Ok(Built {
        sys,
        tc,
        frame_steps,
    })
}

/// Relaxes to the gate: servo phase (until the loads are within tolerance),
/// then walls frozen and relaxation with local and light viscous damping.
/// Ends with an evaluation of the state (contacts recorded) that met the gate,
/// or the last one when the step limit ran out. Returns the gate figures.
fn relax(
    sys: &mut System,
    c: &DemConfig,
    tc: f64,
    started: std::time::Instant,
    on_progress: &mut dyn FnMut(&DemProgress),
) -> Gate {
    let check = 10;
    sys.local_damping = c.local_damping;
    // Light viscous drag (a small fraction of the contact frequency) damps
    // free-flying grains and rattlers, which local damping cannot reach.
    sys.viscous_damping = 0.01 / tc;
    sys.evaluate();
    let has_servo = sys
        .walls
        .iter()
        .any(|w| matches!(w.motion, Motion::Servo { .. }));
    let servo_ratio = c.gate.max(1e-6);
    let mut next_print = 0u64;
    let mut progress = |sys: &System, phase: &'static str, next: &mut u64| {
        if sys.steps >= *next {
            let (unbalanced, moment) = sys.unbalanced();
            on_progress(&DemProgress::Relaxing {
                phase,
                step: sys.steps,
                unbalanced,
                moment,
                servo_error: sys.servo_error(),
                seconds: started.elapsed().as_secs_f64(),
            });
            *next = sys.steps + 20_000;
        }
    };
    // Servo phase: hold the target load until the packing has (nearly)
    // stopped rearranging; freezing earlier lets a metastable packing collapse
    // inside fixed walls and lose its contacts. If the load drifts away while
    // frozen, the servo takes over again.
    let servos: Vec<(usize, Motion)> = sys
        .walls
        .iter()
        .enumerate()
        .filter(|(_, w)| matches!(w.motion, Motion::Servo { .. }))
        .map(|(k, w)| (k, w.motion))
        .collect();
    'prepare: loop {
        if has_servo {
            sys.resume_servos(&servos);
            while sys.steps < c.max_steps {
                for _ in 0..check {
                    sys.step();
                }
                progress(sys, "servo", &mut next_print);
                let (f, m) = sys.unbalanced();
                if sys.load_error(&servos) < c.stress_tolerance
                    && f < servo_ratio
                    && m < servo_ratio
                {
                    break;
                }
            }
            sys.freeze_servos();
        }
        loop {
            let (f, m) = sys.unbalanced();
            if f < c.gate && m < c.gate || sys.steps >= c.max_steps {
                sys.record = true;
                sys.evaluate();
                sys.record = false;
                let gate = gate_figures(sys, c.gate);
                if gate.passed || sys.steps >= c.max_steps {
                    return gate;
                }
            }
            if has_servo && sys.load_error(&servos) > 2.0 * c.stress_tolerance {
                continue 'prepare;
            }
            for _ in 0..check {
                sys.step();
            }
            progress(sys, "relax", &mut next_print);
        }
    }
}

struct Gate {
    passed: bool,
    force: f64,
    moment: f64,
    kinetic: f64,
    kinetic_ratio: f64,
}

fn gate_figures(sys: &System, gate: f64) -> Gate {
    let (force, moment) = sys.unbalanced();
    let kinetic = sys.kinetic_energy();
    let elastic = sys.elastic_energy();
    let kinetic_ratio = if elastic > 0.0 {
        kinetic / elastic
    } else {
        f64::INFINITY
    };
    Gate {
        passed: force < gate && moment < gate && kinetic_ratio < gate,
        force,
        moment,
        kinetic,
        kinetic_ratio,
    }
}

fn settings(c: &DemConfig, text: String) -> Settings {
    Settings {
        gravity: c.gravity.map(|g| g[..c.dim].to_vec()),
        mu: Some(c.grain.mu),
        thickness: if c.dim == 2 { Some(c.thickness) } else { None },
        description: Some(text),
    }
}

fn law_name(l: ContactLaw) -> &'static str {
    match l {
        ContactLaw::Linear => "linear spring-dashpot",
        ContactLaw::Hertz => "Hertz-Mindlin",
    }
}

/// Builds the preset and relaxes it to the gate (for dynamic presets: the
/// settled packing before the impact). Returns the system, the gate part of
/// the report and the steps per frame.
pub(super) fn prepare(
    c: &DemConfig,
    on_progress: &mut dyn FnMut(&DemProgress),
) -> Result<(System, GateReport, u64)> {
    let started = std::time::Instant::now();
    let Built {
        mut sys,
        tc,
        frame_steps,
    } = build(c)?;
    on_progress(&DemProgress::Built {
        preset: c.preset.name(),
        grains: c.grains,
        dim: c.dim,
        time_step: sys.dt,
    });
    let gate = relax(&mut sys, c, tc, started, on_progress);
    let mut report = GateReport {
        preset: c.preset.name().into(),
        dim: c.dim,
        grains: c.grains,
        gate: c.gate,
        passed: gate.passed,
        unbalanced_ratio: gate.force,
        moment_ratio: gate.moment,
        kinetic_energy: gate.kinetic,
        kinetic_ratio: gate.kinetic_ratio,
        time_step: sys.dt,
        target_stress: if c.preset.is_dynamic() {
            0.0
        } else {
            c.pressure
        },
        ..Default::default()
    };
    for k in 0..sys.walls.len() {
        if matches!(sys.walls[k].shape, WallShape::Plane { .. }) {
            let area = sys.wall_area(k);
            report
                .wall_stress
                .push((sys.walls[k].name.clone(), sys.wall_normal_force(k) / area));
        }
    }
    report.steps = sys.steps;
    report.simulated_time = sys.time;
    report.contacts = sys.contact_count;
    report.max_overlap = sys.max_overlap;
    report.seconds = started.elapsed().as_secs_f64();
    Ok((sys, report, frame_steps))
}

pub(super) fn run(c: &DemConfig, on_progress: &mut dyn FnMut(&DemProgress)) -> Result<DemRun> {
    let started = std::time::Instant::now();
    let (mut sys, mut report, frame_steps) = prepare(c, on_progress)?;
    let gate_force = report.unbalanced_ratio;
    let gate_moment = report.moment_ratio;
    let passed = report.passed;
    let (frames, forces, max_overlap) = if !c.preset.is_dynamic() {
        let text = format!(
            "grainforce dem {} ({}D, {} grains, seed {}, {} law): quasi-static state, \
             exact DEM contact forces in forces.csv; unbalanced-force ratio {:.2e}, moment ratio {:.2e} (gate {:.1e}{})",
            c.preset.name(),
            c.dim,
            c.grains,
            c.seed,
            law_name(c.law),
            gate_force,
            gate_moment,
            c.gate,
            if passed { "" } else { ", NOT reached" }
        );
        let (scene, f) = snapshot(&sys, &settings(c, text), None, false, true);
        (vec![scene], vec![f], sys.max_overlap)
    } else {
        impact(&mut sys, c, frame_steps, gate_force, on_progress)?
    };
    let mut worst_f: f64 = 0.0;
    let mut worst_m: f64 = 0.0;
    for (s, f) in frames.iter().zip(&forces) {
        let b = balance_residuals(s, f);
        worst_f = worst_f.max(b.max_force);
        worst_m = worst_m.max(b.max_moment);
    }
    report.max_momentum_residual = worst_f;
    report.max_moment_residual = worst_m;
    report.max_overlap = max_overlap;
    report.contacts = frames.last().map(|s| s.contacts.len()).unwrap_or(0);
    report.steps = sys.steps;
    report.simulated_time = sys.time;
    report.seconds = started.elapsed().as_secs_f64();
    Ok(DemRun {
        frames,
        forces,
        report,
    })
}

type Frames = (Vec<Scene>, Vec<Vec<Vec3>>, f64);

/// Launches the impactor (impact) or intruder (bed-impact) at the settled
/// packing and records frames; no numerical damping acts from here on.
fn impact(
    sys: &mut System,
    c: &DemConfig,
    frame_steps: u64,
    settled: f64,
    on_progress: &mut dyn FnMut(&DemProgress),
) -> Result<Frames> {
    let speed = c.impact_velocity.iter().map(|x| x * x).sum::<f64>().sqrt();
    let (name, centre) = match c.preset {
        Preset::Impact => {
            // Strike the grain farthest from the corner along the direction of travel.
            let dir = if speed > 0.0 {
                [
                    c.impact_velocity[0] / speed,
                    c.impact_velocity[1] / speed,
                    0.0,
                ]
            } else {
                [-1.0, 0.0, 0.0]
            };
            let target = (0..sys.len())
                .max_by(|&a, &b| {
                    let da = -(sys.x[a][0] * dir[0] + sys.x[a][1] * dir[1]);
                    let db = -(sys.x[b][0] * dir[0] + sys.x[b][1] * dir[1]);
                    da.total_cmp(&db)
                })
                .unwrap_or(0);
            let reach = sys.radius[target] + c.impactor_radius + 5e-4;
            let x = sys.x[target];
            (
                "impactor",
                [x[0] - dir[0] * reach, x[1] - dir[1] * reach, 0.0],
            )
        }
        _ => {
            // Above the middle of the bed, 2 mm above the height where it
            // would first touch a grain.
            let (xc, rb) = (0.5 * 1.22, c.impactor_radius);
            let touch = (0..sys.len())
                .filter_map(|i| {
                    let dx = sys.x[i][0] - xc;
                    let reach = rb + sys.radius[i];
                    (dx.abs() < reach).then(|| sys.x[i][1] + (reach * reach - dx * dx).sqrt())
                })
                .fold(rb, f64::max);
            ("intruder", [xc, touch + 2e-3, 0.0])
        }
    };
    let impactor_law = interaction(c, &c.wall);
    sys.add_wall(
        name,
        WallShape::Ball {
            radius: c.impactor_radius,
        },
        centre,
        c.impact_velocity,
        Motion::Free {
            mass: c.impactor_mass,
        },
        impactor_law,
        0.0,
    );
    sys.local_damping = 0.0;
    sys.viscous_damping = 0.0;
    let frames_total = (c.duration * c.frame_rate).round().max(1.0) as u64;
    let description = format!(
        "grainforce dem {} (2D, {} grains, seed {}, {} law): dynamic, frames every {} steps of {:.4e} s; \
         accelerations are kinematic and include gravity, so sum f = m (a - g) with g from `gravity`; \
         exact DEM contact forces in forces.csv; the settled state before the impact had unbalanced ratio {:.2e}",
        c.preset.name(),
        c.grains,
        c.seed,
        law_name(c.law),
        frame_steps,
        sys.dt,
        settled
    );
    let settings = settings(c, description);
    let mut frames = Vec::with_capacity(frames_total as usize + 1);
    let mut forces = Vec::with_capacity(frames_total as usize + 1);
    sys.record = true;
    sys.evaluate();
    sys.record = false;
    let (s, f) = snapshot(sys, &settings, Some(0), true, false);
    frames.push(s);
    forces.push(f);
    let mut max_overlap = sys.max_overlap;
    for frame in 1..=frames_total {
        for k in 0..frame_steps {
            sys.record = k + 1 == frame_steps;
            sys.step();
            max_overlap = max_overlap.max(sys.max_overlap);
        }
        sys.record = false;
        let (s, f) = snapshot(sys, &settings, Some(frame as i64), true, false);
        frames.push(s);
        forces.push(f);
        if frame % 20 == 0 {
            on_progress(&DemProgress::Frame {
                frame,
                total: frames_total,
                contacts: frames.last().map(|s| s.contacts.len()).unwrap_or(0),
            });
        }
    }
    Ok((frames, forces, max_overlap))
}
