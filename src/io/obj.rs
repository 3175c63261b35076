//! Wavefront OBJ reader (pure Rust), including OpenSubdiv shape-file tags.
//!
//! Supported: `v x y z [w | r g b]`, `f` with any number of corners in the
//! forms `v`, `v/vt`, `v//vn`, `v/vt/vn`, negative (relative) indices, `#`
//! comments, CRLF line ends, `\` line continuation, a leading UTF-8 byte
//! order mark. Non-finite coordinates are errors naming the vertex and the
//! line. Texture coordinates (`vt u v [w]`, the `vt` of `f v/vt` corners)
//! become the face-varying channel [`ObjMesh::uv`] when every face corner
//! has one (when only some do, none is kept and [`ObjMesh::uv_note`] names
//! the first corner without: the geometry is still good). Ignored: `vn vp g o s usemtl mtllib l p` and unknown
//! statements. OpenSubdiv's shape files (`regression/shapes/*.h`,
//! parsed by `regression/common/shape_utils.cpp`) add tags
//! `t <name> <nints>/<nfloats>/<nstrings> ints... floats... strings...` with
//! **0-based** vertex and face indices. Every tag OpenSubdiv's regression
//! harness interprets (`regression/common/far_utils.h`: `GetSdcOptions`,
//! `assignComponentTags`) is honoured, into [`ObjMesh::creases`],
//! [`ObjMesh::corners`] and [`ObjMesh::scheme`]:
//! - `crease` (an edge chain with one sharpness for the chain or one per
//!   edge) and `corner` (vertices with one sharpness or one each);
//! - `interpolateboundary 1/0/0 i`: 0 none, 1 edge and corner, 2 edge only;
//! - `facevaryinginterpolateboundary 1/0/0 i`: 0..=5 in the order of
//!   `Sdc::Options::FVarLinearInterpolation` (none, corners only, corners
//!   +1, corners +2, boundaries, all);
//! - `facevaryingpropagatecorners 1/0/0 b`: OpenSubdiv 3 has no such
//!   option; Hbr's "propagate corners" on an "edge and corner" face-varying
//!   boundary is 3.x's corners +2 (OpenSubdiv's "Subdivision Compatibility"
//!   notes), so `1` turns mode 2 into 3 and is an error with any other mode;
//! - `creasemethod 0/0/1 normal|uniform|chaikin`;
//! - `smoothtriangles 0/0/1 catmark|smooth` (far_utils.h), or Hbr's integer
//!   form `1/0/0 i` with 0 the Catmark rule and 2 `k_New`, the weights
//!   `TRI_SUB_SMOOTH` reproduces (1, Hbr's `k_Old`, has no 3.x equivalent);
//! - `hole n/0/0 faces...`.
//!
//! Any other tag (hierarchical edits such as `vertexedit`, `edgeedit`,
//! `faceedit`, or a misspelling) is an error naming the file and line: a
//! dropped tag would change the surface without a word.
//!
//! OBJ declares no counts, so a file cut between two statements cannot be
//! told from a shorter file; a statement cut short (`v 1 2`, `f 1/1 2/`) is
//! an error naming its line.
//!
//! The whole file is read into memory and scanned in place: no allocation per
//! line (the 1.3 MB bunny as OBJ parses in a few milliseconds).

use std::path::Path;

use crate::error::{Error, Result};
use crate::io::text::{
    bad_token, bom_len, non_finite, parse_f64, parse_i64, strip_comment, Tokens,
};
use crate::mesh::{
    BoundaryInterpolation, CreaseMethod, FVarChannel, FVarLinear, FaceId, PolySoup, SchemeOptions,
    TriangleSubdivision,
};
use crate::{DVec2, DVec3};

