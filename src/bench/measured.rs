//! Scenes that look like measured frames (photoelastic disks): the detector
//! misses the weakest contacts and each grain's forces are fitted on their
//! own, so the data do not balance.
//!
//! From a scene with exact forces: the weakest `drop_weakest` fraction of the
//! grain–grain contacts (by |f|) is removed from the contact list; every grain's
//! stress is computed from ALL its forces (the missed ones included, as the
//! fringes of the whole disk carry them), each force seen by that grain with
//! its own relative error: f_side = f + `force_noise`·|f|·N(0, I). Walls
//! touching grains are kept (a load cell or boundary is known).

use crate::error::{Error, Result};
use crate::scene::{self, Body, Scene, Vec3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredConfig {
    /// Fraction of grain–grain contacts, the weakest first, the detector misses.
    pub drop_weakest: f64,
    /// Relative error of each force.
    pub force_noise: f64,
    /// Each grain fits its own forces (photoelastic disks): the two sides of a
    /// contact get independent errors. Otherwise one error per contact.
    pub per_side: bool,
    pub seed: u64,
}

impl Default for MeasuredConfig {
    fn default() -> Self {
        MeasuredConfig {
            drop_weakest: 0.2,
            force_noise: 0.15,
            per_side: true,
            seed: 1,
        }
    }
}

/// A measured-like frame and the exact forces of the contacts it keeps.
#[derive(Debug, Clone)]
pub struct MeasuredFrame {
    pub scene: Scene,
    /// Exact force per contact of `scene` (its contact order).
    pub truth: Vec<Vec3>,
    /// The noisy force per kept contact as grain `a` reports it.
    pub measured: Vec<Vec3>,
    /// How many contacts were dropped.
    pub dropped: usize,
    /// Median over grains of |Σ f| / mean |f| with the kept measured forces:
    /// how far from balance the data are (the 0.36 on real data).
    pub median_imbalance: f64,
}

/// Drops the weakest contacts and recomputes noisy stresses from all forces.
pub fn measured_frame(
    scene: &Scene,
    truth: &[Vec3],
    cfg: &MeasuredConfig,
) -> Result<MeasuredFrame> {
    if truth.len() != scene.contacts.len() {
        return Err(Error::Invalid(format!(
            "{} forces for {} contacts",
            truth.len(),
            scene.contacts.len()
        )));
    }
    let valid = (0.0..1.0).contains(&cfg.drop_weakest)
        && cfg.force_noise >= 0.0
        && cfg.force_noise.is_finite();
    if !valid {
        return Err(Error::Invalid(format!(
            "drop fraction must lie in [0, 1) and force noise be ≥ 0, got {} and {}",
            cfg.drop_weakest, cfg.force_noise
        )));
    }
    let dim = scene.dim;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let noisy = |f: Vec3, rng: &mut ChaCha8Rng| -> Vec3 {
        let m = scene::norm(f);
        let mut g = f;
        for v in g.iter_mut().take(dim) {
            let e: f64 = StandardNormal.sample(rng);
            *v += cfg.force_noise * m * e;
        }
        g
    };
    // Stresses from every force, as each grain sees it.
    let mut acc = vec![[0.0; 6]; scene.grains.len()];
    let mut seen_by_a = Vec::with_capacity(truth.len());
    for (c, f) in scene.contacts.iter().zip(truth) {
        let on_a = noisy(*f, &mut rng);
        seen_by_a.push(on_a);
        let mut sides = vec![(c.a, on_a)];
        if let Body::Grain(b) = c.b {
            let on_b = if cfg.per_side {
                noisy([-f[0], -f[1], -f[2]], &mut rng)
            } else {
                [-on_a[0], -on_a[1], -on_a[2]]
            };
            sides.push((b, on_b));
        }
        for (p, seen) in sides {
            let r = scene::sub(c.point, scene.grains[p].position);
            let t = scene::sym_outer(r, seen);
            for k in 0..6 {
                acc[p][k] += t[k];
            }
        }
    }
    let mut out = scene.clone();
    for (g, s) in out.grains.iter_mut().zip(acc) {
        g.stress = s.map(|v| v / g.volume);
    }
    // The weakest grain–grain contacts go missing.
    let mut grain_contacts: Vec<usize> = (0..scene.contacts.len())
        .filter(|&c| matches!(scene.contacts[c].b, Body::Grain(_)))
        .collect();
    grain_contacts.sort_by(|&x, &y| scene::norm(truth[x]).total_cmp(&scene::norm(truth[y])));
    let dropped = (cfg.drop_weakest * grain_contacts.len() as f64).round() as usize;
    let mut keep = vec![true; scene.contacts.len()];
    for &c in &grain_contacts[..dropped] {
        keep[c] = false;
    }
    out.contacts = scene
        .contacts
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(c, _)| c.clone())
        .collect();
    let kept_truth: Vec<Vec3> = truth
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(f, _)| *f)
        .collect();
    let measured: Vec<Vec3> = seen_by_a
        .iter()
        .zip(&keep)
        .filter(|(_, k)| **k)
        .map(|(f, _)| *f)
        .collect();
    let median_imbalance = median_imbalance(&out, &measured);
    Ok(MeasuredFrame {
        scene: out,
        truth: kept_truth,
        measured,
        dropped,
        median_imbalance,
    })
}

/// Median over grains with contacts of |Σ f| / (mean |f| of the scene).
pub fn median_imbalance(scene: &Scene, forces: &[Vec3]) -> f64 {
    let mut net = vec![[0.0; 3]; scene.grains.len()];
    let mut touched = vec![false; scene.grains.len()];
    for (c, f) in scene.contacts.iter().zip(forces) {
        touched[c.a] = true;
        for k in 0..3 {
            net[c.a][k] += f[k];
        }
        if let Body::Grain(b) = c.b {
            touched[b] = true;
            for k in 0..3 {
                net[b][k] -= f[k];
            }
        }
    }
    let mean = forces.iter().map(|f| scene::norm(*f)).sum::<f64>() / forces.len().max(1) as f64;
    let mut v: Vec<f64> = net
        .iter()
        .zip(&touched)
        .filter(|(_, t)| **t)
        .map(|(n, _)| scene::norm(*n) / mean.max(f64::MIN_POSITIVE))
        .collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}
