//! Synthetic scenes with exactly known geometry, for tests and benchmarks of
//! the image pipeline: random packings of disks where every contact is an
//! exact tangency and every non-contact gap is clearly open, and the matching
//! of a detection back to such a scene.

use super::contacts::{ContactBody, PixelContact};
use super::detect::Disk;
use super::elastic::Elasticity;
use super::PixelFrame;
use crate::error::{Error, Result};
use crate::scene::{Body, Contact, Grain, Scene};
use rand::{Rng, SeedableRng};

#[derive(Debug, Clone)]
pub struct PackingSpec {
    /// The box [m] that holds the disks: [0, width] × [0, height].
    pub width: f64,
    pub height: f64,
    pub radius_min: f64,
    pub radius_max: f64,
    /// Stop after this many disks (fewer if the box fills up).
    pub count: usize,
    /// Smallest gap [m] between disks that do not touch, so that contacts are
    /// unambiguous.
    pub min_gap: f64,
    pub seed: u64,
}

/// A packing grown by placing each new disk tangent to two touching-distance
/// neighbours (or one, when that fails), rejecting any placement that overlaps
/// or leaves a gap smaller than `min_gap`. Contacts are exactly the tangent
/// pairs; each contact point is the tangency point and the normal points from
/// `a` to `b`. Stresses are zero.
pub fn touching_disks(spec: &PackingSpec) -> Result<Scene> {
    grow(spec, &mut |rng| {
        rng.gen_range(spec.radius_min..=spec.radius_max)
    })
}

/// As [`touching_disks`], with each radius drawn from `sizes` (equally
/// likely), e.g. a bidisperse packing; `spec`'s radius range must cover them.
pub fn touching_disks_of_sizes(spec: &PackingSpec, sizes: &[f64]) -> Result<Scene> {
    if sizes.is_empty()
        || sizes
            .iter()
            .any(|&r| !(r >= spec.radius_min && r <= spec.radius_max))
    {
        return Err(Error::Invalid(
            "the sizes must lie in the packing's radius range".into(),
        ));
    }
    grow(spec, &mut |rng| sizes[rng.gen_range(0..sizes.len())])
}

