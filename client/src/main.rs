//! `cangate`: command-line client of the cangate gateway. The grammar,
//! output and errors are in `cli/` (one module per command).

mod cli;

#[tokio::main]
async fn main() -> std::process::ExitCode {
    cli::main().await
}
