//! `grainforce merge`: the outputs of `infer --frames` blocks (cluster
//! tasks) into the files one run over every frame writes.

use grainforce::infer::shards;
use grainforce::Result;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// The merged file. Ending in .json: `infer --report` files, one entry
    /// per frame in frame order; else forces.csv files (any table whose
    /// first column is frame): the header once and the rows in frame order,
    /// byte for byte the file of one run.
    pub output: PathBuf,
    /// The blocks' files, in any order; their frames must not overlap.
    #[arg(required = true)]
    pub shards: Vec<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    shards::merge(&args.output, &args.shards)?;
    status!(
        "wrote {} (merged from {} files)",
        args.output.display(),
        args.shards.len()
    );
    Ok(())
}
