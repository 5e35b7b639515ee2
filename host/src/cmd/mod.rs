//! One module per `qhm` subcommand.
pub mod calibrate;
pub mod rectify;
