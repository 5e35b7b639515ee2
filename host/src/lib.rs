//! The qhm program's library side: glue between the pipeline crates
//! (`qhm-link`, `qhm-acquire`, `qhm-model`, `qhm-render`) used by the binary
//! and by the cross-crate tests.
