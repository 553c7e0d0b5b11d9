//! The `voxserve` binary: parses the command line and runs a subcommand.

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::Parser;
use server::cli::{BenchCommand, Cli, Command};
use tracing_subscriber::EnvFilter;

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(
            EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| EnvFilter::new("info,wgpu=warn,naga=warn")),
        )
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Serve(args) => tokio::runtime::Runtime::new()
            .map_err(anyhow::Error::from)
            .and_then(|rt| rt.block_on(server::commands::serve(args))),
        Command::Render(args) => server::commands::render(args),
        Command::Info(args) => server::commands::info(&args),
        Command::Ingest(args) => server::commands::ingest(&args),
        Command::Bench(args) => match &args.what {
            BenchCommand::Render(a) => server::bench::render(a),
            BenchCommand::Read(a) => server::bench::read(a),
            BenchCommand::Blocks(a) => server::bench::blocks(a),
            BenchCommand::Light(a) => server::bench::light(a),
            BenchCommand::Stream(a) => server::bench::stream(a),
            BenchCommand::Extinction(a) => server::bench::extinction(a),
        },
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e:#}");
            ExitCode::FAILURE
        }
    }
}
