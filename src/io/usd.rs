//! `control.usda`: the control mesh as a UsdGeomMesh in USD's text format,
//! ready for any USD renderer to subdivide:
//! - `subdivisionScheme = "catmullClark"`, `interpolateBoundary =
//!   "edgeAndCorner"` (the convention of [`crate::subdiv`]);
//! - creases as `creaseIndices` / `creaseLengths` (one crease of 2 vertices
//!   per sharp edge) / `creaseSharpnesses`, corners as `cornerIndices` /
//!   `cornerSharpnesses`; USD, like OpenSubdiv, reads 10 as infinitely sharp;
//! - the displacement atlas UVs as `primvars:st`, `texCoord2f[]`,
//!   face-varying and indexed, with `faceVaryingLinearInterpolation =
//!   "all"`: the UVs are piecewise bilinear over each patch (a tile per
//!   patch, seams everywhere), so they must not be smoothed.
//!
//! Points are `point3f` (UsdGeomMesh's type); the OBJ keeps full precision.

use std::fmt::Write as _;
use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::DVec2;

/// Writes `mesh` to `path` (atomically). `uvs`: per face, one UV per corner
/// in the face's corner order.
pub fn write_usda(path: &Path, mesh: &ControlMesh, uvs: Option<&[[DVec2; 4]]>) -> Result<()> {
    if let Some(u) = uvs {
        if u.len() != mesh.num_faces() || !mesh.is_all_quads() {
            return Err(Error::InvalidArgument(format!(
                "{}: {} UV quads for {} faces (UVs need a pure-quad mesh)",
                path.display(),
                u.len(),
                mesh.num_faces()
            )));
        }
    }
    let text = usda_text(mesh, uvs);
    super::write_atomically(path, |w| {
        w.write_all(text.as_bytes()).map_err(|e| Error::io(path, e))
    })
}

fn list<T>(
    out: &mut String,
    items: impl IntoIterator<Item = T>,
    mut f: impl FnMut(&mut String, T),
) {
    out.push('[');
    for (k, it) in items.into_iter().enumerate() {
        if k > 0 {
            out.push_str(", ");
        }
        f(out, it);
    }
    out.push(']');
}

/// The `.usda` text (deterministic: the same mesh gives the same bytes).
pub fn usda_text(mesh: &ControlMesh, uvs: Option<&[[DVec2; 4]]>) -> String {
    let mut s = String::with_capacity(64 * mesh.num_vertices() + 1024);
    let (lo, hi) = mesh.bbox();
    let v3 = |s: &mut String, p: crate::DVec3| {
        let _ = write!(s, "({}, {}, {})", p.x as f32, p.y as f32, p.z as f32);
    };
    let _ = writeln!(
        s,
        "#usda 1.0\n(\n    defaultPrim = \"control\"\n    doc = \"subdfit {}: Catmull-Clark control mesh\"\n    upAxis = \"Y\"\n)\n\ndef Mesh \"control\"\n{{",
        env!("CARGO_PKG_VERSION")
    );
    s.push_str("    uniform token subdivisionScheme = \"catmullClark\"\n");
    s.push_str("    uniform token interpolateBoundary = \"edgeAndCorner\"\n");
    s.push_str("    uniform token faceVaryingLinearInterpolation = \"all\"\n");
    s.push_str("    uniform token orientation = \"rightHanded\"\n");
    s.push_str("    float3[] extent = ");
    list(&mut s, [lo, hi], v3);
    s.push_str("\n    int[] faceVertexCounts = ");
    list(&mut s, mesh.face_sizes(), |s, n| {
        let _ = write!(s, "{n}");
    });
    s.push_str("\n    int[] faceVertexIndices = ");
    list(&mut s, mesh.face_indices_flat(), |s, i| {
        let _ = write!(s, "{i}");
    });
    s.push_str("\n    point3f[] points = ");
    list(&mut s, mesh.positions().iter().copied(), v3);
    s.push('\n');
    let creases = mesh.creases();
    if !creases.is_empty() {
        s.push_str("    int[] creaseIndices = ");
        list(&mut s, creases.iter(), |s, c| {
            let _ = write!(s, "{}, {}", c.0 .0, c.1 .0);
        });
        s.push_str("\n    int[] creaseLengths = ");
        list(&mut s, creases.iter(), |s, _| s.push('2'));
        s.push_str("\n    float[] creaseSharpnesses = ");
        list(&mut s, creases.iter(), |s, c| {
            let _ = write!(s, "{}", c.2 as f32);
        });
        s.push('\n');
    }
    let corners = mesh.corners();
    if !corners.is_empty() {
        s.push_str("    int[] cornerIndices = ");
        list(&mut s, corners.iter(), |s, c| {
            let _ = write!(s, "{}", c.0 .0);
        });
        s.push_str("\n    float[] cornerSharpnesses = ");
        list(&mut s, corners.iter(), |s, c| {
            let _ = write!(s, "{}", c.1 as f32);
        });
        s.push('\n');
    }
    if let Some(uvs) = uvs {
        s.push_str("    texCoord2f[] primvars:st = ");
        list(&mut s, uvs.iter().flatten(), |s, uv| {
            let _ = write!(s, "({}, {})", uv.x as f32, uv.y as f32);
        });
        s.push_str(" (\n        interpolation = \"faceVarying\"\n    )\n");
        s.push_str("    int[] primvars:st:indices = ");
        list(&mut s, 0..4 * uvs.len(), |s, i| {
            let _ = write!(s, "{i}");
        });
        s.push('\n');
    }
    s.push_str("}\n");
    s
}
