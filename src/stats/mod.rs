//! Force-network statistics researchers report, from a scene and its contact
//! forces (inferred or true):
//! - P(f/⟨f⟩) and an exponential fit of its tail above the mean;
//! - the strong/weak split (Radjai et al.): share of contacts with a normal
//!   force above the mean, and the share of the mean stress they carry;
//! - mean coordination with and without rattlers;
//! - the fabric tensor Σ n⊗n / N_c and its deviatoric anisotropy;
//! - the macroscopic stress (eq. 2.1, [`crate::scene::macroscopic_stress`]);
//! - force chains and their length distribution.
//!
//! Definitions used throughout: f is the *normal* force of a contact,
//! f = −f·n (compression positive); a contact is force-carrying when f exceeds
//! 1e-9 of the largest normal force. The force distribution, fabric and chains
//! use grain–grain contacts; coordination counts wall contacts too (a grain
//! resting on a wall is held by it).

pub mod plot;

use crate::error::{Error, Result};
use crate::scene::{self, Body, Scene, Sym, Vec3};

#[derive(Debug, Clone)]
pub struct Options {
    /// Histogram bin width in units of ⟨f⟩.
    pub bin_width: f64,
    /// Largest angle between consecutive branch vectors of a chain [degrees].
    pub chain_angle_deg: f64,
    /// Shortest chain reported, in contacts (2 contacts = 3 grains).
    pub min_chain_contacts: usize,
    /// A grain with fewer force-carrying contacts is a rattler; `None`: 2 when
    /// any contact has friction (two collinear contacts can balance a grain),
    /// d + 1 when all are frictionless.
    pub rattler_min_contacts: Option<usize>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            bin_width: 0.2,
            chain_angle_deg: 45.0,
            min_chain_contacts: 2,
            rattler_min_contacts: None,
        }
    }
}

/// The probability density of x = f/⟨f⟩ on bins [edges[i], edges[i+1]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Histogram {
    pub edges: Vec<f64>,
    pub counts: Vec<usize>,
    pub density: Vec<f64>,
}

/// P(x) ≈ amplitude · exp(−rate · x) for x = f/⟨f⟩ > 1, fitted to ln P by least
/// squares weighted by bin counts (the variance of ln P of a bin is ≈ 1/count).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TailFit {
    pub rate: f64,
    pub amplitude: f64,
    /// Non-empty bins used.
    pub bins: usize,
}

#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct FrameStats {
    pub frame: Option<i64>,
    pub dim: usize,
    pub grains: usize,
    /// Grain–grain contacts.
    pub contacts: usize,
    /// Grain–grain contacts carrying force.
    pub force_carrying: usize,
    /// ⟨f⟩ over force-carrying grain–grain contacts [N, N/m in 2D].
    pub mean_normal_force: f64,
    pub histogram: Histogram,
    pub tail: Option<TailFit>,
    /// Share of force-carrying contacts with f > ⟨f⟩.
    pub strong_contact_share: f64,
    /// Share of the mean stress −tr⟨σ⟩/d carried by the strong contacts.
    pub strong_stress_share: f64,
    /// Mean number of force-carrying contacts per grain (walls included).
    pub coordination: f64,
    /// The same over non-rattlers, counting only contacts between them (and walls).
    pub coordination_without_rattlers: f64,
    /// Grains with fewer than [`Options::rattler_min_contacts`] force-carrying
    /// contacts, found iteratively.
    pub rattlers: usize,
    /// The contact count below which a grain was a rattler.
    pub rattler_min_contacts: usize,
    /// Σ n⊗n / N_c over force-carrying grain–grain contacts, [`Sym`] order.
    pub fabric: Sym,
    /// Deviatoric fabric anisotropy: 2D a = 2(λ₁ − λ₂) (Rothenburg–Bathurst
    /// E(θ) ∝ 1 + a cos 2(θ − θ₀)); 3D a = √(3/2 a′:a′) with a′ = 15/2 F′.
    pub fabric_anisotropy: f64,
    /// Macroscopic stress (eq. 2.1) over the assembly's bounding box, tension positive.
    pub stress: Sym,
    /// Length of each force chain, in contacts.
    pub chain_lengths: Vec<usize>,
}

