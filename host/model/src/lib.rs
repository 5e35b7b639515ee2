//! The quasi-homogeneous material model: dipole, fitting, file format, report.
