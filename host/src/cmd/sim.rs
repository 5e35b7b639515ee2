//! `qhm sim`: the simulated world. `--pty` serves an emulated rig on a
//! pseudo-terminal (see `simpty.rs`).

use std::process::ExitCode;

use anyhow::{Result, bail};
use clap::Args;

use crate::cmd::simpty;

#[derive(Args, Debug)]
pub struct SimArgs {
    /// Serve an emulated rig on a pseudo-terminal; print its path; serve until Ctrl-C.
    #[arg(long)]
    pub pty: bool,
    #[command(flatten)]
    pub rig: simpty::PtyArgs,
}

pub fn run(args: SimArgs) -> Result<ExitCode> {
    if args.pty {
        return simpty::serve(&args.rig);
    }
    bail!("say what to simulate: --pty serves an emulated rig on a pseudo-terminal")
}