/// An OBJ file: its polygons and the shape-file sharpness tags.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObjMesh {
    pub soup: PolySoup,
    /// `(a, b, sharpness)` per creased edge, 0-based vertex indices, in file
    /// order (a `t crease` chain is split into its edges).
    pub creases: Vec<(u32, u32, f64)>,
    /// `(vertex, sharpness)`, 0-based, in file order.
    pub corners: Vec<(u32, f64)>,
    /// Scheme options and holes stated by the tags (defaults where none).
    pub scheme: SchemeOptions,
    /// The texture coordinates as a face-varying channel (one index per
    /// face corner, in the soup's corner order), when the faces have them.
    pub uv: Option<FVarChannel>,
    /// Why the file's texture coordinates were not kept, if it has some.
    pub uv_note: Option<String>,
}

/// Reads an OBJ file.
pub fn read_obj(path: &Path) -> Result<ObjMesh> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_obj(&bytes, path)
}

/// Parses OBJ text already in memory; `path` only names the file in errors.
pub fn parse_obj(bytes: &[u8], path: &Path) -> Result<ObjMesh> {
    let mut st = ObjState {
        path,
        out: ObjMesh {
            soup: PolySoup::new(),
            ..ObjMesh::default()
        },
        face_lines: Vec::new(),
        crease_lines: Vec::new(),
        corner_lines: Vec::new(),
        tag_ints: Vec::new(),
        tag_floats: Vec::new(),
        tag_strings: Vec::new(),
        hole_lines: Vec::new(),
        uv_values: Vec::new(),
        uv_indices: Vec::new(),
        first_corner_without_uv: None,
        uv_problem: None,
        propagate_corners: None,
    };
    // A rough guess that avoids most reallocations: ~30 bytes per `v` line.
    st.out.soup.positions.reserve(bytes.len() / 64);
    for_each_line(&bytes[bom_len(bytes)..], |lineno, line| {
        st.statement(lineno, line)
    })?;
    st.finish()
}

/// Calls `f(line number, logical line)` for every line of `text`, comments
/// removed. A `\` ending a line joins the next one to it (OBJ spec, "line
/// continuation"); the joined line is reported at its first physical line.
/// The backslash is looked for after the comment is removed, so that a
/// comment ending in one (`# saved in C:\models\`) does not swallow the next
/// statement: losing a `v` line would shift every index after it.
fn for_each_line(text: &[u8], mut f: impl FnMut(usize, &[u8]) -> Result<()>) -> Result<()> {
    let mut joined: Vec<u8> = Vec::new();
    let mut joined_line = 0;
    for (k, raw) in text.split(|&b| b == b'\n').enumerate() {
        let line = strip_comment(raw.strip_suffix(b"\r").unwrap_or(raw));
        let trimmed = line.trim_ascii_end();
        let (body, continued) = match trimmed.strip_suffix(b"\\") {
            Some(b) => (b, true),
            None => (line, false),
        };
        if !continued && joined.is_empty() {
            f(k + 1, line)?;
            continue;
        }
        if joined.is_empty() {
            joined_line = k + 1;
        }
        joined.extend_from_slice(body);
        joined.push(b' ');
        if !continued {
            f(joined_line, &joined)?;
            joined.clear();
        }
    }
    if !joined.is_empty() {
        // A continuation on the last line: the statement simply ends there.
        f(joined_line, &joined)?;
    }
    Ok(())
}

/// The reader's state between lines.
struct ObjState<'p> {
    path: &'p Path,
    out: ObjMesh,
    /// Line of each face and of each tag, for errors raised after the scan
    /// (positive indices may refer to vertices defined later in the file).
    face_lines: Vec<u32>,
    crease_lines: Vec<u32>,
    corner_lines: Vec<u32>,
    tag_ints: Vec<i64>,
    tag_floats: Vec<f64>,
    tag_strings: Vec<String>,
    hole_lines: Vec<u32>,
    /// `vt` records, and each corner's `vt` index (0-based; `u32::MAX`
    /// where the corner has none) with the line of the first such corner.
    uv_values: Vec<DVec2>,
    uv_indices: Vec<u32>,
    first_corner_without_uv: Option<(usize, usize)>,
    uv_problem: Option<String>,
    /// `facevaryingpropagatecorners` and its line, resolved at the end (the
    /// tag may come before or after `facevaryinginterpolateboundary`).
    propagate_corners: Option<(bool, usize)>,
}

