//! STL reader (pure Rust), ascii and binary.
//!
//! Why our own and not OpenMesh's `_STLReader_` (still reachable as
//! [`crate::io::Reader::OpenMesh`]): that reader stops silently wherever an
//! ascii file is cut (a file cut mid-facet read as 79 of its 1,280 faces
//! without a word), does not look at NaN coordinates, and reports every
//! failure as a mesh without faces. The format is two pages long; parsing it
//! here gives errors that name the facet, the line or the byte. The Rust
//! crate for it, `stl_io`, returns `std::io::Error`s that name neither; its
//! vertex welding would also have to match OpenMesh's for outputs to stay
//! unchanged, which is simpler to guarantee here (see below).
//!
//! Binary or ascii: a file whose size is exactly `84 + 50 n` for the `n` at
//! byte 80 is binary; a NUL-free file starting with `solid` is ascii (many
//! binary files also start with `solid` in their free-form header, hence the
//! size test first). Anything else is an error that says why it is neither.
//!
//! Like OpenMesh (and every STL consumer: STL stores no connectivity),
//! corners with identical coordinates become one vertex, numbered in order
//! of first appearance; `-0` and `0` are the same point. Unlike OpenMesh,
//! facets that collapse by that (two equal corners) are kept, so that
//! validation counts and reports them instead of them vanishing here.
//! Coordinates are single precision, as stored in binary STL; ascii ones are
//! rounded to it, as OpenMesh did, so that meshes read before keep
//! byte-identical outputs.

use std::path::Path;

use crate::error::{Error, Result};
use crate::io::text::{bom_len, non_finite, parse_f64, to_f32, SpanTokens};
use crate::mesh::{weld_identical, PolySoup};
use crate::DVec3;

/// Reads an STL file, ascii or binary.
pub fn read_stl(path: &Path) -> Result<PolySoup> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_stl(&bytes, path)
}

/// Parses STL data already in memory; `path` only names the file in errors.
pub fn parse_stl(bytes: &[u8], path: &Path) -> Result<PolySoup> {
    let mut w = Welder::default();
    if binary_size(bytes) == Some(bytes.len() as u64) {
        read_binary(bytes, path, &mut w)?;
    } else if starts_with_solid(bytes) && !bytes.contains(&0) {
        read_ascii(bytes, path, &mut w)?;
    } else {
        return Err(neither(bytes, path));
    }
    Ok(w.into_soup())
}

/// `84 + 50 n` for the triangle count `n` of a binary header.
fn binary_size(bytes: &[u8]) -> Option<u64> {
    let n = u32::from_le_bytes(bytes.get(80..84)?.try_into().ok()?);
    Some(84 + 50 * n as u64)
}

fn starts_with_solid(bytes: &[u8]) -> bool {
    let text = bytes[bom_len(bytes)..].trim_ascii_start();
    text.len() >= 5 && text[..5].eq_ignore_ascii_case(b"solid")
}

/// Why a file is neither ascii nor binary STL.
fn neither(bytes: &[u8], path: &Path) -> Error {
    let len = bytes.len();
    let msg = match binary_size(bytes) {
        _ if len == 0 => "empty file".to_string(),
        None => format!(
            "{len} bytes: too short for a binary STL (at least 84 bytes) and not an ascii STL (no 'solid' at the start)"
        ),
        Some(want) if starts_with_solid(bytes) => format!(
            "starts with 'solid' but contains NUL bytes, so it is no ascii STL; read as binary, the header announces {} triangles ({want} bytes) and the file has {len} bytes",
            (want - 84) / 50
        ),
        Some(want) => {
            let n = (want - 84) / 50;
            let what = if (len as u64) < want {
                format!(
                    "truncated: it ends inside triangle {} (byte {len})",
                    (len as u64).saturating_sub(84) / 50
                )
            } else {
                format!("{} bytes of trailing data after the last triangle", len as u64 - want)
            };
            format!("binary STL whose header announces {n} triangles (84 + 50 x {n} = {want} bytes) but the file has {len} bytes: {what}")
        }
    };
    Error::parse(path, format!("byte {}", len.min(84)), msg)
}

/// The corners as read, three per facet, welded at the end by the one weld
/// every reader path shares ([`crate::mesh::weld_identical`]: identical
/// coordinates, `-0` = `+0`, numbered in order of first appearance).
#[derive(Default)]
struct Welder {
    corners: Vec<DVec3>,
}

impl Welder {
    fn triangle(&mut self, c: [[f32; 3]; 3]) {
        self.corners
            .extend(c.map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)));
    }

    fn into_soup(self) -> PolySoup {
        let weld = weld_identical(&self.corners);
        PolySoup {
            positions: weld.positions,
            face_offsets: (0..=self.corners.len() as u32 / 3).map(|f| 3 * f).collect(),
            face_indices: weld.remap,
        }
    }
}

