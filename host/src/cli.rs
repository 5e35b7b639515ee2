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
    /// The whole job on the built-in simulated rig: calibrate, capture, rectify, fit, render, report.
    Demo(cmd::demo::DemoArgs),
    /// Render a mesh made of a material model (EXR/PNG); export pbrt-v4/Mitsuba 3 snippets.
    Render(cmd::render::RenderArgs),
    /// Calibrate the rig: plan, capture the calibration targets, compute the calibration file (or all).
    Calibrate(cmd::calibrate::CalibrateArgs),
    /// HDR-merge and rectify a capture directory into CAPTURE_DIR/rectified/.
    Rectify(cmd::rectify::RectifyArgs),
    /// Capture: `plan` (frames, disk, rig time vs lower bound), `run` (into a resumable capture directory).
    Capture(cmd::capture::CaptureArgs),
    /// Talk to the rig's MCU: ping, status, home, move, galvo, laser, lamps, trigger, estop, clear.
    Rig(cmd::rig::RigArgs),
    /// Flash the firmware to the Nucleo-F446RE with probe-rs.
    Flash(cmd::flash::FlashArgs),
    /// The simulated world (`--pty`: an emulated rig on a pseudo-terminal).
    Sim(cmd::sim::SimArgs),
    /// Fit a' and s'_t to a laser-stripe profile CSV (distance_mm,intensity_per_mm).
    FitProfile(cmd::fit::FitProfileArgs),
    /// Fit the material model of a rectified capture: qhm fit CAPTURE_DIR -o MODEL_DIR.
    Fit(cmd::fit::FitArgs),
    /// Plots and an HTML page of a material model and its fit.
    Report(cmd::report::ReportArgs),
    /// A local web page to relight a material model on a mesh: qhm view MODEL_DIR [--port 8080] [--open].
    View(cmd::view::ViewArgs),
    /// A render against a ground truth: means, low-pass block RMSE, local-contrast histograms.
    Compare(cmd::compare::CompareArgs),
}

pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        // One arm per command.
        Command::Demo(args) => cmd::demo::run(args),
        Command::Render(args) => cmd::render::run(args),
        Command::Calibrate(args) => cmd::calibrate::run(args),
        Command::Rectify(args) => cmd::rectify::run(args),
        Command::Capture(args) => cmd::capture::run(args),
        Command::Rig(args) => cmd::rig::run(args),
        Command::Flash(args) => cmd::flash::run(args),
        Command::Sim(args) => cmd::sim::run(args),
        Command::FitProfile(args) => cmd::fit::run_profile(args),
        Command::Fit(args) => cmd::fit::run_fit(args),
        Command::Compare(args) => cmd::compare::run(args),
        Command::Report(args) => cmd::report::run(args),
        Command::View(args) => cmd::view::run(args),
    }
}