/// Statistics of one frame.
pub fn frame_stats(scene: &Scene, forces: &[Vec3], options: &Options) -> Result<FrameStats> {
    if forces.len() != scene.contacts.len() {
        return Err(Error::Invalid(format!(
            "{} forces for {} contacts",
            forces.len(),
            scene.contacts.len()
        )));
    }
    if options.bin_width.is_nan() || options.bin_width <= 0.0 {
        return Err(Error::Invalid("the bin width must be positive".into()));
    }
    let dim = scene.dim;
    let normal: Vec<f64> = scene
        .contacts
        .iter()
        .zip(forces)
        .map(|(c, f)| -scene::dot(*f, c.normal))
        .collect();
    let max = normal.iter().cloned().fold(0.0, f64::max);
    let threshold = 1e-9 * max;
    let carrying: Vec<bool> = normal.iter().map(|&f| max > 0.0 && f > threshold).collect();
    let grain_grain: Vec<usize> = (0..scene.contacts.len())
        .filter(|&c| matches!(scene.contacts[c].b, Body::Grain(_)))
        .collect();
    let active: Vec<usize> = grain_grain
        .iter()
        .copied()
        .filter(|&c| carrying[c])
        .collect();
    let mean = if active.is_empty() {
        0.0
    } else {
        active.iter().map(|&c| normal[c]).sum::<f64>() / active.len() as f64
    };

    let (histogram, tail) = distribution(
        &active.iter().map(|&c| normal[c] / mean).collect::<Vec<_>>(),
        options.bin_width,
    );

    let strong: Vec<bool> = (0..scene.contacts.len())
        // A relative margin keeps equal forces (all at the mean) out of the
        // strong network despite rounding in the mean.
        .map(|c| {
            carrying[c]
                && matches!(scene.contacts[c].b, Body::Grain(_))
                && normal[c] > mean * (1.0 + 1e-9)
        })
        .collect();
    let n_strong = strong.iter().filter(|&&s| s).count();
    let strong_contact_share = if active.is_empty() {
        0.0
    } else {
        n_strong as f64 / active.len() as f64
    };
    let volume = scene::assembly_volume(scene);
    let stress = scene::macroscopic_stress(scene, forces, volume);
    let grain_grain_forces: Vec<Vec3> = (0..forces.len())
        .map(|c| {
            if matches!(scene.contacts[c].b, Body::Grain(_)) {
                forces[c]
            } else {
                [0.0; 3]
            }
        })
        .collect();
    let strong_forces: Vec<Vec3> = (0..forces.len())
        .map(|c| if strong[c] { forces[c] } else { [0.0; 3] })
        .collect();
    let pressure = |s: &Sym| -(0..dim).map(|k| s[k]).sum::<f64>() / dim as f64;
    let p_all = pressure(&scene::macroscopic_stress(
        scene,
        &grain_grain_forces,
        volume,
    ));
    let strong_stress_share = if p_all != 0.0 {
        pressure(&scene::macroscopic_stress(scene, &strong_forces, volume)) / p_all
    } else {
        0.0
    };

    // With friction two collinear contacts can balance a grain; without it a
    // grain needs d + 1.
    let frictional = scene
        .contacts
        .iter()
        .any(|c| scene.contact_mu(c).is_some_and(|m| m > 0.0));
    let min_contacts = options
        .rattler_min_contacts
        .unwrap_or(if frictional { 2 } else { dim + 1 });
    let (coordination, coordination_without_rattlers, rattlers) =
        coordination(scene, &carrying, min_contacts);
    let mut fabric = [0.0; 6];
    for &c in &active {
        let t = scene::sym_outer(scene.contacts[c].normal, scene.contacts[c].normal);
        for k in 0..6 {
            fabric[k] += t[k] / active.len() as f64;
        }
    }
    let fabric_anisotropy = anisotropy(dim, &fabric);
    let chain_lengths = force_chains(scene, &normal, &strong, options);
    Ok(FrameStats {
        frame: scene.frame,
        dim,
        grains: scene.grains.len(),
        contacts: grain_grain.len(),
        force_carrying: active.len(),
        mean_normal_force: mean,
        histogram,
        tail,
        strong_contact_share,
        strong_stress_share,
        coordination,
        coordination_without_rattlers,
        rattlers,
        rattler_min_contacts: min_contacts,
        fabric,
        fabric_anisotropy,
        stress,
        chain_lengths,
    })
}

