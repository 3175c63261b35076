//! Bad input: every malformed file is an `Err` naming the file and the
//! element at fault, and no input whatsoever makes a reader panic.

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subdfit::io::{self, Reader};
use subdfit::mesh::validate_soup;
use subdfit::Error;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

/// Reads `name` with `read_mesh` and checks the error names the file and
/// contains `needle` (the element or the reason).
fn expect_err(name: &str, needle: &str) -> Error {
    let path = data(name);
    let e = match io::read_mesh(&path) {
        Ok(_) => panic!("{name}: read without error"),
        Err(e) => e,
    };
    let msg = e.to_string();
    assert!(
        msg.contains(name),
        "{name}: message does not name the file: {msg}"
    );
    assert!(
        msg.contains(needle),
        "{name}: expected '{needle}' in: {msg}"
    );
    e
}

#[test]
fn malformed_fixtures_are_errors_naming_file_and_element() {
    assert!(matches!(
        expect_err("bad_token.obj", "line 2"),
        Error::Parse { .. }
    ));
    assert!(matches!(
        expect_err("bad_index.obj", "line 4"),
        Error::Parse { .. }
    ));
    assert!(matches!(
        expect_err("out_of_range.obj", "face 0 (line 4)"),
        Error::InvalidMesh { .. }
    ));
    assert!(matches!(
        expect_err("out_of_range.ply", "face 0"),
        Error::InvalidMesh { .. }
    ));
    let e = expect_err("nan_vertex.obj", "vertex 1");
    assert!(e.to_string().contains("non-finite coordinate (NaN)"), "{e}");
    assert!(matches!(
        expect_err("face_two_vertices.obj", "face 1"),
        Error::InvalidMesh { .. }
    ));
    assert!(matches!(
        expect_err("empty.obj", "no faces"),
        Error::InvalidMesh { .. }
    ));
    assert!(matches!(
        expect_err("no_faces.obj", "no faces"),
        Error::InvalidMesh { .. }
    ));
    assert!(matches!(
        expect_err("truncated_ascii.ply", "face 1"),
        Error::Parse { .. }
    ));
    assert!(matches!(expect_err("no_z.ply", "'z'"), Error::Parse { .. }));
}

#[test]
fn missing_files_and_unknown_extensions() {
    for reader in [Reader::Rust, Reader::OpenMesh] {
        let e = io::read_soup_with(&data("missing.obj"), reader).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");
        assert!(e.to_string().contains("missing.obj"));
    }
    let e = io::read_soup(&data("mesh.xyz")).unwrap_err();
    assert!(e.to_string().contains("mesh.xyz"), "{e}");
    // Every format has a pure-Rust reader now: a missing OFF is an I/O error.
    let e = io::read_soup_with(Path::new("x.off"), Reader::Rust).unwrap_err();
    assert!(
        matches!(e, Error::Io { .. }) && e.to_string().contains("x.off"),
        "{e}"
    );
}

#[test]
fn openmesh_failures_name_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("garbage.off");
    std::fs::write(&path, b"this is not an OFF file\n\x00\x01").unwrap();
    // The default (Rust) reader names the line; OpenMesh either refuses the
    // file or reads nothing, which ends as an error naming the file once
    // validated.
    let e = io::read_mesh(&path).unwrap_err();
    assert!(
        e.to_string()
            .contains("garbage.off: line 1: not an OFF file"),
        "{e}"
    );
    let s = io::read_soup_with(&path, Reader::OpenMesh);
    let e = s.and_then(|s| validate_soup(s, &path)).unwrap_err();
    assert!(e.to_string().contains("garbage.off"), "{e}");
}

#[test]
fn control_mesh_errors_name_file_and_element() {
    let dir = tempfile::tempdir().unwrap();
    // Vertex 3 is used by no face.
    let path = dir.path().join("unreferenced.obj");
    std::fs::write(&path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3\n").unwrap();
    let e = io::read_control_mesh(&path).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, Error::InvalidMesh { .. }), "{msg}");
    assert!(
        msg.contains("unreferenced.obj") && msg.contains("vertex 3"),
        "{msg}"
    );
    // A crease on an edge that does not exist.
    let path = dir.path().join("bad_crease.obj");
    std::fs::write(
        &path,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 4 3\nt crease 2/1/0 0 3 1\n",
    )
    .unwrap();
    let msg = io::read_control_mesh(&path).unwrap_err().to_string();
    assert!(
        msg.contains("bad_crease.obj") && msg.contains("edge (0, 3)"),
        "{msg}"
    );
    // Tags out of range and malformed tags are caught by the reader.
    let path = dir.path().join("bad_tag.obj");
    std::fs::write(
        &path,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nt corner 1/1/0 9 1\n",
    )
    .unwrap();
    let msg = io::read_control_mesh(&path).unwrap_err().to_string();
    assert!(
        msg.contains("bad_tag.obj") && msg.contains("line 5"),
        "{msg}"
    );
    std::fs::write(
        &path,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nt crease 2/1/0 0 1\n",
    )
    .unwrap();
    let msg = io::read_control_mesh(&path).unwrap_err().to_string();
    assert!(
        msg.contains("line 5") && msg.contains("fewer floats"),
        "{msg}"
    );
}