fn read_binary(bytes: &[u8], path: &Path, w: &mut Welder) -> Result<()> {
    let n = (bytes.len() - 84) / 50;
    w.corners.reserve(3 * n);
    for k in 0..n {
        let rec = &bytes[84 + 50 * k..84 + 50 * (k + 1)];
        let f = |i: usize| f32::from_le_bytes(rec[4 * i..4 * i + 4].try_into().unwrap());
        // Floats 0..3 are the normal: unused (often zero or even NaN on
        // degenerate facets), so not checked.
        let mut c = [[0.0f32; 3]; 3];
        for (j, corner) in c.iter_mut().enumerate() {
            *corner = [f(3 + 3 * j), f(4 + 3 * j), f(5 + 3 * j)];
            let p = DVec3::new(corner[0] as f64, corner[1] as f64, corner[2] as f64);
            if let Some(msg) = non_finite(p) {
                return Err(Error::invalid_mesh(
                    path,
                    format!("facet {k}, vertex {j} (byte {})", 84 + 50 * k + 12 + 12 * j),
                    msg,
                ));
            }
        }
        w.triangle(c);
    }
    Ok(())
}

/// The ascii grammar: `solid name`, then facets `facet normal nx ny nz /
/// outer loop / vertex x y z (3 times) / endloop / endfacet`, then `endsolid
/// [name]`; several solids may follow each other. Keywords in any case.
fn read_ascii(bytes: &[u8], path: &Path, w: &mut Welder) -> Result<()> {
    let mut s = Ascii {
        toks: SpanTokens {
            rest: &bytes[bom_len(bytes)..],
            line: 1,
        },
        path,
        facets: 0,
        // A final newline ends the last line rather than starting one.
        last_line: bytes.iter().filter(|&&b| b == b'\n').count() + !bytes.ends_with(b"\n") as usize,
    };
    while s.toks.next().is_some() {
        // `solid` was checked for the first solid; its name is the rest of
        // the line, any tokens.
        s.skip_line();
        loop {
            let Some(t) = s.toks.next() else {
                return Err(s.eof("'endsolid' after the last facet"));
            };
            if t.eq_ignore_ascii_case(b"endsolid") {
                s.skip_line();
                break;
            }
            if !t.eq_ignore_ascii_case(b"facet") {
                return Err(s.unexpected(t, "'facet' or 'endsolid'"));
            }
            let c = s.facet()?;
            w.triangle(c);
            s.facets += 1;
        }
        // Another solid, or the end.
        let save = (s.toks.rest, s.toks.line);
        match s.toks.next() {
            None => return Ok(()),
            Some(t) if t.eq_ignore_ascii_case(b"solid") => (s.toks.rest, s.toks.line) = save,
            Some(t) => {
                return Err(s.unexpected(t, "the end of the file or another 'solid'"));
            }
        }
    }
    Ok(())
}

/// At most 40 bytes of `t`, for messages.
fn shown(t: &[u8]) -> String {
    String::from_utf8_lossy(&t[..t.len().min(40)]).into_owned()
}

struct Ascii<'a> {
    toks: SpanTokens<'a>,
    path: &'a Path,
    /// Facets read completely.
    facets: usize,
    last_line: usize,
}

impl Ascii<'_> {
    /// Skips the tokens left on the current line (a solid's name).
    fn skip_line(&mut self) {
        let rest = self.toks.rest;
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.toks.rest = &rest[len..];
    }

    fn eof(&self, expected: &str) -> Error {
        Error::parse(
            self.path,
            format!("line {} (end of file)", self.last_line),
            format!(
                "the file ends after {} complete facets, before {expected}: truncated",
                self.facets
            ),
        )
    }

    fn unexpected(&self, t: &[u8], expected: &str) -> Error {
        Error::parse(
            self.path,
            format!("facet {} (line {})", self.facets, self.toks.line),
            format!("expected {expected}, found '{}'", shown(t)),
        )
    }

    fn keyword(&mut self, k: &str) -> Result<()> {
        match self.toks.next() {
            None => Err(self.eof(&format!("'{k}' in facet {}", self.facets))),
            Some(t) if t.eq_ignore_ascii_case(k.as_bytes()) => Ok(()),
            Some(t) => Err(self.unexpected(t, &format!("'{k}'"))),
        }
    }

    fn number(&mut self, what: &str) -> Result<f64> {
        let t = self
            .toks
            .next()
            .ok_or_else(|| self.eof(&format!("the {what} of facet {}", self.facets)))?;
        parse_f64(t).ok_or_else(|| self.unexpected(t, &format!("a {what}")))
    }

    /// One facet after its `facet` keyword.
    fn facet(&mut self) -> Result<[[f32; 3]; 3]> {
        self.keyword("normal")?;
        for _ in 0..3 {
            // Unused, and NaN on degenerate facets in some writers' output.
            self.number("normal component")?;
        }
        self.keyword("outer")?;
        self.keyword("loop")?;
        let mut c = [[0.0f32; 3]; 3];
        for (j, corner) in c.iter_mut().enumerate() {
            self.keyword("vertex")?;
            let mut p = [0.0f64; 3];
            for x in p.iter_mut() {
                let v = self.number("coordinate")?;
                *x = to_f32(v).ok_or_else(|| {
                    Error::invalid_mesh(
                        self.path,
                        format!(
                            "facet {}, vertex {j} (line {})",
                            self.facets, self.toks.line
                        ),
                        format!("coordinate {v:e} overflows single precision"),
                    )
                })?;
            }
            if let Some(msg) = non_finite(DVec3::from_array(p)) {
                return Err(Error::invalid_mesh(
                    self.path,
                    format!(
                        "facet {}, vertex {j} (line {})",
                        self.facets, self.toks.line
                    ),
                    msg,
                ));
            }
            *corner = p.map(|x| x as f32);
        }
        self.keyword("endloop")?;
        self.keyword("endfacet")?;
        Ok(c)
    }
}
