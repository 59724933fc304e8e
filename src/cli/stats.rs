//! `grainforce stats SCENE_DIR FORCES.csv`: force-network statistics.

use grainforce::scene;
use grainforce::stats::{self, FrameStats, Options};
use grainforce::{Error, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Scene folder (one frame or a sequence).
    scene: PathBuf,
    /// Forces (inferred or true), forces.csv format.
    forces: PathBuf,
    /// Write one row of statistics per frame to this CSV file.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Write every statistic (histograms and chain lengths included) as JSON.
    #[arg(long, value_name = "STATS.json", alias = "json")]
    report: Option<PathBuf>,
    /// Draw P(f/<f>) of the first frame with its exponential tail fit (log y) to this PNG.
    #[arg(long, value_name = "STATS.png")]
    plot: Option<PathBuf>,
    /// Histogram bin width of P(f/<f>), in units of <f>.
    #[arg(long, default_value_t = 0.2)]
    bin_width: f64,
    /// Largest turn between consecutive branch vectors of a force chain [degrees].
    #[arg(long, default_value_t = 45.0)]
    chain_angle: f64,
    /// Shortest force chain counted, in contacts.
    #[arg(long, default_value_t = 2)]
    min_chain: usize,
    /// Grains with fewer force-carrying contacts are rattlers (default: d + 1).
    #[arg(long)]
    rattler_contacts: Option<usize>,
}

fn write_file(path: &std::path::Path, text: &str) -> Result<()> {
    scene::write_file_atomically(path, text.as_bytes())
}

pub fn run(args: Args) -> Result<()> {
    let frames = scene::read_sequence(&args.scene)?;
    let forces = scene::read_forces(&args.forces)?;
    let options = Options {
        bin_width: args.bin_width,
        chain_angle_deg: args.chain_angle,
        min_chain_contacts: args.min_chain,
        rattler_min_contacts: args.rattler_contacts,
    };
    let mut all: Vec<FrameStats> = Vec::new();
    for frame in &frames {
        let f = forces.for_scene(frame, &args.forces)?;
        let s = stats::frame_stats(frame, &f, &options)?;
        print!("{}", stats::summary(&s));
        all.push(s);
    }
    if let Some(path) = &args.csv {
        let dim = frames[0].dim;
        let mut text = stats::csv_header(dim).join(",") + "\n";
        for s in &all {
            text.push_str(&stats::csv_row(s).join(","));
            text.push('\n');
        }
        write_file(path, &text)?;
    }
    if let (Some(path), Some(first)) = (&args.plot, all.first()) {
        let img = stats::plot::distribution_chart(first, 900, 600).render();
        grainforce::report::save_png(path, &img)?;
        if all.len() > 1 {
            eprintln!("note: --plot draws the first frame");
        }
    }
    if let Some(path) = &args.report {
        let text = serde_json::to_string_pretty(&all).map_err(|e| Error::Invalid(e.to_string()))?;
        write_file(path, &(text + "\n"))?;
    }
    Ok(())
}
