//! `control.obj` with texture coordinates: the control mesh (as
//! [`super::write_control_obj`]: round-trippable `v` lines, OpenSubdiv
//! shape-file `t crease` / `t corner` tags) plus one `vt` per face corner
//! and `f v/vt` faces, so the displacement atlas maps onto each patch.

use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::DVec2;

use super::write::fmt_f64;

/// Writes `mesh` with per-face corner UVs `uvs` (one `[DVec2; 4]` per quad,
/// in the face's corner order) to `path`, atomically.
pub fn write_control_obj_with_uvs(
    path: &Path,
    mesh: &ControlMesh,
    uvs: &[[DVec2; 4]],
) -> Result<()> {
    check_uvs(path, mesh, uvs)?;
    super::write_atomically(path, |w| emit(w, mesh, uvs).map_err(|e| Error::io(path, e)))
}

/// The bytes [`write_control_obj_with_uvs`] writes, in memory (the C++ API
/// hands them to hosts so their files match the CLI's byte for byte).
pub fn control_obj_with_uvs(mesh: &ControlMesh, uvs: &[[DVec2; 4]]) -> Result<Vec<u8>> {
    let name = Path::new("control.obj");
    let mut out = Vec::new();
    check_uvs(name, mesh, uvs)?;
    emit(&mut out, mesh, uvs).map_err(|e| Error::io(name, e))?;
    Ok(out)
}

fn check_uvs(path: &Path, mesh: &ControlMesh, uvs: &[[DVec2; 4]]) -> Result<()> {
    if uvs.len() != mesh.num_faces() || !mesh.is_all_quads() {
        return Err(Error::InvalidArgument(format!(
            "{}: {} UV quads for {} faces (UVs need a pure-quad mesh)",
            path.display(),
            uvs.len(),
            mesh.num_faces()
        )));
    }
    if uvs.iter().flatten().any(|u| !u.is_finite()) {
        return Err(Error::InvalidArgument(format!(
            "{}: non-finite UV",
            path.display()
        )));
    }
    Ok(())
}

fn emit(w: &mut dyn std::io::Write, mesh: &ControlMesh, uvs: &[[DVec2; 4]]) -> std::io::Result<()> {
    let creases = mesh.creases();
    let corners = mesh.corners();
    let mut s = String::with_capacity(1 << 16);
    s.push_str(&format!(
        "# subdfit {}\n# {} vertices, {} faces, {} creases, {} corners; vt: displacement.exr atlas\n",
        env!("CARGO_PKG_VERSION"),
        mesh.num_vertices(),
        mesh.num_faces(),
        creases.len(),
        corners.len()
    ));
    let flush = |s: &mut String, w: &mut dyn std::io::Write| -> std::io::Result<()> {
        w.write_all(s.as_bytes())?;
        s.clear();
        Ok(())
    };
    for p in mesh.positions() {
        s.push('v');
        for c in p.to_array() {
            s.push(' ');
            fmt_f64(c, &mut s);
        }
        s.push('\n');
        if s.len() > 1 << 15 {
            flush(&mut s, w)?;
        }
    }
    for uv in uvs.iter().flatten() {
        s.push_str("vt ");
        fmt_f64(uv.x, &mut s);
        s.push(' ');
        fmt_f64(uv.y, &mut s);
        s.push('\n');
        if s.len() > 1 << 15 {
            flush(&mut s, w)?;
        }
    }
    for (f, verts) in mesh.to_polygons().iter().enumerate() {
        s.push('f');
        for (k, &v) in verts.iter().enumerate() {
            s.push_str(&format!(" {}/{}", v as u64 + 1, 4 * f + k + 1));
        }
        s.push('\n');
        if s.len() > 1 << 15 {
            flush(&mut s, w)?;
        }
    }
    for (a, b, sh) in creases {
        s.push_str(&format!("t crease 2/1/0 {} {} ", a.0, b.0));
        fmt_f64(sh, &mut s);
        s.push('\n');
    }
    for (v, sh) in corners {
        s.push_str(&format!("t corner 1/1/0 {} ", v.0));
        fmt_f64(sh, &mut s);
        s.push('\n');
    }
    flush(&mut s, w)
}
