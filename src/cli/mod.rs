//! One module per verb; each parses its flags (clap) and calls the library.

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use std::sync::atomic::{AtomicBool, Ordering};

/// Set once from the global `-q/--quiet` before the verb runs.
static QUIET: AtomicBool = AtomicBool::new(false);

/// Whether "wrote …" and progress lines are silenced.
pub(crate) fn quiet() -> bool {
    QUIET.load(Ordering::Relaxed)
}

/// A "wrote …" or progress line: on stderr (stdout holds results), and not
/// under `-q`. Notes, warnings and errors use `eprintln!` directly.
macro_rules! status {
    ($($arg:tt)*) => {
        if !crate::cli::quiet() {
            eprintln!($($arg)*);
        }
    };
}

mod bench;
mod dem;
mod detect;
mod export;
mod import;
mod infer;
mod merge;
mod perturb;
mod photoelastic;
mod plot;
mod render;
mod score;
mod stats;
mod strain;

#[derive(Parser)]
#[command(
    name = "grainforce",
    version,
    about = "Contact forces inside granular materials from measured grain stresses (the Granular Element Method)",
    long_about = "grainforce infers every contact force in a granular packing from each grain's \
position, contacts and volume-averaged stress (2D and 3D, static and dynamic). Scenes are folders \
of CSV files (grains.csv, contacts.csv, optional walls.csv and scene.json); see the README."
)]
struct Cli {
    /// Silence the run summaries, "wrote …" and progress lines on stderr (errors still show).
    #[arg(short, long, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Infer contact forces of a scene (or of every frame of a sequence).
    Infer(infer::Args),
    /// Merge the outputs of `infer --frames` blocks into one run's files.
    Merge(merge::Args),
    /// Compare inferred forces with ground truth: relative error and more.
    Score(score::Args),
    /// Draw a force-chain picture (or a Pareto front).
    Plot(plot::Args),
    /// Generate a synthetic scene with exact forces by the discrete element method.
    Dem(dem::Args),
    /// Add measurement noise to a scene.
    Perturb(perturb::Args),
    /// Find disks in photographs and write a scene.
    Detect(detect::Args),
    /// Measure grain strains by image correlation and write stresses into a scene.
    Strain(strain::Args),
    /// Draw a scene as a camera would see it (speckled, deformed disks).
    Render(render::Args),
    /// Fit every contact force to a photoelastic photograph's fringes.
    Photoelastic(photoelastic::Args),
    /// Convert DEM or diffraction output into a scene.
    Import(import::Args),
    /// Write a scene and its forces for ParaView.
    Export(export::Args),
    /// Force-network statistics of a scene and its forces.
    Stats(stats::Args),
    /// Measure the speed/accuracy trade of the methods on synthetic scenes.
    Bench(bench::Args),
}

pub fn main() -> std::process::ExitCode {
    // The matches too: `infer --config` needs to know which flags were given.
    let matches = Cli::command().get_matches();
    let cli = Cli::from_arg_matches(&matches)
        .map_err(|e| e.format(&mut Cli::command()))
        .unwrap_or_else(|e| e.exit());
    QUIET.store(cli.quiet, Ordering::Relaxed);
    let result = match cli.command {
        Command::Infer(mut a) => {
            a.quiet = cli.quiet;
            if let Some(("infer", sub)) = matches.subcommand() {
                a.given = infer::given_fields(sub);
            }
            match infer::run(a) {
                Ok(infer::Finished::FramesFailed) => {
                    return std::process::ExitCode::from(infer::FRAMES_FAILED_EXIT)
                }
                other => other.map(drop),
            }
        }
        Command::Merge(a) => merge::run(a),
        Command::Score(a) => score::run(a),
        Command::Plot(a) => plot::run(a),
        Command::Dem(a) => dem::run(a),
        Command::Perturb(a) => perturb::run(a),
        Command::Detect(a) => detect::run(a),
        Command::Strain(a) => strain::run(a),
        Command::Render(a) => render::run(a),
        Command::Photoelastic(a) => photoelastic::run(a),
        Command::Import(a) => import::run(a),
        Command::Export(a) => export::run(a),
        Command::Stats(a) => stats::run(a),
        Command::Bench(a) => bench::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}