impl ObjState<'_> {
    fn err(&self, lineno: usize, msg: impl Into<String>) -> Error {
        Error::parse(self.path, format!("line {lineno}"), msg)
    }

    fn statement(&mut self, lineno: usize, line: &[u8]) -> Result<()> {
        let mut toks = Tokens(line);
        match toks.next() {
            Some(b"v") => self.vertex(lineno, toks),
            Some(b"vt") => self.texture_vertex(lineno, toks),
            Some(b"f") => self.face(lineno, toks),
            Some(b"t") => self.tag(lineno, toks),
            // Attributes, grouping and materials carry nothing we use.
            _ => Ok(()),
        }
    }

    fn vertex(&mut self, lineno: usize, mut toks: Tokens) -> Result<()> {
        let mut p = [0.0f64; 3];
        for (k, c) in p.iter_mut().enumerate() {
            let t = toks
                .next()
                .ok_or_else(|| self.err(lineno, format!("vertex has {k} coordinates, needs 3")))?;
            *c = parse_f64(t).ok_or_else(|| self.err(lineno, bad_token("coordinate", t)))?;
        }
        // An optional w or r g b may follow; they are not used, but must
        // still be numbers or the line is not what we think.
        for t in toks {
            parse_f64(t).ok_or_else(|| self.err(lineno, bad_token("number", t)))?;
        }
        let p = DVec3::from_array(p);
        if let Some(msg) = non_finite(p) {
            let i = self.out.soup.positions.len();
            return Err(Error::invalid_mesh(
                self.path,
                format!("vertex {i} (line {lineno})"),
                msg,
            ));
        }
        self.out.soup.positions.push(p);
        Ok(())
    }

    /// `vt u [v [w]]`: v defaults to 0 (OBJ spec); w is not used. A
    /// malformed record drops the UVs with a note (the geometry does not
    /// depend on them); its place is kept so later indices stay right.
    fn texture_vertex(&mut self, lineno: usize, toks: Tokens) -> Result<()> {
        let mut c = [0.0f64; 3];
        let mut n = 0;
        let mut bad = None;
        for t in toks {
            match parse_f64(t) {
                Some(x) if n < 3 => c[n] = x,
                _ => bad = Some(bad_token("texture coordinate (at most 3 numbers)", t)),
            }
            n += 1;
        }
        let uv = DVec2::new(c[0], c[1]);
        if n == 0 {
            bad = Some("texture vertex without coordinates".to_string());
        } else if bad.is_none() && !uv.is_finite() {
            bad = Some("non-finite texture coordinate".to_string());
        }
        if let Some(b) = bad {
            self.uv_problem
                .get_or_insert_with(|| format!("line {lineno}: {b}"));
        }
        self.uv_values.push(uv);
        Ok(())
    }

    fn face(&mut self, lineno: usize, toks: Tokens) -> Result<()> {
        let nv = self.out.soup.positions.len() as i64;
        let start = self.out.soup.face_indices.len();
        for t in toks {
            let (i, vt) = face_vertex(t).ok_or_else(|| {
                Error::parse(
                    self.path,
                    format!("line {lineno}"),
                    bad_token("vertex index (v, v/vt, v//vn or v/vt/vn)", t),
                )
            })?;
            let idx = if i > 0 {
                i - 1
            } else if i < 0 {
                // Relative to the vertices defined so far (OBJ spec).
                nv + i
            } else {
                return Err(Error::parse(
                    self.path,
                    format!("line {lineno}"),
                    "vertex index 0 (OBJ indices start at 1)",
                ));
            };
            if !(0..=u32::MAX as i64 - 1).contains(&idx) {
                return Err(Error::invalid_mesh(
                    self.path,
                    format!("face {} (line {lineno})", self.face_lines.len()),
                    format!("vertex index {i} out of range ({nv} vertices defined so far)"),
                ));
            }
            self.out.soup.face_indices.push(idx as u32);
            let uv = match vt {
                Some(k) => {
                    let nt = self.uv_values.len() as i64;
                    let j = if k > 0 { k - 1 } else { nt + k };
                    if k == 0 || !(0..nt).contains(&j) {
                        // The geometry does not depend on it: the UVs are
                        // dropped with a note, the mesh is still read.
                        self.uv_problem.get_or_insert_with(|| {
                            format!(
                                "face {} (line {lineno}) has texture index {k}, out of range \
                                 ({nt} `vt` defined so far)",
                                self.face_lines.len()
                            )
                        });
                        u32::MAX
                    } else {
                        j as u32
                    }
                }
                None => {
                    self.first_corner_without_uv
                        .get_or_insert((self.face_lines.len(), lineno));
                    u32::MAX
                }
            };
            self.uv_indices.push(uv);
        }
        if self.out.soup.face_indices.len() == start {
            return Err(self.err(lineno, "face without vertices"));
        }
        let end = u32::try_from(self.out.soup.face_indices.len()).map_err(|_| {
            Error::parse(
                self.path,
                format!("line {lineno}"),
                "more than 2^32 face corners",
            )
        })?;
        self.out.soup.face_offsets.push(end);
        self.face_lines.push(lineno as u32);
        Ok(())
    }

    /// `t <name> <nints>/<nfloats>/<nstrings> ints... floats... strings...`
    fn tag(&mut self, lineno: usize, mut toks: Tokens) -> Result<()> {
        let name = toks
            .next()
            .ok_or_else(|| self.err(lineno, "tag without a name"))?;
        let counts = toks
            .next()
            .ok_or_else(|| self.err(lineno, "tag without its nints/nfloats/nstrings counts"))?;
        let (ni, nf, ns) = parse_tag_counts(counts).ok_or_else(|| {
            self.err(
                lineno,
                bad_token("tag counts nints/nfloats/nstrings", counts),
            )
        })?;
        self.tag_ints.clear();
        self.tag_floats.clear();
        for _ in 0..ni {
            let t = toks
                .next()
                .ok_or_else(|| self.err(lineno, "tag has fewer integers than announced"))?;
            let v = parse_i64(t).ok_or_else(|| self.err(lineno, bad_token("integer", t)))?;
            self.tag_ints.push(v);
        }
        for _ in 0..nf {
            let t = toks
                .next()
                .ok_or_else(|| self.err(lineno, "tag has fewer floats than announced"))?;
            let v = parse_f64(t).ok_or_else(|| self.err(lineno, bad_token("float", t)))?;
            self.tag_floats.push(v);
        }
        self.tag_strings.clear();
        for t in toks {
            self.tag_strings
                .push(String::from_utf8_lossy(t).into_owned());
        }
        if self.tag_strings.len() != ns {
            return Err(self.err(
                lineno,
                format!("tag announces {ns} strings, has {}", self.tag_strings.len()),
            ));
        }
        match name {
            b"crease" => self.crease_tag(lineno),
            b"corner" => self.corner_tag(lineno),
            b"hole" => self.hole_tag(lineno),
            b"interpolateboundary" => {
                self.out.scheme.boundary = match self.one_int(lineno, "interpolateboundary")? {
                    0 => BoundaryInterpolation::None,
                    1 => BoundaryInterpolation::EdgeAndCorner,
                    2 => BoundaryInterpolation::EdgeOnly,
                    i => return Err(self.bad_value(lineno, "interpolateboundary", i, "0, 1 or 2")),
                };
                Ok(())
            }
            b"facevaryinginterpolateboundary" => {
                let what = "facevaryinginterpolateboundary";
                self.out.scheme.fvar = match self.one_int(lineno, what)? {
                    0 => FVarLinear::None,
                    1 => FVarLinear::CornersOnly,
                    2 => FVarLinear::CornersPlus1,
                    3 => FVarLinear::CornersPlus2,
                    4 => FVarLinear::Boundaries,
                    5 => FVarLinear::All,
                    i => return Err(self.bad_value(lineno, what, i, "0 to 5")),
                };
                Ok(())
            }
            b"facevaryingpropagatecorners" => {
                let what = "facevaryingpropagatecorners";
                let b = match self.one_int(lineno, what)? {
                    0 => false,
                    1 => true,
                    i => return Err(self.bad_value(lineno, what, i, "0 or 1")),
                };
                self.propagate_corners = Some((b, lineno));
                Ok(())
            }
            b"creasemethod" => {
                self.out.scheme.crease_method = match self.one_string(lineno, "creasemethod")? {
                    "normal" | "uniform" => CreaseMethod::Uniform,
                    "chaikin" => CreaseMethod::Chaikin,
                    v => {
                        return Err(self.err(
                            lineno,
                            format!(
                                "creasemethod `{v}`: expected `normal` (or `uniform`) or `chaikin`"
                            ),
                        ))
                    }
                };
                Ok(())
            }
            b"smoothtriangles" => self.smooth_triangles_tag(lineno),
            other => Err(self.err(
                lineno,
                format!(
                    "unknown tag `{}`: known tags are crease, corner, hole, interpolateboundary, \
                     facevaryinginterpolateboundary, facevaryingpropagatecorners, creasemethod, \
                     smoothtriangles (hierarchical edits are not supported)",
                    String::from_utf8_lossy(other)
                ),
            )),
        }
    }

    fn bad_value(&self, lineno: usize, what: &str, v: i64, expected: &str) -> Error {
        self.err(lineno, format!("{what} value {v}: expected {expected}"))
    }

    /// The single integer of a `1/0/0` tag.
    fn one_int(&self, lineno: usize, what: &str) -> Result<i64> {
        match (
            self.tag_ints.as_slice(),
            self.tag_floats.len(),
            self.tag_strings.len(),
        ) {
            (&[i], 0, 0) => Ok(i),
            (ints, nf, ns) => Err(self.err(
                lineno,
                format!(
                    "{what} tag takes 1/0/0 arguments, has {}/{nf}/{ns}",
                    ints.len()
                ),
            )),
        }
    }

    /// The single string of a `0/0/1` tag.
    fn one_string(&self, lineno: usize, what: &str) -> Result<&str> {
        match (
            self.tag_ints.len(),
            self.tag_floats.len(),
            self.tag_strings.as_slice(),
        ) {
            (0, 0, [s]) => Ok(s.as_str()),
            (ni, nf, strings) => Err(self.err(
                lineno,
                format!(
                    "{what} tag takes 0/0/1 arguments, has {ni}/{nf}/{}",
                    strings.len()
                ),
            )),
        }
    }

    fn smooth_triangles_tag(&mut self, lineno: usize) -> Result<()> {
        let what = "smoothtriangles";
        self.out.scheme.triangles =
            if self.tag_strings.is_empty() {
                match self.one_int(lineno, what)? {
                    0 => TriangleSubdivision::Catmark,
                    2 => TriangleSubdivision::Smooth,
                    1 => return Err(self.err(
                        lineno,
                        "smoothtriangles 1 is Hbr's old triangle rule (k_Old), which OpenSubdiv 3 \
                         does not have; use 2 or `smooth` for TRI_SUB_SMOOTH",
                    )),
                    i => return Err(self.bad_value(lineno, what, i, "0 (catmark) or 2 (smooth)")),
                }
            } else {
                match self.one_string(lineno, what)? {
                    "catmark" => TriangleSubdivision::Catmark,
                    "smooth" => TriangleSubdivision::Smooth,
                    v => {
                        return Err(self.err(
                            lineno,
                            format!("smoothtriangles `{v}`: expected `catmark` or `smooth`"),
                        ))
                    }
                }
            };
        Ok(())
    }

    /// `hole n/0/0 f...`: 0-based face indices (range-checked at the end).
    fn hole_tag(&mut self, lineno: usize) -> Result<()> {
        if self.tag_ints.is_empty() || !self.tag_floats.is_empty() || !self.tag_strings.is_empty() {
            return Err(self.err(
                lineno,
                format!(
                    "hole tag takes n/0/0 arguments (n >= 1 face indices), has {}/{}/{}",
                    self.tag_ints.len(),
                    self.tag_floats.len(),
                    self.tag_strings.len()
                ),
            ));
        }
        for k in 0..self.tag_ints.len() {
            let i = self.tag_ints[k];
            let f = u32::try_from(i).map_err(|_| {
                self.err(
                    lineno,
                    format!("hole face index {i} is negative or too large"),
                )
            })?;
            self.out.scheme.holes.push(FaceId(f));
            self.hole_lines.push(lineno as u32);
        }
        Ok(())
    }

    fn tag_vertex(&self, lineno: usize, i: i64) -> Result<u32> {
        u32::try_from(i).map_err(|_| {
            self.err(
                lineno,
                format!("tag vertex index {i} is negative or too large"),
            )
        })
    }

    /// shape_utils: one sharpness for the whole chain, or one per edge.
    fn crease_tag(&mut self, lineno: usize) -> Result<()> {
        let (ni, nf) = (self.tag_ints.len(), self.tag_floats.len());
        if ni < 2 || !(nf == 1 || nf == ni - 1) {
            return Err(self.err(
                lineno,
                format!(
                    "crease tag needs >= 2 vertices and 1 or {} sharpness values, has {ni}/{nf}",
                    ni.saturating_sub(1)
                ),
            ));
        }
        for k in 0..ni - 1 {
            let s = self.tag_floats[if nf == 1 { 0 } else { k }];
            let a = self.tag_vertex(lineno, self.tag_ints[k])?;
            let b = self.tag_vertex(lineno, self.tag_ints[k + 1])?;
            self.out.creases.push((a, b, s));
            self.crease_lines.push(lineno as u32);
        }
        Ok(())
    }

    fn corner_tag(&mut self, lineno: usize) -> Result<()> {
        let (ni, nf) = (self.tag_ints.len(), self.tag_floats.len());
        if ni < 1 || !(nf == 1 || nf == ni) {
            return Err(self.err(
                lineno,
                format!(
                    "corner tag needs >= 1 vertex and 1 or {ni} sharpness values, has {ni}/{nf}"
                ),
            ));
        }
        for k in 0..ni {
            let s = self.tag_floats[if nf == 1 { 0 } else { k }];
            let v = self.tag_vertex(lineno, self.tag_ints[k])?;
            self.out.corners.push((v, s));
            self.corner_lines.push(lineno as u32);
        }
        Ok(())
    }

    /// Range checks that need the whole file (forward references).
    /// The face-varying channel: kept when every corner has a `vt`.
    fn finish_uv(&mut self) {
        let any = self.uv_indices.iter().any(|&i| i != u32::MAX);
        if let Some(p) = self.uv_problem.take() {
            self.out.uv_note = Some(format!(
                "{}: texture coordinates not used: {p}",
                self.path.display()
            ));
            return;
        }
        match self.first_corner_without_uv {
            Some((f, line)) if any => {
                self.out.uv_note = Some(format!(
                    "{}: texture coordinates not used: face {f} (line {line}) has a corner \
                     without one (face-varying data needs one per corner of every face)",
                    self.path.display()
                ))
            }
            _ if any => {
                self.out.uv = Some(FVarChannel {
                    values: std::mem::take(&mut self.uv_values),
                    indices: std::mem::take(&mut self.uv_indices),
                });
            }
            _ => {}
        }
    }

    fn finish(mut self) -> Result<ObjMesh> {
        if let Some((true, line)) = self.propagate_corners {
            let fvar = &mut self.out.scheme.fvar;
            match *fvar {
                FVarLinear::CornersPlus1 | FVarLinear::CornersPlus2 => *fvar = FVarLinear::CornersPlus2,
                other => {
                    return Err(self.err(
                        line,
                        format!(
                            "facevaryingpropagatecorners 1 needs facevaryinginterpolateboundary 2 \
                             (Hbr's edge-and-corner, OpenSubdiv 3's corners-plus2); the file's mode is {}",
                            other.name()
                        ),
                    ))
                }
            }
        }
        let nf = self.out.soup.num_faces();
        for (k, f) in self.out.scheme.holes.iter().enumerate() {
            if f.idx() >= nf {
                return Err(Error::invalid_mesh(
                    self.path,
                    format!("hole tag (line {})", self.hole_lines[k]),
                    format!(
                        "face {} out of range (the file has {nf} faces; tags are 0-based)",
                        f.0
                    ),
                ));
            }
        }
        self.finish_uv();
        let holes = std::mem::take(&mut self.out.scheme.holes);
        self.out.scheme = std::mem::take(&mut self.out.scheme).with_holes(holes);
        let (out, path) = (&self.out, self.path);
        let nv = out.soup.positions.len();
        for (f, face) in out.soup.faces().enumerate() {
            if let Some(&i) = face.iter().find(|&&i| i as usize >= nv) {
                return Err(Error::invalid_mesh(
                    path,
                    format!("face {f} (line {})", self.face_lines[f]),
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
                    format!("crease tag (line {})", self.crease_lines[k]),
                    format!("edge ({a}, {b}) names a vertex out of range (the file has {nv} vertices; tags are 0-based)"),
                ));
            }
        }
        for (k, &(v, _)) in out.corners.iter().enumerate() {
            if v as usize >= nv {
                return Err(Error::invalid_mesh(
                    path,
                    format!("corner tag (line {})", self.corner_lines[k]),
                    format!(
                        "vertex {v} out of range (the file has {nv} vertices; tags are 0-based)"
                    ),
                ));
            }
        }
        Ok(self.out)
    }
}