/// Histogram of x (already divided by its mean) and the exponential tail fit.
pub fn distribution(x: &[f64], bin_width: f64) -> (Histogram, Option<TailFit>) {
    let xmax = x.iter().cloned().fold(0.0, f64::max);
    let n_bins = ((xmax / bin_width).floor() as usize + 1).max(1);
    let edges: Vec<f64> = (0..=n_bins).map(|i| i as f64 * bin_width).collect();
    let mut counts = vec![0usize; n_bins];
    for &v in x {
        let i = ((v / bin_width).floor() as usize).min(n_bins - 1);
        counts[i] += 1;
    }
    let total = x.len().max(1) as f64;
    let density: Vec<f64> = counts
        .iter()
        .map(|&c| c as f64 / (total * bin_width))
        .collect();
    // Weighted least squares of ln P = ln A − rate·x over non-empty bins above the mean.
    let (mut sw, mut sx, mut sy, mut sxx, mut sxy, mut used) = (0.0, 0.0, 0.0, 0.0, 0.0, 0);
    for i in 0..n_bins {
        let centre = 0.5 * (edges[i] + edges[i + 1]);
        if edges[i] < 1.0 - 1e-12 || counts[i] == 0 {
            continue;
        }
        let w = counts[i] as f64;
        let y = density[i].ln();
        sw += w;
        sx += w * centre;
        sy += w * y;
        sxx += w * centre * centre;
        sxy += w * centre * y;
        used += 1;
    }
    let det = sw * sxx - sx * sx;
    let tail = (used >= 2 && det > 0.0).then(|| {
        let slope = (sw * sxy - sx * sy) / det;
        let intercept = (sy - slope * sx) / sw;
        TailFit {
            rate: -slope,
            amplitude: intercept.exp(),
            bins: used,
        }
    });
    (
        Histogram {
            edges,
            counts,
            density,
        },
        tail,
    )
}

/// (Z, Z without rattlers, number of rattlers).
fn coordination(scene: &Scene, carrying: &[bool], min_contacts: usize) -> (f64, f64, usize) {
    let n = scene.grains.len();
    if n == 0 {
        return (0.0, 0.0, 0);
    }
    let count = |alive: &[bool]| {
        let mut k = vec![0usize; n];
        for (c, contact) in scene.contacts.iter().enumerate() {
            if !carrying[c] || !alive[contact.a] {
                continue;
            }
            match contact.b {
                Body::Grain(b) if alive[b] => {
                    k[contact.a] += 1;
                    k[b] += 1;
                }
                Body::Grain(_) => {}
                Body::Wall(_) => k[contact.a] += 1,
            }
        }
        k
    };
    let all = vec![true; n];
    let k_all = count(&all);
    let z = k_all.iter().sum::<usize>() as f64 / n as f64;
    // Removing a rattler can turn its neighbours into rattlers: repeat.
    let mut alive = all;
    loop {
        let k = count(&alive);
        let mut changed = false;
        for g in 0..n {
            if alive[g] && k[g] < min_contacts {
                alive[g] = false;
                changed = true;
            }
        }
        if !changed {
            let kept = alive.iter().filter(|&&a| a).count();
            let z_kept = if kept == 0 {
                0.0
            } else {
                (0..n).filter(|&g| alive[g]).map(|g| k[g]).sum::<usize>() as f64 / kept as f64
            };
            return (z, z_kept, n - kept);
        }
    }
}

