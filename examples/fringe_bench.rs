//! The fringe fit's speed and accuracy on the rendered photograph:
//! the 58-disk DEM oedometer at r ≈ 40 px, blur 0.8 px, noise 2 %, JPEG q90.
//!
//!     cargo run --release --example fringe_bench [-- --detect] [--per-disk] [--repeat N]
//!         [--candidates GAP] [--prune FLOOR] [--wall-mu MU] [--settle-edges] [--detail]
//!         [--fsigma-scale F] [--iterations N] [--extrapolate]
//!         [--scene DIR] [--seed N] [--dump DIR] [--circles] [--walls-last]
//!         [--no-wall-candidates] [--mu MU] [--penalty-start W]
//!         [--narrow-start MU] [--box-walls] [--local-starts N] [--no-outermost-outline]
//!         [--drop-pair A,B] [--add-pair A,B] [--radius-px R]
//!
//! Without flags the disks and contacts are the DEM's; `--detect` finds them
//! in the photograph (`detect`, walls at the DEM's lines, or with
//! `--box-walls` at its default box) and scores the fit
//! against the DEM contacts matched by disk pair (a missed contact counts as
//! zero force). Prints relerr ‖f − f_true‖/‖f_true‖, the imbalance and the
//! fit's time (wall and CPU). `--scene` takes another DEM folder with its
//! forces.csv (e.g. `grainforce dem oedometer --seed 2 --gate 1e-10 -o DIR`)
//! in place of fixtures/oedometer, `--seed` the renderer's noise seed, so a
//! default is not judged on one picture alone.

use grainforce::image::fringe_fit::local_restarts;
use grainforce::image::fringe_fit::{fit_fringes_per_disk, FringeFitSettings};
use grainforce::image::fringe_run::{fit_with_second_starts, second_starts_in_order};
use grainforce::image::photoelastic::{render_photoelastic, save_jpeg, PhotoelasticOptions};
use grainforce::image::synthetic::match_disks;
use grainforce::image::{detect_images, load_channel, Channel, DetectSettings, WallSource};
use grainforce::scene::{read_forces, read_scene, Body, Scene};
use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::time::Instant;

fn cpu_seconds() -> f64 {
    grainforce::bench::cpu_seconds().unwrap_or(f64::NAN)
}

