//! `grainforce infer`: scene → forces.csv (+ summary on stderr, JSON report).

use grainforce::error::{Error, Result};
use grainforce::infer::config::{spell_fields, FIELDS};
use grainforce::infer::run::{Event, Run, Source};
use grainforce::infer::{self, InferConfig};
use grainforce::report::forcechain::{draw_force_chains_with_sd, ForceChainOptions};
use grainforce::report::pareto::pareto_csv;
use grainforce::scene::{self, Vec3};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Scene folder (grains.csv, contacts.csv, optional walls.csv and scene.json).
    pub scene: PathBuf,
    /// Where to write the forces (forces.csv format; force on grain `a` by `b`).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Read the configuration from this JSON file (an object of the fields,
    /// each named as its flag with `_` for `-`); flags given on the command
    /// line override it.
    #[arg(long = "config", value_name = "CONFIG.json")]
    pub config_file: Option<PathBuf>,
    #[command(flatten)]
    pub config: InferConfig,
    /// Dynamic: write the Pareto front (lambda, stress_residual,
    /// momentum_residual, knee) to this CSV (sweeps even when the rule is not knee).
    #[arg(long, value_name = "PARETO.csv")]
    pub pareto: Option<PathBuf>,
    /// Sequences: write the impulse check (table 3.1) to this CSV, one row per
    /// grain tracked over at least --impulse-window + 1 consecutive frames.
    /// Columns: grain, first_frame, last_frame; start_window, end_window: the
    /// frames of the two end windows (--impulse-window, or the whole
    /// contact-free stretch at an end where the grain flies freely);
    /// dv_x_measured, dv_x_inferred (and y, z): the change of velocity
    /// between the two windows, measured = least-squares slopes of the track,
    /// inferred = the same slopes of the track integrated twice from
    /// (Σ inferred contact forces)/m + g; dv_sd: standard deviation of each
    /// measured component due to the position noise; disagreement:
    /// |Δv inferred − Δv measured| / |Δv measured|; gap_in_sd: that gap over
    /// dv_sd (a few units is noise); moves: 1 when |Δv measured| ≥ 20 dv_sd.
    #[arg(long, value_name = "IMPULSE.csv")]
    pub impulse: Option<PathBuf>,
    /// Also draw the force chains of the (first) frame to this PNG.
    #[arg(long, value_name = "FORCES.png")]
    pub plot: Option<PathBuf>,
    /// Write the report (sizes, residuals, λ, solver status, warnings) as JSON.
    #[arg(long, value_name = "REPORT.json")]
    pub report: Option<PathBuf>,
    /// The global -q/--quiet: print no report, summary or progress on stderr.
    #[arg(skip)]
    pub quiet: bool,
    /// The configuration fields given as flags (they override `--config`).
    #[arg(skip)]
    pub given: Vec<String>,
}

/// The configuration fields given on the command line among these matches.
pub fn given_fields(matches: &clap::ArgMatches) -> Vec<String> {
    matches
        .ids()
        .map(|id| id.as_str())
        .filter(|id| FIELDS.contains(id))
        .filter(|id| matches.value_source(id) == Some(clap::parser::ValueSource::CommandLine))
        .map(str::to_owned)
        .collect()
}

/// A configuration field as its flag: `time_fit` → `--time-fit`.
fn flag(field: &str, value: Option<&str>) -> String {
    let flag = field.replace('_', "-");
    match value {
        Some(v) => format!("--{flag} {v}"),
        None => format!("--{flag}"),
    }
}

/// The library's configuration of these flags (over the `--config` file's),
/// checked; its errors name the flag, or the file and the field.
fn config(args: &Args) -> Result<InferConfig> {
    let (base, from_file) = match &args.config_file {
        Some(path) => config_file(path, &args.config, &args.given)?,
        None => (args.config.clone(), Vec::new()),
    };
    let config = InferConfig {
        pareto: args.pareto.is_some(),
        impulse: args.impulse.is_some(),
        ..base
    };
    let spell = |field: &str, value: Option<&str>| match &args.config_file {
        Some(path) if from_file.iter().any(|f| f == field) => match value {
            Some(v) => format!("`{field}` = {v} in {}", path.display()),
            None => format!("`{field}` in {}", path.display()),
        },
        _ => flag(field, value),
    };
    config
        .validate()
        .map_err(|e| Error::Invalid(e.spelled(spell)))?;
    Ok(config)
}

/// The configuration of a JSON file with the flags given on the command
/// line over it, and the fields that came from the file.
fn config_file(
    path: &std::path::Path,
    flags: &InferConfig,
    given: &[String],
) -> Result<(InferConfig, Vec<String>)> {
    let at = |e: String| Error::Invalid(format!("{}: {e}", path.display()));
    let text = std::fs::read_to_string(path).map_err(|e| at(e.to_string()))?;
    let mut value: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| at(format!("not JSON: {e}")))?;
    let serde_json::Value::Object(fields) = &mut value else {
        return Err(at("a configuration is a JSON object of fields".into()));
    };
    for output in ["pareto", "impulse"] {
        if fields.contains_key(output) {
            return Err(at(format!(
                "`{output}` is asked for with its output file: give --{output} FILE"
            )));
        }
    }
    let from_file = fields
        .keys()
        .filter(|k| !given.contains(k))
        .cloned()
        .collect();
    let flags = serde_json::to_value(flags).map_err(|e| at(e.to_string()))?;
    for field in given {
        if let Some(v) = flags.get(field) {
            fields.insert(field.clone(), v.clone());
        }
    }
    let config = InferConfig::from_value(value).map_err(at)?;
    Ok((config, from_file))
}

