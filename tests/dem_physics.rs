//! Analytic checks of the DEM: Hertz law and collision, restitution, oblique
//! impact, a disk on an incline, energy and momentum conservation.

use grainforce::dem::law::{effective_shear, effective_young, ContactLaw, Interaction};
use grainforce::dem::sim::{Motion, System, WallShape};
use rand::{Rng, SeedableRng};
use std::f64::consts::PI;

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

/// Two equal grains approaching head-on along x with relative speed `v`.
fn pair(dim: usize, law: Interaction, r: f64, density: f64, v: f64, dt: f64) -> System {
    let x = vec![[0.0, 0.0, 0.0], [2.0 * r + 1e-6, 0.0, 0.0]];
    let mut s = System::new(dim, x, vec![r, r], density, law, [0.0; 3], dt, 0.5 * r);
    s.v[0] = [0.5 * v, 0.0, 0.0];
    s.v[1] = [-0.5 * v, 0.0, 0.0];
    s.evaluate();
    s
}

fn overlap(s: &System) -> f64 {
    s.radius[0] + s.radius[1] - (s.x[1][0] - s.x[0][0])
}

#[test]
fn hertz_force_overlap_law_peak_overlap_and_duration() {
    let (e, nu, r, rho, v): (f64, f64, f64, f64, f64) = (1e8, 0.3, 0.01, 2500.0, 1.0);
    let estar = effective_young(e, nu, e, nu);
    let gstar = effective_shear(e, nu, e, nu);
    let law = Interaction::new(ContactLaw::Hertz, estar, gstar, 1.0, 0.0, 0.0);
    let m = rho * 4.0 / 3.0 * PI * r.powi(3);
    let (mstar, rstar) = (0.5 * m, 0.5 * r);
    let delta_max = (15.0 * mstar * v * v / (16.0 * estar * rstar.sqrt())).powf(0.4);
    let duration = 2.868 * (mstar * mstar / (rstar * estar * estar * v)).powf(0.2);
    let mut s = pair(3, law, r, rho, v, duration / 4000.0);
    let (mut peak, mut start, mut end) = (0.0f64, None, None);
    let mut checked = 0;
    for _ in 0..20_000 {
        s.step();
        let d = overlap(&s);
        if d > 0.0 {
            start.get_or_insert(s.time);
            peak = peak.max(d);
            let expected = 4.0 / 3.0 * estar * rstar.sqrt() * d.powf(1.5);
            let got = norm(s.f[0]);
            assert!(
                (got - expected).abs() <= 1e-12 * expected,
                "force {got} vs Hertz {expected} at overlap {d}"
            );
            assert!(
                s.f[0][0] < 0.0,
                "the force must push grain 0 away from grain 1"
            );
            checked += 1;
        } else if start.is_some() && end.is_none() {
            end = Some(s.time);
            break;
        }
    }
    assert!(checked > 1000);
    assert!(
        (peak - delta_max).abs() / delta_max < 2e-3,
        "peak overlap {peak} vs analytic {delta_max}"
    );
    let measured = end.unwrap() - start.unwrap();
    assert!(
        (measured - duration).abs() / duration < 5e-3,
        "contact duration {measured} vs analytic {duration}"
    );
    // Elastic: the grains leave with their approach speed.
    let rel = s.v[0][0] - s.v[1][0];
    assert!((rel + v).abs() < 1e-4, "rebound speed {rel}");
}

fn restitution(dim: usize, law: ContactLaw, e: f64) -> f64 {
    let (r, rho, v): (f64, f64, f64) = (0.005, 1000.0, 0.5);
    let it = match law {
        ContactLaw::Linear => Interaction::new(law, 1e5, 1e5, e, 0.0, 0.0),
        ContactLaw::Hertz => {
            let estar = effective_young(1e7, 0.3, 1e7, 0.3);
            Interaction::new(law, estar, effective_shear(1e7, 0.3, 1e7, 0.3), e, 0.0, 0.0)
        }
    };
    let m = if dim == 2 {
        rho * PI * r * r
    } else {
        rho * 4.0 / 3.0 * PI * r.powi(3)
    };
    // A step well below the contact time of either law at this speed.
    let dt = match law {
        ContactLaw::Linear => 0.005 * (m / 1e5).sqrt(),
        ContactLaw::Hertz => 2e-7,
    };
    let mut s = pair(dim, it, r, rho, v, dt);
    let mut touched = false;
    for _ in 0..200_000 {
        s.step();
        if overlap(&s) > 0.0 {
            touched = true;
        } else if touched {
            break;
        }
    }
    assert!(touched);
    -(s.v[0][0] - s.v[1][0]) / v
}

