//! Throughput of the DEM on the `box` scene, and of LAMMPS on the same system.
//!
//! `cargo run --release --example dem_throughput [-- --large] [--dim D] [--no-lammps] [--out DIR]`
//!
//! A `box` packing of 1000 grains is prepared (servo compression, loose gate)
//! in 2D and 3D (the relaxed state is cached in DIR: preparing the 3D box
//! takes minutes) and tiled into larger boxes (≈10⁴, and ≈10⁵ with --large).
//! The walls are moved 0.5 % of a copy into the packing so it stays jammed. Each
//! system then runs with fixed walls (linear spring–dashpot with history,
//! friction, no numerical damping) and the particle-steps per CPU second
//! (per wall-clock second where the CPU time is not available) are printed. The same systems are written as LAMMPS inputs (pair gran/hooke/history,
//! fix wall/gran, nve/sphere) into DIR; when `lmp` is on the PATH (see
//! benches/lammps/run.sh) they are run and the ratio printed.

use grainforce::dem::sim::{Motion, System, WallShape};
use grainforce::dem::{prepare, DemConfig, Preset};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

struct Case {
    dim: usize,
    grains: usize,
    steps: u64,
    ours: f64,
    theirs: Option<f64>,
    contacts_per_grain: f64,
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let large = args.iter().any(|a| a == "--large");
    let out = args
        .iter()
        .position(|a| a == "--out")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("target/dem_bench"));
    let only_dim: Option<usize> = args
        .iter()
        .position(|a| a == "--dim")
        .and_then(|i| args.get(i + 1))
        .map(|d| d.parse().expect("--dim takes 2 or 3"));
    std::fs::create_dir_all(&out).expect("output folder");
    let lammps = which("lmp").filter(|_| !args.iter().any(|a| a == "--no-lammps"));
    let mut cases = Vec::new();
    for dim in [2usize, 3] {
        if only_dim.is_some_and(|d| d != dim) {
            continue;
        }
        let config = DemConfig::preset(Preset::Box, dim).grains(1000).gate(1e-2);
        let base = prepared_base(&config, &out);
        let mut targets = vec![1_000usize, 10_000];
        if large {
            targets.push(100_000);
        }
        for target in targets {
            let copies = copies_for(target, base.len(), dim);
            let mut sys = tile(&base, copies, config.density, config.sizes.max_radius());
            // About 3·10⁷ particle-steps per case.
            let steps = ((3e7 / sys.len() as f64) as u64).clamp(100, 30_000);
            // LAMMPS starts from the same state: the tiled packing at rest.
            let input = write_lammps(&out, &sys, steps, config.grain.mu);
            for _ in 0..20 {
                sys.step();
            }
            let t = Instant::now();
            let cpu = cpu_seconds();
            let mut contacts = 0usize;
            for _ in 0..steps {
                sys.step();
                contacts += sys.contact_count;
            }
            let wall = t.elapsed().as_secs_f64();
            let seconds = match (cpu, cpu_seconds()) {
                (Some(a), Some(b)) => b - a,
                _ => wall,
            };
            let ours = sys.len() as f64 * steps as f64 / seconds;
            // Right after ours, so both see about the same load on a shared machine.
            let theirs = lammps
                .as_ref()
                .and_then(|lmp| run_lammps(lmp, &input, sys.len()));
            cases.push(Case {
                dim,
                grains: sys.len(),
                steps,
                ours,
                theirs,
                contacts_per_grain: 2.0 * contacts as f64 / steps as f64 / sys.len() as f64,
            });
            eprintln!(
                "{dim}D {:>7} grains: {:.3e} particle-steps/s ({} steps, {} neighbour-list builds, {:.0} % CPU)",
                sys.len(),
                ours,
                steps,
                sys.neighbour_builds(),
                100.0 * seconds / wall
            );
        }
    }
    if lammps.is_none() {
        eprintln!("lmp not found on PATH: LAMMPS inputs written to {} (benches/lammps/run.sh installs and runs it)", out.display());
    }
    println!("| dim | grains | contacts/grain | steps | grainforce [particle-steps/s] | LAMMPS [particle-steps/s] | ratio |");
    println!("|---|---|---|---|---|---|---|");
    for case in &cases {
        let (t, r) = match case.theirs {
            Some(v) => (format!("{v:.3e}"), format!("{:.2}", case.ours / v)),
            None => ("–".into(), "–".into()),
        };
        println!(
            "| {} | {} | {:.2} | {} | {:.3e} | {} | {} |",
            case.dim, case.grains, case.contacts_per_grain, case.steps, case.ours, t, r
        );
    }
}

