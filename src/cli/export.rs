//! `grainforce export` (not built yet).

#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> grainforce::Result<()> {
    Err(grainforce::Error::Invalid(
        "`export` is not available yet".into(),
    ))
}
