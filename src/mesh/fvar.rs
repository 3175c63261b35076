//! Face-varying data: one value per face corner, shared between corners by
//! index (an OBJ file's `vt` records and `f v/vt` corners). Corners of one
//! vertex with different indices are a seam: the data is discontinuous
//! there while the surface is not. How such data is subdivided (Sdc's
//! `FVarLinearInterpolation`) is a scheme option ([`super::FVarLinear`]);
//! the evaluation is `crate::subdiv::fvar`'s.

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::DVec2;

/// A face-varying channel (UVs) of a control mesh.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FVarChannel {
    /// The distinct values, indexed by `indices`.
    pub values: Vec<DVec2>,
    /// One value index per face corner, in the order of
    /// [`ControlMesh::face_indices_flat`].
    pub indices: Vec<u32>,
}

impl FVarChannel {
    /// Checks the channel against `mesh`: one index per corner, each in
    /// range, every value finite. The error names the face.
    pub fn check(&self, mesh: &ControlMesh) -> Result<()> {
        let corners: usize = mesh.faces().map(|f| mesh.face_size(f)).sum();
        if self.indices.len() != corners {
            return Err(Error::invalid_data(
                "face-varying channel",
                "indices",
                format!(
                    "{} corner indices for a mesh of {corners} face corners",
                    self.indices.len()
                ),
            ));
        }
        let mut c = 0;
        for f in mesh.faces() {
            for _ in 0..mesh.face_size(f) {
                let i = self.indices[c];
                if i as usize >= self.values.len() {
                    return Err(Error::invalid_data(
                        "face-varying channel",
                        format!("face {}", f.0),
                        format!("uses value {i}, but there are {} values", self.values.len()),
                    ));
                }
                c += 1;
            }
        }
        if let Some(i) = self.values.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid_data(
                "face-varying channel",
                format!("value {i}"),
                "is not finite",
            ));
        }
        Ok(())
    }
}
