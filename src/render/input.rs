//! What a picture is made from: a mesh file, or the output folder of
//! `subdfit convert` / `fit` (file names of [`crate::report::OUTPUT_NAMES`]).

use std::path::{Path, PathBuf};

use crate::analysis::{compute_fitmap, FitmapOptions};
use crate::error::{Error, Result};
use crate::io::{read_control_mesh, read_mesh, read_soup};
use crate::mesh::{ControlMesh, TriMesh};
use crate::raycast::{make_raycaster, RayBackend};

/// `(F_S, F_M)` per vertex.
pub type FitmapFields = (Vec<f64>, Vec<f64>);

/// The data behind the pictures, loaded on demand and kept.
pub struct Sources {
    /// The mesh file, or the output folder.
    pub path: PathBuf,
    pub is_dir: bool,
    /// Overrides the input mesh M of an output folder.
    pub input_override: Option<PathBuf>,
    input: Option<TriMesh>,
    control: Option<ControlMesh>,
    fitmap: Option<FitmapFields>,
}

impl Sources {
    /// `path` is a mesh file or an output folder; `input_override` names
    /// the input mesh M of a folder when it is not to be taken from
    /// `fitmap.ply` (which holds M's geometry) or `report.json`.
    pub fn new(path: &Path, input_override: Option<&Path>) -> Result<Sources> {
        let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
        Ok(Sources {
            path: path.to_path_buf(),
            is_dir: meta.is_dir(),
            input_override: input_override.map(Path::to_path_buf),
            input: None,
            control: None,
            fitmap: None,
        })
    }

    fn file(&self, name: &str) -> Result<PathBuf> {
        let p = self.path.join(name);
        if p.is_file() {
            Ok(p)
        } else {
            Err(Error::io(
                &p,
                std::io::Error::new(
                    std::io::ErrorKind::NotFound,
                    "missing from the output folder (written by `subdfit convert` / `fit`)",
                ),
            ))
        }
    }

    fn needs_dir(&self, what: &str) -> Result<()> {
        if self.is_dir {
            Ok(())
        } else {
            Err(Error::option(
                "input",
                format!(
                    "{}: the {what} picture needs a `subdfit convert` output folder, not a mesh file",
                    self.path.display()
                ),
            ))
        }
    }

    /// The input mesh M: the mesh file itself; for a folder, the override,
    /// else `fitmap.ply` (M's geometry with the Fitmap), else the mesh named
    /// in `report.json`.
    pub fn input(&mut self) -> Result<&TriMesh> {
        if self.input.is_none() {
            // Errors say which mesh, as the other commands do.
            let input = |e: crate::Error| e.in_role("input mesh");
            let mesh = if let Some(p) = &self.input_override {
                read_mesh(p).map_err(input)?.mesh
            } else if !self.is_dir {
                read_mesh(&self.path).map_err(input)?.mesh
            } else if let Ok(p) = self.file("fitmap.ply") {
                read_trimesh_as_is(&p).map_err(input)?
            } else {
                let p = self.report_mesh_path()?;
                read_mesh(&p).map_err(input)?.mesh
            };
            self.input = Some(mesh);
        }
        Ok(self.input.as_ref().expect("set above"))
    }

    fn report_mesh_path(&self) -> Result<PathBuf> {
        let p = self.file("report.json")?;
        crate::report::WrittenReport::read(&p)?
            .input_mesh()
            .map(PathBuf::from)
            .ok_or_else(|| {
                Error::invalid_data(
                    self.path.display().to_string(),
                    "report.json",
                    "names no input mesh and there is no fitmap.ply; pass the input mesh",
                )
            })
    }

    /// The control mesh: `control.obj` of a folder, or the mesh file read
    /// as a control mesh (any polygons).
    pub fn control(&mut self) -> Result<&ControlMesh> {
        if self.control.is_none() {
            let p = if self.is_dir {
                self.file("control.obj")?
            } else {
                self.path.clone()
            };
            self.control = Some(read_control_mesh(&p)?);
        }
        Ok(self.control.as_ref().expect("set above"))
    }

    /// A tessellated surface of the folder: `limit.ply` or `displaced.ply`.
    pub fn surface_file(&self, name: &str) -> Result<TriMesh> {
        self.needs_dir(name)?;
        read_trimesh_as_is(&self.file(name)?)
    }

    /// `(F_S, F_M)` per vertex of M: from `fitmap.ply` of a folder (its own
    /// geometry is M), else computed on the mesh file (default options).
    pub fn fitmap(&mut self, rays: RayBackend) -> Result<(&TriMesh, &FitmapFields)> {
        if self.fitmap.is_none() {
            // A folder's fitmap.ply is the Fitmap of its input M (checked
            // against an overridden M by vertex count below).
            let f = if self.is_dir && self.path.join("fitmap.ply").is_file() {
                let p = self.file("fitmap.ply")?;
                let mut props = read_ply_vertex_floats(&p, &["s", "m"])?;
                let m = props.pop().expect("two properties");
                let s = props.pop().expect("two properties");
                (s, m)
            } else {
                let mesh = self.input()?;
                let caster = make_raycaster(rays, mesh)?;
                let fm = compute_fitmap(mesh, caster.as_ref(), &FitmapOptions::default())?;
                (fm.s, fm.m)
            };
            let n = self.input()?.positions.len();
            if f.0.len() != n {
                return Err(Error::invalid_data(
                    self.path.display().to_string(),
                    "fitmap.ply",
                    format!("{} values for the {n} vertices of the input", f.0.len()),
                ));
            }
            self.fitmap = Some(f);
        }
        Ok((
            self.input.as_ref().expect("loaded with the fitmap"),
            self.fitmap.as_ref().expect("set above"),
        ))
    }
}

