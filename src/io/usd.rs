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
//! - stage metadata `metersPerUnit` (what one unit of the input is, from
//!   `--units`; readers assume centimetres when it is missing) and
//!   `upAxis = "Y"`;
//! - with a texture ([`UsdOptions::texture`]), a `UsdPreviewSurface`
//!   material bound to the mesh whose `displacement` input reads the atlas
//!   through a `UsdUVTexture` (`sourceColorSpace = "raw"`: the texels are
//!   distances, not colours; `r` output, scale 1, bias 0) fed by a
//!   `UsdPrimvarReader_float2` of `st`. UsdPreviewSurface displaces along
//!   the normal by the value in scene units, which is our offset.
//!
//! Layout: `/subdfit` (an Xform, the default prim) holds the Mesh
//! `control` and the Scope `materials`.
//!
//! Points are `point3f` (UsdGeomMesh's type); the OBJ keeps full precision.

use std::fmt::Write as _;
use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::DVec2;

/// What [`write_usda_with`] writes besides the mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct UsdOptions {
    /// `metersPerUnit` of the stage: the length of one unit of the points.
    pub meters_per_unit: f64,
    /// The displacement texture, relative to the `.usda` (e.g.
    /// `displacement.exr`, `displacement.<UDIM>.exr`): a material reading
    /// it is bound to the mesh. Needs `uvs`.
    pub texture: Option<String>,
}

impl Default for UsdOptions {
    /// Metres, no material.
    fn default() -> Self {
        UsdOptions {
            meters_per_unit: 1.0,
            texture: None,
        }
    }
}

/// Writes `mesh` to `path` (atomically), in metres, without a material.
/// `uvs`: per face, one UV per corner in the face's corner order.
pub fn write_usda(path: &Path, mesh: &ControlMesh, uvs: Option<&[[DVec2; 4]]>) -> Result<()> {
    write_usda_with(path, mesh, uvs, &UsdOptions::default())
}