/// The relaxed base box. Preparing it takes minutes (the 3D box most), so the
/// relaxed positions are cached in `out` under a name that hashes the whole
/// configuration; a cached state is put back into the freshly built (not
/// relaxed) system of the same configuration, whose radii must match.
fn prepared_base(config: &DemConfig, out: &Path) -> System {
    use std::hash::{Hash, Hasher};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    format!("{config:?}").hash(&mut hasher);
    let dim = config.dim;
    let cache = out.join(format!("base{dim}d_{:016x}.txt", hasher.finish()));
    if let Ok(text) = std::fs::read_to_string(&cache) {
        let (mut sys, _) = prepare(&config.clone().max_steps(1)).expect("box build");
        let mut grains = 0;
        let mut walls = 0;
        for line in text.lines() {
            let words: Vec<&str> = line.split_whitespace().collect();
            let num = |k: usize| -> f64 { words[k].parse().expect("cached number") };
            match words.first() {
                Some(&"grain") => {
                    assert_eq!(sys.radius[grains], num(4), "cached radii differ");
                    sys.x[grains] = [num(1), num(2), num(3)];
                    grains += 1;
                }
                Some(&"wall") => {
                    assert_eq!(sys.walls[walls].name, words[1], "cached walls differ");
                    sys.walls[walls].position = [num(2), num(3), num(4)];
                    walls += 1;
                }
                _ => {}
            }
        }
        assert!(
            grains == sys.len() && walls == sys.walls.len(),
            "cache incomplete"
        );
        eprintln!(
            "{dim}D base box: {grains} grains, read from {}",
            cache.display()
        );
        return sys;
    }
    let t = Instant::now();
    let (base, report) = prepare(config).expect("box preparation");
    eprintln!(
        "{dim}D base box: {} grains, {} contacts, unbalanced {:.1e}, prepared in {:.1} s ({} steps)",
        base.len(),
        report.contacts,
        report.unbalanced_ratio,
        t.elapsed().as_secs_f64(),
        report.steps
    );
    let mut text = String::new();
    for (x, r) in base.x.iter().zip(&base.radius) {
        writeln!(text, "grain {:?} {:?} {:?} {:?}", x[0], x[1], x[2], r).unwrap();
    }
    for wall in &base.walls {
        let p = wall.position;
        writeln!(text, "wall {} {:?} {:?} {:?}", wall.name, p[0], p[1], p[2]).unwrap();
    }
    std::fs::write(&cache, text).expect("writing the base cache");
    base
}

/// Copies of the base box per axis whose product is nearest `target` grains
/// (in ratio): each axis gets ⌊c⌋ or ⌈c⌉ copies, c = (target/base)^(1/dim).
fn copies_for(target: usize, base: usize, dim: usize) -> [usize; 3] {
    let c = (target as f64 / base as f64).powf(1.0 / dim as f64);
    let (lo, hi) = ((c.floor() as usize).max(1), (c.ceil() as usize).max(1));
    let mut best = [1usize; 3];
    let mut best_miss = f64::INFINITY;
    for high_axes in 0..=dim {
        let mut k = [1usize; 3];
        for (a, ka) in k.iter_mut().enumerate().take(dim) {
            *ka = if a < high_axes { hi } else { lo };
        }
        let n = (k[0] * k[1] * k[2] * base) as f64;
        let miss = (n / target as f64).ln().abs();
        if miss < best_miss - 1e-12 {
            best = k;
            best_miss = miss;
        }
    }
    best
}

