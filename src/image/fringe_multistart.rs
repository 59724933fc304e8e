//! Local restarts where a disk's fringes are not explained (issue 42, item
//! 2: multi-start only where a disk's fit is poor).
//!
//! After the run's fit, each flagged disk is fitted again from several
//! starts with only the contacts near it free: those of the disk and of its
//! neighbours (a disk's own contacts alone are pinned by its neighbours'
//! balance, three rows on each neighbour's one free contact). Every other
//! unknown is held at the fit's value by equalities, so each touched disk's
//! balance holds exactly with the frozen contacts' share in it; the pixels
//! are those of the disks the free contacts touch. A start is kept only
//! where the whole packing's objective falls, and a short polish of every
//! contact follows from the improved point.

use super::*;

/// What a local restart did for one flagged disk (in the report as
/// `local_restarts`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct LocalRestart {
    pub grain: String,
    /// Contacts freed (the disk's and its neighbours').
    pub contacts: usize,
    /// Starts fitted (a start whose projection onto the constraints failed
    /// is not counted).
    pub starts: usize,
    /// The whole packing's objective before and after this disk's restart.
    pub objective_before: f64,
    pub objective_after: f64,
    /// The start kept, if one lowered the whole packing's objective.
    pub kept: Option<LocalStart>,
}

/// The starts of a local restart, in the order they are tried.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LocalStart {
    /// The flagged disk fitted alone and freely from its fringe-gradient
    /// levels (the per-disk fit), its contacts set to that answer.
    PerDisk,
    /// Every free contact at its fringe-gradient (G²) level.
    Gradients,
    /// The fit's tangential forces reversed (a fringe pattern is symmetric
    /// under mirroring a load about its normal).
    Flipped,
    /// The fit's free forces doubled, and halved.
    Doubled,
    Halved,
}

/// Neighbour hops whose disks' contacts are freed around a flagged disk
/// (measured on noise seed 3 before [`MIN_GAIN`]: 1, 2, 3 hops gave relerr
/// 0.191, 0.189, 0.199 against 0.187 without restarts; docs/photoelastic.md,
/// round 13).
const RING_HOPS: usize = 1;

const STARTS: [LocalStart; 5] = [
    LocalStart::PerDisk,
    LocalStart::Gradients,
    LocalStart::Flipped,
    LocalStart::Doubled,
    LocalStart::Halved,
];

/// The share of the whole objective a restart must gain to be kept: a
/// start that only returns to the basin it left gains round-off (≤ 3·10⁻⁵
/// on noise seed 3), and the polish that followed cost that render relerr
/// 0.187 → 0.191 (docs/photoelastic.md, round 13).
const MIN_GAIN: f64 = 1e-4;

/// Steps of a local fit on the smoothed data, then on the photograph's
/// pixels, and of the global polish after the restarts.
const LOCAL_COARSE_STEPS: usize = 10;
const LOCAL_STEPS: usize = 20;
const POLISH_STEPS_AFTER: usize = 10;

/// The extra blur of a local fit's coarse stage, in median radii (the
/// fit's middle stage, [`STAGES`]).
const LOCAL_SMOOTHING: f64 = STAGES[1];