#[test]
fn binary_collision_restitution_matches_the_configured_coefficient() {
    for (dim, law) in [
        (2, ContactLaw::Linear),
        (3, ContactLaw::Hertz),
        (3, ContactLaw::Linear),
    ] {
        for e in [0.3, 0.7, 0.95] {
            let got = restitution(dim, law, e);
            assert!(
                (got - e).abs() < 2e-3,
                "{law:?} {dim}D: restitution {got} for configured {e}"
            );
        }
    }
}

/// A sphere hits a rigid frictional floor obliquely.
fn oblique(tangential: f64, normal: f64, mu: f64, e: f64) -> ([f64; 3], [f64; 3]) {
    let (young, nu, r, rho) = (1e8, 0.3, 0.01, 2500.0);
    let grain = Interaction::new(ContactLaw::Hertz, 1.0, 1.0, 1.0, 0.0, 0.0);
    let floor = Interaction::new(
        ContactLaw::Hertz,
        effective_young(young, nu, f64::INFINITY, 0.0),
        effective_shear(young, nu, f64::INFINITY, 0.0),
        e,
        0.0,
        mu,
    );
    let mut s = System::new(
        3,
        vec![[0.0, r + 1e-6, 0.0]],
        vec![r],
        rho,
        grain,
        [0.0; 3],
        1e-7,
        0.5 * r,
    );
    s.add_wall(
        "bottom",
        WallShape::Plane {
            normal: [0.0, 1.0, 0.0],
        },
        [0.0; 3],
        [0.0; 3],
        Motion::Prescribed,
        floor,
        0.0,
    );
    s.v[0] = [tangential, -normal, 0.0];
    s.evaluate();
    let mut touched = false;
    for _ in 0..1_000_000 {
        s.step();
        if s.x[0][1] < r {
            touched = true;
        } else if touched {
            break;
        }
    }
    assert!(touched);
    (s.v[0], s.w[0])
}

#[test]
fn oblique_impact_gross_sliding_and_sticking() {
    let (mu, e, vn, r) = (0.3, 0.8, 1.0, 0.01);
    // Steep incidence: the contact slides throughout, so the tangential
    // impulse is μ times the normal one (Chung & Ooi, test 3/4 sliding branch).
    let (v, w) = oblique(5.0, vn, mu, e);
    assert!(
        (v[1] - e * vn).abs() / (e * vn) < 3e-3,
        "normal rebound {}",
        v[1]
    );
    let dvt = 5.0 - v[0];
    let expected = mu * (1.0 + e) * vn;
    assert!(
        (dvt - expected).abs() / expected < 5e-3,
        "Δv_t {dvt} vs {expected}"
    );
    let spin = 5.0 * mu * (1.0 + e) * vn / (2.0 * r);
    assert!(
        (w[2] + spin).abs() / spin < 5e-3,
        "spin {} vs −{spin}",
        w[2]
    );
    // Shallow incidence: the contact sticks, the tangential impulse stays
    // below the Coulomb bound and the grain leaves rolling-ish (contact-point
    // slip far below the incident tangential speed).
    let (v, w) = oblique(0.1, vn, mu, e);
    let dvt = 0.1 - v[0];
    assert!(dvt.abs() < mu * (1.0 + e) * vn);
    let slip = v[0] + w[2] * r;
    assert!(slip.abs() < 0.1, "contact-point slip {slip}");
}

/// Disk of radius r on a floor, gravity tilted by θ (downhill +x); returns
/// the distance travelled in `t` and the final contact-point slip speed.
fn incline(theta: f64, mu: f64, t: f64) -> (f64, f64, f64) {
    let (r, rho, k, g) = (0.01, 1000.0, 1e6, 9.81);
    let m = rho * PI * r * r;
    let grain = Interaction::new(ContactLaw::Linear, k, k, 0.3, 0.0, 0.0);
    let floor = Interaction::new(ContactLaw::Linear, k, k, 0.3, 1.0, mu);
    let gravity = [g * theta.sin(), -g * theta.cos(), 0.0];
    let delta = m * g * theta.cos() / k;
    let dt = 0.02 * (m / k).sqrt();
    let mut s = System::new(
        2,
        vec![[0.0, r - delta, 0.0]],
        vec![r],
        rho,
        grain,
        gravity,
        dt,
        0.5 * r,
    );
    s.add_wall(
        "bottom",
        WallShape::Plane {
            normal: [0.0, 1.0, 0.0],
        },
        [0.0; 3],
        [0.0; 3],
        Motion::Prescribed,
        floor,
        0.0,
    );
    s.evaluate();
    let steps = (t / dt).round() as usize;
    for _ in 0..steps {
        s.step();
    }
    (s.x[0][0], s.v[0][0] + s.w[0][2] * r, s.time)
}

