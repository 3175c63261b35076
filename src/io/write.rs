//! Writers: OBJ (with OpenSubdiv shape-file sharpness tags) and binary PLY,
//! both through [`write_atomically`], so that a reader never sees a half
//! written file and a failed write leaves nothing behind.

use std::fs::{self, File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};
use crate::mesh::ControlMesh;
use crate::DVec3;

/// Writes `path` atomically: `body` writes into a temporary file in the same
/// directory (so the final rename stays on one file system and is atomic on
/// POSIX), which is flushed, fsynced and renamed over `path`. On any error
/// the temporary file is removed and `path` is left as it was.
///
/// `body` sees a buffered writer; its I/O errors are mapped to
/// [`Error::Io`] naming `path`.
pub fn write_atomically<F>(path: &Path, body: F) -> Result<()>
where
    F: FnOnce(&mut dyn Write) -> Result<()>,
{
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .ok_or_else(|| Error::InvalidArgument(format!("{}: not a file path", path.display())))?;
    let tmp = dir.join(format!(
        ".{}.tmp-{}-{}",
        name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .map_err(|e| Error::io(path, e))?;
    let result = (|| {
        let mut w = BufWriter::with_capacity(1 << 20, file);
        body(&mut w)?;
        let file: File = w
            .into_inner()
            .map_err(|e| Error::io(path, e.into_error()))?;
        file.sync_all().map_err(|e| Error::io(path, e))?;
        drop(file);
        fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Shortest decimal that parses back to the same `f64` (Rust's float
/// formatting is round-trip exact, like C's `%.17g` but shorter); scientific
/// notation outside the range where plain notation stays short.
pub(crate) fn fmt_f64(x: f64, out: &mut String) {
    use std::fmt::Write as _;
    let a = x.abs();
    if x == 0.0 || (1e-5..1e16).contains(&a) || !x.is_finite() {
        let _ = write!(out, "{x}");
    } else {
        let _ = write!(out, "{x:e}");
    }
}

fn check_polygons<F: AsRef<[u32]>>(path: &Path, nv: usize, polygons: &[F]) -> Result<()> {
    for (f, p) in polygons.iter().enumerate() {
        let p = p.as_ref();
        if p.len() < 3 {
            return Err(Error::InvalidArgument(format!(
                "{}: face {f} has {} vertices, needs at least 3",
                path.display(),
                p.len()
            )));
        }
        if let Some(&i) = p.iter().find(|&&i| i as usize >= nv) {
            return Err(Error::InvalidArgument(format!(
                "{}: face {f}: vertex index {i} out of range ({nv} vertices)",
                path.display()
            )));
        }
    }
    Ok(())
}

/// Writes an OBJ file: `v` lines with round-trippable coordinates, `f` lines
/// (1-based), then creases as `t crease 2/1/0 a b s` and corners as
/// `t corner 1/1/0 v s` (OpenSubdiv shape-file tags, 0-based indices).
pub fn write_obj<F: AsRef<[u32]>>(
    path: &Path,
    positions: &[DVec3],
    polygons: &[F],
    creases: &[(u32, u32, f64)],
    corners: &[(u32, f64)],
) -> Result<()> {
    let nv = positions.len();
    check_polygons(path, nv, polygons)?;
    for &(a, b, s) in creases {
        if a as usize >= nv || b as usize >= nv || !s.is_finite() {
            return Err(Error::InvalidArgument(format!(
                "{}: crease ({a}, {b}, {s}) out of range or not finite",
                path.display()
            )));
        }
    }
    for &(v, s) in corners {
        if v as usize >= nv || !s.is_finite() {
            return Err(Error::InvalidArgument(format!(
                "{}: corner ({v}, {s}) out of range or not finite",
                path.display()
            )));
        }
    }
    write_atomically(path, |w| {
        let io = |e| Error::io(path, e);
        let mut line = String::with_capacity(128);
        writeln!(
            w,
            "# subdfit {}\n# {} vertices, {} faces, {} creases, {} corners",
            env!("CARGO_PKG_VERSION"),
            nv,
            polygons.len(),
            creases.len(),
            corners.len()
        )
        .map_err(io)?;
        for p in positions {
            line.clear();
            line.push('v');
            for c in p.to_array() {
                line.push(' ');
                fmt_f64(c, &mut line);
            }
            line.push('\n');
            w.write_all(line.as_bytes()).map_err(io)?;
        }
        for p in polygons {
            line.clear();
            line.push('f');
            for &i in p.as_ref() {
                use std::fmt::Write as _;
                let _ = write!(line, " {}", i as u64 + 1);
            }
            line.push('\n');
            w.write_all(line.as_bytes()).map_err(io)?;
        }
        for &(a, b, s) in creases {
            line.clear();
            line.push_str(&format!("t crease 2/1/0 {a} {b} "));
            fmt_f64(s, &mut line);
            line.push('\n');
            w.write_all(line.as_bytes()).map_err(io)?;
        }
        for &(v, s) in corners {
            line.clear();
            line.push_str(&format!("t corner 1/1/0 {v} "));
            fmt_f64(s, &mut line);
            line.push('\n');
            w.write_all(line.as_bytes()).map_err(io)?;
        }
        Ok(())
    })
}

/// Writes a control mesh, with its creases and corners, as OBJ.
pub fn write_control_obj(path: &Path, mesh: &ControlMesh) -> Result<()> {
    let creases: Vec<(u32, u32, f64)> = mesh
        .creases()
        .into_iter()
        .map(|(a, b, s)| (a.0, b.0, s))
        .collect();
    let corners: Vec<(u32, f64)> = mesh.corners().into_iter().map(|(v, s)| (v.0, s)).collect();
    write_obj(
        path,
        mesh.positions(),
        &mesh.to_polygons(),
        &creases,
        &corners,
    )
}

/// Writes a control mesh with its scheme options as an OpenSubdiv shape
/// file: [`write_control_obj`] plus the `t` tags of [`scheme_tags`], which
/// `read_control_file` reads back.
pub fn write_control_file(
    path: &Path,
    mesh: &ControlMesh,
    scheme: &crate::mesh::SchemeOptions,
) -> Result<()> {
    write_control_obj(path, mesh)?;
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(path)
        .map_err(|e| Error::io(path, e))?;
    f.write_all(scheme_tags(scheme).as_bytes())
        .map_err(|e| Error::io(path, e))
}

/// The shape-file tags stating `scheme` (all four options, and the holes).
pub fn scheme_tags(scheme: &crate::mesh::SchemeOptions) -> String {
    use crate::mesh::TriangleSubdivision as T;
    use crate::mesh::{BoundaryInterpolation as B, CreaseMethod as C, FVarLinear as F};
    let b = match scheme.boundary {
        B::None => 0,
        B::EdgeAndCorner => 1,
        B::EdgeOnly => 2,
    };
    let fv = match scheme.fvar {
        F::None => 0,
        F::CornersOnly => 1,
        F::CornersPlus1 => 2,
        F::CornersPlus2 => 3,
        F::Boundaries => 4,
        F::All => 5,
    };
    let c = match scheme.crease_method {
        C::Uniform => "normal",
        C::Chaikin => "chaikin",
    };
    let t = match scheme.triangles {
        T::Catmark => "catmark",
        T::Smooth => "smooth",
    };
    let mut s = format!(
        "t interpolateboundary 1/0/0 {b}\nt facevaryinginterpolateboundary 1/0/0 {fv}\n\
         t creasemethod 0/0/1 {c}\nt smoothtriangles 0/0/1 {t}\n"
    );
    if !scheme.holes.is_empty() {
        s += &format!("t hole {}/0/0", scheme.holes.len());
        for h in &scheme.holes {
            s += &format!(" {}", h.0);
        }
        s += "\n";
    }
    s
}

/// Writes a binary little-endian PLY: `float` x, y, z, then one `float`
/// property per entry of `vertex_props` (name, one value per vertex), then
/// optional `uchar` red, green, blue; faces as `list uchar int
/// vertex_indices`. Positions are stored in single precision, which is what
/// viewers expect; OBJ is the lossless format.
pub fn write_ply<F: AsRef<[u32]>>(
    path: &Path,
    positions: &[DVec3],
    polygons: &[F],
    vertex_props: &[(&str, &[f32])],
    colors: Option<&[[u8; 3]]>,
) -> Result<()> {
    let nv = positions.len();
    check_polygons(path, nv, polygons)?;
    let reserved = ["x", "y", "z", "red", "green", "blue"];
    for (k, (name, values)) in vertex_props.iter().enumerate() {
        let bad_name = name.is_empty()
            || name.bytes().any(|b| !b.is_ascii_graphic())
            || reserved.contains(name)
            || vertex_props[..k].iter().any(|(n, _)| n == name);
        if bad_name {
            return Err(Error::InvalidArgument(format!(
                "{}: vertex property name '{name}' is empty, not a single printable token, reserved or repeated",
                path.display()
            )));
        }
        if values.len() != nv {
            return Err(Error::InvalidArgument(format!(
                "{}: vertex property '{name}' has {} values for {nv} vertices",
                path.display(),
                values.len()
            )));
        }
    }
    if let Some(c) = colors {
        if c.len() != nv {
            return Err(Error::InvalidArgument(format!(
                "{}: {} colours for {nv} vertices",
                path.display(),
                c.len()
            )));
        }
    }
    if let Some((f, p)) = polygons
        .iter()
        .enumerate()
        .find(|(_, p)| p.as_ref().len() > u8::MAX as usize)
    {
        return Err(Error::InvalidArgument(format!(
            "{}: face {f} has {} corners; PLY's uchar list count holds at most 255",
            path.display(),
            p.as_ref().len()
        )));
    }
    if nv > i32::MAX as usize {
        return Err(Error::InvalidArgument(format!(
            "{}: {nv} vertices do not fit PLY int indices",
            path.display()
        )));
    }
    write_atomically(path, |w| {
        let io = |e| Error::io(path, e);
        let mut header = format!(
            "ply\nformat binary_little_endian 1.0\ncomment subdfit {}\nelement vertex {nv}\n\
             property float x\nproperty float y\nproperty float z\n",
            env!("CARGO_PKG_VERSION")
        );
        for (name, _) in vertex_props {
            header.push_str(&format!("property float {name}\n"));
        }
        if colors.is_some() {
            header.push_str("property uchar red\nproperty uchar green\nproperty uchar blue\n");
        }
        header.push_str(&format!(
            "element face {}\nproperty list uchar int vertex_indices\nend_header\n",
            polygons.len()
        ));
        w.write_all(header.as_bytes()).map_err(io)?;
        let mut rec = Vec::with_capacity(12 + 4 * vertex_props.len() + 3);
        for (i, p) in positions.iter().enumerate() {
            rec.clear();
            for c in p.to_array() {
                rec.extend_from_slice(&(c as f32).to_le_bytes());
            }
            for (_, values) in vertex_props {
                rec.extend_from_slice(&values[i].to_le_bytes());
            }
            if let Some(c) = colors {
                rec.extend_from_slice(&c[i]);
            }
            w.write_all(&rec).map_err(io)?;
        }
        for p in polygons {
            let p = p.as_ref();
            rec.clear();
            rec.push(p.len() as u8);
            for &i in p {
                rec.extend_from_slice(&(i as i32).to_le_bytes());
            }
            w.write_all(&rec).map_err(io)?;
        }
        Ok(())
    })
}
