//! The command line as data: every subcommand and its flags. Each command's
//! work is in `cmd/<name>.rs`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use crate::cmd;

#[derive(Parser, Debug)]
#[command(
    name = "qhm",
    version,
    about = "Acquire and render quasi-homogeneous materials (Tong et al. 2005)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    // One variant per command; keep one line each so parallel edits do not collide.
}

pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        // One arm per command.
    }
}
