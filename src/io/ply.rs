//! Stanford PLY reader (pure Rust): ascii, binary_little_endian and
//! binary_big_endian (Turk's PLY format description).
//!
//! Vertex positions come from the `x`, `y`, `z` properties of the `vertex`
//! element, of any scalar type; faces from the `vertex_indices` (or
//! `vertex_index`, written by some exporters) list of the `face` element, with
//! any count and index types. Every other property and element is skipped by
//! its declared size, so colours, normals, `edge` or `material` elements do
//! not disturb the read.

use std::path::Path;

use crate::error::{Error, Result};
use crate::io::text::{bad_token, bom_len, non_finite, parse_f64, SpanTokens};
use crate::mesh::PolySoup;
use crate::DVec3;

/// Reads a PLY file.
pub fn read_ply(path: &Path) -> Result<PolySoup> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_ply(&bytes, path)
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    /// Decodes one value from the first `size()` bytes of `b` (caller checks
    /// the length). Every scalar type converts to `f64` exactly.
    #[inline]
    fn decode(self, b: &[u8], big: bool) -> f64 {
        macro_rules! get {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                (if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }) as f64
            }};
        }
        match self {
            Scalar::I8 => b[0] as i8 as f64,
            Scalar::U8 => b[0] as f64,
            Scalar::I16 => get!(i16, 2),
            Scalar::U16 => get!(u16, 2),
            Scalar::I32 => get!(i32, 4),
            Scalar::U32 => get!(u32, 4),
            Scalar::F32 => get!(f32, 4),
            Scalar::F64 => get!(f64, 8),
        }
    }
}

#[derive(Clone, Debug)]
enum Property {
    Scalar {
        name: String,
        ty: Scalar,
    },
    List {
        name: String,
        count: Scalar,
        item: Scalar,
    },
}

impl Property {
    fn name(&self) -> &str {
        match self {
            Property::Scalar { name, .. } | Property::List { name, .. } => name,
        }
    }
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

struct Header {
    format: Format,
    elements: Vec<Element>,
    /// Byte offset of the body.
    body: usize,
    /// Number of header lines (ascii body line numbers continue from here).
    lines: usize,
}

fn parse_header(bytes: &[u8], path: &Path) -> Result<Header> {
    // A UTF-8 BOM before `ply` (Windows editors) is skipped; offsets in
    // errors stay offsets in the file.
    let mut pos = bom_len(bytes);
    let mut lineno = 0usize;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    loop {
        let Some(len) = bytes[pos..].iter().position(|&b| b == b'\n') else {
            return Err(Error::parse(
                path,
                format!("line {}", lineno + 1),
                "header not terminated by 'end_header'",
            ));
        };
        let raw = &bytes[pos..pos + len];
        pos += len + 1;
        lineno += 1;
        let at = || format!("line {lineno}");
        let line = std::str::from_utf8(raw)
            .map_err(|_| Error::parse(path, at(), "header line is not text"))?
            .trim_end_matches('\r');
        let toks: Vec<&str> = line.split_ascii_whitespace().collect();
        if lineno == 1 {
            if toks != ["ply"] {
                return Err(Error::parse(
                    path,
                    at(),
                    "not a PLY file (first line is not 'ply')",
                ));
            }
            continue;
        }
        match toks.as_slice() {
            [] => {}
            ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, version] => {
                if !version.starts_with('1') {
                    return Err(Error::parse(
                        path,
                        at(),
                        format!("unsupported PLY version {version}"),
                    ));
                }
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::BinaryLe,
                    "binary_big_endian" => Format::BinaryBe,
                    _ => return Err(Error::parse(path, at(), format!("unknown format '{f}'"))),
                });
            }
            ["element", name, count] => {
                let count = count.parse().map_err(|_| {
                    Error::parse(path, at(), format!("bad element count '{count}'"))
                })?;
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            ["property", "list", count, item, name] => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| Error::parse(path, at(), "property before any element"))?;
                let ty = |t: &str| {
                    Scalar::parse(t)
                        .ok_or_else(|| Error::parse(path, at(), format!("unknown type '{t}'")))
                };
                let (count, item) = (ty(count)?, ty(item)?);
                if matches!(count, Scalar::F32 | Scalar::F64) {
                    return Err(Error::parse(
                        path,
                        at(),
                        "list count type must be an integer type",
                    ));
                }
                el.props.push(Property::List {
                    name: name.to_string(),
                    count,
                    item,
                });
            }
            ["property", ty, name] => {
                let el = elements
                    .last_mut()
                    .ok_or_else(|| Error::parse(path, at(), "property before any element"))?;
                let ty = Scalar::parse(ty)
                    .ok_or_else(|| Error::parse(path, at(), format!("unknown type '{ty}'")))?;
                el.props.push(Property::Scalar {
                    name: name.to_string(),
                    ty,
                });
            }
            ["end_header"] => break,
            _ => {
                let shown: String = line.chars().take(60).collect();
                return Err(Error::parse(
                    path,
                    at(),
                    format!("unrecognised header line '{shown}'"),
                ));
            }
        }
    }
    let format = format.ok_or_else(|| Error::parse(path, "header", "no 'format' line"))?;
    Ok(Header {
        format,
        elements,
        body: pos,
        lines: lineno,
    })
}

