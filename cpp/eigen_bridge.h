#pragma once
#include "rust/cxx.h"

#include <cstdint>

namespace subdfit::eigen {
rust::String library_version();

// Minimises |A x - b|^2 + lambda |R x|^2 for `nrhs` right-hand sides.
// A is rows_a x cols, R is rows_r x cols, both as triplets (row, col, value).
// b is column-major, rows_a * nrhs. Returns x column-major, cols * nrhs.
// method 0: Cholesky (LDL^T) of the normal equations; 1: sparse QR of the
// stacked system. Throws std::runtime_error naming the cause on failure or
// rank deficiency (which cxx turns into a Rust Err).
rust::Vec<double> sparse_least_squares(std::size_t rows_a, std::size_t cols, rust::Slice<const uint32_t> a_rows,
                                       rust::Slice<const uint32_t> a_cols, rust::Slice<const double> a_vals,
                                       std::size_t rows_r, rust::Slice<const uint32_t> r_rows,
                                       rust::Slice<const uint32_t> r_cols, rust::Slice<const double> r_vals,
                                       double lambda, rust::Slice<const double> b, std::size_t nrhs, uint32_t method,
                                       double tolerance);

// Solves N x = b for a symmetric positive definite N given whole (both
// triangles) in compressed rows: row i's columns are inner[outer[i]..outer[i+1]]
// (sorted), its values vals[...]. Jacobi-preconditioned conjugate gradients to
// a relative residual of `tolerance`; throws when it does not converge or the
// solution is not finite.
rust::Vec<double> spd_conjugate_gradients(std::size_t n, rust::Slice<const int32_t> outer,
                                          rust::Slice<const int32_t> inner, rust::Slice<const double> vals,
                                          rust::Slice<const double> b, double tolerance);
}  // namespace subdfit::eigen
