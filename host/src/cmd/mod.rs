//! One module per `qhm` subcommand.
