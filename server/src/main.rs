//! The `voxserve` binary: parses the command line and runs a subcommand. The
//! benchmarks (`voxserve bench`) and the real datasets they measure live here,
//! in the binary's own module tree, not in the server library.

mod bench;

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use server::cli::Command;
use tracing_subscriber::EnvFilter;

/// Remote viewing of large 3D scans and simulations in a browser.
///
/// voxserve renders volumes on the GPU (through wgpu: Vulkan, Metal, DX12 or GL;
/// Mesa's lavapipe where there is no GPU) and serves the frames to a thin web
/// client. Without a dataset it serves a built-in CT head phantom.
///
/// Environment: WGPU_BACKEND picks the graphics backend (vulkan, gl, metal, dx12),
/// WGPU_ADAPTER_NAME picks an adapter by part of its name, RUST_LOG sets the log
/// level (default info).
#[derive(Debug, Parser)]
#[command(name = "voxserve", version)]
struct Cli {
    /// What to do.
    #[command(subcommand)]
    command: Subcommands,
    #[command(flatten)]
    store: server::cli::ObjectStoreArgs,
}

/// The server's subcommands, and `bench`.
#[derive(Debug, Subcommand)]
enum Subcommands {
    #[command(flatten)]
    Server(Box<Command>),
    /// Measure phantom generation, frame rendering and slab reading; prints JSON lines.
    Bench(bench::args::BenchArgs),
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_env_filter(EnvFilter::try_from_default_env().unwrap_or_else(|_| {
            EnvFilter::new(
                "info,wgpu=warn,naga=warn,foyer=warn,foyer_storage=warn,foyer_memory=warn",
            )
        }))
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .init();
    // A panic inside a decoder of a volume file is reported as that file's
    // error (see blocks::ingest::boundary), not as a crash.
    blocks::ingest::boundary::install_panic_hook();
    let cli = Cli::parse();
    blocks::store::remote::set_policy(cli.store.policy());
    if let Some(folder) = &cli.store.store_cache
        && let Err(e) = blocks::store::disk_cache::open(folder, cli.store.store_cache_mib)
    {
        tracing::error!("{e}");
        return ExitCode::FAILURE;
    }
    let result = match cli.command {
        Subcommands::Server(command) => server::commands::run(*command),
        Subcommands::Bench(args) => bench::run(&args),
    };
    // Ranges still in memory go to disk before the process ends.
    if let Some(cache) = blocks::store::disk_cache::get() {
        cache.close();
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{}", message(&e));
            ExitCode::FAILURE
        }
    }
}

/// `error` and its causes, each after a colon, leaving out a cause whose text
/// the message already ends with (errors that repeat their source's words).
fn message(error: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in error.chain() {
        let part = cause.to_string();
        if text.is_empty() {
            text = part;
        } else if !text.ends_with(&part) {
            text = format!("{text}: {part}");
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    #[test]
    fn an_error_message_names_each_cause_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file");
        let error = anyhow::Error::new(blocks::Error::Io {
            path: "/nowhere.raw".into(),
            source: io,
        })
        .context("opening the dataset");
        assert_eq!(
            super::message(&error),
            "opening the dataset: /nowhere.raw: No such file"
        );
    }

    #[test]
    fn the_command_line_is_well_formed() {
        super::Cli::command().debug_assert();
    }
}