#[test]
fn disk_on_incline_rolls_below_and_slips_above_tan_theta_3mu() {
    let (mu, g) = (0.2, 9.81);
    // tan θ = 0.25 < 3μ: rolls without slipping, x = g t² sin θ / 3.
    let theta = 0.25f64.atan();
    let (x, slip, t) = incline(theta, mu, 0.1);
    let expected = g * t * t * theta.sin() / 3.0;
    assert!(
        (x - expected).abs() / expected < 5e-3,
        "rolling: {x} vs {expected}"
    );
    assert!(slip.abs() < 1e-3 * (g * t), "rolling disk slips at {slip}");
    // tan θ = 0.9 > 3μ: slips, x = g t² (sin θ − μ cos θ) / 2.
    let theta = 0.9f64.atan();
    let (x, slip, t) = incline(theta, mu, 0.1);
    let expected = 0.5 * g * t * t * (theta.sin() - mu * theta.cos());
    assert!(
        (x - expected).abs() / expected < 5e-3,
        "slipping: {x} vs {expected}"
    );
    assert!(
        slip > 0.1 * g * t * theta.sin(),
        "slipping disk does not slip ({slip})"
    );
    // Just above and below the threshold the regimes switch.
    let below = incline((0.9 * 3.0 * mu).atan(), mu, 0.05).1;
    let above = incline((1.2 * 3.0 * mu).atan(), mu, 0.05).1;
    assert!(
        below.abs() < 1e-3 && above > 1e-2,
        "slip speeds {below} / {above}"
    );
}

fn gas(dim: usize, law: Interaction, n_side: usize, seed: u64, walls: bool) -> System {
    let r = 0.005;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut x = Vec::new();
    let mut radii = Vec::new();
    let nz = if dim == 3 { n_side } else { 1 };
    for i in 0..n_side {
        for j in 0..n_side {
            for k in 0..nz {
                let p = |c: usize| (c as f64 + 0.5) * 2.6 * r;
                x.push([p(i), p(j), if dim == 3 { p(k) } else { 0.0 }]);
                radii.push(r * rng.gen_range(0.8..1.0));
            }
        }
    }
    let m = 1000.0 * PI * r * r;
    let dt = 0.01 * (m / 1e5f64).sqrt();
    let mut s = System::new(dim, x, radii, 1000.0, law, [0.0; 3], dt, 0.4 * r);
    for v in s.v.iter_mut() {
        for c in v.iter_mut().take(dim) {
            *c = rng.gen_range(-0.5..0.5);
        }
    }
    if walls {
        let side = n_side as f64 * 2.6 * r;
        for axis in 0..dim {
            for (at, sign) in [(0.0, 1.0), (side, -1.0)] {
                let mut normal = [0.0; 3];
                normal[axis] = sign;
                let mut p = [0.0; 3];
                p[axis] = at;
                s.add_wall(
                    &format!("w{axis}{at}"),
                    WallShape::Plane { normal },
                    p,
                    [0.0; 3],
                    Motion::Prescribed,
                    law,
                    0.0,
                );
            }
        }
    }
    s.evaluate();
    s
}

#[test]
fn energy_is_conserved_without_damping_or_friction() {
    for (dim, law) in [
        (
            2,
            Interaction::new(ContactLaw::Linear, 1e5, 1e5, 1.0, 0.0, 0.0),
        ),
        (
            3,
            Interaction::new(ContactLaw::Hertz, 1e7, 4e6, 1.0, 0.0, 0.0),
        ),
    ] {
        let mut s = gas(dim, law, 5, 7, true);
        let e0 = s.kinetic_energy() + s.potential_energy();
        let mut worst: f64 = 0.0;
        let mut collisions = 0;
        for _ in 0..20_000 {
            s.step();
            if s.contact_count > 0 {
                collisions += 1;
            }
            let e = s.kinetic_energy() + s.potential_energy();
            worst = worst.max((e - e0).abs() / e0);
        }
        assert!(
            collisions > 1000,
            "{dim}D: too few steps with contacts ({collisions})"
        );
        assert!(worst < 1e-4, "{dim}D: energy drift {worst}");
    }
}