/// `fit` with each flagged disk refitted locally from up to `starts` starts
/// ([`STARTS`] in order; 0: off), and what each restart did. Only under
/// exact balance (under a penalty the residual alone does not rank fits).
pub fn local_restarts(
    image: &FloatImage,
    frame: &PixelFrame,
    scene: &Scene,
    settings: &FringeFitSettings,
    fit: FringeFit,
    starts: usize,
) -> Result<(FringeFit, Vec<LocalRestart>)> {
    if starts == 0 || settings.balance != Balance::Hard || fit.report.flagged.is_empty() {
        return Ok((fit, Vec::new()));
    }
    let clock = std::time::Instant::now();
    let settings = &FringeFitSettings {
        polariscope: match fit.report.bright_field {
            true => Polariscope::Bright,
            false => Polariscope::Dark,
        },
        start: None,
        ..settings.clone()
    };
    // The fit's own problem: candidates as contacts, its balanced disks,
    // dropped contacts pinned at zero.
    let (work, forces) = fit.with_candidates(scene);
    let mut p = prepare(image, frame, &work, settings, false)?;
    let left_out = &fit.report.balance_left_out;
    for (b, d) in p.balanced.iter_mut().zip(&p.disks) {
        *b = !d.loads.is_empty() && !left_out.contains(&work.grains[d.grain].id);
    }
    let dropped: Vec<bool> = (work.contacts.iter())
        .map(|c| fit.report.dropped.contains(&c.id))
        .collect();
    p.pinned = (0..work.contacts.len())
        .filter(|&k| dropped[k])
        .flat_map(|k| [(2 * k, 0.0), (2 * k + 1, 0.0)])
        .collect();
    let mut x = to_unknowns(&work, &forces, p.scale)?;
    let levels = load_levels(&p, &settings.shared);
    let mut objective_now = objective(&p, &x, &p.optics);
    let mut records = Vec::new();
    let mut steps = 0;
    let radius_px = p.scale / settings.fringe_stress * frame.px_per_m;
    for id in &fit.report.flagged {
        let Some(g) = work.grains.iter().position(|grain| &grain.id == id) else {
            continue;
        };
        let group = Group::around(&p, &work, g, &dropped);
        let mut record = LocalRestart {
            grain: id.clone(),
            contacts: group.free.len(),
            starts: 0,
            objective_before: objective_now,
            objective_after: objective_now,
            kept: None,
        };
        if group.free.is_empty() {
            records.push(record);
            continue;
        }
        let local = group.problem(&p, &x);
        let local_scene = group.scene(&work);
        let x_local = group.gather(&x);
        let mut best = (
            objective(&local, &x_local, &p.optics),
            None,
            x_local.clone(),
        );
        for &start in STARTS.iter().take(starts) {
            let Some(x0) =
                group.start(start, &p, &local, &local_scene, &x_local, &levels, settings)
            else {
                continue;
            };
            let Ok(fitted) = fit_locally(
                &local,
                &local_scene,
                frame,
                settings,
                x0,
                radius_px,
                &mut steps,
            ) else {
                continue;
            };
            record.starts += 1;
            let (rows, values) = constraint_rows(&local);
            let value = objective(&local, &fitted, &p.optics);
            if balance_violation(&rows, &values, &fitted) <= BALANCE_TOLERANCE && value < best.0 {
                best = (value, Some(start), fitted);
            }
        }
        if let (Some(start), fitted) = (best.1, best.2) {
            let mut trial = x.clone();
            group.scatter(&fitted, &mut trial);
            // The other disks' pixels are untouched, but the whole packing's
            // objective decides.
            let after = objective(&p, &trial, &p.optics);
            if after < (1.0 - MIN_GAIN) * objective_now {
                x = trial;
                objective_now = after;
                record.kept = Some(start);
                record.objective_after = after;
            }
        }
        records.push(record);
    }
    let mut fit = fit;
    if records.iter().any(|r| r.kept.is_some()) {
        let out = Stepper {
            p: &p,
            scene: Some(&work),
            settings,
            sparsity: 0.0,
            accuracy: 0.0,
        }
        .run(
            x,
            &p.optics,
            POLISH_STEPS_AFTER,
            FINAL_TOLERANCE,
            &mut FitTiming::default(),
        )?;
        steps += out.iterations;
        fit = refitted_report(&p, &work, scene, settings, fit, &out.x);
    }
    fit.report.iterations += steps;
    fit.report.seconds += clock.elapsed().as_secs_f64();
    Ok((fit, records))
}

/// The fit with the unknowns `x` of the problem `p` over `work` (the scene
/// and the candidates): its forces and a report recomputed there, with the
/// first fit's start, steps, timing and drops.
fn refitted_report(
    p: &Prepared,
    work: &Scene,
    scene: &Scene,
    settings: &FringeFitSettings,
    fit: FringeFit,
    x: &[f64],
) -> FringeFit {
    let first = fit.report;
    let mut forces = to_forces(work, x, p.scale);
    let mut report = report(
        first.method,
        p,
        work,
        settings,
        x,
        &forces,
        &[],
        first.objective_start,
        first.iterations,
        first.damping,
        std::time::Instant::now(),
        first.timing,
    );
    for (new, old) in report.disks.iter_mut().zip(&first.disks) {
        new.start_level = old.start_level;
    }
    report.seconds = first.seconds;
    report.dropped = first.dropped;
    let n = scene.contacts.len();
    report.candidates = first.candidates;
    for (c, f) in report.candidates.iter_mut().zip(&forces[n..]) {
        c.force = *f;
    }
    forces.truncate(n);
    FringeFit { forces, report }
}

