//! `grainforce bench` (not built yet).

#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> grainforce::Result<()> {
    Err(grainforce::Error::Invalid(
        "`bench` is not available yet".into(),
    ))
}