/// Where the positions and the face indices sit in the file's elements.
struct Layout {
    vertex: usize,
    xyz: [usize; 3],
    face: Option<(usize, usize)>,
}

fn layout(h: &Header, path: &Path) -> Result<Layout> {
    let vertex = h
        .elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| Error::parse(path, "header", "no 'vertex' element"))?;
    let ve = &h.elements[vertex];
    let mut xyz = [0usize; 3];
    for (k, axis) in ["x", "y", "z"].iter().enumerate() {
        xyz[k] = ve
            .props
            .iter()
            .position(|p| matches!(p, Property::Scalar { name, .. } if name == axis))
            .ok_or_else(|| {
                Error::parse(
                    path,
                    "header",
                    format!("vertex element has no scalar property '{axis}'"),
                )
            })?;
    }
    let face = match h.elements.iter().position(|e| e.name == "face") {
        None => None,
        Some(fi) => {
            let pi = h.elements[fi]
                .props
                .iter()
                .position(|p| {
                    matches!(p, Property::List { name, .. } if name == "vertex_indices" || name == "vertex_index")
                })
                .ok_or_else(|| {
                    Error::parse(path, "header", "face element has no list property 'vertex_indices' or 'vertex_index'")
                })?;
            Some((fi, pi))
        }
    };
    Ok(Layout { vertex, xyz, face })
}

/// Parses PLY data already in memory; `path` only names the file in errors.
pub fn parse_ply(bytes: &[u8], path: &Path) -> Result<PolySoup> {
    let h = parse_header(bytes, path)?;
    let lay = layout(&h, path)?;
    let mut soup = PolySoup::new();
    let body = &bytes[h.body..];
    match h.format {
        Format::Ascii => read_ascii(body, &h, &lay, path, &mut soup)?,
        Format::BinaryLe => read_binary(body, h.body, false, &h, &lay, path, &mut soup)?,
        Format::BinaryBe => read_binary(body, h.body, true, &h, &lay, path, &mut soup)?,
    }
    Ok(soup)
}

/// Converts a decoded list entry to a vertex index below `nv` (the header's
/// vertex count, known before any face is read whatever the element order),
/// or explains why not; the caller names the line or byte.
#[inline]
fn to_index(v: f64, nv: usize) -> std::result::Result<u32, String> {
    if v >= 0.0 && v < u32::MAX as f64 && v.fract() == 0.0 {
        if (v as usize) < nv {
            Ok(v as u32)
        } else {
            Err(format!(
                "vertex index {v} out of range (the file has {nv} vertices)"
            ))
        }
    } else {
        Err(format!("vertex index {v} is not a valid index"))
    }
}