/// The vertex index of a face corner `v`, `v/vt`, `v//vn` or `v/vt/vn`, and
/// its texture index where it has one. The normal part is unused but must
/// be an integer where the form has it: `1/` or `1//` is a record cut
/// short, not a corner.
fn face_vertex(t: &[u8]) -> Option<(i64, Option<i64>)> {
    let mut parts = t.split(|&b| b == b'/');
    let v = parse_i64(parts.next()?)?;
    let int = |p: &[u8]| parse_i64(p).is_some();
    match (parts.next(), parts.next(), parts.next()) {
        (None, _, _) => Some((v, None)),
        (Some(vt), None, _) => Some((v, Some(parse_i64(vt)?))),
        (Some(b""), Some(vn), None) => int(vn).then_some((v, None)),
        (Some(vt), Some(vn), None) => {
            let vt = parse_i64(vt)?;
            int(vn).then_some((v, Some(vt)))
        }
        _ => None,
    }
}

fn parse_tag_counts(t: &[u8]) -> Option<(usize, usize, usize)> {
    let mut it = t.split(|&b| b == b'/');
    // Huge garbage counts are harmless: the token loops stop at the end of
    // the line with an error.
    let mut n = || -> Option<usize> { std::str::from_utf8(it.next()?).ok()?.parse().ok() };
    let r = (n()?, n()?, n()?);
    it.next().is_none().then_some(r)
}
