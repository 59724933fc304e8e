//! Local inference, friction under noise, rattlers and clusters.

mod common;
use common::*;
use grainforce::infer::{infer, InferOptions, Method};
use grainforce::scene::{self, Body, Scene, Selection};

fn noisy(scene: &Scene, level: f64) -> Scene {
    let mut s = scene.clone();
    for (i, g) in s.grains.iter_mut().enumerate() {
        for (k, v) in g.stress.iter_mut().enumerate() {
            let u = ((i * 7 + k) as f64 * 12.9898).sin() * 43758.5453;
            *v *= 1.0 + level * (2.0 * u.fract().abs() - 1.0);
        }
    }
    s
}

#[test]
fn local_inference_matches_global() {
    // Coordination 4: a small region has enough equations for its boundary contacts.
    let (s, truth) = square_2d(6, 5, 0.5);
    let global = infer(&s, &InferOptions::default()).unwrap();
    let mut opts = InferOptions::default();
    // An interior region of a few grains.
    let sel = Selection::Region(vec![(0.0, 0.037), (0.0, 0.05)]);
    let mask = scene::select_subassembly(&s, &sel).unwrap();
    let chosen = mask.iter().filter(|&&m| m).count();
    assert!(chosen < s.grains.len(), "{chosen} grains chosen");
    opts.assemble.active = Some(mask.clone());
    let local = infer(&s, &opts).unwrap();
    let mut compared = 0;
    for (c, contact) in s.contacts.iter().enumerate() {
        let touches = mask[contact.a] || matches!(contact.b, Body::Grain(b) if mask[b]);
        match local.forces[c] {
            Some(f) => {
                assert!(touches);
                let g = global.forces[c].unwrap();
                let scale = scene::norm(truth[c]);
                for k in 0..3 {
                    assert!(
                        (f[k] - g[k]).abs() <= 1e-7 * scale,
                        "contact {c}: local {f:?} global {g:?} truth {:?}",
                        truth[c]
                    );
                    assert!((f[k] - truth[c][k]).abs() <= 1e-7 * scale);
                }
                compared += 1;
            }
            None => assert!(!touches, "contact {c} touches the region but has no force"),
        }
    }
    assert!(compared >= chosen);
    assert!(local.report.unknowns < global.report.unknowns);
}

#[test]
fn friction_holds_on_noisy_data_2d() {
    let (s, _) = lattice_2d(6, 5, 0.3);
    let r = infer(&noisy(&s, 0.3), &InferOptions::default()).unwrap();
    assert!(r.report.coulomb_violation <= 1e-6, "{}", r.report);
    for (c, f) in s.contacts.iter().zip(r.forces_or_zero()) {
        let fn_ = -scene::dot(f, c.normal);
        let ft = scene::norm([f[0] + fn_ * c.normal[0], f[1] + fn_ * c.normal[1], 0.0]);
        let mu = c.mu.unwrap();
        assert!(
            ft <= mu * fn_ + 1e-6 * 100.0,
            "contact {}: |f_t| {ft} > μ f_n {}",
            c.id,
            mu * fn_
        );
    }
    // qs on noisy data is not exact: this is what the constraints are for.
    assert!(r.report.stress_residual > 1e-3);
}

#[test]
fn rattlers_and_single_contacts_drop_out() {
    let (mut s, mut truth) = lattice_2d(4, 3, 0.5);
    let r = 0.004;
    // A loose grain with no contact, and one resting on a single contact.
    s.grains.push(grain("loose", [1.0, 1.0, 0.0], r, 2));
    let lone = s.grains.len();
    let top = s.grains.iter().map(|g| g.position[1]).fold(0.0, f64::max);
    s.grains.push(grain("lone", [r, top + 2.0 * r, 0.0], r, 2));
    touch(&mut s, 0, lone, Some(0.5)); // geometry is not checked; contact point is the mid-surface
    truth.push([0.0; 3]);
    let res = infer(&s, &InferOptions::default()).unwrap();
    assert_eq!(res.report.rattlers, 2, "{}", res.report);
    assert_eq!(res.report.zero_force_contacts, 1);
    assert_eq!(res.forces.last().unwrap(), &Some([0.0; 3]));
    assert!(relerr(&truth, &res.forces_or_zero()) <= 1e-8);
}