/// Deviatoric anisotropy of a fabric tensor (see [`FrameStats::fabric_anisotropy`]).
pub(crate) fn anisotropy(dim: usize, fabric: &Sym) -> f64 {
    let trace: f64 = (0..dim).map(|k| fabric[k]).sum();
    if trace == 0.0 {
        return 0.0;
    }
    let mut dev = *fabric;
    for d in dev.iter_mut().take(dim) {
        *d -= trace / dim as f64;
    }
    // F′:F′ with off-diagonal terms counted twice.
    let comps = scene::sym::components(dim);
    let norm2: f64 = comps
        .iter()
        .map(|&k| {
            if k < 3 {
                dev[k] * dev[k]
            } else {
                2.0 * dev[k] * dev[k]
            }
        })
        .sum();
    if dim == 2 {
        // a′ = 4F′ has eigenvalues ±a, so a = √(a′:a′ / 2).
        (16.0 * norm2 / 2.0).sqrt()
    } else {
        let c = 15.0 / 2.0;
        (1.5 * c * c * norm2).sqrt()
    }
}

/// Force chains: starting from the strongest unused strong contact, a chain
/// grows at both ends through strong grain–grain contacts whose branch vector
/// turns by at most the tolerance angle from the previous one, taking the
/// largest force when several qualify. Each contact joins at most one chain.
/// Returns the lengths (in contacts) of chains with at least
/// `min_chain_contacts` contacts.
fn force_chains(scene: &Scene, normal: &[f64], strong: &[bool], options: &Options) -> Vec<usize> {
    let cos_tol = options.chain_angle_deg.to_radians().cos();
    let mut by_grain: Vec<Vec<usize>> = vec![Vec::new(); scene.grains.len()];
    for (c, contact) in scene.contacts.iter().enumerate() {
        if let (true, Body::Grain(b)) = (strong[c], contact.b) {
            by_grain[contact.a].push(c);
            by_grain[b].push(c);
        }
    }
    let other = |c: usize, g: usize| -> usize {
        let contact = &scene.contacts[c];
        match contact.b {
            Body::Grain(b) if contact.a == g => b,
            _ => contact.a,
        }
    };
    let unit = |from: usize, to: usize| -> Vec3 {
        let d = scene::sub(scene.grains[to].position, scene.grains[from].position);
        let l = scene::norm(d);
        [d[0] / l, d[1] / l, d[2] / l]
    };
    let mut used = vec![false; scene.contacts.len()];
    let mut order: Vec<usize> = (0..scene.contacts.len()).filter(|&c| strong[c]).collect();
    order.sort_by(|&x, &y| normal[y].total_cmp(&normal[x]));
    let mut lengths = Vec::new();
    for start in order {
        if used[start] {
            continue;
        }
        used[start] = true;
        let Body::Grain(b0) = scene.contacts[start].b else {
            continue;
        };
        let a0 = scene.contacts[start].a;
        let mut length = 1;
        // Grow forward from b0 (direction a0→b0), then backward from a0 (b0→a0).
        for (mut prev, mut tip) in [(a0, b0), (b0, a0)] {
            loop {
                let dir = unit(prev, tip);
                let next = by_grain[tip]
                    .iter()
                    .copied()
                    .filter(|&c| !used[c])
                    .filter(|&c| scene::dot(dir, unit(tip, other(c, tip))) >= cos_tol)
                    .max_by(|&x, &y| normal[x].total_cmp(&normal[y]));
                let Some(c) = next else { break };
                used[c] = true;
                length += 1;
                prev = tip;
                tip = other(c, tip);
            }
        }
        if length >= options.min_chain_contacts {
            lengths.push(length);
        }
    }
    lengths.sort_unstable_by(|a, b| b.cmp(a));
    lengths
}

