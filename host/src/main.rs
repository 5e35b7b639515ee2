//! `qhm`: measure quasi-homogeneous materials with the capture rig (or its
//! simulation) and render objects made of them. Parsing and dispatch only;
//! each command lives in `cmd/`.

use std::process::ExitCode;

use clap::Parser;

mod cli;
mod cmd;

fn main() -> ExitCode {
    // Output piped into a reader that quits early (`qhm fit ... | head`)
    // ends qhm quietly, as for other Unix tools, instead of a panic in
    // println!.
    #[cfg(unix)]
    // SAFETY: no other thread exists yet, and SIG_DFL installs no handler.
    unsafe {
        use nix::sys::signal::{SigHandler, Signal, signal};
        let _ = signal(Signal::SIGPIPE, SigHandler::SigDfl);
    }
    let cli = cli::Cli::parse();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("QHM_LOG")
                .unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match cli::run(cli) {
        Ok(code) => code,
        Err(err) => {
            // Broken pipes (`qhm ... | head`) are not errors.
            if err.chain().any(|e| {
                e.downcast_ref::<std::io::Error>()
                    .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
            }) {
                return ExitCode::SUCCESS;
            }
            eprintln!("qhm: {err:#}");
            ExitCode::FAILURE
        }
    }
}
