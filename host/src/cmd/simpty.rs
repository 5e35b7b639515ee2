//! `qhm sim --pty`: serve an emulated rig on a pseudo-terminal, print its
//! device path (one line on stdout), and serve until Ctrl-C. Another process
//! then talks to it as to a real rig: `qhm rig --port <path> status`.

use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;

/// Options of the served rig.
#[derive(Args, Debug, Clone)]
pub struct PtyArgs {
    /// Virtual seconds per wall second of the emulated rig.
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Seed of the rig (boot ids, start angles) and of the line faults.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Modelled line rate, bits/s (0 = no transmission delay).
    #[arg(long, default_value_t = sim::DEFAULT_BAUD)]
    pub line_baud: u32,
    /// Probability each byte is lost (both directions).
    #[arg(long, default_value_t = 0.0)]
    pub drop: f64,
    /// Probability each byte has a bit flipped (both directions).
    #[arg(long, default_value_t = 0.0)]
    pub corrupt: f64,
    /// Probability each byte arrives twice (both directions).
    #[arg(long, default_value_t = 0.0)]
    pub duplicate: f64,
}

impl PtyArgs {
    pub fn sim_config(&self) -> sim::SimConfig {
        let mut cfg = sim::SimConfig::seeded(self.seed);
        cfg.speed = self.speed;
        cfg.link.baud = self.line_baud;
        let faults = sim::ByteFaults {
            drop: self.drop,
            corrupt: self.corrupt,
            duplicate: self.duplicate,
            ..sim::ByteFaults::NONE
        };
        cfg.link.faults = sim::FaultConfig::symmetric(cfg.link.faults.seed, faults);
        cfg
    }
}

/// Serve until Ctrl-C (or a disconnect fault).
pub fn serve(args: &PtyArgs) -> Result<ExitCode> {
    let cfg = args.sim_config();
    cfg.validate()?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(async {
        let mut out = std::io::stdout();
        sim::serve_pty_until_ctrl_c(&cfg, &mut out).await
    })
    .context("emulated rig on a pseudo-terminal")?;
    Ok(ExitCode::SUCCESS)
}
