//! OFF reader (pure Rust): the Geomview / Princeton `OFF` family in ascii.
//!
//! Why our own and not OpenMesh's `_OFFReader_` (still reachable as
//! [`crate::io::Reader::OpenMesh`] for cross-checks): that reader reads
//! uninitialised stack memory on ordinary files (valgrind: "conditional jump
//! depends on uninitialised value" from `read_ascii`), so one file gave
//! different messages from run to run; it takes a `#` comment line for the
//! counts, refuses counts on the `OFF` line and per-face colours, and invents
//! copies of the last face when the file has fewer faces than it declares.
//! The format is small; parsing it here gives errors that name the line.
//!
//! Supported:
//! - header keyword `[ST][C][N][4][n]OFF` (texture coordinates, colours,
//!   normals, homogeneous `x y z w` vertices divided by `w`, a dimension line
//!   that must say 3), or no keyword at all (the first line is the counts);
//! - the counts `nv nf [ne]` on the keyword line or on the following line(s);
//!   `ne` is ignored, as every writer fills it with 0 or a guess;
//! - `#` comments anywhere, blank lines, CRLF, a leading UTF-8 BOM;
//! - per-vertex extras after the coordinates (normal, colour of 1, 3 or 4
//!   numbers, texture coordinates) and per-face colours after the indices,
//!   checked to be numbers and ignored.
//!
//! Not supported, with an error naming the line: `OFF BINARY`, `nOFF`
//! dimensions other than 3.
//!
//! Each vertex and each face is one line (every writer does that); this is
//! what lets a count that disagrees with the file be caught at the line
//! where it shows: fewer records than declared is an error at the end of the
//! file, more is an error at the first extra line. Coordinates are read in
//! double precision, as written (OpenMesh's reader, used for OFF before,
//! rounded them to single precision).

use std::path::Path;

use crate::error::{Error, Result};
use crate::io::text::{bad_token, bom_len, non_finite, parse_f64, strip_comment, Tokens};
use crate::mesh::PolySoup;
use crate::DVec3;

/// Reads an OFF file.
pub fn read_off(path: &Path) -> Result<PolySoup> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_off(&bytes, path)
}

/// Parses OFF data already in memory; `path` only names the file in errors.
pub fn parse_off(bytes: &[u8], path: &Path) -> Result<PolySoup> {
    let mut lines = Lines {
        text: bytes,
        pos: bom_len(bytes),
        line: 0,
    };
    let h = header(&mut lines, path)?;
    let mut soup = PolySoup::new();
    // Each record takes at least two bytes ("0\n"): absurd counts must not
    // reserve memory.
    soup.positions.reserve(h.nv.min(bytes.len() / 2));
    soup.face_offsets.reserve(h.nf.min(bytes.len() / 2));
    for i in 0..h.nv {
        let (lineno, line) = lines
            .next()
            .ok_or_else(|| short(&h, &lines, path, i, "vertices"))?;
        soup.positions.push(vertex(&h, i, lineno, line, path)?);
    }
    for f in 0..h.nf {
        let (lineno, line) = lines
            .next()
            .ok_or_else(|| short(&h, &lines, path, f, "faces"))?;
        face(&h, f, lineno, line, path, &mut soup).map_err(|e| match f {
            // The first "face" line not being one is the usual sign of a
            // vertex count that is too small.
            0 => with_hint(
                e,
                &format!(
                    "; if this line is a vertex, the vertex count on line {} is too small",
                    h.counts_line
                ),
            ),
            _ => e,
        })?;
    }
    if let Some((lineno, line)) = lines.next() {
        return Err(Error::parse(
            path,
            format!("line {lineno}"),
            format!(
                "trailing data after the {} vertices and {} faces the header (line {}) declares: '{}'",
                h.nv,
                h.nf,
                h.counts_line,
                shown(line)
            ),
        ));
    }
    Ok(soup)
}

/// Lines with content (comment removed), with their 1-based numbers.
struct Lines<'a> {
    text: &'a [u8],
    pos: usize,
    /// Number of the last line read: at the end, the last line of the file.
    line: usize,
}

impl<'a> Lines<'a> {
    fn next(&mut self) -> Option<(usize, &'a [u8])> {
        while self.pos < self.text.len() {
            let rest = &self.text[self.pos..];
            let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
            self.pos += len + 1;
            self.line += 1;
            let line = strip_comment(&rest[..len]);
            if Tokens(line).next().is_some() {
                return Some((self.line, line));
            }
        }
        None
    }
}