fn main() -> grainforce::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let detect = args.iter().any(|a| a == "--detect");
    let per_disk = args.iter().any(|a| a == "--per-disk");
    let repeat: usize = args
        .iter()
        .position(|a| a == "--repeat")
        .and_then(|k| args.get(k + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let dir = match args.iter().position(|a| a == "--scene") {
        Some(k) => std::path::PathBuf::from(
            args.get(k + 1)
                .ok_or_else(|| grainforce::Error::Invalid("--scene needs a scene folder".into()))?,
        ),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/oedometer"),
    };
    let scene = read_scene(&dir)?;
    let rows = read_forces(&dir.join("forces.csv"))?.rows;
    let truth: Vec<[f64; 2]> = scene
        .contacts
        .iter()
        .map(|c| {
            let r = rows.iter().find(|r| r.contact == c.id).expect("a force");
            [r.force[0], r.force[1]]
        })
        .collect();
    let mean_r: f64 = scene
        .grains
        .iter()
        .map(|g| g.radius.unwrap_or(0.0))
        .sum::<f64>()
        / scene.grains.len() as f64;
    // `--radius-px R`: the same packing drawn with disks of mean radius R px.
    let radius_px: f64 = args
        .iter()
        .position(|a| a == "--radius-px")
        .and_then(|k| args.get(k + 1)?.parse().ok())
        .unwrap_or(40.0);
    let mut o = PhotoelasticOptions::new(radius_px / mean_r, 4e4);
    o.blur_px = 0.8;
    o.noise = 0.02;
    o.uneven_lighting = 0.1;
    if let Some(seed) = args
        .iter()
        .position(|a| a == "--seed")
        .and_then(|k| args.get(k + 1)?.parse().ok())
    {
        o.seed = seed;
    }
    let (rgb, frame) = render_photoelastic(&scene, &truth, &o)?;
    let tmp = tempfile::tempdir().map_err(|e| grainforce::Error::io("a temporary folder", e))?;
    let path = tmp.path().join("oedometer.jpg");
    save_jpeg(&path, &rgb, 90)?;
    let image = load_channel(&path, Channel::Green)?;
    let mut s = FringeFitSettings::new(4e4);
    s.blur_px = 0.8;
    let value = |flag: &str| -> Option<f64> {
        let k = args.iter().position(|a| a == flag)?;
        args.get(k + 1)?.parse().ok()
    };
    // f_σ scaled by a rounding-level factor (1.000000001): the fit is the
    // same problem, its forces scaled by that factor; how far the answer
    // moves shows how much the fit's path hangs on round-off.
    if let Some(factor) = value("--fsigma-scale") {
        s.fringe_stress *= factor;
    }
    // A larger step budget: where the fit converges when not cut short.
    if let Some(steps) = value("--iterations") {
        s.max_iterations = steps as usize;
    }
    s.extrapolate = args.iter().any(|a| a == "--extrapolate");
    // μ where the scene gives none (a detected scene: the DEM's is 0.5).
    if let Some(mu) = value("--mu") {
        s.mu = mu;
    }
    // As `grainforce photoelastic` sets them for a scene from `detect` (or not).
    grainforce::image::fringe_run::set_for_scene(&mut s, detect, value("--candidates"));
    // The walls' friction from the start only (round 8's fit).
    if args.iter().any(|a| a == "--walls-last") {
        s.smooth_walls_first = false;
    }
    s.support_prune = value("--prune");
    // No disk–wall candidates: round 9's fit.
    if args.iter().any(|a| a == "--no-wall-candidates") {
        s.wall_candidates = false;
    }
    let detail = args.iter().any(|a| a == "--detail");
    let found = if detect {
        let px = frame.px_per_m;
        let mut settings = DetectSettings::new(2.2e-3 * px, 4.2e-3 * px, px);
        settings.frame = Some(frame);
        settings.detect.settle_edges = args.iter().any(|a| a == "--settle-edges");
        // `detect --outermost-outline=false`: round 15's circles.
        settings.detect.outermost_outline = !args.iter().any(|a| a == "--no-outermost-outline");
        settings.walls = WallSource::Lines(grainforce::image::contacts::walls_from_scene_contacts(
            &scene, &frame,
        ));
        // `detect`'s default walls instead of the DEM's lines.
        if args.iter().any(|a| a == "--box-walls") {
            settings.walls = WallSource::PackingBox;
        }
        let detection =
            detect_images(std::slice::from_ref(&path), &settings, &mut |_, _, _, _| {
                Ok(())
            })?;
        let found = detection.frames[0].clone();
        let walls = found
            .scene
            .contacts
            .iter()
            .filter(|c| matches!(c.b, Body::Wall(_)))
            .count();
        println!(
            "  detected: {} disks, {} contacts ({walls} with walls, {} walls)",
            found.scene.grains.len(),
            found.scene.contacts.len(),
            found.scene.walls.len()
        );
        if args.iter().any(|a| a == "--circles") {
            // Each detected circle's error against its grain beside the
            // detector's own measures of it.
            let matched = match_disks(&scene, &frame, &found.disks, |r| 0.5 * r);
            for (g, k) in matched.disk_of_grain.iter().enumerate() {
                let Some(k) = *k else { continue };
                let d = &found.disks[k];
                let t = &scene.grains[g];
                let c = frame.to_pixel([t.position[0], t.position[1]]);
                let r = t.radius.unwrap_or(0.0) * frame.px_per_m;
                println!(
                    "  circle {g} = disk {k}: centre off {:.2} px, radius {:+.2} px; support {:.3} visible {:.3} contrast {:.3} rms {:.3}",
                    (d.x - c[0]).hypot(d.y - c[1]),
                    d.r - r,
                    d.support,
                    d.visible,
                    d.contrast,
                    d.rms
                );
            }
        }
        if let Some(k) = args.iter().position(|a| a == "--dump") {
            let out = Path::new(
                args.get(k + 1)
                    .ok_or_else(|| grainforce::Error::Invalid("--dump needs a folder".into()))?,
            );
            grainforce::scene::write_scene(out, &found.scene)?;
            frame.write(&out.join("image-frame.json"))?;
            std::fs::copy(&path, out.join("photo.jpg"))
                .map_err(|e| grainforce::Error::io(out, e))?;
        }
        let mut found = found;
        // One contact list change at a time (detected grain indices "A,B"):
        // which of two contacts moves the fit into another basin.
        for (k, flag) in args.iter().enumerate() {
            if flag != "--drop-pair" && flag != "--add-pair" {
                continue;
            }
            let Some(pair) = args.get(k + 1) else {
                continue;
            };
            let ids: Vec<usize> = pair.split(',').filter_map(|v| v.parse().ok()).collect();
            let [a, b] = ids[..] else {
                return Err(grainforce::Error::Invalid(format!("{flag} needs A,B")));
            };
            edit_pair(&mut found.scene, a, b, flag == "--add-pair");
        }
        // The walls' friction, where known (the DEM's walls are frictionless).
        if let Some(mu) = value("--wall-mu") {
            for c in &mut found.scene.contacts {
                if matches!(c.b, Body::Wall(_)) {
                    c.mu = Some(mu);
                }
            }
        }
        Some(found)
    } else {
        None
    };
    let fit_scene = found.as_ref().map_or(&scene, |f| &f.scene);
    for _ in 0..repeat {
        let (wall, cpu) = (Instant::now(), cpu_seconds());
        let fit = if per_disk {
            fit_fringes_per_disk(&image, &frame, fit_scene, &s)?
        } else {
            // The run's fit and its second starts where disks are left
            // flagged (`photoelastic --penalty-start W --narrow-start MU`;
            // off here unless asked).
            let firsts = second_starts_in_order(
                value("--penalty-start").unwrap_or(0.0),
                value("--narrow-start").unwrap_or(0.0),
            );
            let (fit, tried) = fit_with_second_starts(&image, &frame, fit_scene, &s, &firsts)?;
            for t in &tried {
                println!(
                    "  second start {:?}: objective {:.2} against {}, balance left out on {}, {} flagged, {}",
                    t.first,
                    t.objective,
                    t.compared_objective
                        .map_or("no plain fit".into(), |o| format!("{o:.2}")),
                    t.balance_left_out,
                    t.flagged,
                    if t.kept { "kept" } else { "not kept" }
                );
            }
            // The run's local restarts on the disks still flagged
            // (`photoelastic --local-starts N`).
            let starts = value("--local-starts").map_or(0, |n: f64| n as usize);
            let (fit, restarts) = local_restarts(&image, &frame, fit_scene, &s, fit, starts)?;
            for r in &restarts {
                println!(
                    "  local restart of disk {} ({} contacts, {} starts): objective {:.2} → {:.2}, kept {:?}",
                    r.grain, r.contacts, r.starts, r.objective_before, r.objective_after, r.kept
                );
            }
            fit
        };
        let (wall, cpu) = (wall.elapsed().as_secs_f64(), cpu_seconds() - cpu);
        let e = if let Some(found) = &found {
            let matched = match_disks(&scene, &frame, &found.disks, |r| 0.5 * r);
            // Candidate contacts count as contacts of the fitted scene.
            let (fitted, forces) = fit.with_candidates(fit_scene);
            score(&scene, &truth, &fitted, &forces, &matched.disk_of_grain)
        } else {
            relerr(&fit.forces, &truth)
        };
        println!(
            "{} disks, {} contacts{}: relerr {e:.5}, imbalance median {:.2e} max {:.2e}, {} steps, {} flagged, {wall:.2} s wall, {cpu:.2} s CPU ({} threads)",
            fit_scene.grains.len(),
            fit_scene.contacts.len(),
            if detect { " (detected)" } else { "" },
            fit.report.median_imbalance,
            fit.report.max_imbalance,
            fit.report.iterations,
            fit.report.flagged.len(),
            rayon::current_num_threads()
        );
        println!(
            "  phases: {}; objective {:.2} → {:.2}",
            fit.report.timing, fit.report.objective_start, fit.report.objective
        );
        if detail {
            if let Some(found) = &found {
                walls_detail(&scene, &truth, &frame, found, &fit);
            }
            for c in fit.report.candidates.iter().filter(|c| c.wall) {
                println!(
                    "  wall candidate {}: gap {:.3} R, fitted ({:.1}, {:.1})",
                    c.id, c.gap, c.force[0], c.force[1]
                );
            }
            for d in fit.report.disks.iter().filter(|d| d.imbalance > 1e-6) {
                let left_out = fit.report.balance_left_out.contains(&d.grain);
                println!(
                    "  disk {}: imbalance {:.3e}{}",
                    d.grain,
                    d.imbalance,
                    if left_out { " (balance left out)" } else { "" }
                );
            }
        }
    }
    Ok(())
}

fn relerr(fit: &[[f64; 2]], truth: &[[f64; 2]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (f, t) in fit.iter().zip(truth) {
        num += (f[0] - t[0]).powi(2) + (f[1] - t[1]).powi(2);
        den += t[0] * t[0] + t[1] * t[1];
    }
    (num / den).sqrt()
}

/// relerr over the true contacts, matched by (disk, disk) or (disk, wall
/// name); a true contact not found counts as zero force.
fn score(
    truth_scene: &Scene,
    truth: &[[f64; 2]],
    found: &Scene,
    forces: &[[f64; 2]],
    disk_of_grain: &[Option<usize>],
) -> f64 {
    type Key = (usize, String);
    let key = |sc: &Scene, a: usize, b: &Body, disk: &dyn Fn(usize) -> Option<usize>| {
        let da = disk(a)?;
        match b {
            Body::Grain(j) => {
                let dj = disk(*j)?;
                Some(((da.min(dj), da.max(dj).to_string()), da > dj))
            }
            Body::Wall(w) => Some(((da, format!("wall:{}", sc.walls[*w].name)), false)),
        }
    };
    let mut fitted: HashMap<Key, [f64; 2]> = HashMap::new();
    for (c, f) in found.contacts.iter().zip(forces) {
        if let Some((k, flip)) = key(found, c.a, &c.b, &|g| Some(g)) {
            fitted.insert(k, if flip { [-f[0], -f[1]] } else { *f });
        }
    }
    let (mut num, mut den, mut missed) = (0.0, 0.0, 0);
    // Squared error by kind: true contacts missing from the fitted list,
    // disk–wall and disk–disk contacts present in it.
    let mut by_kind = [0.0f64; 3];
    let mut used = HashSet::new();
    let mut errors = Vec::new();
    for (c, t) in truth_scene.contacts.iter().zip(truth) {
        den += t[0] * t[0] + t[1] * t[1];
        let f = match key(truth_scene, c.a, &c.b, &|g| disk_of_grain[g]) {
            Some((k, flip)) => {
                let t = if flip { [-t[0], -t[1]] } else { *t };
                let f = fitted.get(&k).copied().unwrap_or([0.0; 2]);
                let e2 = (f[0] - t[0]).powi(2) + (f[1] - t[1]).powi(2);
                if fitted.contains_key(&k) {
                    used.insert(k.clone());
                    by_kind[if matches!(c.b, Body::Wall(_)) { 1 } else { 2 }] += e2;
                } else {
                    missed += 1;
                    by_kind[0] += e2;
                    if std::env::args().any(|a| a == "--detail") {
                        println!(
                            "  missed {k:?}: {}",
                            gaps(truth_scene, found, c, disk_of_grain)
                        );
                    }
                }
                num += e2;
                errors.push(((f[0] - t[0]).hypot(f[1] - t[1]), format!("{k:?}"), t, f));
                continue;
            }
            None => [0.0; 2],
        };
        missed += 1;
        let e2 = (f[0] - t[0]).powi(2) + (f[1] - t[1]).powi(2);
        by_kind[0] += e2;
        num += e2;
    }
    println!(
        "  relerr alone: missed {:.4}, disk–wall {:.4}, disk–disk {:.4}",
        (by_kind[0] / den).sqrt(),
        (by_kind[1] / den).sqrt(),
        (by_kind[2] / den).sqrt()
    );
    if std::env::args().any(|a| a == "--detail") {
        errors.sort_by(|a, b| b.0.total_cmp(&a.0));
        for (e, k, t, f) in &errors {
            println!(
                "  error {e:.1} at {k}: truth ({:.1}, {:.1}) fitted ({:.1}, {:.1})",
                t[0], t[1], f[0], f[1]
            );
        }
    }
    let extra: Vec<f64> = fitted
        .iter()
        .filter(|(k, _)| !used.contains(*k))
        .map(|(_, f)| f[0].hypot(f[1]))
        .collect();
    if std::env::args().any(|a| a == "--detail") {
        for (k, f) in fitted.iter().filter(|(k, _)| !used.contains(*k)) {
            if f[0].hypot(f[1]) > 10.0 {
                println!("  extra {k:?}: ({:.1}, {:.1})", f[0], f[1]);
            }
        }
    }
    println!(
        "  {missed} true contacts missed; {} extra contacts carry {:.1} N/m in all (largest {:.1})",
        extra.len(),
        extra.iter().sum::<f64>(),
        extra.iter().fold(0.0f64, |m, v| m.max(*v))
    );
    (num / den).sqrt()
}

/// Why a true contact is missing from the detected list: its gap over the
/// smaller radius in the detected circles and in the DEM's, and how far each
/// detected circle is from its grain (centre, radius; over its radius).
fn gaps(
    truth: &Scene,
    found: &Scene,
    c: &grainforce::scene::Contact,
    disk_of: &[Option<usize>],
) -> String {
    let Body::Grain(b) = c.b else {
        return "a wall contact".into();
    };
    let gap = |sc: &Scene, i: usize, j: usize| {
        let (p, q) = (sc.grains[i].position, sc.grains[j].position);
        let (ri, rj) = (
            sc.grains[i].equivalent_radius(2),
            sc.grains[j].equivalent_radius(2),
        );
        ((q[0] - p[0]).hypot(q[1] - p[1]) - ri - rj) / ri.min(rj)
    };
    let (Some(i), Some(j)) = (disk_of[c.a], disk_of[b]) else {
        return "a disk not found".into();
    };
    let off = |g: usize, k: usize| {
        let (t, f) = (&truth.grains[g], &found.grains[k]);
        let r = t.equivalent_radius(2);
        format!(
            "centre {:.3} radius {:+.3}",
            (f.position[0] - t.position[0]).hypot(f.position[1] - t.position[1]) / r,
            (f.equivalent_radius(2) - r) / r
        )
    };
    format!(
        "detected gap {:.3} R, DEM gap {:.3} R; circles off ({}), ({}) R",
        gap(found, i, j),
        gap(truth, c.a, b),
        off(c.a, i),
        off(b, j)
    )
}

/// Each DEM wall contact beside the detected one: the disk's distance to the
/// wall line and radius (DEM and detected, px), the detected gap, and the
/// forces; then the detected wall contacts the DEM lacks.
fn walls_detail(
    scene: &Scene,
    truth: &[[f64; 2]],
    frame: &grainforce::image::PixelFrame,
    found: &grainforce::image::DetectedFrame,
    fit: &grainforce::image::fringe_fit::FringeFit,
) {
    let matched = match_disks(scene, frame, &found.disks, |r| 0.5 * r);
    let fs = &found.scene;
    let px = frame.px_per_m;
    let wall_of = |sc: &Scene, b: &Body| match b {
        Body::Wall(w) => Some(sc.walls[*w].name.clone()),
        Body::Grain(_) => None,
    };
    let mut seen = HashSet::new();
    for (c, t) in scene.contacts.iter().zip(truth) {
        let Some(name) = wall_of(scene, &c.b) else {
            continue;
        };
        let g = &scene.grains[c.a];
        let n = [c.normal[0], c.normal[1]];
        // DEM: centre to the wall along the normal, radius.
        let reach = (c.point[0] - g.position[0]) * n[0] + (c.point[1] - g.position[1]) * n[1];
        let dem = format!(
            "DEM r {:.2} reach {:.2}",
            g.radius.unwrap_or(0.0) * px,
            reach * px
        );
        let Some(k) = matched.disk_of_grain[c.a] else {
            println!("  wall {name}, grain {}: {dem}; disk not found", c.a);
            continue;
        };
        let d = &found.disks[k];
        let centre = frame.to_pixel([g.position[0], g.position[1]]);
        let hit = (fs.contacts.iter().enumerate())
            .find(|(_, f)| f.a == k && wall_of(fs, &f.b).as_deref() == Some(name.as_str()));
        let dreach = (c.point[0] - fs.grains[k].position[0]) * n[0]
            + (c.point[1] - fs.grains[k].position[1]) * n[1];
        let fitted = hit.map(|(j, _)| fit.forces[j]);
        if let Some((j, _)) = hit {
            seen.insert(j);
        }
        println!(
            "  wall {name}, grain {} = disk {k}: {dem}; detected r {:.2} reach {:.2} (centre off {:+.2},{:+.2} px); truth ({:.1}, {:.1}) fitted {}",
            c.a,
            d.r,
            dreach * px,
            d.x - centre[0],
            d.y - centre[1],
            t[0],
            t[1],
            fitted.map_or("— (no contact)".to_string(), |f| format!("({:.1}, {:.1})", f[0], f[1]))
        );
    }
    for (j, (c, f)) in fs.contacts.iter().zip(&fit.forces).enumerate() {
        if let (Some(name), false) = (wall_of(fs, &c.b), seen.contains(&j)) {
            let g = &fs.grains[c.a];
            let reach = (c.point[0] - g.position[0]) * c.normal[0]
                + (c.point[1] - g.position[1]) * c.normal[1];
            println!(
                "  extra wall contact {name}, disk {}: r {:.2} reach {:.2} px, fitted ({:.1}, {:.1})",
                c.a,
                g.radius.unwrap_or(0.0) * px,
                reach * px,
                f[0],
                f[1]
            );
        }
    }
}

/// Drops the contact between grains `a` and `b` of `scene`, or adds one at
/// the middle of their gap (normal along the line of centres).
fn edit_pair(scene: &mut Scene, a: usize, b: usize, add: bool) {
    let joins = |c: &grainforce::scene::Contact| {
        (c.a == a && c.b == Body::Grain(b)) || (c.a == b && c.b == Body::Grain(a))
    };
    let before = scene.contacts.len();
    scene.contacts.retain(|c| !joins(c));
    println!(
        "  pair {a}–{b}: {} contact(s) dropped{}",
        before - scene.contacts.len(),
        if add { ", one added" } else { "" }
    );
    if !add {
        return;
    }
    let (pa, pb) = (scene.grains[a].position, scene.grains[b].position);
    let (ra, rb) = (
        scene.grains[a].radius.unwrap_or(0.0),
        scene.grains[b].radius.unwrap_or(0.0),
    );
    let d = [pb[0] - pa[0], pb[1] - pa[1]];
    let dist = d[0].hypot(d[1]);
    let n = [d[0] / dist, d[1] / dist, 0.0];
    let reach = ra + 0.5 * (dist - ra - rb);
    let mu = scene.contacts.first().and_then(|c| c.mu);
    scene.contacts.push(grainforce::scene::Contact {
        id: format!("added-{a}-{b}"),
        a,
        b: Body::Grain(b),
        point: [pa[0] + reach * n[0], pa[1] + reach * n[1], pa[2]],
        normal: n,
        mu,
    });
}