/// copies[a] copies of the base packing along each axis, side by side, inside
/// walls around them all.
fn tile(base: &System, copies: [usize; 3], density: f64, rmax: f64) -> System {
    let dim = base.dim;
    let mut lo = [0.0f64; 3];
    let mut hi = [0.0f64; 3];
    for wall in &base.walls {
        if let WallShape::Plane { normal } = wall.shape {
            for a in 0..dim {
                if normal[a] > 0.5 {
                    lo[a] = wall.position[a];
                } else if normal[a] < -0.5 {
                    hi[a] = wall.position[a];
                }
            }
        }
    }
    let span: Vec<f64> = (0..3).map(|a| hi[a] - lo[a]).collect();
    let mut x = Vec::new();
    let mut radius = Vec::new();
    for i in 0..copies[0] {
        for j in 0..copies[1] {
            for l in 0..copies[2] {
                for (p, r) in base.x.iter().zip(&base.radius) {
                    x.push([
                        p[0] + i as f64 * span[0],
                        p[1] + j as f64 * span[1],
                        p[2] + l as f64 * span[2],
                    ]);
                    radius.push(*r);
                }
            }
        }
    }
    let mut sys = System::new(
        dim,
        x,
        radius,
        density,
        base.grain_law,
        [0.0; 3],
        base.dt,
        0.3 * rmax,
    );
    for wall in &base.walls {
        let WallShape::Plane { normal } = wall.shape else {
            continue;
        };
        // Walls 0.5 % of one copy's span inside the packing on every side:
        // tiling and the fresh start (no tangential history, in both codes)
        // would otherwise let the packing relax away from its walls and lose
        // its contacts; squeezed, it stays jammed with a realistic number of
        // contacts per grain. (A squeeze growing with the copies would put
        // the walls of a 10⁵-grain box through the grains' centres.)
        let squeeze = 0.005;
        let mut position = wall.position;
        for a in 0..dim {
            if normal[a] > 0.5 {
                position[a] = lo[a] + squeeze * span[a];
            } else if normal[a] < -0.5 {
                position[a] = lo[a] + (copies[a] as f64 - squeeze) * span[a];
            }
        }
        sys.add_wall(
            &wall.name,
            wall.shape,
            position,
            [0.0; 3],
            Motion::Prescribed,
            wall.law,
            0.0,
        );
    }
    sys.evaluate();
    sys
}

/// CPU time of this thread (Linux: /proc/thread-self/schedstat, ns on CPU).
/// On a shared machine it counts only the time we ran, as LAMMPS' "% CPU use"
/// lets us count for it.
fn cpu_seconds() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = text.split_whitespace().next()?.parse().ok()?;
    Some(ns * 1e-9)
}

