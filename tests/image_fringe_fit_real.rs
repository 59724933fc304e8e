//! Issue 42 on real photographs: the experimenters' disks and contacts
//! (PeGS 1.x lists, read here from the shared folder named by
//! `GRAINFORCE_TEST_DATA`), our joint fringe fit, compared with PeGS's own
//! per-disk forces. Skipped (with a message) when the variable is unset.

use grainforce::image::fringe_fit::{fit_fringes, Balance, FringeFitSettings};
use grainforce::image::{load_channel, Channel, PixelFrame};
use grainforce::scene::{Body, Contact, Grain, Scene};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

fn data() -> Option<PathBuf> {
    match std::env::var_os("GRAINFORCE_TEST_DATA") {
        Some(d) => Some(PathBuf::from(d).join("real-photos")),
        None => {
            eprintln!("skipping: GRAINFORCE_TEST_DATA is not set");
            None
        }
    }
}

fn rows(path: &Path) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(|s| s.trim().to_string()).collect())
        .collect()
}

/// The scene of a PeGS frame, in pixel units (1 px = 1 m, so forces are
/// relative, as PeGS's are): disks from the centres file (1-based MATLAB
/// pixels), disk–disk contacts from the reference list, wall contacts along
/// their angle. Returns the scene, its frame and PeGS's force magnitude per
/// contact (the mean of the sides it reports).
fn pegs_scene(dir: &Path, image: &Path, stem: &str) -> (Scene, PixelFrame, Vec<Option<f64>>) {
    let img = load_channel(image, Channel::Green).unwrap();
    let frame = PixelFrame::at_origin(1.0, img.width(), img.height());
    let mut scene = Scene::new(2);
    let centres = rows(&dir.join(format!("{stem}_centers.txt")));
    for (i, r) in centres.iter().enumerate() {
        let (x, y, radius): (f64, f64, f64) = (
            r[0].parse().unwrap(),
            r[1].parse().unwrap(),
            r[2].parse().unwrap(),
        );
        let p = frame.to_scene([x - 1.0, y - 1.0]);
        let mut g = Grain::new(
            (i + 1).to_string(),
            [p[0], p[1], 0.0],
            std::f64::consts::PI * radius * radius,
            [0.0; 6],
        );
        g.radius = Some(radius);
        scene.grains.push(g);
    }
    let mut pairs = Vec::new();
    for r in rows(&dir.join(format!("{stem}_contacts_ref.csv")))
        .iter()
        .skip(1)
    {
        let (a, b): (usize, usize) = (r[0].parse().unwrap(), r[1].parse().unwrap());
        pairs.push((a - 1, Some(b - 1), 0.0));
    }
    let walls = dir.join(format!("{stem}_wall_contacts.csv"));
    if walls.exists() {
        for r in rows(&walls).iter().skip(1) {
            let a: usize = r[0].parse().unwrap();
            let beta: f64 = r[2].parse().unwrap();
            pairs.push((a - 1, None, beta));
        }
    }
    for (k, (a, b, beta)) in pairs.iter().enumerate() {
        let pa = scene.grains[*a].position;
        let ra = scene.grains[*a].radius.unwrap();
        let (normal, body) = match b {
            Some(b) => {
                let pb = scene.grains[*b].position;
                let d = [pb[0] - pa[0], pb[1] - pa[1]];
                let len = d[0].hypot(d[1]);
                ([d[0] / len, d[1] / len], Body::Grain(*b))
            }
            None => {
                // β is atan2(dy, dx) in image axes (y down).
                let w = scene.wall_or_insert(&format!("wall{}", k));
                ([beta.cos(), -beta.sin()], Body::Wall(w))
            }
        };
        scene.contacts.push(Contact {
            id: k.to_string(),
            a: *a,
            b: body,
            point: [pa[0] + ra * normal[0], pa[1] + ra * normal[1], 0.0],
            normal: [normal[0], normal[1], 0.0],
            mu: None,
        });
    }
    // PeGS forces per (disk, neighbour); walls are negative neighbour codes.
    let forces_path = dir.join(format!("{}_forces.csv", stem.trim_end_matches("_solved")));
    let mut side: HashMap<(usize, i64), Vec<f64>> = HashMap::new();
    for r in rows(&forces_path).iter().skip(1) {
        let id: usize = r[0].parse().unwrap();
        let nb: i64 = r[1].parse().unwrap();
        side.entry((id - 1, nb))
            .or_default()
            .push(r[4].parse().unwrap());
    }
    let mut wall_seen: HashMap<usize, usize> = HashMap::new();
    let pegs = scene
        .contacts
        .iter()
        .map(|c| match c.b {
            Body::Grain(b) => {
                let one = side
                    .get(&(c.a, b as i64 + 1))
                    .and_then(|v| v.first().copied());
                let two = side
                    .get(&(b, c.a as i64 + 1))
                    .and_then(|v| v.first().copied());
                match (one, two) {
                    (Some(x), Some(y)) => Some(0.5 * (x + y)),
                    (x, y) => x.or(y),
                }
            }
            Body::Wall(_) => {
                // The k-th wall row of disk a with a negative neighbour.
                let n = wall_seen.entry(c.a).or_default();
                let found = side
                    .iter()
                    .filter(|((id, nb), _)| *id == c.a && *nb < 0)
                    .flat_map(|(_, v)| v.iter().copied())
                    .nth(*n);
                *n += 1;
                found
            }
        })
        .collect();
    (scene, frame, pegs)
}

