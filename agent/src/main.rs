//! `agent`: command-line entry point (the binary, `main.rs` and `cli/`, is the only code
//! that uses `anyhow`; each subcommand lives in `cli/`).
#![allow(clippy::print_stdout, reason = "a CLI prints its results")]

mod cli;

use anyhow::Result;
use clap::Parser;

fn main() -> Result<()> {
    // Before the runtime's threads exist: mallopt's settings are process-wide.
    agent::core::device::tune_allocator();
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?
        .block_on(run())
}

async fn run() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    cli::Cli::parse().command.run().await
}
