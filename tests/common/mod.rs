//! TEMPORARY test helpers: a minimal binary-little-endian PLY reader for the
//! shared test meshes, until `subdfit::io` lands (another branch). Replace
//! with `subdfit::io` when merging.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use subdfit::mesh::TriMesh;
use subdfit::DVec3;

pub fn data_dir() -> Option<PathBuf> {
    let d = PathBuf::from("/work/shared/data");
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!("SKIP: test data directory {} is absent", d.display());
        None
    }
}

/// TEMPORARY: reads `element vertex` (float x, y, z first, other scalar
/// properties skipped) and `element face` (`property list uchar int|uint`)
/// of a binary little-endian PLY.
pub fn load_ply(path: &Path) -> TriMesh {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("PLY header")
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.contains("format binary_little_endian 1.0"));
    let size = |t: &str| match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        _ => panic!("PLY type {t}"),
    };
    let (mut nv, mut nf) = (0usize, 0usize);
    let mut vprops: Vec<(String, usize)> = Vec::new();
    let mut cur = "";
    for line in header.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => {
                nv = n.parse().unwrap();
                cur = "vertex";
            }
            ["element", "face", n] => {
                nf = n.parse().unwrap();
                cur = "face";
            }
            ["element", ..] => panic!("unexpected element: {line}"),
            ["property", "list", c, i, _] if cur == "face" => {
                assert_eq!(size(c), 1);
                assert_eq!(size(i), 4);
            }
            ["property", t, name] if cur == "vertex" => vprops.push((name.to_string(), size(t))),
            _ => {}
        }
    }
    assert!(vprops.len() >= 3 && vprops[..3].iter().all(|p| p.1 == 4));
    let stride: usize = vprops.iter().map(|p| p.1).sum();
    let f32at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap()) as f64;
    let mut o = end;
    let mut positions = Vec::with_capacity(nv);
    for _ in 0..nv {
        positions.push(DVec3::new(f32at(o), f32at(o + 4), f32at(o + 8)));
        o += stride;
    }
    let mut triangles = Vec::with_capacity(nf);
    for _ in 0..nf {
        let k = bytes[o] as usize;
        assert_eq!(k, 3, "{}: non-triangle face", path.display());
        o += 1;
        let mut t = [0u32; 3];
        for v in &mut t {
            *v = u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
            o += 4;
        }
        triangles.push(t);
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// Closed meshes of the shared data set (README: watertight = yes).
pub const CLOSED: &[&str] = &[
    "gargoyle",
    "fandisk",
    "block",
    "joint",
    "homer",
    "spot",
    "cheburashka",
];