/// Column names of [`csv_row`].
pub fn csv_header(dim: usize) -> Vec<String> {
    let mut h: Vec<String> = [
        "frame",
        "grains",
        "contacts",
        "force_carrying",
        "mean_normal_force",
        "tail_rate",
        "strong_contact_share",
        "strong_stress_share",
        "coordination",
        "coordination_without_rattlers",
        "rattlers",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let names = ["xx", "yy", "zz", "xy", "xz", "yz"];
    for &k in scene::sym::components(dim) {
        h.push(format!("fabric_{}", names[k]));
    }
    h.push("fabric_anisotropy".into());
    for &k in scene::sym::components(dim) {
        h.push(format!("stress_{}", names[k]));
    }
    h.extend(["chains", "mean_chain_length", "longest_chain"].map(String::from));
    h
}

/// One CSV row per frame (see [`csv_header`]).
pub fn csv_row(s: &FrameStats) -> Vec<String> {
    let mut r = vec![
        s.frame.map(|f| f.to_string()).unwrap_or_default(),
        s.grains.to_string(),
        s.contacts.to_string(),
        s.force_carrying.to_string(),
        s.mean_normal_force.to_string(),
        s.tail
            .as_ref()
            .map(|t| t.rate.to_string())
            .unwrap_or_default(),
        s.strong_contact_share.to_string(),
        s.strong_stress_share.to_string(),
        s.coordination.to_string(),
        s.coordination_without_rattlers.to_string(),
        s.rattlers.to_string(),
    ];
    for &k in scene::sym::components(s.dim) {
        r.push(s.fabric[k].to_string());
    }
    r.push(s.fabric_anisotropy.to_string());
    for &k in scene::sym::components(s.dim) {
        r.push(s.stress[k].to_string());
    }
    let n = s.chain_lengths.len();
    r.push(n.to_string());
    r.push(if n == 0 {
        String::new()
    } else {
        (s.chain_lengths.iter().sum::<usize>() as f64 / n as f64).to_string()
    });
    r.push(
        s.chain_lengths
            .first()
            .map(|l| l.to_string())
            .unwrap_or_default(),
    );
    r
}

/// A readable multi-line summary of one frame.
pub fn summary(s: &FrameStats) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let names = ["xx", "yy", "zz", "xy", "xz", "yz"];
    let tensor = |t: &Sym| {
        scene::sym::components(s.dim)
            .iter()
            .map(|&k| format!("{}={:.4e}", names[k], t[k]))
            .collect::<Vec<_>>()
            .join(" ")
    };
    if let Some(f) = s.frame {
        let _ = writeln!(out, "frame {f}");
    }
    let _ = writeln!(
        out,
        "  {} grains, {} grain-grain contacts ({} carrying force), mean normal force {:.4e}",
        s.grains, s.contacts, s.force_carrying, s.mean_normal_force
    );
    match &s.tail {
        Some(t) => {
            let _ = writeln!(
                out,
                "  P(f/<f>) tail above the mean ~ exp(-{:.3} f/<f>) ({} bins)",
                t.rate, t.bins
            );
        }
        None => {
            let _ = writeln!(out, "  P(f/<f>) tail: too few forces above the mean to fit");
        }
    }
    let _ = writeln!(
        out,
        "  strong network (f > <f>): {:.1} % of contacts carrying {:.1} % of the mean stress",
        100.0 * s.strong_contact_share,
        100.0 * s.strong_stress_share
    );
    let _ = writeln!(
        out,
        "  coordination Z = {:.3}; without the {} rattlers (< {} contacts) Z = {:.3}",
        s.coordination, s.rattlers, s.rattler_min_contacts, s.coordination_without_rattlers
    );
    let _ = writeln!(
        out,
        "  fabric {}  anisotropy a = {:.4}",
        tensor(&s.fabric),
        s.fabric_anisotropy
    );
    let _ = writeln!(out, "  macroscopic stress [Pa] {}", tensor(&s.stress));
    let n = s.chain_lengths.len();
    if n == 0 {
        let _ = writeln!(out, "  force chains: none");
    } else {
        let mut dist: std::collections::BTreeMap<usize, usize> = Default::default();
        for &l in &s.chain_lengths {
            *dist.entry(l).or_default() += 1;
        }
        let d: Vec<String> = dist.iter().map(|(l, c)| format!("{l}:{c}")).collect();
        let _ = writeln!(
            out,
            "  force chains: {n}, longest {} contacts; length:count {}",
            s.chain_lengths[0],
            d.join(" ")
        );
    }
    out
}