fn which(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// Writes data + input for LAMMPS; returns the input path.
fn write_lammps(dir: &Path, sys: &System, steps: u64, mu: f64) -> PathBuf {
    let dim = sys.dim;
    let n = sys.len();
    let tag = format!("box{dim}d_{n}");
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for wall in &sys.walls {
        for a in 0..dim {
            if let WallShape::Plane { normal } = wall.shape {
                if normal[a].abs() > 0.5 {
                    lo[a] = lo[a].min(wall.position[a]);
                    hi[a] = hi[a].max(wall.position[a]);
                }
            }
        }
    }
    let rmax = sys.radius.iter().cloned().fold(0.0, f64::max);
    let mut data = String::new();
    writeln!(
        data,
        "grainforce box {dim}D, {n} grains\n\n{n} atoms\n1 atom types\n"
    )
    .unwrap();
    for a in 0..3 {
        let (l, h) = if a < dim {
            (lo[a] - 2.0 * rmax, hi[a] + 2.0 * rmax)
        } else {
            (-0.5 * rmax, 0.5 * rmax)
        };
        let name = ["x", "y", "z"][a];
        writeln!(data, "{l:.17e} {h:.17e} {name}lo {name}hi").unwrap();
    }
    writeln!(data, "\nAtoms # sphere\n").unwrap();
    for i in 0..n {
        let r = sys.radius[i];
        // LAMMPS derives mass from a sphere's volume; choose the density so the
        // masses equal ours (per unit thickness in 2D).
        let density = sys.mass[i] / (4.0 / 3.0 * std::f64::consts::PI * r * r * r);
        writeln!(
            data,
            "{} 1 {:.17e} {:.17e} {:.17e} {:.17e} {:.17e}",
            i + 1,
            2.0 * r,
            density,
            sys.x[i][0],
            sys.x[i][1],
            sys.x[i][2]
        )
        .unwrap();
    }
    std::fs::write(dir.join(format!("{tag}.data")), data).unwrap();
    let law = &sys.grain_law;
    let wall = &sys.walls[0].law;
    // LAMMPS' dashpot is meff·γ_n; ours is a·√(m* k): match at the mean m*.
    let mean_mass = sys.mass.iter().sum::<f64>() / n as f64;
    let gamma = |k: f64, a: f64, m: f64| a * (k / m).sqrt();
    let (kn, kt) = (law.normal, law.tangential);
    let mut input = String::new();
    writeln!(input, "units si\natom_style sphere\ndimension {dim}").unwrap();
    writeln!(input, "boundary f f {}", if dim == 2 { "p" } else { "f" }).unwrap();
    writeln!(input, "comm_modify vel yes\nread_data {tag}.data").unwrap();
    writeln!(
        input,
        "pair_style gran/hooke/history {kn:e} {kt:e} {:e} 0 {mu} 0\npair_coeff * *",
        gamma(kn, law.damp_n, 0.5 * mean_mass)
    )
    .unwrap();
    writeln!(
        input,
        "neighbor {:e} bin\nneigh_modify delay 0 every 1 check yes",
        0.3 * rmax
    )
    .unwrap();
    if dim == 2 {
        writeln!(
            input,
            "fix integrate all nve/sphere disc\nfix planar all enforce2d"
        )
        .unwrap();
    } else {
        writeln!(input, "fix integrate all nve/sphere").unwrap();
    }
    for a in 0..dim {
        writeln!(
            input,
            "fix wall{a} all wall/gran hooke/history {:e} {:e} {:e} 0 {} 0 {}plane {:.17e} {:.17e}",
            wall.normal,
            wall.tangential,
            gamma(wall.normal, wall.damp_n, mean_mass),
            wall.mu,
            ["x", "y", "z"][a],
            lo[a],
            hi[a]
        )
        .unwrap();
    }
    writeln!(
        input,
        "timestep {:e}\nthermo {}\nrun 20\nrun {steps}",
        sys.dt, steps
    )
    .unwrap();
    let path = dir.join(format!("{tag}.in"));
    std::fs::write(&path, input).unwrap();
    path
}

/// Runs LAMMPS on one input; parses "Loop time of T on 1 procs for S steps
/// with N atoms" and the "% CPU use" below it: particle-steps per CPU second.
fn run_lammps(lmp: &Path, input: &Path, grains: usize) -> Option<f64> {
    let dir = input.parent()?;
    let log = format!("{}.log", input.file_stem()?.to_str()?);
    let output = std::process::Command::new(lmp)
        .current_dir(dir)
        .args([
            "-in",
            input.file_name()?.to_str()?,
            "-log",
            &log,
            "-screen",
            "none",
        ])
        .output()
        .ok()?;
    let text = std::fs::read_to_string(dir.join(&log)).ok()?;
    let lines: Vec<&str> = text.lines().collect();
    let at = lines.iter().rposition(|l| l.starts_with("Loop time of"))?;
    let words: Vec<&str> = lines[at].split_whitespace().collect();
    let wall: f64 = words.get(3)?.parse().ok()?;
    let steps: f64 = words.get(8)?.parse().ok()?;
    // "97.3% CPU use with 1 MPI tasks x 1 OpenMP threads": CPU time, as for ours.
    let cpu_share = lines[at + 1..]
        .iter()
        .find_map(|l| {
            l.split_once("% CPU use")
                .map(|(p, _)| p.trim().parse::<f64>())
        })
        .and_then(|p| p.ok())
        .map(|p| p / 100.0);
    let seconds = wall * cpu_share.unwrap_or(1.0);
    if !output.status.success() || seconds <= 0.0 {
        eprintln!("LAMMPS failed on {}", input.display());
        return None;
    }
    Some(grains as f64 * steps / seconds)
}