/// What the header says.
#[derive(Debug)]
struct Header {
    /// Numbers per vertex line before the extras: 3, or 4 with `4OFF`.
    coords: usize,
    homogeneous: bool,
    normals: bool,
    colours: bool,
    texcoords: bool,
    nv: usize,
    nf: usize,
    counts_line: usize,
}

/// `[ST][C][N][4][n]OFF` as (texcoords, colours, normals, homogeneous,
/// dimension line), or `None` if `t` is no such keyword.
fn keyword(t: &[u8]) -> Option<(bool, bool, bool, bool, bool)> {
    let mut s = t;
    let mut flag = |prefix: &[u8]| match s.strip_prefix(prefix) {
        Some(r) => {
            s = r;
            true
        }
        None => false,
    };
    let k = (flag(b"ST"), flag(b"C"), flag(b"N"), flag(b"4"), flag(b"n"));
    (s == b"OFF").then_some(k)
}

fn header(lines: &mut Lines, path: &Path) -> Result<Header> {
    let err = |l: usize, msg: String| Error::parse(path, format!("line {l}"), msg);
    let (first_line, first) = lines
        .next()
        .ok_or_else(|| err(lines.line.max(1), "empty file: no OFF header".into()))?;
    let mut toks = Tokens(first);
    let t0 = toks.next().unwrap_or_default();
    let mut h = Header {
        coords: 3,
        homogeneous: false,
        normals: false,
        colours: false,
        texcoords: false,
        nv: 0,
        nf: 0,
        counts_line: first_line,
    };
    // The numbers that follow the keyword: [dimension] nv nf [ne].
    let mut nums: Vec<(usize, &[u8])> = Vec::new();
    let mut dim_line = false;
    if let Some((st, c, n, four, dim)) = keyword(t0) {
        (h.texcoords, h.colours, h.normals, h.homogeneous) = (st, c, n, four);
        dim_line = dim;
        if let Some(t) = toks.next() {
            if t.eq_ignore_ascii_case(b"BINARY") {
                return Err(err(
                    first_line,
                    "binary OFF is not supported; convert it to ascii OFF or to PLY".into(),
                ));
            }
            nums.push((first_line, t));
        }
    } else if t0.first().is_some_and(|b| b.is_ascii_digit()) {
        // No keyword (allowed by Geomview): this line holds the counts.
        nums.push((first_line, t0));
    } else {
        return Err(err(
            first_line,
            format!(
                "not an OFF file: expected a header keyword ([ST][C][N][4][n]OFF), found '{}'",
                shown(t0)
            ),
        ));
    }
    nums.extend(toks.map(|t| (first_line, t)));
    // The counts may sit on the keyword line or on the lines after it.
    let needed = dim_line as usize + 2;
    while nums.len() < needed {
        let (l, line) = lines.next().ok_or_else(|| {
            err(
                lines.line,
                "the file ends before the vertex and face counts".into(),
            )
        })?;
        nums.extend(Tokens(line).map(|t| (l, t)));
    }
    if nums.len() > needed + 1 {
        let (l, t) = nums[needed + 1];
        return Err(err(
            l,
            format!(
                "expected the counts 'vertices faces [edges]', found an extra '{}'",
                shown(t)
            ),
        ));
    }
    let count = |k: usize, what: &str| -> Result<usize> {
        let (l, t) = nums[k];
        std::str::from_utf8(t)
            .ok()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| err(l, bad_token(what, t)))
    };
    if dim_line {
        let d = count(0, "vertex dimension")?;
        if d != 3 {
            return Err(err(
                nums[0].0,
                format!("nOFF with {d}-dimensional vertices is not supported (only 3)"),
            ));
        }
    }
    let d = dim_line as usize;
    h.nv = count(d, "vertex count")?;
    h.nf = count(d + 1, "face count")?;
    if nums.len() > d + 2 {
        count(d + 2, "edge count")?;
    }
    h.counts_line = nums[d + 1].0;
    h.coords = 3 + h.homogeneous as usize;
    Ok(h)
}

/// Error for a file that ends after `got` of the `what` the header declares.
fn short(h: &Header, lines: &Lines, path: &Path, got: usize, what: &str) -> Error {
    Error::parse(
        path,
        format!("line {} (end of file)", lines.line),
        format!(
            "the file ends after {got} of the {} {what} the header (line {}) declares: truncated, or the counts are wrong",
            if what == "faces" { h.nf } else { h.nv },
            h.counts_line
        ),
    )
}

