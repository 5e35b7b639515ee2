//! One module per `qhm` subcommand.
pub mod calibrate;
pub mod capture;
pub mod compare;
pub mod demo;
pub mod fit;
pub mod flash;
pub mod rectify;
pub mod render;
pub mod report;
pub mod rig;
pub mod sim;
pub mod sim_object;
pub mod simpty;
pub mod view;
