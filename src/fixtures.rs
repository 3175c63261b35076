//! Procedural control meshes for tests and benchmarks.

use crate::mesh::ControlMesh;
use crate::DVec3;

/// The cube `[-1, 1]^3` as six quads, outward orientation.
pub fn cube() -> ControlMesh {
    let p: Vec<DVec3> = (0..8)
        .map(|i| {
            DVec3::new(
                (i & 1) as f64 * 2.0 - 1.0,
                ((i >> 1) & 1) as f64 * 2.0 - 1.0,
                ((i >> 2) & 1) as f64 * 2.0 - 1.0,
            )
        })
        .collect();
    let f = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    ControlMesh::from_polygons(p, &f).expect("cube is a valid control mesh")
}
