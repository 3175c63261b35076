// Sparse linear least squares with Eigen, for the global fit (Fitmaps §3.5)
// and the local refits of the simplification (§3.4).
#include "subdfit/cpp/eigen_bridge.h"

#include <Eigen/Core>
#include <Eigen/IterativeLinearSolvers>
#include <Eigen/OrderingMethods>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseQR>

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace subdfit::eigen {

rust::String library_version() {
  return rust::String(std::to_string(EIGEN_WORLD_VERSION) + "." + std::to_string(EIGEN_MAJOR_VERSION) + "." +
                      std::to_string(EIGEN_MINOR_VERSION));
}

namespace {
using SpMat = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

SpMat from_triplets(const char* name, std::size_t rows, std::size_t cols, rust::Slice<const uint32_t> r,
                    rust::Slice<const uint32_t> c, rust::Slice<const double> v) {
  if (r.size() != c.size() || r.size() != v.size()) {
    throw std::runtime_error(std::string(name) + ": triplet arrays differ in length");
  }
  std::vector<Eigen::Triplet<double, int>> t;
  t.reserve(v.size());
  for (std::size_t k = 0; k < v.size(); ++k) {
    if (r[k] >= rows || c[k] >= cols) {
      std::ostringstream s;
      s << name << ": entry " << k << " at (" << r[k] << ", " << c[k] << ") outside " << rows << " x " << cols;
      throw std::runtime_error(s.str());
    }
    if (!std::isfinite(v[k])) {
      std::ostringstream s;
      s << name << ": entry " << k << " at (" << r[k] << ", " << c[k] << ") is not finite";
      throw std::runtime_error(s.str());
    }
    t.emplace_back(int(r[k]), int(c[k]), v[k]);
  }
  SpMat m{Eigen::Index(rows), Eigen::Index(cols)};
  m.setFromTriplets(t.begin(), t.end());  // duplicates are summed
  return m;
}

// Conjugate gradients, Jacobi-preconditioned: for systems whose normal
// matrix is close to a mass matrix (every unknown pulled by data rows around
// it, as the displacement offsets' are), the condition number does not grow
// with the size and CG converges in tens of iterations, where LDL^T's
// fill-in grows as n^1.5 (567k offsets: 5.6 s with LDL^T, 2.2 s with CG
// and forming N). Single-threaded column-major products: the same bytes
// whatever the thread count. `tolerance` is the relative residual.
Eigen::MatrixXd conjugate_gradients(const SpMat &N, const Eigen::MatrixXd &rhs, double tolerance) {
  Eigen::MatrixXd X(N.cols(), rhs.cols());
  Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::DiagonalPreconditioner<double>> cg;
  cg.setTolerance(tolerance);
  cg.setMaxIterations(2000);
  cg.compute(N);
  if (cg.info() != Eigen::Success) throw std::runtime_error("conjugate gradients: set-up failed");
  for (Eigen::Index j = 0; j < rhs.cols(); ++j) {
    X.col(j) = cg.solve(rhs.col(j));
    if (cg.info() != Eigen::Success) {
      std::ostringstream s;
      s << "conjugate gradients did not converge in " << cg.iterations() << " iterations (residual "
        << cg.error() << ", tolerance " << tolerance << ")";
      throw std::runtime_error(s.str());
    }
  }
  return X;
}

// LDL^T of the normal equations: fast, and the fitting systems are well
// conditioned once the fairness term is in; a pivot check (relative pivot
// below `tolerance`) catches rank deficiency.
Eigen::MatrixXd ldlt_solve(const SpMat &N, const Eigen::MatrixXd &rhs, double tolerance) {
  Eigen::SimplicialLDLT<SpMat> ldlt;
  ldlt.compute(N);
  if (ldlt.info() != Eigen::Success) throw std::runtime_error("rank deficient: LDL^T factorisation failed");
  const Eigen::VectorXd d = ldlt.vectorD();
  const double dmax = d.cwiseAbs().maxCoeff();
  for (Eigen::Index i = 0; i < d.size(); ++i) {
    if (!(d[i] > tolerance * dmax)) {
      // vectorD is in the permuted order; report the original unknown.
      const int col = ldlt.permutationPinv().indices()[i];
      std::ostringstream s;
      s << "rank deficient: unknown " << col << " is not determined (pivot " << d[i] << ", largest " << dmax
        << ")";
      throw std::runtime_error(s.str());
    }
  }
  Eigen::MatrixXd X = ldlt.solve(rhs);
  if (ldlt.info() != Eigen::Success) throw std::runtime_error("LDL^T solve failed");
  return X;
}

}  // namespace

rust::Vec<double> sparse_least_squares(std::size_t rows_a, std::size_t cols, rust::Slice<const uint32_t> a_rows,
                                       rust::Slice<const uint32_t> a_cols, rust::Slice<const double> a_vals,
                                       std::size_t rows_r, rust::Slice<const uint32_t> r_rows,
                                       rust::Slice<const uint32_t> r_cols, rust::Slice<const double> r_vals,
                                       double lambda, rust::Slice<const double> b, std::size_t nrhs, uint32_t method,
                                       double tolerance) {
  if (cols == 0) throw std::runtime_error("no unknowns");
  if (b.size() != rows_a * nrhs) throw std::runtime_error("right-hand side has the wrong length");
  SpMat A = from_triplets("A", rows_a, cols, a_rows, a_cols, a_vals);
  SpMat R = from_triplets("R", rows_r, cols, r_rows, r_cols, r_vals);
  Eigen::Map<const Eigen::MatrixXd> B(b.data(), Eigen::Index(rows_a), Eigen::Index(nrhs));
  Eigen::MatrixXd X(cols, nrhs);

  if (method == 0 || method == 2) {
    // Both solve the normal equations N x = A^T b.
    SpMat N = SpMat(A.transpose() * A);
    if (lambda != 0.0 && rows_r > 0) N += lambda * SpMat(R.transpose() * R);
    Eigen::MatrixXd rhs = A.transpose() * B;
    if (method == 2)
      X = conjugate_gradients(N, rhs, tolerance);
    else
      X = ldlt_solve(N, rhs, tolerance);
  } else {
    // QR of the stacked system [A; sqrt(lambda) R]: slower, but avoids
    // squaring the condition number.
    SpMat S(int(rows_a + (lambda != 0.0 ? rows_r : 0)), int(cols));
    std::vector<Eigen::Triplet<double, int>> t;
    for (int k = 0; k < A.outerSize(); ++k)
      for (SpMat::InnerIterator it(A, k); it; ++it) t.emplace_back(int(it.row()), int(it.col()), it.value());
    if (lambda != 0.0) {
      const double s = std::sqrt(lambda);
      for (int k = 0; k < R.outerSize(); ++k)
        for (SpMat::InnerIterator it(R, k); it; ++it)
          t.emplace_back(int(rows_a + it.row()), int(it.col()), s * it.value());
    }
    S.setFromTriplets(t.begin(), t.end());
    S.makeCompressed();
    Eigen::MatrixXd Bs = Eigen::MatrixXd::Zero(S.rows(), Eigen::Index(nrhs));
    Bs.topRows(Eigen::Index(rows_a)) = B;
    Eigen::SparseQR<SpMat, Eigen::COLAMDOrdering<int>> qr;
    qr.setPivotThreshold(tolerance);
    qr.compute(S);
    if (qr.info() != Eigen::Success) throw std::runtime_error("sparse QR factorisation failed: " + qr.lastErrorMessage());
    if (qr.rank() < Eigen::Index(cols)) {
      std::ostringstream s;
      s << "rank deficient: rank " << qr.rank() << " < " << cols << " unknowns";
      throw std::runtime_error(s.str());
    }
    X = qr.solve(Bs);
    if (qr.info() != Eigen::Success) throw std::runtime_error("sparse QR solve failed");
  }
  rust::Vec<double> out;
  out.reserve(X.size());
  for (Eigen::Index j = 0; j < X.cols(); ++j)
    for (Eigen::Index i = 0; i < X.rows(); ++i) out.push_back(X(i, j));
  for (double x : out)
    if (!std::isfinite(x)) throw std::runtime_error("solution is not finite (ill-conditioned system)");
  return out;
}

rust::Vec<double> spd_conjugate_gradients(std::size_t n, rust::Slice<const int32_t> outer,
                                          rust::Slice<const int32_t> inner, rust::Slice<const double> vals,
                                          rust::Slice<const double> b, double tolerance) {
  if (n == 0) throw std::runtime_error("no unknowns");
  if (outer.size() != n + 1 || b.size() != n) throw std::runtime_error("matrix and right-hand side disagree in size");
  const std::size_t nnz = std::size_t(outer[n]);
  if (inner.size() != nnz || vals.size() != nnz) throw std::runtime_error("compressed rows have the wrong length");
  // N is symmetric, so its compressed rows are the compressed columns of
  // N^T = N: the column-major map needs no copy.
  const Eigen::Map<const SpMat> N{Eigen::Index(n), Eigen::Index(n), Eigen::Index(nnz), outer.data(), inner.data(),
                                  vals.data()};
  Eigen::Map<const Eigen::VectorXd> rhs(b.data(), Eigen::Index(n));
  // The solver keeps a Ref to the map (no copy of N).
  Eigen::ConjugateGradient<SpMat, Eigen::Lower | Eigen::Upper, Eigen::DiagonalPreconditioner<double>> cg;
  cg.setTolerance(tolerance);
  cg.setMaxIterations(2000);
  cg.compute(N);
  if (cg.info() != Eigen::Success) throw std::runtime_error("conjugate gradients: set-up failed");
  Eigen::VectorXd x = cg.solve(rhs);
  if (cg.info() != Eigen::Success) {
    std::ostringstream s;
    s << "conjugate gradients did not converge in " << cg.iterations() << " iterations (residual " << cg.error()
      << ", tolerance " << tolerance << ")";
    throw std::runtime_error(s.str());
  }
  rust::Vec<double> out;
  out.reserve(n);
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    if (!std::isfinite(x[i])) throw std::runtime_error("solution is not finite (ill-conditioned system)");
    out.push_back(x[i]);
  }
  return out;
}

}  // namespace subdfit::eigen