fn push_face_end(soup: &mut PolySoup, path: &Path, at: impl Fn() -> String) -> Result<()> {
    let end = u32::try_from(soup.face_indices.len())
        .map_err(|_| Error::parse(path, at(), "more than 2^32 face corners"))?;
    soup.face_offsets.push(end);
    Ok(())
}

/// Positions from vertex records of `size` bytes each; `records` starts at
/// byte `at` of the file.
#[allow(clippy::too_many_arguments)]
fn fixed_vertices(
    records: &[u8],
    at: usize,
    size: usize,
    big: bool,
    el: &Element,
    lay: &Layout,
    path: &Path,
    soup: &mut PolySoup,
) -> Result<()> {
    let mut offs = [0usize; 3];
    let mut tys = [Scalar::F32; 3];
    for (k, &pi) in lay.xyz.iter().enumerate() {
        offs[k] = el.props[..pi]
            .iter()
            .map(|p| match p {
                Property::Scalar { ty, .. } => ty.size(),
                Property::List { .. } => 0,
            })
            .sum();
        if let Property::Scalar { ty, .. } = el.props[pi] {
            tys[k] = ty;
        }
    }
    for (k, rec) in records.chunks_exact(size.max(1)).enumerate() {
        let p = DVec3::new(
            tys[0].decode(&rec[offs[0]..], big),
            tys[1].decode(&rec[offs[1]..], big),
            tys[2].decode(&rec[offs[2]..], big),
        );
        check_finite(p, path, || format!("vertex {k} (byte {})", at + k * size))?;
        soup.positions.push(p);
    }
    Ok(())
}

