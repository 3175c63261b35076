//! `subdfit metrics MESH CONTROL [--json]`: Table 1's accuracy and
//! projectability for any control mesh (implementation in `fit.rs`, which
//! shares the mesh/control loading with `subdfit fit`).

pub use crate::fit::{metrics_cmd as metrics, MetricsArgs};
