//! `qhm flash`: write the firmware to the Nucleo-F446RE through its ST-LINK
//! with probe-rs (`probe-rs run --chip STM32F446RETx <elf>`), which then
//! streams the firmware's defmt log until Ctrl-C.

use std::path::PathBuf;
use std::process::{Command, ExitCode};

use anyhow::{Context, Result, bail};
use clap::Args;

/// The ELF `cargo build -p firmware --release --target thumbv7em-none-eabihf --features stm32` writes.
const DEFAULT_ELF: &str = "target/thumbv7em-none-eabihf/release/firmware";

#[derive(Args, Debug)]
pub struct FlashArgs {
    /// Firmware ELF to flash (default: the release build in the workspace target dir).
    #[arg(long)]
    pub elf: Option<PathBuf>,
    /// probe-rs chip name.
    #[arg(long, default_value = "STM32F446RETx")]
    pub chip: String,
    /// Flash and reset only; do not attach to the defmt log.
    #[arg(long)]
    pub no_log: bool,
}

pub fn run(args: FlashArgs) -> Result<ExitCode> {
    let elf = match args.elf {
        Some(p) => p,
        None => {
            let dir = std::env::var_os("CARGO_TARGET_DIR")
                .map(PathBuf::from)
                .unwrap_or_else(|| PathBuf::from("target"));
            dir.join(DEFAULT_ELF.trim_start_matches("target/"))
        }
    };
    if !elf.is_file() {
        bail!(
            "no firmware ELF at {}: build it with `cargo build -p firmware --release --target thumbv7em-none-eabihf --features stm32` or pass --elf",
            elf.display()
        );
    }
    let mut cmd = Command::new("probe-rs");
    if args.no_log {
        cmd.args(["download", "--chip", &args.chip]).arg(&elf);
    } else {
        cmd.args(["run", "--chip", &args.chip]).arg(&elf);
    }
    let status = match cmd.status() {
        Ok(s) => s,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "probe-rs is not installed: `cargo install probe-rs-tools --locked` (and the udev rules for the ST-LINK)"
        ),
        Err(e) => return Err(e).context("cannot run probe-rs"),
    };
    if !status.success() {
        bail!("probe-rs failed ({status}) flashing {}", elf.display());
    }
    if args.no_log {
        // `download` leaves the core halted after programming on some probes.
        let reset = Command::new("probe-rs")
            .args(["reset", "--chip", &args.chip])
            .status()
            .context("cannot run probe-rs reset")?;
        if !reset.success() {
            bail!("probe-rs reset failed ({reset})");
        }
    }
    Ok(ExitCode::SUCCESS)
}