fn grow(
    spec: &PackingSpec,
    radius: &mut dyn FnMut(&mut rand_chacha::ChaCha8Rng) -> f64,
) -> Result<Scene> {
    if !(spec.radius_min > 0.0 && spec.radius_max >= spec.radius_min && spec.min_gap >= 0.0) {
        return Err(Error::Invalid("bad packing radii or gap".into()));
    }
    if spec.width < 2.0 * spec.radius_max || spec.height < 2.0 * spec.radius_max {
        return Err(Error::Invalid(
            "the packing box is smaller than one disk".into(),
        ));
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(spec.seed);
    let mut disks: Vec<([f64; 2], f64)> = Vec::new();
    let mut touching: Vec<(usize, usize)> = Vec::new();
    let r = radius(&mut rng);
    disks.push(([spec.width / 2.0, spec.height / 2.0], r));
    let attempts = 400 * spec.count.max(1);
    let eps = 1e-9 * spec.radius_max;
    for _ in 0..attempts {
        if disks.len() >= spec.count {
            break;
        }
        let r = radius(&mut rng);
        let i = rng.gen_range(0..disks.len());
        let (ci, ri) = disks[i];
        // Partner: another disk close enough that the new one can touch both.
        let partners: Vec<usize> = (0..disks.len())
            .filter(|&j| j != i && dist(disks[j].0, ci) < ri + disks[j].1 + 2.0 * r)
            .collect();
        let (centre, neighbours) = if !partners.is_empty() && rng.gen_bool(0.9) {
            let j = partners[rng.gen_range(0..partners.len())];
            let (cj, rj) = disks[j];
            let Some(points) = circle_intersections(ci, ri + r, cj, rj + r) else {
                continue;
            };
            (points[rng.gen_range(0..2)], vec![i, j])
        } else {
            let a = rng.gen_range(0.0..std::f64::consts::TAU);
            (
                [ci[0] + (ri + r) * a.cos(), ci[1] + (ri + r) * a.sin()],
                vec![i],
            )
        };
        if centre[0] - r < 0.0
            || centre[1] - r < 0.0
            || centre[0] + r > spec.width
            || centre[1] + r > spec.height
        {
            continue;
        }
        let fits = disks.iter().enumerate().all(|(k, &(ck, rk))| {
            let gap = dist(ck, centre) - rk - r;
            if neighbours.contains(&k) {
                gap.abs() < eps * 10.0
            } else {
                gap >= spec.min_gap
            }
        });
        if !fits {
            continue;
        }
        let new = disks.len();
        disks.push((centre, r));
        for k in neighbours {
            touching.push((k, new));
        }
    }
    let mut scene = Scene::new(2);
    for (k, &(c, r)) in disks.iter().enumerate() {
        let mut g = Grain::new(
            k.to_string(),
            [c[0], c[1], 0.0],
            std::f64::consts::PI * r * r,
            [0.0; 6],
        );
        g.radius = Some(r);
        scene.grains.push(g);
    }
    touching.sort();
    for (n, &(a, b)) in touching.iter().enumerate() {
        let (ca, ra) = disks[a];
        let (cb, _) = disks[b];
        let d = dist(ca, cb);
        let normal = [(cb[0] - ca[0]) / d, (cb[1] - ca[1]) / d];
        scene.contacts.push(Contact {
            id: n.to_string(),
            a,
            b: Body::Grain(b),
            point: [ca[0] + ra * normal[0], ca[1] + ra * normal[1], 0.0],
            normal: [normal[0], normal[1], 0.0],
            mu: None,
        });
    }
    Ok(scene)
}

/// Gives every grain a random homogeneous stress whose strain components
/// (under `elasticity`) are uniform in [−strain, strain].
pub fn assign_random_stresses(scene: &mut Scene, elasticity: &Elasticity, strain: f64, seed: u64) {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    for g in &mut scene.grains {
        let e = [
            rng.gen_range(-strain..=strain),
            rng.gen_range(-strain..=strain),
            rng.gen_range(-strain..=strain),
        ];
        let s = elasticity.stress_from_strain(e);
        g.stress = [s[0], s[1], 0.0, s[2], 0.0, 0.0];
    }
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// The two intersection points of two circles, if they intersect.
fn circle_intersections(c0: [f64; 2], r0: f64, c1: [f64; 2], r1: f64) -> Option<[[f64; 2]; 2]> {
    let d = dist(c0, c1);
    if d <= 0.0 || d > r0 + r1 || d < (r0 - r1).abs() {
        return None;
    }
    let a = (r0 * r0 - r1 * r1 + d * d) / (2.0 * d);
    let h = (r0 * r0 - a * a).max(0.0).sqrt();
    let u = [(c1[0] - c0[0]) / d, (c1[1] - c0[1]) / d];
    let m = [c0[0] + a * u[0], c0[1] + a * u[1]];
    Some([
        [m[0] - h * u[1], m[1] + h * u[0]],
        [m[0] + h * u[1], m[1] - h * u[0]],
    ])
}

/// Two detected disks in contact, the smaller index first.
pub type DiskPair = (usize, usize);

/// A detection matched to the scene it was rendered from, for scoring a
/// detector against exact geometry.
#[derive(Debug, Clone, Default)]
pub struct DetectionMatch {
    /// The detected disk of each grain, when one lay close enough.
    pub disk_of_grain: Vec<Option<usize>>,
    /// Each match in grain order: grain, disk, centre distance [px] and
    /// detected minus true radius [px].
    pub pairs: Vec<(usize, usize, f64, f64)>,
    /// Detected disks that match no grain.
    pub unmatched_disks: Vec<usize>,
}

/// Matches grains to detected disks, grain by grain: the nearest disk not yet
/// taken, when its centre lies within `max_distance(radius in px)` px of the
/// grain's (grains without a radius count as radius 0).
pub fn match_disks(
    scene: &Scene,
    frame: &PixelFrame,
    disks: &[Disk],
    max_distance: impl Fn(f64) -> f64,
) -> DetectionMatch {
    let mut taken = vec![false; disks.len()];
    let mut disk_of_grain = vec![None; scene.grains.len()];
    let mut pairs = Vec::new();
    for (g, grain) in scene.grains.iter().enumerate() {
        let p = frame.to_pixel([grain.position[0], grain.position[1]]);
        let r = grain.radius.unwrap_or(0.0) * frame.px_per_m;
        let nearest = (disks.iter().enumerate())
            .filter(|(k, _)| !taken[*k])
            .map(|(k, d)| (k, (d.x - p[0]).hypot(d.y - p[1])))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((k, distance)) = nearest {
            if distance < max_distance(r) {
                taken[k] = true;
                disk_of_grain[g] = Some(k);
                pairs.push((g, k, distance, disks[k].r - r));
            }
        }
    }
    DetectionMatch {
        disk_of_grain,
        pairs,
        unmatched_disks: (0..disks.len()).filter(|&k| !taken[k]).collect(),
    }
}

impl DetectionMatch {
    /// The scene's grain–grain contacts between matched grains and the
    /// detected disk–disk contacts, both as disk pairs (smaller index first).
    pub fn contact_pairs(
        &self,
        scene: &Scene,
        found: &[PixelContact],
    ) -> (Vec<DiskPair>, Vec<DiskPair>) {
        let key = |a: usize, b: usize| (a.min(b), a.max(b));
        let disk = |g: usize| self.disk_of_grain.get(g).copied().flatten();
        let truth = (scene.contacts.iter())
            .filter_map(|c| match c.b {
                Body::Grain(b) => Some(key(disk(c.a)?, disk(b)?)),
                Body::Wall(_) => None,
            })
            .collect();
        let detected = (found.iter())
            .filter_map(|c| match c.b {
                ContactBody::Disk(b) => Some(key(c.a, b)),
                ContactBody::Wall(_) => None,
            })
            .collect();
        (truth, detected)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three touching disks; the detection finds two of them (one exact, one
    /// 1 px off and 1 px too large) and a disk far from every grain.
    #[test]
    fn disks_match_nearest_first_within_the_distance_and_contacts_pair_up() {
        let scene = touching_disks(&PackingSpec {
            width: 0.3,
            height: 0.3,
            radius_min: 0.03,
            radius_max: 0.03,
            count: 3,
            min_gap: 0.005,
            seed: 4,
        })
        .unwrap();
        assert_eq!(scene.grains.len(), 3);
        let frame = PixelFrame::around([0.0, 0.0], [0.3, 0.3], 1000.0, 10.0).unwrap();
        let at = |g: usize, dx: f64| {
            let p = frame.to_pixel([scene.grains[g].position[0], scene.grains[g].position[1]]);
            Disk {
                x: p[0] + dx,
                y: p[1],
                r: 31.0,
                support: 1.0,
                visible: 1.0,
                contrast: 1.0,
                rms: 0.1,
            }
        };
        let far = Disk {
            x: -500.0,
            ..at(0, 0.0)
        };
        let disks = [far, at(1, 1.0), at(0, 0.0)];
        let matched = match_disks(&scene, &frame, &disks, |r| 0.25 * r);
        assert_eq!(matched.disk_of_grain, vec![Some(2), Some(1), None]);
        assert_eq!(matched.unmatched_disks, vec![0]);
        let (g, k, distance, dr) = matched.pairs[1];
        assert_eq!((g, k), (1, 1));
        assert!((distance - 1.0).abs() < 1e-9 && (dr - 1.0).abs() < 1e-9);
        // Within 0.5 px only the exact disk matches.
        let strict = match_disks(&scene, &frame, &disks, |_| 0.5);
        assert_eq!(strict.disk_of_grain, vec![Some(2), None, None]);

        let found = [PixelContact {
            a: 1,
            b: ContactBody::Disk(2),
            point: [0.0; 2],
            normal: [1.0, 0.0],
            gap: 0.0,
        }];
        let (truth, detected) = matched.contact_pairs(&scene, &found);
        let touching_01 = scene
            .contacts
            .iter()
            .any(|c| (c.a, c.b) == (0, Body::Grain(1)) || (c.a, c.b) == (1, Body::Grain(0)));
        assert_eq!(truth, if touching_01 { vec![(1, 2)] } else { vec![] });
        assert_eq!(detected, vec![(1, 2)]);
    }
}