#[allow(clippy::too_many_arguments)]
fn read_binary(
    body: &[u8],
    body_offset: usize,
    big: bool,
    h: &Header,
    lay: &Layout,
    path: &Path,
    soup: &mut PolySoup,
) -> Result<()> {
    let mut pos = 0usize;
    let nv = h.elements[lay.vertex].count;
    for (ei, el) in h.elements.iter().enumerate() {
        if el.props.is_empty() {
            // Its records hold no bytes, so the count is bounded by nothing
            // in the file: a 4 KB header declaring billions of them kept
            // the fuzzer busy for seconds. There is nothing to read.
            continue;
        }
        let fixed: Option<usize> = el
            .props
            .iter()
            .map(|p| match p {
                Property::Scalar { ty, .. } => Some(ty.size()),
                Property::List { .. } => None,
            })
            .sum();
        // Smallest possible record: lists with zero entries.
        let min_size: usize = el
            .props
            .iter()
            .map(|p| match p {
                Property::Scalar { ty, .. } => ty.size(),
                Property::List { count, .. } => count.size(),
            })
            .sum();
        let truncated = |k: usize, at: usize| {
            Error::parse(
                path,
                format!("{} {k} (byte {})", el.name, body_offset + at),
                format!(
                    "file truncated: the header announces {} {} elements",
                    el.count, el.name
                ),
            )
        };
        // Reject absurd counts before reserving memory for them.
        if min_size > 0 && el.count > (body.len() - pos) / min_size {
            let k = (body.len() - pos) / min_size;
            return Err(truncated(k, pos + k * min_size));
        }
        if ei == lay.vertex {
            soup.positions.reserve_exact(el.count);
        }
        if let (Some(size), true) = (fixed, ei == lay.vertex) {
            // Fast path: fixed-size vertex records.
            let n = el.count * size; // checked against the body length above
            let at = body_offset + pos;
            fixed_vertices(&body[pos..pos + n], at, size, big, el, lay, path, soup)?;
            pos += n;
            continue;
        }
        if let (Some(size), false) = (fixed, lay.face.map(|f| f.0) == Some(ei)) {
            pos += el.count * size; // an element we skip wholesale
            continue;
        }
        let face_prop = lay.face.filter(|f| f.0 == ei).map(|f| f.1);
        if face_prop.is_some() {
            soup.face_offsets.reserve(el.count);
            soup.face_indices
                .reserve(el.count.saturating_mul(3).min(body.len() - pos));
        }
        let mut xyz = [0.0f64; 3];
        for k in 0..el.count {
            let record = pos;
            for (pi, p) in el.props.iter().enumerate() {
                match *p {
                    Property::Scalar { ty, .. } => {
                        let s = ty.size();
                        if body.len() - pos < s {
                            return Err(truncated(k, pos));
                        }
                        if ei == lay.vertex {
                            if let Some(a) = lay.xyz.iter().position(|&q| q == pi) {
                                xyz[a] = ty.decode(&body[pos..], big);
                            }
                        }
                        pos += s;
                    }
                    Property::List { count, item, .. } => {
                        let cs = count.size();
                        if body.len() - pos < cs {
                            return Err(truncated(k, pos));
                        }
                        let c = count.decode(&body[pos..], big);
                        if c < 0.0 {
                            return Err(Error::parse(
                                path,
                                format!("{} {k} (byte {})", el.name, body_offset + pos),
                                format!("negative list length {c}"),
                            ));
                        }
                        pos += cs;
                        let c = c as usize;
                        let is = item.size();
                        let len = c.checked_mul(is).filter(|&l| l <= body.len() - pos);
                        let Some(len) = len else {
                            return Err(truncated(k, pos));
                        };
                        if face_prop == Some(pi) {
                            for j in 0..c {
                                let v = item.decode(&body[pos + j * is..], big);
                                let i = to_index(v, nv).map_err(|m| {
                                    let at = body_offset + pos + j * is;
                                    Error::invalid_mesh(path, format!("face {k} (byte {at})"), m)
                                })?;
                                soup.face_indices.push(i);
                            }
                        }
                        pos += len;
                    }
                }
            }
            if ei == lay.vertex {
                let p = DVec3::from_array(xyz);
                check_finite(p, path, || {
                    format!("vertex {k} (byte {})", body_offset + record)
                })?;
                soup.positions.push(p);
            } else if face_prop.is_some() {
                push_face_end(soup, path, || format!("face {k}"))?;
            }
        }
    }
    if pos < body.len() {
        // More data than the header announces: the counts are wrong, and
        // whatever was read under them cannot be trusted either.
        return Err(Error::parse(
            path,
            format!("byte {}", body_offset + pos),
            format!(
                "{} bytes of trailing data after the last element the header announces: the counts in the header are wrong, or the file has extra data",
                body.len() - pos
            ),
        ));
    }
    Ok(())
}

/// Rejects a vertex with a NaN or infinite coordinate at `at()`.
fn check_finite(p: DVec3, path: &Path, at: impl Fn() -> String) -> Result<()> {
    match non_finite(p) {
        Some(msg) => Err(Error::invalid_mesh(path, at(), msg)),
        None => Ok(()),
    }
}

