//! Cross-crate tests: the whole pipeline on the simulated rig, faults.