#[test]
fn momentum_is_conserved_to_round_off() {
    let law = Interaction::new(ContactLaw::Linear, 1e5, 8e4, 0.5, 0.5, 0.5);
    for dim in [2, 3] {
        let mut s = gas(dim, law, 4, 3, false);
        // Converge on the centre so that grains collide.
        let c = 2.0 * 2.6 * 0.005;
        for i in 0..s.len() {
            for k in 0..dim {
                s.v[i][k] += -2.0 * (s.x[i][k] - c);
            }
        }
        s.evaluate();
        let p0 = s.momentum();
        let l0 = s.angular_momentum();
        let scale: f64 = (0..s.len()).map(|i| s.mass[i] * norm(s.v[i])).sum();
        let lscale: f64 = (0..s.len())
            .map(|i| s.mass[i] * norm(s.v[i]) * norm(s.x[i]))
            .sum();
        let mut contacts = 0;
        for _ in 0..20_000 {
            s.step();
            contacts += s.contact_count;
        }
        assert!(
            contacts > 500,
            "{dim}D: too few collisions ({contacts} contact-steps)"
        );
        let p = s.momentum();
        let l = s.angular_momentum();
        for k in 0..3 {
            assert!(
                (p[k] - p0[k]).abs() < 1e-13 * scale,
                "{dim}D momentum {p:?} vs {p0:?}"
            );
            assert!(
                (l[k] - l0[k]).abs() < 1e-12 * lscale,
                "{dim}D angular momentum {l:?} vs {l0:?}"
            );
        }
    }
}

/// Walls only look at grains that were within the skin of them at the last
/// neighbour-list build: a wall that moves (with its velocity, or moved by
/// hand) must still find every grain it overlaps, and no other.
#[test]
fn moving_and_moved_walls_find_exactly_the_grains_they_overlap() {
    let law = Interaction::new(ContactLaw::Linear, 1e5, 1e5, 0.5, 0.0, 0.5);
    let r = 1e-3;
    // A row of grains at rest; a plane rises under them from ten skins below
    // and a ball sweeps along above them.
    let x: Vec<[f64; 3]> = (0..8).map(|k| [3.0 * r * k as f64, 0.0, 0.0]).collect();
    let skin = 0.3 * r;
    let mut s = System::new(3, x, vec![r; 8], 2500.0, law, [0.0; 3], 1e-6, skin);
    let plane = s.add_wall(
        "floor",
        WallShape::Plane {
            normal: [0.0, 1.0, 0.0],
        },
        [0.0, -r - 10.0 * skin, 0.0],
        [0.0, 0.5, 0.0],
        Motion::Prescribed,
        law,
        0.0,
    );
    let ball = s.add_wall(
        "ball",
        WallShape::Ball { radius: 2.0 * r },
        [-10.0 * r, 2.9 * r, 0.0],
        [20.0, 0.0, 0.0],
        Motion::Prescribed,
        law,
        0.0,
    );
    s.evaluate();
    // Every overlap, found by brute force (grains pushed by the walls may
    // also touch each other).
    let touching = |s: &System| -> usize {
        let mut n = 0;
        for i in 0..s.len() {
            for j in i + 1..s.len() {
                let d = norm([
                    s.x[j][0] - s.x[i][0],
                    s.x[j][1] - s.x[i][1],
                    s.x[j][2] - s.x[i][2],
                ]);
                if d < s.radius[i] + s.radius[j] {
                    n += 1;
                }
            }
        }
        for (x, r) in s.x.iter().zip(&s.radius) {
            if x[1] - r < s.walls[plane].position[1] {
                n += 1;
            }
            let c = s.walls[ball].position;
            let d = norm([x[0] - c[0], x[1] - c[1], x[2] - c[2]]);
            if d < r + 2.0 * r {
                n += 1;
            }
        }
        n
    };
    let (mut plane_hits, mut ball_hits) = (0, 0);
    for step in 0..2000 {
        if step == 1000 {
            // Moved by hand far beyond the skin: from below the grains to into them.
            s.walls[plane].velocity = [0.0; 3];
            s.walls[plane].position = [0.0, -r - 20.0 * skin, 0.0];
            s.step();
            s.walls[plane].position = [0.0, -0.9 * r, 0.0];
            s.evaluate();
        } else {
            s.step();
        }
        assert_eq!(s.contact_count, touching(&s), "step {step}");
        if s.walls[plane].force[1].abs() > 0.0 {
            plane_hits += 1;
        }
        if norm(s.walls[ball].force) > 0.0 {
            ball_hits += 1;
        }
    }
    assert!(
        plane_hits > 100 && ball_hits > 100,
        "{plane_hits} {ball_hits}"
    );
}
