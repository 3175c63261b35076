//! Lexing shared by the text readers (OBJ, PLY header and ascii body, OFF,
//! ascii STL): BOM, lines, tokens, numbers, and the messages for bad ones.
//!
//! Kept byte-based and allocation-free: every reader scans the whole file in
//! memory, and a per-line `String` would dominate the time on a dense mesh.

/// The UTF-8 byte order mark some Windows editors put at the start of a text
/// file. It is not whitespace to `u8::is_ascii_whitespace`, so left in place
/// it glues itself to the first token (`\u{feff}v` is no `v` statement).
pub(crate) const BOM: &[u8] = b"\xEF\xBB\xBF";

/// Length of the BOM at the start of `bytes`, 0 if there is none; readers
/// skip that many bytes and still report file offsets.
pub(crate) fn bom_len(bytes: &[u8]) -> usize {
    if bytes.starts_with(BOM) {
        BOM.len()
    } else {
        0
    }
}

/// Whitespace-separated tokens of one line, without allocating.
pub(crate) struct Tokens<'a>(pub(crate) &'a [u8]);

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

/// Tokens of a text that may span lines, with the line each one is on
/// (PLY ascii bodies and ascii STL are token streams, not line formats).
pub(crate) struct SpanTokens<'a> {
    pub(crate) rest: &'a [u8],
    /// Line of the last token returned (or of the start, before any).
    pub(crate) line: usize,
}

impl<'a> SpanTokens<'a> {
    #[allow(clippy::should_implement_trait)] // `line` is read between calls
    pub(crate) fn next(&mut self) -> Option<&'a [u8]> {
        let s = self.rest;
        let mut i = 0;
        while i < s.len() && s[i].is_ascii_whitespace() {
            if s[i] == b'\n' {
                self.line += 1;
            }
            i += 1;
        }
        if i == s.len() {
            self.rest = &s[i..];
            return None;
        }
        let start = i;
        while i < s.len() && !s[i].is_ascii_whitespace() {
            i += 1;
        }
        self.rest = &s[i..];
        Some(&s[start..i])
    }
}

/// `line` without what follows a `#` (comments in OBJ and OFF).
pub(crate) fn strip_comment(line: &[u8]) -> &[u8] {
    match line.iter().position(|&b| b == b'#') {
        Some(k) => &line[..k],
        None => line,
    }
}

pub(crate) fn parse_f64(t: &[u8]) -> Option<f64> {
    std::str::from_utf8(t).ok()?.parse().ok()
}

pub(crate) fn parse_i64(t: &[u8]) -> Option<i64> {
    std::str::from_utf8(t).ok()?.parse().ok()
}

pub(crate) fn bad_token(what: &str, t: &[u8]) -> String {
    let shown: String = String::from_utf8_lossy(&t[..t.len().min(40)]).into_owned();
    format!("expected a {what}, found '{shown}'")
}

/// The one wording of a NaN/Inf coordinate, shared with `validate_soup`
/// (it lives in `mesh`, the lower layer).
pub(crate) use crate::mesh::non_finite;

/// Narrows a coordinate parsed as `f64` to the single precision the STL and
/// OFF readers keep (see their module docs), refusing values that only turn
/// infinite by the narrowing: `1e39` is a typo or garbage, not a position.
pub(crate) fn to_f32(v: f64) -> Option<f64> {
    let f = v as f32;
    (f.is_finite() || !v.is_finite()).then_some(f as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::DVec3;

    #[test]
    fn bom_tokens_and_numbers() {
        assert_eq!(bom_len(b"\xEF\xBB\xBFv 1"), 3);
        assert_eq!(bom_len(b"v 1"), 0);
        let t: Vec<&[u8]> = Tokens(b"  v\t1 2\r").collect();
        assert_eq!(t, [&b"v"[..], b"1", b"2"]);
        assert_eq!(strip_comment(b"v 1 # x"), b"v 1 ");
        assert_eq!(to_f32(1e39), None);
        assert_eq!(to_f32(0.5), Some(0.5));
        assert!(to_f32(f64::NAN).unwrap().is_nan());
        assert!(non_finite(DVec3::new(0.0, f64::NAN, 0.0))
            .unwrap()
            .contains("NaN"));
    }
}
