//! The qhm program.