/// The unknowns of one flagged disk's restart.
struct Group {
    /// The flagged disk.
    disk: usize,
    /// Contacts freed, then the frozen ones the touched disks also carry.
    free: Vec<usize>,
    frozen: Vec<usize>,
    /// Disks with a free contact.
    touched: Vec<usize>,
}

impl Group {
    /// The contacts of disk `g` and of its neighbours (dropped ones stay
    /// at zero), and what they touch.
    fn around(p: &Prepared, work: &Scene, g: usize, dropped: &[bool]) -> Group {
        let mut ring = vec![g];
        for _ in 0..RING_HOPS {
            for d in ring.clone() {
                for l in &p.disks[d].loads {
                    let c = &work.contacts[l.unknown];
                    if let Body::Grain(b) = c.b {
                        let other = if b == d { c.a } else { b };
                        if !ring.contains(&other) {
                            ring.push(other);
                        }
                    }
                }
            }
        }
        let mut free: Vec<usize> = (ring.iter())
            .flat_map(|&d| p.disks[d].loads.iter().map(|l| l.unknown))
            .filter(|&k| !dropped[k])
            .collect();
        free.sort_unstable();
        free.dedup();
        let touched: Vec<usize> = (0..p.disks.len())
            .filter(|&d| p.disks[d].loads.iter().any(|l| free.contains(&l.unknown)))
            .collect();
        let mut frozen: Vec<usize> = (touched.iter())
            .flat_map(|&d| p.disks[d].loads.iter().map(|l| l.unknown))
            .filter(|k| !free.contains(k))
            .collect();
        frozen.sort_unstable();
        frozen.dedup();
        Group {
            disk: g,
            free,
            frozen,
            touched,
        }
    }

    /// Contact `k`'s place among the local unknowns.
    fn local(&self, k: usize) -> Option<usize> {
        (self.free.iter().chain(&self.frozen)).position(|&c| c == k)
    }

    /// The touched disks as a problem of their own: their pixels, their
    /// balance, the frozen contacts pinned at their values in `x`.
    fn problem(&self, p: &Prepared, x: &[f64]) -> Prepared {
        let disks = (self.touched.iter())
            .map(|&d| {
                let mut loads = p.disks[d].loads.clone();
                for l in &mut loads {
                    l.unknown = self.local(l.unknown).expect("a touched disk's contact");
                }
                DiskData {
                    loads,
                    ..p.disks[d].with_intensity(p.disks[d].intensity.clone())
                }
            })
            .collect();
        let offset = self.free.len();
        let pinned = (self.frozen.iter().enumerate())
            .flat_map(|(i, &k)| {
                let j = offset + i;
                [(2 * j, x[2 * k]), (2 * j + 1, x[2 * k + 1])]
            })
            .collect();
        Prepared {
            disks,
            unknowns: self.free.len() + self.frozen.len(),
            scale: p.scale,
            optics: p.optics,
            pixel: p.pixel,
            balanced: self.touched.iter().map(|&d| p.balanced[d]).collect(),
            pinned,
        }
    }

    /// `work` with its contacts in the local order (for the wedges).
    fn scene(&self, work: &Scene) -> Scene {
        let mut local = work.clone();
        local.contacts = (self.free.iter().chain(&self.frozen))
            .map(|&k| work.contacts[k].clone())
            .collect();
        local
    }

    fn gather(&self, x: &[f64]) -> Vec<f64> {
        (self.free.iter().chain(&self.frozen))
            .flat_map(|&k| [x[2 * k], x[2 * k + 1]])
            .collect()
    }

