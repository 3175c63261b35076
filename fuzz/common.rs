//! What every fuzz target checks on one input: the reader for `format`
//! either fails with a non-empty message, or returns a soup whose face
//! offsets are consistent, whose face indices are all below the vertex count
//! and whose coordinates are all finite; that soup then goes through
//! validation, which again either fails with a non-empty message or returns
//! a triangle mesh with the same invariants. Any panic (including a failed
//! assertion here) or sanitizer report is a finding.

use std::path::Path;

use subdfit::io::{read_soup_bytes, Format};
use subdfit::mesh::validate_soup;

pub fn check(bytes: &[u8], format: Format, name: &str) {
    let name = Path::new(name);
    let soup = match read_soup_bytes(bytes, format, name) {
        Ok(s) => s,
        Err(e) => {
            assert!(!e.to_string().trim().is_empty(), "empty reader error");
            return;
        }
    };
    let nv = soup.positions.len();
    // Empty offsets are tolerated as "no faces" (validation reads them so).
    assert_eq!(
        soup.face_offsets.first().copied().unwrap_or(0),
        0,
        "face_offsets[0]"
    );
    assert!(
        soup.face_offsets.windows(2).all(|w| w[0] <= w[1]),
        "face offsets decrease"
    );
    assert_eq!(
        soup.face_offsets.last().map_or(0, |&e| e as usize),
        soup.face_indices.len(),
        "last face offset"
    );
    for &i in &soup.face_indices {
        assert!((i as usize) < nv, "face index {i} >= vertex count {nv}");
    }
    for p in &soup.positions {
        assert!(p.is_finite(), "non-finite vertex {p:?}");
    }
    match validate_soup(soup, name) {
        Ok(v) => {
            let m = &v.mesh;
            let nv = m.positions.len();
            assert!(!m.triangles.is_empty(), "validated mesh without triangles");
            for t in &m.triangles {
                for &i in t.iter() {
                    assert!((i as usize) < nv, "triangle index {i} >= {nv}");
                }
            }
            for p in &m.positions {
                assert!(p.is_finite(), "non-finite validated vertex {p:?}");
            }
            let _ = v.report.to_string();
        }
        Err(e) => assert!(!e.to_string().trim().is_empty(), "empty validation error"),
    }
}