/// [`write_usda`] with `opts` (units, material).
pub fn write_usda_with(
    path: &Path,
    mesh: &ControlMesh,
    uvs: Option<&[[DVec2; 4]]>,
    opts: &UsdOptions,
) -> Result<()> {
    if !(opts.meters_per_unit.is_finite() && opts.meters_per_unit > 0.0) {
        return Err(Error::option(
            "units",
            format!(
                "{}: metersPerUnit {} must be finite and > 0",
                path.display(),
                opts.meters_per_unit
            ),
        ));
    }
    if opts.texture.is_some() && uvs.is_none() {
        return Err(Error::InvalidArgument(format!(
            "{}: a displacement texture needs UVs",
            path.display()
        )));
    }
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
    let text = usda_text_with(mesh, uvs, opts);
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

/// The `.usda` text of [`write_usda`].
pub fn usda_text(mesh: &ControlMesh, uvs: Option<&[[DVec2; 4]]>) -> String {
    usda_text_with(mesh, uvs, &UsdOptions::default())
}

/// Where the material lives, for the binding and the connections.
const MATERIAL: &str = "/subdfit/materials/displacement";

/// The `.usda` text (deterministic: the same mesh gives the same bytes).
pub fn usda_text_with(mesh: &ControlMesh, uvs: Option<&[[DVec2; 4]]>, opts: &UsdOptions) -> String {
    let mut s = String::with_capacity(64 * mesh.num_vertices() + 1024);
    let (lo, hi) = mesh.bbox();
    let v3 = |s: &mut String, p: crate::DVec3| {
        let _ = write!(s, "({}, {}, {})", p.x as f32, p.y as f32, p.z as f32);
    };
    let _ = writeln!(
        s,
        "#usda 1.0\n(\n    defaultPrim = \"subdfit\"\n    doc = \"subdfit {}: Catmull-Clark control mesh\"\n    metersPerUnit = {}\n    upAxis = \"Y\"\n)\n\ndef Xform \"subdfit\"\n{{",
        env!("CARGO_PKG_VERSION"),
        opts.meters_per_unit
    );
    let texture = opts.texture.as_deref().filter(|_| uvs.is_some());
    if texture.is_some() {
        s.push_str("    def Mesh \"control\" (\n        prepend apiSchemas = [\"MaterialBindingAPI\"]\n    )\n    {\n");
        let _ = writeln!(s, "        rel material:binding = <{MATERIAL}>");
    } else {
        s.push_str("    def Mesh \"control\"\n    {\n");
    }
    s.push_str("        uniform token subdivisionScheme = \"catmullClark\"\n");
    s.push_str("        uniform token interpolateBoundary = \"edgeAndCorner\"\n");
    s.push_str("        uniform token faceVaryingLinearInterpolation = \"all\"\n");
    s.push_str("        uniform token orientation = \"rightHanded\"\n");
    s.push_str("        float3[] extent = ");
    list(&mut s, [lo, hi], v3);
    s.push_str("\n        int[] faceVertexCounts = ");
    list(&mut s, mesh.face_sizes(), |s, n| {
        let _ = write!(s, "{n}");
    });
    s.push_str("\n        int[] faceVertexIndices = ");
    list(&mut s, mesh.face_indices_flat(), |s, i| {
        let _ = write!(s, "{i}");
    });
    s.push_str("\n        point3f[] points = ");
    list(&mut s, mesh.positions().iter().copied(), v3);
    s.push('\n');
    let creases = mesh.creases();
    if !creases.is_empty() {
        s.push_str("        int[] creaseIndices = ");
        list(&mut s, creases.iter(), |s, c| {
            let _ = write!(s, "{}, {}", c.0 .0, c.1 .0);
        });
        s.push_str("\n        int[] creaseLengths = ");
        list(&mut s, creases.iter(), |s, _| s.push('2'));
        s.push_str("\n        float[] creaseSharpnesses = ");
        list(&mut s, creases.iter(), |s, c| {
            let _ = write!(s, "{}", c.2 as f32);
        });
        s.push('\n');
    }
    let corners = mesh.corners();
    if !corners.is_empty() {
        s.push_str("        int[] cornerIndices = ");
        list(&mut s, corners.iter(), |s, c| {
            let _ = write!(s, "{}", c.0 .0);
        });
        s.push_str("\n        float[] cornerSharpnesses = ");
        list(&mut s, corners.iter(), |s, c| {
            let _ = write!(s, "{}", c.1 as f32);
        });
        s.push('\n');
    }
    if let Some(uvs) = uvs {
        s.push_str("        texCoord2f[] primvars:st = ");
        list(&mut s, uvs.iter().flatten(), |s, uv| {
            let _ = write!(s, "({}, {})", uv.x as f32, uv.y as f32);
        });
        s.push_str(" (\n            interpolation = \"faceVarying\"\n        )\n");
        s.push_str("        int[] primvars:st:indices = ");
        list(&mut s, 0..4 * uvs.len(), |s, i| {
            let _ = write!(s, "{i}");
        });
        s.push('\n');
    }
    s.push_str("    }\n");
    if let Some(t) = texture {
        material(&mut s, t);
    }
    s.push_str("}\n");
    s
}

/// The material of the module docs, reading `texture`.
fn material(s: &mut String, texture: &str) {
    let _ = write!(
        s,
        r#"
    def Scope "materials"
    {{
        def Material "displacement"
        {{
            token outputs:surface.connect = <{MATERIAL}/surface.outputs:surface>
            token outputs:displacement.connect = <{MATERIAL}/surface.outputs:displacement>

            def Shader "surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0.6, 0.6, 0.6)
                float inputs:roughness = 0.5
                float inputs:displacement.connect = <{MATERIAL}/texture.outputs:r>
                token outputs:surface
                token outputs:displacement
            }}

            def Shader "texture"
            {{
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @./{texture}@
                token inputs:sourceColorSpace = "raw"
                float2 inputs:st.connect = <{MATERIAL}/st.outputs:result>
                token inputs:wrapS = "clamp"
                token inputs:wrapT = "clamp"
                float4 inputs:scale = (1, 1, 1, 1)
                float4 inputs:bias = (0, 0, 0, 0)
                float outputs:r
            }}

            def Shader "st"
            {{
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "st"
                float2 outputs:result
            }}
        }}
    }}
"#
    );
}