/// A binary PLY cut anywhere is an error naming the element and byte.
#[test]
fn truncated_binary_ply_names_element_and_byte() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.ply");
    let positions = vec![subdfit::DVec3::ZERO, subdfit::DVec3::X, subdfit::DVec3::Y];
    io::write_ply(&path, &positions, &[[0u32, 1, 2]], &[], None).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    assert_eq!(bytes.len(), header + 3 * 12 + 1 + 12);
    // Cut inside the second vertex, then inside the face.
    let e = io::parse_ply(&bytes[..header + 20], &path)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("t.ply") && e.contains("vertex 1") && e.contains("truncated"),
        "{e}"
    );
    let e = io::parse_ply(&bytes[..bytes.len() - 2], &path)
        .unwrap_err()
        .to_string();
    assert!(e.contains(&format!("face 0 (byte {})", header + 37)), "{e}");
}

fn never_panics(bytes: &[u8], path: &Path) {
    // Errors are fine; a panic fails the test. Whatever parses must also
    // survive validation.
    let soups = [
        io::parse_obj(bytes, path).map(|o| o.soup),
        io::parse_ply(bytes, path),
        io::parse_off(bytes, path),
        io::parse_stl(bytes, path),
    ];
    for s in soups.into_iter().flatten() {
        let _ = validate_soup(s, path);
    }
}

#[test]
fn fuzzed_inputs_never_panic() {
    // The fixtures and the hostile corpus (every format, every defect).
    let mut inputs: Vec<Vec<u8>> = [data(""), data("hostile")]
        .iter()
        .flat_map(|d| std::fs::read_dir(d).unwrap())
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file() && !p.extension().is_some_and(|x| x == "md" || x == "py"))
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    // Binary PLYs of every endianness from the writer and by hand.
    let dir = tempfile::tempdir().unwrap();
    let cube = subdfit::fixtures::cube();
    let ply = dir.path().join("cube.ply");
    let props: Vec<f32> = (0..8).map(|i| i as f32).collect();
    io::write_ply(
        &ply,
        cube.positions(),
        &cube.to_polygons(),
        &[("k", &props)],
        Some(&[[1, 2, 3]; 8]),
    )
    .unwrap();
    let le = std::fs::read(&ply).unwrap();
    let be = {
        let s = String::from_utf8_lossy(&le).replace("binary_little_endian", "binary_big_endian");
        s.into_bytes()
    };
    inputs.push(le);
    inputs.push(be);
    let path = Path::new("fuzz");
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed);
    for input in &inputs {
        // Every truncation.
        for n in 0..=input.len() {
            never_panics(&input[..n], path);
        }
        // Random byte flips, insertions of hostile tokens.
        for _ in 0..300 {
            let mut b = input.clone();
            for _ in 0..rng.gen_range(1..6) {
                if b.is_empty() {
                    break;
                }
                let k = rng.gen_range(0..b.len());
                match rng.gen_range(0..4) {
                    0 => b[k] = rng.gen(),
                    1 => b[k] = b" \n/-#9e"[rng.gen_range(0..7)],
                    2 => {
                        let tok: &[u8] = [
                            &b"4294967295"[..],
                            b"-99999999999",
                            b"1e308",
                            b"nan",
                            b"65535",
                        ][rng.gen_range(0..5)];
                        b.splice(k..k, tok.iter().copied());
                    }
                    _ => {
                        b.remove(k);
                    }
                }
            }
            never_panics(&b, path);
        }
    }
    // Headers announcing absurd counts must not allocate them.
    let huge = b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\nproperty float x\nproperty float y\nproperty float z\nelement face 4294967295\nproperty list uint uint vertex_indices\nend_header\n\0\0\0\0";
    assert!(io::parse_ply(huge, path).is_err());
    let huge_ascii = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uint uint vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n4000000000 1 2 3\n";
    assert!(io::parse_ply(huge_ascii, path).is_err());
}
