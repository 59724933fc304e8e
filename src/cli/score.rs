//! `grainforce score`: compare inferred forces with the truth. The last line
//! printed is always `relerr=<value>`, for scripts.

use grainforce::report::metrics::{self, ErrorNorm, PairedFrame, Score};
use grainforce::scene::{self, Sym};
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Ground-truth forces.csv.
    truth: PathBuf,
    /// Inferred forces.csv (rows matched by frame and contact id).
    inferred: PathBuf,
    /// Scene folder: enables normal/tangential errors, Coulomb and tension checks,
    /// wall load mismatch and the macroscopic stress.
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Also write every number as JSON here.
    #[arg(long, value_name = "SCORE.json", alias = "json")]
    report: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    let truth = scene::read_forces(&args.truth)?;
    let inferred = scene::read_forces(&args.inferred)?;
    let paired = metrics::pair_forces(&truth, &args.truth, &inferred, &args.inferred)?;
    if paired.is_empty() {
        return Err(Error::Invalid(format!(
            "{} holds no forces to score",
            args.truth.display()
        )));
    }
    let frames = match &args.scene {
        Some(dir) => score_with_scene(dir, &paired)?,
        None => paired
            .iter()
            .map(|p| metrics::score_without_scene(p.frame, &p.truth, &p.inferred))
            .collect(),
    };
    let overall = if frames.len() == 1 {
        frames[0].clone()
    } else {
        Score::overall(&frames)
    };
    if overall.error.truth_norm == 0.0 {
        return Err(Error::Invalid(format!(
            "every true force in {} is zero: the relative error is undefined (absolute error {})",
            args.truth.display(),
            overall.error.absolute
        )));
    }

    if frames.len() > 1 {
        print_frame_table(&frames);
        println!();
        println!("all {} frames together:", frames.len());
    }
    print_summary(&overall);
    if frames.len() == 1 {
        print_walls(&overall);
        print_stress(&overall);
    }

    if let Some(path) = &args.report {
        let report = serde_json::json!({ "overall": overall, "frames": frames });
        let text =
            serde_json::to_string_pretty(&report).map_err(|e| Error::Invalid(e.to_string()))?;
        write_text(path, &text)?;
    }
    println!("relerr={}", overall.relerr());
    Ok(())
}

fn score_with_scene(dir: &std::path::Path, paired: &[PairedFrame]) -> Result<Vec<Score>> {
    let scenes = scene::read_sequence(dir)?;
    let mut out = Vec::with_capacity(paired.len());
    for p in paired {
        let scene = scenes.iter().find(|s| s.frame == p.frame).ok_or_else(|| {
            Error::Invalid(format!(
                "the forces have frame {} but the scene {} does not",
                p.frame
                    .map(|f| f.to_string())
                    .unwrap_or_else(|| "(none)".into()),
                dir.display()
            ))
        })?;
        let (truth, inferred) = metrics::in_scene_order(scene, p, dir)?;
        out.push(metrics::score(scene, &truth, &inferred)?);
    }
    Ok(out)
}

fn write_text(path: &std::path::Path, text: &str) -> Result<()> {
    grainforce::scene::write_file_atomically(path, format!("{text}\n").as_bytes())
}

fn relative_text(e: &ErrorNorm) -> String {
    if e.truth_norm == 0.0 {
        format!("{:.4e} absolute (the truth is zero here)", e.absolute)
    } else {
        format!(
            "{:.6} (|error| {:.4e} of |truth| {:.4e})",
            e.relative, e.absolute, e.truth_norm
        )
    }
}

fn print_summary(s: &Score) {
    println!("contacts scored: {}", s.contacts);
    println!(
        "relative error |f - f*|/|f*| (eq. 2.15): {}",
        relative_text(&s.error)
    );
    if let Some(n) = &s.normal {
        println!("  normal part:     {}", relative_text(n));
    }
    if let Some(t) = &s.tangential {
        println!("  tangential part: {}", relative_text(t));
    }
    match &s.coulomb {
        Some(c) => match &c.contact {
            Some(id) => println!(
                "worst Coulomb violation: {:.4e} of the mean |f| (contact {id}; {} contacts checked)",
                c.relative, c.checked
            ),
            None => println!("worst Coulomb violation: none ({} contacts checked)", c.checked),
        },
        None if s.normal.is_some() => {
            println!("worst Coulomb violation: not checked (no friction coefficient in the scene)")
        }
        None => {}
    }
    if let (Some(n), Some(f)) = (s.tensile_contacts, s.tensile_fraction()) {
        println!(
            "tensile contacts: {n} of {} ({:.2}%)",
            s.contacts,
            100.0 * f
        );
    }
}

