//! The simulated world: quasi-homogeneous samples, Monte Carlo light transport, camera sensors, calibration targets.