fn read_ascii(
    body: &[u8],
    h: &Header,
    lay: &Layout,
    path: &Path,
    soup: &mut PolySoup,
) -> Result<()> {
    let mut toks = SpanTokens {
        rest: body,
        line: h.lines + 1,
    };
    let nv = h.elements[lay.vertex].count;
    for (ei, el) in h.elements.iter().enumerate() {
        if el.props.is_empty() {
            // No tokens per record: nothing to read, however many (see
            // read_binary).
            continue;
        }
        let face_prop = lay.face.filter(|f| f.0 == ei).map(|f| f.1);
        // Each record needs at least two bytes per property ("0 ").
        let cap = el.count.min(body.len() / 2 / el.props.len().max(1));
        if ei == lay.vertex {
            soup.positions.reserve(cap);
        } else if face_prop.is_some() {
            soup.face_offsets.reserve(cap);
        }
        for k in 0..el.count {
            let mut xyz = [0.0f64; 3];
            for (pi, p) in el.props.iter().enumerate() {
                let number = |what: &str, toks: &mut SpanTokens| -> Result<f64> {
                    let line = toks.line;
                    let t = toks.next().ok_or_else(|| {
                        Error::parse(
                            path,
                            format!("{} {k} (line {line})", el.name),
                            format!(
                                "unexpected end of file: the header announces {} {} elements",
                                el.count, el.name
                            ),
                        )
                    })?;
                    parse_f64(t).ok_or_else(|| {
                        Error::parse(
                            path,
                            format!("{} {k} (line {})", el.name, toks.line),
                            bad_token(what, t),
                        )
                    })
                };
                match *p {
                    Property::Scalar { ref name, .. } => {
                        let v = number(name, &mut toks)?;
                        if ei == lay.vertex {
                            if let Some(a) = lay.xyz.iter().position(|&q| q == pi) {
                                xyz[a] = v;
                            }
                        }
                    }
                    Property::List { .. } => {
                        let line = toks.line;
                        let c = number("list length", &mut toks)?;
                        if !(c >= 0.0 && c.fract() == 0.0 && c <= body.len() as f64) {
                            return Err(Error::parse(
                                path,
                                format!("{} {k} (line {line})", el.name),
                                format!("bad list length {c}"),
                            ));
                        }
                        for _ in 0..c as usize {
                            let v = number(p.name(), &mut toks)?;
                            if face_prop == Some(pi) {
                                let i = to_index(v, nv).map_err(|m| {
                                    Error::invalid_mesh(
                                        path,
                                        format!("face {k} (line {})", toks.line),
                                        m,
                                    )
                                })?;
                                soup.face_indices.push(i);
                            }
                        }
                    }
                }
            }
            if ei == lay.vertex {
                let p = DVec3::from_array(xyz);
                // `toks.line` is the line of the record's last token.
                check_finite(p, path, || format!("vertex {k} (line {})", toks.line))?;
                soup.positions.push(p);
            } else if face_prop.is_some() {
                push_face_end(soup, path, || format!("face {k}"))?;
            }
        }
    }
    if let Some(t) = toks.next() {
        return Err(Error::parse(
            path,
            format!("line {}", toks.line),
            format!(
                "trailing data after the last element the header announces ('{}'): the counts in the header are wrong, or the file has extra data",
                String::from_utf8_lossy(&t[..t.len().min(40)])
            ),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An element without properties holds no bytes, so its count is not
    /// bounded by the file's size (found by `scripts/fuzz.sh ply` as a
    /// 13 s timeout): 4e9 of them, binary and ascii, are skipped at once,
    /// and the mesh after them is read.
    #[test]
    fn billions_of_empty_records_are_skipped() {
        let head = |fmt: &str| {
            format!(
                "ply\nformat {fmt} 1.0\nelement junk 4000000000\nelement vertex 3\n\
                 property float x\nproperty float y\nproperty float z\nelement face 1\n\
                 property list uchar int vertex_indices\nend_header\n"
            )
        };
        let mut bin = head("binary_little_endian").into_bytes();
        for x in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
            bin.extend(x.to_le_bytes());
        }
        bin.push(3);
        for i in [0i32, 1, 2] {
            bin.extend(i.to_le_bytes());
        }
        let ascii = head("ascii") + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        for bytes in [bin, ascii.into_bytes()] {
            let t = std::time::Instant::now();
            let soup = parse_ply(&bytes, Path::new("junk.ply")).unwrap();
            assert_eq!((soup.positions.len(), soup.faces().count()), (3, 1));
            assert!(t.elapsed().as_secs_f64() < 1.0, "{:?}", t.elapsed());
        }
    }
}
