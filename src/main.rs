//! `rig`: the TransForce rig's command line. See [`rig::cli`] for the subcommands.

use std::process::ExitCode;

use clap::Parser;
use tracing_subscriber::EnvFilter;

fn main() -> ExitCode {
    rig::train::keep_freed_memory();
    // Usage errors (and --help / --version) exit here, with status 2 for errors.
    let cli = rig::cli::Cli::parse();

    // Logs go to stderr so stdout stays clean for --json; RUST_LOG overrides the default: the
    // rig at `info`, the simulated devices' own chatter (connections, program starts) only from
    // `warn` (RUST_LOG=info shows it).
    let filter = EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| EnvFilter::new(format!("info,{}", rig::simrig::QUIET_DEVICES_LOG)));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        // Colour only on a terminal, so logs redirected to a file stay plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();

    match rig::cli::run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            report(&e);
            ExitCode::FAILURE
        }
    }
}

/// Prints an error and its causes, skipping causes whose text the message already includes.
fn report(e: &anyhow::Error) {
    let top = e.to_string();
    eprintln!("error: {top}");
    let mut shown = top;
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        if !shown.contains(&text) {
            eprintln!("  caused by: {text}");
            shown.push_str(&text);
        }
    }
}
