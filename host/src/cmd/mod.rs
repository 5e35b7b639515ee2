//! One module per `qhm` subcommand.
pub mod capture;
pub mod calibrate;
pub mod rectify;
pub mod report;
pub mod fit;
pub mod flash;
pub mod rig;
pub mod sim;
pub mod simpty;
pub mod render;