/// A triangle mesh exactly as stored (vertex order kept, so per-vertex
/// properties of the same file line up; no cleanup).
pub fn read_trimesh_as_is(path: &Path) -> Result<TriMesh> {
    let soup = read_soup(path)?;
    let nv = soup.positions.len();
    let mut triangles = Vec::with_capacity(soup.num_faces());
    for (f, face) in soup.faces().enumerate() {
        if face.len() != 3 || face.iter().any(|&i| i as usize >= nv) {
            return Err(Error::invalid_mesh(
                path,
                format!("face {f}"),
                "not a triangle with in-range vertex indices",
            ));
        }
        triangles.push([face[0], face[1], face[2]]);
    }
    if let Some(i) = soup.positions.iter().position(|p| !p.is_finite()) {
        return Err(Error::invalid_mesh(
            path,
            format!("vertex {i}"),
            "non-finite position",
        ));
    }
    Ok(TriMesh {
        positions: soup.positions,
        triangles,
    })
}

/// Reads the named scalar vertex properties of a binary little-endian PLY
/// whose first element is `vertex` (what [`crate::io::write_ply`] writes,
/// e.g. `s` and `m` of `fitmap.ply`).
pub fn read_ply_vertex_floats(path: &Path, names: &[&str]) -> Result<Vec<Vec<f64>>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let end = b"end_header\n";
    let hend = bytes
        .windows(end.len())
        .position(|w| w == end)
        .ok_or_else(|| Error::parse(path, "header", "no end_header"))?
        + end.len();
    let header = std::str::from_utf8(&bytes[..hend])
        .map_err(|_| Error::parse(path, "header", "not ASCII"))?;
    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err(Error::parse(path, "line 1", "not a PLY file"));
    }
    let mut count = None;
    let mut props: Vec<(String, usize, &str)> = Vec::new();
    let mut in_vertex = false;
    for (ln, line) in lines.enumerate() {
        let tok: Vec<&str> = line.split_whitespace().collect();
        let at = || format!("line {}", ln + 2);
        match tok.as_slice() {
            ["format", f, _] if *f != "binary_little_endian" => {
                return Err(Error::parse(
                    path,
                    at(),
                    format!(
                        "format {f}: only binary_little_endian vertex properties are read here"
                    ),
                ))
            }
            ["element", name, n] => {
                if count.is_some() {
                    break;
                }
                if *name != "vertex" {
                    return Err(Error::parse(path, at(), "the first element must be vertex"));
                }
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| Error::parse(path, at(), "bad count"))?,
                );
                in_vertex = true;
            }
            ["property", "list", ..] if in_vertex => {
                return Err(Error::parse(
                    path,
                    at(),
                    "list property in the vertex element",
                ))
            }
            ["property", ty, name] if in_vertex => {
                let size = match *ty {
                    "char" | "uchar" | "int8" | "uint8" => 1,
                    "short" | "ushort" | "int16" | "uint16" => 2,
                    "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
                    "double" | "float64" => 8,
                    _ => return Err(Error::parse(path, at(), format!("unknown type {ty}"))),
                };
                props.push((name.to_string(), size, ty));
            }
            _ => {}
        }
    }
    let n = count.ok_or_else(|| Error::parse(path, "header", "no vertex element"))?;
    let stride: usize = props.iter().map(|p| p.1).sum();
    if bytes.len() < hend + n * stride {
        return Err(Error::parse(path, "vertex data", "file too short"));
    }
    names
        .iter()
        .map(|want| {
            let k = props.iter().position(|p| p.0 == *want).ok_or_else(|| {
                Error::parse(path, "header", format!("no vertex property '{want}'"))
            })?;
            let off: usize = props[..k].iter().map(|p| p.1).sum();
            let ty = props[k].2;
            Ok((0..n)
                .map(|i| {
                    let b = &bytes[hend + i * stride + off..];
                    match ty {
                        "float" | "float32" => {
                            f32::from_le_bytes(b[..4].try_into().unwrap()) as f64
                        }
                        "double" | "float64" => f64::from_le_bytes(b[..8].try_into().unwrap()),
                        "int" | "int32" => i32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
                        "uint" | "uint32" => u32::from_le_bytes(b[..4].try_into().unwrap()) as f64,
                        "short" | "int16" => i16::from_le_bytes(b[..2].try_into().unwrap()) as f64,
                        "ushort" | "uint16" => {
                            u16::from_le_bytes(b[..2].try_into().unwrap()) as f64
                        }
                        "char" | "int8" => b[0] as i8 as f64,
                        _ => b[0] as f64,
                    }
                })
                .collect())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_back_written_vertex_properties() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.ply");
        let pos = vec![crate::DVec3::ZERO, crate::DVec3::X, crate::DVec3::Y];
        crate::io::write_ply(
            &p,
            &pos,
            &[[0u32, 1, 2]],
            &[("s", &[1.0, 2.0, 3.0]), ("m", &[4.0, 5.0, 6.5])],
            None,
        )
        .unwrap();
        let v = read_ply_vertex_floats(&p, &["m", "s"]).unwrap();
        assert_eq!(v, vec![vec![4.0, 5.0, 6.5], vec![1.0, 2.0, 3.0]]);
        assert!(read_ply_vertex_floats(&p, &["q"]).is_err());
        let m = read_trimesh_as_is(&p).unwrap();
        assert_eq!(m.triangles, vec![[0, 1, 2]]);
    }
}
