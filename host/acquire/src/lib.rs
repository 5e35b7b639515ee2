//! Acquisition: cameras, calibration, capture planning and runs, HDR, rectification.