fn print_frame_table(frames: &[Score]) {
    let with_scene = frames.iter().any(|s| s.normal.is_some());
    if with_scene {
        println!(
            "{:>8} {:>8} {:>12} {:>12} {:>12} {:>12} {:>8}",
            "frame", "contacts", "relerr", "normal", "tangential", "coulomb", "tensile"
        );
    } else {
        println!("{:>8} {:>8} {:>12}", "frame", "contacts", "relerr");
    }
    let cell = |x: Option<f64>| x.map(|v| format!("{v:.4e}")).unwrap_or_else(|| "-".into());
    for s in frames {
        let frame = s.frame.map(|f| f.to_string()).unwrap_or_default();
        let relerr = if s.error.truth_norm == 0.0 {
            format!("abs {:.3e}", s.error.absolute)
        } else {
            format!("{:.4e}", s.error.relative)
        };
        if with_scene {
            println!(
                "{:>8} {:>8} {:>12} {:>12} {:>12} {:>12} {:>8}",
                frame,
                s.contacts,
                relerr,
                cell(s.normal.map(|e| e.relative).filter(|x| x.is_finite())),
                cell(s.tangential.map(|e| e.relative).filter(|x| x.is_finite())),
                cell(s.coulomb.as_ref().map(|c| c.relative)),
                s.tensile_contacts
                    .map(|n| n.to_string())
                    .unwrap_or_default()
            );
        } else {
            println!("{:>8} {:>8} {:>12}", frame, s.contacts, relerr);
        }
    }
}

fn vector_text(v: [f64; 3], dim3: bool) -> String {
    if dim3 {
        format!("({:.4e}, {:.4e}, {:.4e})", v[0], v[1], v[2])
    } else {
        format!("({:.4e}, {:.4e})", v[0], v[1])
    }
}

fn print_walls(s: &Score) {
    if s.walls.is_empty() {
        return;
    }
    let dim3 = s.walls.iter().any(|w| {
        w.inferred[2] != 0.0 || w.truth[2] != 0.0 || w.measured.is_some_and(|m| m[2] != 0.0)
    });
    println!("walls (force on the grains by the wall):");
    for w in &s.walls {
        let measured = w
            .measured
            .map(|m| format!("measured {}", vector_text(m, dim3)))
            .unwrap_or_else(|| "not measured".into());
        println!("  {}: {measured}", w.wall);
        println!(
            "    inferred {}   truth {}",
            vector_text(w.inferred, dim3),
            vector_text(w.truth, dim3)
        );
        if let (Some(a), Some(r)) = (w.absolute, w.relative) {
            println!(
                "    mismatch |measured - inferred| = {a:.4e} ({:.4}% of measured)",
                100.0 * r
            );
        }
    }
}

fn print_stress(s: &Score) {
    let (Some(inferred), Some(truth)) = (s.stress_inferred, s.stress_truth) else {
        return;
    };
    let dim3 = inferred[2] != 0.0 || inferred[4] != 0.0 || inferred[5] != 0.0 || truth[2] != 0.0;
    let names: &[(usize, &str)] = if dim3 {
        &[
            (0, "xx"),
            (1, "yy"),
            (2, "zz"),
            (3, "xy"),
            (4, "xz"),
            (5, "yz"),
        ]
    } else {
        &[(0, "xx"), (1, "yy"), (3, "xy")]
    };
    println!("macroscopic stress (eq. 2.1, tension positive; bounding-box volume):");
    println!("  {:>4} {:>14} {:>14}", "", "inferred", "truth");
    let row = |t: &Sym, k: usize| t[k];
    for &(k, name) in names {
        println!(
            "  {:>4} {:>14.6e} {:>14.6e}",
            name,
            row(&inferred, k),
            row(&truth, k)
        );
    }
}