fn vertex(h: &Header, i: usize, lineno: usize, line: &[u8], path: &Path) -> Result<DVec3> {
    let at = || format!("vertex {i} (line {lineno})");
    let mut c = [0.0f64; 4];
    let mut n = 0;
    for t in Tokens(line) {
        let v = parse_f64(t).ok_or_else(|| Error::parse(path, at(), bad_token("number", t)))?;
        if n < h.coords {
            // Double precision, as written: OpenMesh's reader rounded to
            // f32, which loses what a file at an odd scale or with many
            // digits says.
            c[n] = v;
        }
        n += 1;
    }
    if n < h.coords {
        return Err(Error::parse(
            path,
            at(),
            format!("has {n} coordinates, needs {}", h.coords),
        ));
    }
    // What may follow: normal (N), colour (C: 1, 3 or 4 numbers; some
    // writers add one without the C), texture coordinates (ST).
    let base = h.coords + 3 * h.normals as usize + 2 * h.texcoords as usize;
    let extra = n.saturating_sub(base);
    if n < base || !(matches!(extra, 1 | 3 | 4) || (extra == 0 && !h.colours)) {
        return Err(Error::parse(
            path,
            at(),
            format!(
                "has {n} numbers; the header asks for {}{}{}{}",
                if h.homogeneous { "x y z w" } else { "x y z" },
                if h.normals { ", a normal" } else { "" },
                if h.colours {
                    ", a colour (1, 3 or 4 numbers)"
                } else {
                    ""
                },
                if h.texcoords {
                    ", texture coordinates s t"
                } else {
                    ""
                },
            ),
        ));
    }
    let mut p = DVec3::new(c[0], c[1], c[2]);
    if h.homogeneous {
        if c[3] == 0.0 {
            return Err(Error::invalid_mesh(
                path,
                at(),
                "homogeneous coordinate w = 0",
            ));
        }
        p /= c[3];
    }
    if let Some(msg) = non_finite(p) {
        return Err(Error::invalid_mesh(path, at(), msg));
    }
    Ok(p)
}

fn face(
    h: &Header,
    f: usize,
    lineno: usize,
    line: &[u8],
    path: &Path,
    soup: &mut PolySoup,
) -> Result<()> {
    let at = || format!("face {f} (line {lineno})");
    let mut toks = Tokens(line);
    let t = toks.next().unwrap_or_default();
    let int = |t: &[u8]| {
        std::str::from_utf8(t)
            .ok()
            .and_then(|s| s.parse::<u64>().ok())
    };
    let n = int(t).ok_or_else(|| {
        Error::parse(
            path,
            at(),
            bad_token("vertex count (a face line is 'n i1 ... in')", t),
        )
    })?;
    if n < 3 {
        return Err(Error::invalid_mesh(
            path,
            at(),
            format!("has {n} vertices, needs at least 3"),
        ));
    }
    for k in 0..n {
        let t = toks
            .next()
            .ok_or_else(|| Error::parse(path, at(), format!("announces {n} vertices, has {k}")))?;
        let i = int(t).ok_or_else(|| Error::parse(path, at(), bad_token("vertex index", t)))?;
        if i >= h.nv as u64 {
            return Err(Error::invalid_mesh(
                path,
                at(),
                format!(
                    "vertex index {i} out of range (the file has {} vertices)",
                    h.nv
                ),
            ));
        }
        soup.face_indices.push(i as u32);
    }
    // A colour may follow: a colour-map index, or 3 or 4 components.
    let rest = toks.0;
    let (mut extra, mut numeric) = (0, true);
    for t in Tokens(rest) {
        extra += 1;
        numeric &= parse_f64(t).is_some();
    }
    if !(numeric && matches!(extra, 0 | 1 | 3 | 4)) {
        return Err(Error::parse(
            path,
            at(),
            format!(
                "unexpected '{}' after the {n} vertex indices (a face colour is 1, 3 or 4 numbers)",
                shown(rest)
            ),
        ));
    }
    let end = u32::try_from(soup.face_indices.len())
        .map_err(|_| Error::parse(path, at(), "more than 2^32 face corners"))?;
    soup.face_offsets.push(end);
    Ok(())
}

/// `e` with `hint` appended to its message.
fn with_hint(e: Error, hint: &str) -> Error {
    match e {
        Error::Parse {
            path,
            location,
            msg,
        } => Error::Parse {
            path,
            location,
            msg: msg + hint,
        },
        Error::InvalidMesh { path, element, msg } => Error::InvalidMesh {
            path,
            element,
            msg: msg + hint,
        },
        e => e,
    }
}

/// At most 40 bytes of `t`, trimmed, for messages.
fn shown(t: &[u8]) -> String {
    let t = t.trim_ascii();
    String::from_utf8_lossy(&t[..t.len().min(40)]).into_owned()
}
