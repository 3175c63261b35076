//! Wavefront OBJ reader (pure Rust), including OpenSubdiv shape-file tags.
//!
//! Supported: `v x y z [w | r g b]`, `f` with any number of corners in the
//! forms `v`, `v/vt`, `v//vn`, `v/vt/vn`, negative (relative) indices, `#`
//! comments, CRLF line ends. Ignored: `vt vn vp g o s usemtl mtllib l p` and
//! unknown statements. OpenSubdiv's shape files (`regression/shapes/*.h`,
//! parsed by `regression/common/shape_utils.cpp`) add tags
//! `t <name> <nints>/<nfloats>/<nstrings> ints... floats... strings...` with
//! **0-based** vertex indices; `crease` (an edge chain with one sharpness for
//! the chain or one per edge) and `corner` are kept, other tags ignored.
//!
//! The whole file is read into memory and scanned in place: no allocation per
//! line (the 1.3 MB bunny as OBJ parses in a few milliseconds).

use std::path::Path;

use crate::error::{Error, Result};
use crate::mesh::PolySoup;
use crate::DVec3;

/// An OBJ file: its polygons and the shape-file sharpness tags.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObjMesh {
    pub soup: PolySoup,
    /// `(a, b, sharpness)` per creased edge, 0-based vertex indices, in file
    /// order (a `t crease` chain is split into its edges).
    pub creases: Vec<(u32, u32, f64)>,
    /// `(vertex, sharpness)`, 0-based, in file order.
    pub corners: Vec<(u32, f64)>,
}

/// Reads an OBJ file.
pub fn read_obj(path: &Path) -> Result<ObjMesh> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_obj(&bytes, path)
}

