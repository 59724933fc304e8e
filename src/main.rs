//! The grainforce command line: a thin layer of verbs over the library.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