    /// The free unknowns of `local` written back into `x`.
    fn scatter(&self, local: &[f64], x: &mut [f64]) {
        for (i, &k) in self.free.iter().enumerate() {
            x[2 * k] = local[2 * i];
            x[2 * k + 1] = local[2 * i + 1];
        }
    }

    /// Start `start` from the local answer `x_local`, projected onto the
    /// local balance, pins and wedges (None where that fails).
    #[allow(clippy::too_many_arguments)]
    fn start(
        &self,
        start: LocalStart,
        p: &Prepared,
        local: &Prepared,
        local_scene: &Scene,
        x_local: &[f64],
        levels: &[Vec<f64>],
        settings: &FringeFitSettings,
    ) -> Option<Vec<f64>> {
        let mut x0 = x_local.to_vec();
        let free = 2 * self.free.len();
        match start {
            LocalStart::PerDisk => {
                let d = &p.disks[self.disk];
                let u0: Vec<f64> = (d.loads.iter().zip(&levels[self.disk]))
                    .flat_map(|(_, v)| [*v, 0.0])
                    .collect();
                let alone = p.alone(d, d.loads.clone());
                let out = Stepper {
                    p: &alone,
                    scene: None,
                    settings,
                    sparsity: 0.0,
                    accuracy: 0.0,
                }
                .run(
                    u0,
                    &p.optics,
                    LOCAL_STEPS,
                    FINAL_TOLERANCE,
                    &mut FitTiming::default(),
                )
                .ok()?;
                for (i, l) in d.loads.iter().enumerate() {
                    let j = self.local(l.unknown)?;
                    x0[2 * j] = out.x[2 * i];
                    x0[2 * j + 1] = out.x[2 * i + 1];
                }
            }
            LocalStart::Gradients => {
                // Each contact at the geometric mean of its sides' levels.
                let mut product = vec![1.0; self.free.len()];
                let mut sides = vec![0.0; self.free.len()];
                for &d in &self.touched {
                    for (l, v) in p.disks[d].loads.iter().zip(&levels[d]) {
                        if let Some(i) = self.free.iter().position(|&k| k == l.unknown) {
                            product[i] *= v.max(1e-3);
                            sides[i] += 1.0;
                        }
                    }
                }
                for i in 0..self.free.len() {
                    x0[2 * i] = product[i].powf(1.0 / f64::max(sides[i], 1.0));
                    x0[2 * i + 1] = 0.0;
                }
            }
            LocalStart::Flipped => {
                for i in 0..self.free.len() {
                    x0[2 * i + 1] = -x0[2 * i + 1];
                }
            }
            LocalStart::Doubled | LocalStart::Halved => {
                let factor = if start == LocalStart::Doubled {
                    2.0
                } else {
                    0.5
                };
                x0[..free].iter_mut().for_each(|v| *v *= factor);
            }
        }
        feasible_start(local, local_scene, settings, x0).ok()
    }
}

/// A local fit from `x0`: a coarse stage on the smoothed data, then the
/// photograph's pixels (the run's final optics); counts the steps.
fn fit_locally(
    local: &Prepared,
    local_scene: &Scene,
    frame: &PixelFrame,
    settings: &FringeFitSettings,
    x0: Vec<f64>,
    radius_px: f64,
    steps: &mut usize,
) -> Result<Vec<f64>> {
    let sigma = LOCAL_SMOOTHING * radius_px;
    let coarse = thinned(&smoothed(local, sigma), stride_for(sigma));
    let mut timing = FitTiming::default();
    let stepper = Stepper {
        p: &coarse,
        scene: Some(local_scene),
        settings,
        sparsity: 0.0,
        accuracy: 0.0,
    };
    let optics = stage_optics(local, frame, settings, sigma);
    let out = stepper.run(
        x0,
        &optics,
        LOCAL_COARSE_STEPS,
        COARSE_TOLERANCE,
        &mut timing,
    )?;
    *steps += out.iterations;
    let out = Stepper {
        p: local,
        ..stepper
    }
    .run(
        out.x,
        &local.optics,
        LOCAL_STEPS,
        FINAL_TOLERANCE,
        &mut timing,
    )?;
    *steps += out.iterations;
    Ok(out.x)
}