fn compare(name: &str, folder: &str, image: &str, stem: &str) {
    let Some(root) = data() else { return };
    let dir = root.join(folder);
    let image = dir.join(image);
    let (scene, frame, pegs) = pegs_scene(&dir, &image, stem);
    let photo = load_channel(&image, Channel::Green).unwrap();
    let mut s = FringeFitSettings::new(1.0);
    s.edge_px = 5.0;
    s.blur_px = 1.0;
    // PeGS lists only stressed contacts, so many disks lack one to balance:
    // balance as a penalty (hard, it would force those disks' loads to zero).
    s.balance = Balance::Penalty(10.0);
    let started = std::time::Instant::now();
    let fit = fit_fringes(&photo, &frame, &scene, &s).unwrap();
    let seconds = started.elapsed().as_secs_f64();
    // Strong contacts: PeGS's upper half. One scale (PeGS is uncalibrated).
    let mut both: Vec<(f64, f64)> = scene
        .contacts
        .iter()
        .zip(&fit.forces)
        .zip(&pegs)
        .filter_map(|((_, f), p)| p.map(|p| (f[0].hypot(f[1]), p)))
        .collect();
    both.sort_by(|a, b| b.1.total_cmp(&a.1));
    let strong = &both[..both.len() / 2];
    let k = strong.iter().map(|(o, p)| o * p).sum::<f64>()
        / strong.iter().map(|(o, _)| o * o).sum::<f64>();
    let n = strong.len() as f64;
    let (mo, mp) = (
        strong.iter().map(|v| v.0).sum::<f64>() / n,
        strong.iter().map(|v| v.1).sum::<f64>() / n,
    );
    let cov: f64 = strong.iter().map(|(o, p)| (o - mo) * (p - mp)).sum();
    let so: f64 = strong
        .iter()
        .map(|(o, _)| (o - mo).powi(2))
        .sum::<f64>()
        .sqrt();
    let sp: f64 = strong
        .iter()
        .map(|(_, p)| (p - mp).powi(2))
        .sum::<f64>()
        .sqrt();
    let mut rel: Vec<f64> = strong
        .iter()
        .map(|(o, p)| (k * o - p).abs() / p.abs())
        .collect();
    rel.sort_by(f64::total_cmp);
    let explained: Vec<f64> = fit.report.disks.iter().map(|d| d.explained).collect();
    let mut e = explained.clone();
    e.sort_by(f64::total_cmp);
    eprintln!(
        "{name}: {} disks, {} contacts ({} with PeGS forces); strong contacts: Pearson r {:.2}, median |k·ours − PeGS|/PeGS {:.2}; our imbalance max {:.1e}; explained variance median {:.2} (lowest {:.2}), {} flagged; residual {:.1} → {:.1}; {} steps, {seconds:.1} s",
        scene.grains.len(),
        scene.contacts.len(),
        both.len(),
        cov / (so * sp),
        rel[rel.len() / 2],
        fit.report.max_imbalance,
        e[e.len() / 2],
        e[0],
        fit.report.flagged.len(),
        fit.report.objective_start,
        fit.report.objective,
        fit.report.iterations,
    );
    assert!(fit.report.objective < fit.report.objective_start);
}

#[test]
fn jlin_fixed48_against_pegs() {
    compare("jlin-fixed48", "jlin-fixed48", "image2.jpg", "image2");
}

#[test]
fn jlin_narrow21_against_pegs() {
    compare(
        "jlin-narrow21",
        "jlin-narrow21",
        "image.jpg",
        "image_solved",
    );
}

#[test]
fn jlin_step83_against_pegs() {
    compare("jlin-step83", "jlin-step83", "image3.jpg", "image3_solved");
}
