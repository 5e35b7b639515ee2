//! `qhm`: measure quasi-homogeneous materials with the capture rig (or its
//! simulation) and render objects made of them. Parsing and dispatch only;
//! each command lives in `cmd/`. Every failure, a bad flag included, ends
//! in one line on stderr, `qhm: <what went wrong>`, and a non-zero exit.

use std::io::IsTerminal;
use std::process::ExitCode;

use clap::Parser;
use clap::error::ErrorKind;

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
    let cli = match cli::Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return clap_error(e),
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("QHM_LOG")
                .unwrap_or_else(|_| "warn".into()),
        )
        // Colour codes belong on a terminal, not in a log file.
        .with_ansi(std::io::stderr().is_terminal())
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
            eprintln!("qhm: {}", one_line(&error_chain(&err)));
            ExitCode::FAILURE
        }
    }
}

/// Help and version go to stdout as clap prints them; a usage error becomes
/// one `qhm:` line with clap's exit code (2).
fn clap_error(e: clap::Error) -> ExitCode {
    let text = e.render().to_string();
    let message = match e.kind() {
        ErrorKind::DisplayHelp | ErrorKind::DisplayVersion => e.exit(),
        // `qhm` alone asks what qhm does: the help, as clap prints it.
        ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand if std::env::args_os().len() <= 1 => {
            e.exit()
        }
        // `qhm capture` alone: clap would print the whole help as an error.
        ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => missing_command(&text),
        _ => one_line(&text),
    };
    eprintln!("qhm: {message} (see --help)");
    ExitCode::from(e.exit_code().clamp(1, 255) as u8)
}

/// `qhm capture needs a command: plan, run`, from the help clap renders
/// for a command given without its subcommand.
fn missing_command(help: &str) -> String {
    let usage = help
        .lines()
        .find_map(|l| l.trim().strip_prefix("Usage: "))
        .unwrap_or("qhm");
    let command = usage.split(" [").next().unwrap_or(usage);
    let command = command.split(" <").next().unwrap_or(command);
    let names: Vec<&str> = help
        .lines()
        .skip_while(|l| l.trim() != "Commands:")
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next())
        .filter(|n| *n != "help")
        .collect();
    format!("{command} needs a command: {}", names.join(", "))
}

/// The error and its causes joined by `: `, each cause once: an error whose
/// message already ends with its source's (`{path}: {source}` with the
/// source also linked) would otherwise repeat the reason.
fn error_chain(err: &anyhow::Error) -> String {
    let mut out = String::new();
    let mut last = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        if !last.is_empty() && last.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
        last = text;
    }
    out
}

/// Folds a multi-line message into one line: drops clap's `error:` prefix,
/// its usage and `--help` paragraphs and the source snippets of TOML parse
/// errors (`  |`, `3 | x = `), and joins what is left with `; ` (or a space
/// after a line ending in `:`, as clap lists missing arguments).
fn one_line(text: &str) -> String {
    let text = text.strip_prefix("error: ").unwrap_or(text);
    let mut out = String::new();
    for para in text.split("\n\n") {
        let p = para.trim_start();
        if p.starts_with("Usage:") || p.starts_with("For more information") {
            continue;
        }
        for line in para.lines() {
            let line = line.trim();
            let snippet = line
                .trim_start_matches(|c: char| c.is_ascii_digit())
                .trim_start()
                .starts_with('|');
            if line.is_empty() || snippet {
                continue;
            }
            if !out.is_empty() {
                out.push_str(if out.ends_with(':') { " " } else { "; " });
            }
            out.push_str(line);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_repeated_source_is_said_once() {
        #[derive(Debug, thiserror::Error)]
        #[error("d/manifest.toml: {source}")]
        struct Wrapped {
            source: std::io::Error,
        }
        let io = std::io::Error::from_raw_os_error(21);
        let reason = io.to_string();
        let err = anyhow::Error::new(Wrapped { source: io }).context("loading model d");
        assert_eq!(
            error_chain(&err),
            format!("loading model d: d/manifest.toml: {reason}")
        );
    }

    #[test]
    fn a_missing_subcommand_names_the_choices() {
        let help = "Capture: ...\n\nUsage: qhm capture <COMMAND>\n\nCommands:\n  plan  Print the plan\n  run   Execute\n  help  Print this message\n\nOptions:\n  -h, --help  Print help\n";
        assert_eq!(
            missing_command(help),
            "qhm capture needs a command: plan, run"
        );
        let help = "Usage: qhm rig [OPTIONS] <COMMAND>\n\nCommands:\n  ping  Handshake\n";
        assert_eq!(missing_command(help), "qhm rig needs a command: ping");
    }

    #[test]
    fn toml_and_clap_messages_fold_to_one_line() {
        let toml = "bad scene: TOML parse error at line 1, column 8\n  |\n1 | [camera\n  |        ^\ninvalid table header\nexpected `.`, `]`\n";
        assert_eq!(
            one_line(toml),
            "bad scene: TOML parse error at line 1, column 8; invalid table header; expected `.`, `]`"
        );
        let clap = "error: the following required arguments were not provided:\n  --reflectance <REFLECTANCE>\n\nUsage: qhm fit-profile --reflectance <REFLECTANCE> <PROFILE>\n\nFor more information, try '--help'.\n";
        assert_eq!(
            one_line(clap),
            "the following required arguments were not provided: --reflectance <REFLECTANCE>"
        );
    }
}
