//! `grainforce score` (not built yet).

#[derive(clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> grainforce::Result<()> {
    Err(grainforce::Error::Invalid(
        "`score` is not available yet".into(),
    ))
}
