//! The cxx bridge to `cpp/eigen_bridge.h`: Eigen's sparse least squares
//! and conjugate gradients for [`crate::solve`], which owns the systems;
//! only arrays cross (triplets, right-hand sides, solutions).

#[cxx::bridge(namespace = "subdfit::eigen")]
pub(crate) mod bridge {
    unsafe extern "C++" {
        include!("subdfit/cpp/eigen_bridge.h");
        /// Version string of the wrapped library (smoke test of the bridge).
        fn library_version() -> Result<String>;

        /// See `cpp/eigen_bridge.h`.
        #[allow(clippy::too_many_arguments)]
        fn sparse_least_squares(
            rows_a: usize,
            cols: usize,
            a_rows: &[u32],
            a_cols: &[u32],
            a_vals: &[f64],
            rows_r: usize,
            r_rows: &[u32],
            r_cols: &[u32],
            r_vals: &[f64],
            lambda: f64,
            b: &[f64],
            nrhs: usize,
            method: u32,
            tolerance: f64,
        ) -> Result<Vec<f64>>;

        /// See `cpp/eigen_bridge.h`.
        fn spd_conjugate_gradients(
            n: usize,
            outer: &[i32],
            inner: &[i32],
            vals: &[f64],
            b: &[f64],
            tolerance: f64,
        ) -> Result<Vec<f64>>;
    }
}