#[test]
fn disconnected_clusters_are_separate_problems() {
    let (a, ta) = lattice_2d(3, 3, 0.5);
    let (mut b, tb) = lattice_2d(4, 2, 0.5);
    // Shift the second packing away (1 m) and merge the scenes.
    for g in &mut b.grains {
        g.position[0] += 1.0;
        g.id = format!("b{}", g.id);
    }
    let mut s = a.clone();
    let offset = s.grains.len();
    s.grains.extend(b.grains.iter().cloned());
    for c in &b.contacts {
        let mut c = c.clone();
        c.point[0] += 1.0;
        c.a += offset;
        c.b = match c.b {
            Body::Grain(k) => Body::Grain(k + offset),
            Body::Wall(w) => Body::Wall(s.wall_or_insert(&format!("b-{}", b.walls[w].name))),
        };
        c.id = format!("b{}", c.id);
        s.contacts.push(c);
    }
    let truth: Vec<_> = ta.iter().chain(&tb).copied().collect();
    let res = infer(&s, &InferOptions::default()).unwrap();
    assert_eq!(res.report.clusters, 2);
    let e = relerr(&truth, &res.forces_or_zero());
    assert!(e <= 1e-8, "relerr {e}\n{}", res.report);
}

#[test]
fn ls_floor_recovers_exact_data() {
    let (s, truth) = lattice_2d(5, 4, 0.5);
    let opts = InferOptions {
        method: Method::Ls,
        ..InferOptions::default()
    };
    let r = infer(&s, &opts).unwrap();
    assert!(relerr(&truth, &r.forces_or_zero()) <= 1e-8);
}

#[test]
fn uniqueness_is_reported() {
    let (s, _) = lattice_2d(6, 5, 0.5);
    let global = infer(&s, &InferOptions::default()).unwrap();
    assert_eq!(global.report.unique, Some(true), "{}", global.report);
    // A few interior grains of a coordination-6 packing: their boundary contacts
    // add unknowns without equations, so other force fields fit equally well.
    let mut opts = InferOptions::default();
    let sel = Selection::Region(vec![(0.007, 0.030), (0.005, 0.020)]);
    opts.assemble.active = Some(scene::select_subassembly(&s, &sel).unwrap());
    let local = infer(&s, &opts).unwrap();
    assert_eq!(local.report.unique, Some(false), "{}", local.report);
    assert!(local.report.to_string().contains("NO"));
}

#[test]
fn pyramids_lie_inside_the_cone_3d() {
    use grainforce::infer::ConeModel;
    use grainforce::solver::pyramid_facets;
    let (mut s, truth) = cubic_stack(0.3);
    // Axis-aligned contacts balance with normal forces alone, so a small μ is
    // feasible, and with noisy stresses it binds.
    for c in s
        .contacts
        .iter_mut()
        .filter(|c| c.mu.is_some_and(|m| m > 0.0))
    {
        c.mu = Some(0.05);
    }
    let data = noisy(&s, 0.3);
    let mean = truth.iter().map(|f| scene::norm(*f)).sum::<f64>() / truth.len() as f64;
    let tol = 1e-7 * mean;
    let mut fits = Vec::new();
    for model in [
        ConeModel::Pyramid(4),
        ConeModel::Pyramid(8),
        ConeModel::Pyramid(16),
        ConeModel::Exact,
    ] {
        let opts = InferOptions {
            cone: model,
            ..InferOptions::default()
        };
        let r = infer(&data, &opts).unwrap();
        for (c, f) in s.contacts.iter().zip(r.forces_or_zero()) {
            let Some(mu) = c.mu.filter(|&m| m > 0.0) else {
                continue;
            };
            let (t1, t2) = scene::tangents(3, c.normal);
            let (fn_, u1, u2) = (
                -scene::dot(f, c.normal),
                scene::dot(f, t1),
                scene::dot(f, t2),
            );
            assert!(
                u1.hypot(u2) <= mu * fn_ + tol,
                "{model:?}: contact {} outside the cone",
                c.id
            );
            if let ConeModel::Pyramid(k) = model {
                for (m, cs, sn) in pyramid_facets(k, mu) {
                    assert!(
                        cs * u1 + sn * u2 <= m * fn_ + tol,
                        "{model:?}: contact {} outside a facet",
                        c.id
                    );
                }
            }
        }
        fits.push(r.report.stress_residual);
    }
    // Every pyramid lies inside the cone: the cone fits at least as well, up to
    // the interior-point tolerance (raw answers meet the equalities to ~1e-8).
    let exact = fits[3];
    for (k, f) in [4, 8, 16].iter().zip(&fits) {
        assert!(
            exact <= f * (1.0 + 1e-4),
            "pyramid {k} fits {f}, better than the cone's {exact}"
        );
    }
    // Friction binds: without it the stresses fit clearly better.
    let free = infer(
        &data,
        &InferOptions {
            method: Method::Ls,
            ..InferOptions::default()
        },
    )
    .unwrap();
    assert!(
        free.report.stress_residual < exact * (1.0 - 1e-3),
        "ls {} vs cone {exact}",
        free.report.stress_residual
    );
}