/// The bar drawn on stderr while the frames of a sequence are inferred.
fn frame_bar() -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(0);
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} frames, {elapsed} elapsed, ETA {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

pub fn run(args: Args) -> Result<Finished> {
    let config = config(&args)?;
    let bar = (!args.quiet).then(frame_bar);
    let events = |event: Event<'_>| {
        match event {
        _ if args.quiet => {}
        Event::Note(text) => eprintln!("note: {}", spell_fields(text, flag)),
        Event::Derived(k) => eprintln!(
            "accelerations derived from {} tracks ({} partial, {} too short: zero); position noise {:.3e} m {}",
            k.tracks,
            k.partial_tracks,
            k.short_tracks.len(),
            k.position_sd,
            if args.config.position_sd.is_some() {
                "(stated)"
            } else {
                "estimated from the tracks"
            }
        ),
        Event::Frame(p) => {
            if let Some(bar) = &bar {
                bar.set_length(p.total as u64);
                bar.set_position(p.done as u64);
            }
        }
    }
    };
    let ran = infer::run::run(Source::Folder(&args.scene), &config, Some(&events));
    if let Some(bar) = bar {
        bar.finish_and_clear();
    }
    let run = ran.map_err(|e| match e {
        // The library names its configuration's fields; here they are flags.
        Error::Invalid(m) => Error::Invalid(spell_fields(&m, flag)),
        Error::Infeasible(m) => Error::Infeasible(spell_fields(&m, flag)),
        Error::Solver(m) => Error::Solver(spell_fields(&m, flag)),
        e => e,
    })?;
    for (_, error) in &run.failures {
        eprintln!("not written: {}", spell_fields(error, flag));
    }
    let forces = run.forces();
    // Outputs are gathered first and written once nothing can fail any more,
    // so a failed run leaves no file behind.
    let mut pending: Vec<(&PathBuf, Vec<u8>)> = Vec::new();
    if let Some(path) = &args.report {
        let json = serde_json::to_string_pretty(&run.report_json())
            .map_err(|e| Error::Invalid(e.to_string()))?;
        pending.push((path, json.into_bytes()));
    }
    match (&args.impulse, &run.impulse) {
        (Some(path), Some(check)) => {
            pending.push((path, infer::run::impulse_csv(check, forces.dim).into_bytes()))
        }
        (Some(path), None) => eprintln!(
            "impulse check not written to {}: it integrates every frame's forces, and {} frames failed",
            path.display(),
            run.failures.len()
        ),
        _ => {}
    }
    if let Some(path) = &args.pareto {
        let front = run
            .pareto()
            .ok_or_else(|| Error::Invalid("--pareto needs --method dynamic or soft".into()))?;
        if run.results.len() > 1 {
            eprintln!("note: --pareto writes the front of the first frame");
        }
        pending.push((path, pareto_csv(&front.points, front.knee)?.into_bytes()));
    }
    // Everything that can fail is done before the forces file is written.
    let picture = match &args.plot {
        Some(_) => Some(picture(&args, &run)?),
        None => None,
    };
    scene::write_forces(&args.output, &forces)?;
    for (path, bytes) in &pending {
        scene::write_file_atomically(path, bytes)?;
    }
    if let (Some(path), Some(img)) = (&args.plot, &picture) {
        grainforce::report::chart::save_png(path, img)?;
    }
    if !args.quiet {
        summary(&run, &args, forces.rows.len());
    }
    if run.failures.is_empty() {
        Ok(Finished::AllFrames)
    } else {
        eprintln!(
            "{} of {} frames failed (listed above); the others were written",
            run.failures.len(),
            run.failures.len() + run.results.len()
        );
        Ok(Finished::FramesFailed)
    }
}

/// The force chains of the first frame.
fn picture(args: &Args, run: &Run) -> Result<image::RgbImage> {
    let first = &run.results[0];
    let title = format!("{} - {} forces", args.scene.display(), first.report.method);
    let opts = ForceChainOptions {
        title: Some(title),
        ..Default::default()
    };
    let sd: Option<Vec<Vec3>> = run
        .uncertainty
        .as_ref()
        .map(|u| u[0].sd.iter().map(|s| s.unwrap_or([0.0; 3])).collect());
    draw_force_chains_with_sd(
        &run.frames[0],
        &first.forces_or_zero(),
        sd.as_deref(),
        &opts,
    )
}

/// The run's summary on stderr.
fn summary(run: &Run, args: &Args, forces: usize) {
    match &run.time_fit {
        Some(fit) => eprint!("{}", spell_fields(&fit.to_string(), flag)),
        None => {
            for r in &run.results {
                eprint!("{}", spell_fields(&r.report.to_string(), flag));
            }
        }
    }
    for u in run.uncertainty.iter().flatten() {
        eprintln!("{}", infer::run::uncertainty_summary(u));
    }
    if let Some(check) = &run.impulse {
        eprintln!("{}", infer::run::impulse_summary(check));
    }
    eprintln!("wrote {forces} forces to {}", args.output.display());
}

/// How `infer` ended when it wrote its outputs.
pub enum Finished {
    AllFrames,
    /// Some frames failed and the others were written (exit status
    /// [`FRAMES_FAILED_EXIT`]).
    FramesFailed,
}

/// Exit status when some frames of a sequence failed and the others were written.
pub const FRAMES_FAILED_EXIT: u8 = 3;