/// Parses OBJ text already in memory; `path` only names the file in errors.
pub fn parse_obj(bytes: &[u8], path: &Path) -> Result<ObjMesh> {
    let mut out = ObjMesh {
        soup: PolySoup::new(),
        ..ObjMesh::default()
    };
    // A rough guess that avoids most reallocations: ~30 bytes per `v` line.
    out.soup.positions.reserve(bytes.len() / 64);
    // Line of each face and of each tag, for errors raised after the scan
    // (positive indices may refer to vertices defined later in the file).
    let mut face_lines: Vec<u32> = Vec::new();
    let mut crease_lines: Vec<u32> = Vec::new();
    let mut corner_lines: Vec<u32> = Vec::new();
    let mut tag_ints: Vec<i64> = Vec::new();
    let mut tag_floats: Vec<f64> = Vec::new();

    for (lineno0, raw_line) in bytes.split(|&b| b == b'\n').enumerate() {
        let lineno = lineno0 + 1;
        let line = match raw_line.iter().position(|&b| b == b'#') {
            Some(k) => &raw_line[..k],
            None => raw_line,
        };
        let mut toks = Tokens(line);
        let Some(key) = toks.next() else { continue };
        let at = || format!("line {lineno}");
        match key {
            b"v" => {
                let mut p = [0.0f64; 3];
                for (k, c) in p.iter_mut().enumerate() {
                    let t = toks.next().ok_or_else(|| {
                        Error::parse(path, at(), format!("vertex has {k} coordinates, needs 3"))
                    })?;
                    *c = parse_f64(t)
                        .ok_or_else(|| Error::parse(path, at(), bad_token("coordinate", t)))?;
                }
                // An optional w or r g b may follow; they are not used, but
                // must still be numbers or the line is not what we think.
                for t in toks {
                    parse_f64(t).ok_or_else(|| Error::parse(path, at(), bad_token("number", t)))?;
                }
                out.soup.positions.push(DVec3::from_array(p));
            }
            b"f" => {
                let nv = out.soup.positions.len() as i64;
                let start = out.soup.face_indices.len();
                for t in toks {
                    let vtok = match t.iter().position(|&b| b == b'/') {
                        Some(k) => &t[..k],
                        None => t,
                    };
                    let i = parse_i64(vtok)
                        .ok_or_else(|| Error::parse(path, at(), bad_token("vertex index", t)))?;
                    let idx = if i > 0 {
                        i - 1
                    } else if i < 0 {
                        // Relative to the vertices defined so far (OBJ spec).
                        nv + i
                    } else {
                        return Err(Error::parse(
                            path,
                            at(),
                            "vertex index 0 (OBJ indices start at 1)",
                        ));
                    };
                    if !(0..=u32::MAX as i64 - 1).contains(&idx) {
                        return Err(Error::invalid_mesh(
                            path,
                            format!("face {} (line {lineno})", face_lines.len()),
                            format!("vertex index {i} out of range ({nv} vertices defined so far)"),
                        ));
                    }
                    out.soup.face_indices.push(idx as u32);
                }
                if out.soup.face_indices.len() == start {
                    return Err(Error::parse(path, at(), "face without vertices"));
                }
                let end = u32::try_from(out.soup.face_indices.len())
                    .map_err(|_| Error::parse(path, at(), "more than 2^32 face corners"))?;
                out.soup.face_offsets.push(end);
                face_lines.push(lineno as u32);
            }
            b"t" => {
                let name = toks
                    .next()
                    .ok_or_else(|| Error::parse(path, at(), "tag without a name"))?;
                let counts = toks.next().ok_or_else(|| {
                    Error::parse(path, at(), "tag without its nints/nfloats/nstrings counts")
                })?;
                let (ni, nf, ns) = parse_tag_counts(counts).ok_or_else(|| {
                    Error::parse(
                        path,
                        at(),
                        bad_token("tag counts nints/nfloats/nstrings", counts),
                    )
                })?;
                tag_ints.clear();
                tag_floats.clear();
                for _ in 0..ni {
                    let t = toks.next().ok_or_else(|| {
                        Error::parse(path, at(), "tag has fewer integers than announced")
                    })?;
                    tag_ints.push(
                        parse_i64(t)
                            .ok_or_else(|| Error::parse(path, at(), bad_token("integer", t)))?,
                    );
                }
                for _ in 0..nf {
                    let t = toks.next().ok_or_else(|| {
                        Error::parse(path, at(), "tag has fewer floats than announced")
                    })?;
                    tag_floats.push(
                        parse_f64(t)
                            .ok_or_else(|| Error::parse(path, at(), bad_token("float", t)))?,
                    );
                }
                let strings = toks.count();
                if strings != ns {
                    return Err(Error::parse(
                        path,
                        at(),
                        format!("tag announces {ns} strings, has {strings}"),
                    ));
                }
                let vertex = |i: i64| {
                    u32::try_from(i).map_err(|_| {
                        Error::parse(
                            path,
                            at(),
                            format!("tag vertex index {i} is negative or too large"),
                        )
                    })
                };
                match name {
                    b"crease" => {
                        // shape_utils: one sharpness for the whole chain, or one per edge.
                        if ni < 2 || !(nf == 1 || nf == ni - 1) {
                            return Err(Error::parse(
                                path,
                                at(),
                                format!("crease tag needs >= 2 vertices and 1 or {} sharpness values, has {ni}/{nf}", ni.saturating_sub(1)),
                            ));
                        }
                        for k in 0..ni - 1 {
                            let s = tag_floats[if nf == 1 { 0 } else { k }];
                            out.creases
                                .push((vertex(tag_ints[k])?, vertex(tag_ints[k + 1])?, s));
                            crease_lines.push(lineno as u32);
                        }
                    }
                    b"corner" => {
                        if ni < 1 || !(nf == 1 || nf == ni) {
                            return Err(Error::parse(
                                path,
                                at(),
                                format!("corner tag needs >= 1 vertex and 1 or {ni} sharpness values, has {ni}/{nf}"),
                            ));
                        }
                        for k in 0..ni {
                            let s = tag_floats[if nf == 1 { 0 } else { k }];
                            out.corners.push((vertex(tag_ints[k])?, s));
                            corner_lines.push(lineno as u32);
                        }
                    }
                    // interpolateboundary, facevaryingpropagatecorners, hole, ...:
                    // scheme options this crate does not take from files.
                    _ => {}
                }
            }
            // Attributes, grouping and materials carry nothing we use.
            _ => {}
        }
    }

    let nv = out.soup.positions.len();
    for (f, face) in out.soup.faces().enumerate() {
        if let Some(&i) = face.iter().find(|&&i| i as usize >= nv) {
            return Err(Error::invalid_mesh(
                path,
                format!("face {f} (line {})", face_lines[f]),
                format!(
                    "vertex index {} out of range (the file has {nv} vertices)",
                    i as u64 + 1
                ),
            ));
        }
    }
    for (k, &(a, b, _)) in out.creases.iter().enumerate() {
        if a as usize >= nv || b as usize >= nv {
            return Err(Error::invalid_mesh(
                path,
                format!("crease tag (line {})", crease_lines[k]),
                format!("edge ({a}, {b}) names a vertex out of range (the file has {nv} vertices; tags are 0-based)"),
            ));
        }
    }
    for (k, &(v, _)) in out.corners.iter().enumerate() {
        if v as usize >= nv {
            return Err(Error::invalid_mesh(
                path,
                format!("corner tag (line {})", corner_lines[k]),
                format!("vertex {v} out of range (the file has {nv} vertices; tags are 0-based)"),
            ));
        }
    }
    Ok(out)
}

/// Whitespace-separated tokens of one line, without allocating.
struct Tokens<'a>(&'a [u8]);

impl<'a> Iterator for Tokens<'a> {
    type Item = &'a [u8];
    fn next(&mut self) -> Option<&'a [u8]> {
        let s = self.0;
        let start = s.iter().position(|b| !b.is_ascii_whitespace())?;
        let len = s[start..]
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(s.len() - start);
        self.0 = &s[start + len..];
        Some(&s[start..start + len])
    }
}

pub(crate) fn parse_f64(t: &[u8]) -> Option<f64> {
    std::str::from_utf8(t).ok()?.parse().ok()
}

pub(crate) fn parse_i64(t: &[u8]) -> Option<i64> {
    std::str::from_utf8(t).ok()?.parse().ok()
}

fn parse_tag_counts(t: &[u8]) -> Option<(usize, usize, usize)> {
    let mut it = t.split(|&b| b == b'/');
    // Huge garbage counts are harmless: the token loops stop at the end of
    // the line with an error.
    let mut n = || -> Option<usize> { std::str::from_utf8(it.next()?).ok()?.parse().ok() };
    let r = (n()?, n()?, n()?);
    it.next().is_none().then_some(r)
}

pub(crate) fn bad_token(what: &str, t: &[u8]) -> String {
    let shown: String = String::from_utf8_lossy(&t[..t.len().min(40)]).into_owned();
    format!("expected a {what}, found '{shown}'")
}
