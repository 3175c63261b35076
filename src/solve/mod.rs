//! Sparse linear least squares through Eigen.
