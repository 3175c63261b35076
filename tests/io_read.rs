//! Readers: every format, pure Rust against OpenMesh, and the validation
//! report on the shared test meshes against the numbers in their README.

mod common;

use std::path::{Path, PathBuf};
use std::time::Instant;

use subdfit::io::{self, Reader};
use subdfit::mesh::{validate_soup, PolySoup, VertexId};
use subdfit::DVec3;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn polygons(s: &PolySoup) -> Vec<Vec<u32>> {
    s.faces().map(|f| f.to_vec()).collect()
}

/// Same faces, and positions equal once rounded to `f32` (OpenMesh hands
/// some readers' coordinates over as `Vec3f`).
fn assert_same_soup(a: &PolySoup, b: &PolySoup, what: &str) {
    assert_eq!(a.positions.len(), b.positions.len(), "{what}: vertex count");
    for (i, (p, q)) in a.positions.iter().zip(&b.positions).enumerate() {
        let (p, q) = (p.as_vec3(), q.as_vec3());
        assert_eq!(p, q, "{what}: vertex {i}");
    }
    assert_eq!(polygons(a), polygons(b), "{what}: faces");
}

#[test]
fn obj_face_forms_negative_indices_and_shape_tags() {
    let o = io::read_obj(&data("cube_quads.obj")).unwrap();
    let cube = subdfit::fixtures::cube();
    assert_eq!(o.soup.positions, cube.positions());
    assert_eq!(polygons(&o.soup), cube.to_polygons());
    // `t crease 3/1/0 0 1 3 2.5` is a chain of two edges with one sharpness.
    assert_eq!(o.creases, vec![(0, 1, 2.5), (1, 3, 2.5)]);
    assert_eq!(o.corners, vec![(7, 10.0)]);

    let cm = io::read_control_mesh(&data("cube_quads.obj")).unwrap();
    cm.validate().unwrap();
    assert_eq!(cm.num_faces(), 6);
    let e01 = cm.find_halfedge(VertexId(0), VertexId(1)).unwrap().edge();
    let e13 = cm.find_halfedge(VertexId(1), VertexId(3)).unwrap().edge();
    assert_eq!(cm.edge_sharpness(e01), 2.5);
    assert_eq!(cm.edge_sharpness(e13), 2.5);
    assert_eq!(cm.creases().len(), 2);
    assert_eq!(cm.vertex_sharpness(VertexId(7)), 10.0);
    assert_eq!(cm.corners().len(), 1);
}

#[test]
fn cube_report_triangulates_and_is_a_closed_sphere() {
    let v = io::read_mesh(&data("cube_quads.obj")).unwrap();
    let r = &v.report;
    assert_eq!((r.vertices, r.faces, r.triangles, r.edges), (8, 6, 12, 18));
    assert_eq!(r.face_sizes.get(&4), Some(&6));
    assert!(r.closed && r.manifold);
    assert_eq!((r.euler_characteristic, r.genus), (2, Some(0)));
    assert_eq!(r.components, 1);
    assert!((r.bbox_diagonal - 12f64.sqrt()).abs() < 1e-15);
    // Cube edges have length 2, the 6 fan diagonals 2√2.
    let mean = (12.0 * 2.0 + 6.0 * 2.0 * 2f64.sqrt()) / 18.0;
    assert!((r.mean_edge_length - mean).abs() < 1e-12);
    assert!(
        r.notes.iter().any(|n| n.contains("fan-triangulated 6")),
        "{:?}",
        r.notes
    );
    // Every triangle keeps the orientation of its quad: outward normals.
    for t in 0..v.mesh.triangles.len() {
        let [a, b, c] = v.mesh.triangle(t);
        let n = (b - a).cross(c - a);
        assert!(n.dot((a + b + c) / 3.0) > 0.0, "triangle {t} points inward");
    }
    let text = r.to_string();
    assert!(text.contains("genus") && text.contains("12"), "{text}");
}

#[test]
fn ascii_ply_skips_other_properties_and_elements() {
    let s = io::read_ply(&data("tetra_ascii.ply")).unwrap();
    let p = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z];
    assert_eq!(s.positions, p);
    assert_eq!(
        polygons(&s),
        vec![vec![0, 2, 1], vec![0, 1, 3], vec![0, 3, 2], vec![1, 2, 3]]
    );
    let r = validate_soup(s, Path::new("tetra")).unwrap().report;
    assert!(r.closed && r.manifold);
    assert_eq!(r.genus, Some(0));
}

/// A PLY writer for tests: tetrahedron with awkward types everywhere
/// (`exotic`), or only what OpenMesh's PLY reader supports.
fn tetra_ply(format: &str, exotic: bool) -> Vec<u8> {
    if !exotic {
        return simple_tetra_ply(format);
    }
    let big = format == "binary_big_endian";
    let mut out = format!(
        "ply\r\nformat {format} 1.0\r\ncomment CRLF header on purpose\r\nelement material 2\r\n\
         property list uchar float shininess\r\nproperty uchar id\r\n\
         element vertex 4\r\nproperty uchar tag\r\nproperty double x\r\nproperty short y\r\n\
         property float32 z\r\nproperty list int uchar junk\r\n\
         element face 4\r\nproperty float weight\r\nproperty list ushort uint vertex_index\r\nend_header\r\n"
    )
    .into_bytes();
    let tris = [[0u32, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let pos = [
        (0.0f64, 0i16, 0.5f32),
        (1.0, 0, 0.5),
        (0.0, 1, 0.5),
        (0.0, 0, 1.5),
    ];
    if format == "ascii" {
        out.extend(b"2 0.5 0.25 7\n0 8\n");
        for (i, p) in pos.iter().enumerate() {
            out.extend(format!("{i} {} {} {} 1 9\n", p.0, p.1, p.2).bytes());
        }
        for t in tris {
            out.extend(format!("0.5 3 {} {} {}\n", t[0], t[1], t[2]).bytes());
        }
        return out;
    }
    macro_rules! put {
        ($v:expr) => {
            if big {
                out.extend($v.to_be_bytes())
            } else {
                out.extend($v.to_le_bytes())
            }
        };
    }
    put!(2u8);
    put!(0.5f32);
    put!(0.25f32);
    put!(7u8);
    put!(0u8);
    put!(8u8);
    for (i, p) in pos.iter().enumerate() {
        put!(i as u8);
        put!(p.0);
        put!(p.1);
        put!(p.2);
        put!(2i32);
        put!(3u8);
        put!(4u8);
    }
    for t in tris {
        put!(0.5f32);
        put!(3u16);
        for i in t {
            put!(i);
        }
    }
    out
}

fn simple_tetra_ply(format: &str) -> Vec<u8> {
    let big = format == "binary_big_endian";
    let mut out = format!(
        "ply\nformat {format} 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
         property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
         element face 4\nproperty list uchar int vertex_indices\nend_header\n"
    )
    .into_bytes();
    let tris = [[0i32, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let pos = [
        [0.0f32, 0.0, 0.5],
        [1.0, 0.0, 0.5],
        [0.0, 1.0, 0.5],
        [0.0, 0.0, 1.5],
    ];
    for p in pos {
        if format == "ascii" {
            out.extend(format!("{} {} {} 1 2 3\n", p[0], p[1], p[2]).bytes());
        } else {
            for x in p {
                out.extend(if big {
                    x.to_be_bytes()
                } else {
                    x.to_le_bytes()
                });
            }
            out.extend([1u8, 2, 3]);
        }
    }
    for t in tris {
        if format == "ascii" {
            out.extend(format!("3 {} {} {}\n", t[0], t[1], t[2]).bytes());
        } else {
            out.push(3);
            for i in t {
                out.extend(if big {
                    i.to_be_bytes()
                } else {
                    i.to_le_bytes()
                });
            }
        }
    }
    out
}

#[test]
fn ply_ascii_binary_le_be_with_any_types_agree() {
    let dir = tempfile::tempdir().unwrap();
    let expected_pos = [
        DVec3::new(0.0, 0.0, 0.5),
        DVec3::new(1.0, 0.0, 0.5),
        DVec3::new(0.0, 1.0, 0.5),
        DVec3::new(0.0, 0.0, 1.5),
    ];
    for (format, exotic) in [
        ("ascii", true),
        ("binary_little_endian", true),
        ("binary_big_endian", true),
        ("ascii", false),
        ("binary_little_endian", false),
        ("binary_big_endian", false),
    ] {
        let path = dir.path().join(format!("tetra_{format}_{exotic}.PLY"));
        std::fs::write(&path, tetra_ply(format, exotic)).unwrap();
        let s = io::read_soup(&path).unwrap_or_else(|e| panic!("{format}: {e}"));
        assert_eq!(s.positions, expected_pos, "{format}");
        assert_eq!(
            polygons(&s),
            vec![vec![0, 2, 1], vec![0, 1, 3], vec![0, 3, 2], vec![1, 2, 3]],
            "{format}"
        );
    }
}

#[test]
fn off_and_stl_read_like_openmesh() {
    let dir = tempfile::tempdir().unwrap();
    let cube = subdfit::fixtures::cube();
    // OFF: the quad cube.
    // No comment line: OpenMesh's OFF reader takes "# ..." for the counts and
    // silently reads nothing (it is compared with the Rust reader below).
    let mut off = String::from("OFF\n8 6 0\n");
    for p in cube.positions() {
        off += &format!("{} {} {}\n", p.x, p.y, p.z);
    }
    for f in cube.to_polygons() {
        off += &format!("4 {} {} {} {}\n", f[0], f[1], f[2], f[3]);
    }
    let off_path = dir.path().join("cube.off");
    std::fs::write(&off_path, off).unwrap();
    let s = io::read_soup(&off_path).unwrap();
    assert_eq!(s.positions, cube.positions());
    assert_eq!(polygons(&s), cube.to_polygons());
    let om = io::read_soup_with(&off_path, Reader::OpenMesh).unwrap();
    assert_same_soup(&s, &om, "cube.off");

    // STL: the tetrahedron as 4 unconnected facets; the reader merges the
    // 12 corners back into 4 vertices, in the order OpenMesh did.
    let p = [DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z];
    let tris = [[0usize, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let mut ascii = String::from("solid tetra\n");
    let mut binary = vec![0u8; 80];
    binary.extend(4u32.to_le_bytes());
    for t in tris {
        let n = (p[t[1]] - p[t[0]]).cross(p[t[2]] - p[t[0]]).normalize();
        ascii += &format!("facet normal {} {} {}\nouter loop\n", n.x, n.y, n.z);
        for c in [n, p[t[0]], p[t[1]], p[t[2]]] {
            for x in c.to_array() {
                binary.extend((x as f32).to_le_bytes());
            }
        }
        binary.extend([0u8; 2]);
        for k in t {
            ascii += &format!("vertex {} {} {}\n", p[k].x, p[k].y, p[k].z);
        }
        ascii += "endloop\nendfacet\n";
    }
    ascii += "endsolid tetra\n";
    for (name, bytes) in [("ascii.stl", ascii.into_bytes()), ("binary.STL", binary)] {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        let v = io::read_mesh(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let (a, b) = (
            io::read_soup(&path).unwrap(),
            io::read_soup_with(&path, Reader::OpenMesh).unwrap(),
        );
        assert_same_soup(&a, &b, name);
        let r = &v.report;
        assert_eq!((r.vertices, r.triangles, r.edges), (4, 4, 6), "{name}");
        assert!(r.closed && r.manifold, "{name}: {r}");
        // Same triangles as drawn, up to the vertex numbering.
        for (t, tri) in v.mesh.triangles.iter().enumerate() {
            let got: Vec<DVec3> = tri.iter().map(|&i| v.mesh.positions[i as usize]).collect();
            let want: Vec<DVec3> = tris[t].iter().map(|&i| p[i]).collect();
            assert_eq!(got, want, "{name}: triangle {t}");
        }
    }
}

#[test]
fn rust_and_openmesh_agree_on_fixtures() {
    let path = data("cube_quads.obj");
    let a = io::read_soup_with(&path, Reader::Rust).unwrap();
    let b = io::read_soup_with(&path, Reader::OpenMesh).unwrap();
    assert_same_soup(&a, &b, "cube_quads.obj");

    // OpenMesh's OBJ reader drops a face that repeats a vertex (face 6 here)
    // before the importer sees it; validation drops it on our side, so the
    // validated meshes agree.
    let path = data("nonmanifold.obj");
    let a = io::read_soup_with(&path, Reader::Rust).unwrap();
    let b = io::read_soup_with(&path, Reader::OpenMesh).unwrap();
    assert_eq!((a.num_faces(), b.num_faces()), (7, 6));
    let (va, vb) = (
        validate_soup(a, &path).unwrap(),
        validate_soup(b, &path).unwrap(),
    );
    assert_eq!(va.mesh, vb.mesh);
    assert_eq!(vb.report.repeated_index_faces, 0);
    let dir = tempfile::tempdir().unwrap();
    for format in ["binary_little_endian", "binary_big_endian", "ascii"] {
        let path = dir.path().join(format!("t_{format}.ply"));
        std::fs::write(&path, tetra_ply(format, false)).unwrap();
        let a = io::read_soup_with(&path, Reader::Rust).unwrap();
        let b = io::read_soup_with(&path, Reader::OpenMesh).unwrap();
        assert_same_soup(&a, &b, format);
    }
    // OpenMesh 9 refuses list properties outside faces and ushort list
    // indices: its failure must come back as an error naming the file.
    let path = dir.path().join("exotic.ply");
    std::fs::write(&path, tetra_ply("binary_little_endian", true)).unwrap();
    let e = io::read_soup_with(&path, Reader::OpenMesh).unwrap_err();
    let msg = e.to_string();
    assert!(
        matches!(
            e,
            subdfit::Error::Backend {
                backend: "OpenMesh",
                ..
            }
        ),
        "{msg}"
    );
    assert!(
        msg.contains("exotic.ply") && msg.contains("ushort"),
        "{msg}"
    );
}

#[test]
fn nonmanifold_fixture_report() {
    let v = io::read_mesh(&data("nonmanifold.obj")).unwrap();
    let r = &v.report;
    assert_eq!((r.input_vertices, r.input_faces), (12, 7));
    assert_eq!((r.vertices, r.unreferenced_vertices), (10, 2));
    assert_eq!((r.repeated_index_faces, r.duplicate_faces), (1, 1));
    assert_eq!((r.faces, r.triangles, r.edges), (5, 5, 13));
    assert_eq!(r.non_manifold_edges, 1);
    assert_eq!(r.inconsistently_oriented_edges, 0);
    // Both ends of the triple edge, and the bow-tie vertex.
    assert_eq!(r.non_manifold_vertices, 3);
    assert_eq!(r.boundary_edges, 12);
    assert_eq!(r.components, 2);
    assert_eq!(r.euler_characteristic, 10 - 13 + 5);
    assert!(!r.manifold && r.genus.is_none());
    assert_eq!(r.notes.len(), 4, "{:?}", r.notes);
    // Kept vertices keep their relative order.
    assert_eq!(v.mesh.positions[9], DVec3::new(6.0, 2.0, 0.0));
}

#[test]
fn inconsistent_orientation_and_zero_area_faces() {
    // Two triangles sharing edge (0, 1) in the same direction, and a
    // collinear sliver whose area is exactly zero.
    let p = vec![
        DVec3::ZERO,
        DVec3::X,
        DVec3::Y,
        DVec3::new(0.0, -1.0, 0.0),
        DVec3::new(2.0, 0.0, 0.0),
    ];
    let s = PolySoup::from_faces(p, &[[0u32, 1, 2], [0, 1, 3], [0, 1, 4]]);
    let r = validate_soup(s, Path::new("mem")).unwrap().report;
    assert_eq!(r.zero_area_faces, 1);
    assert_eq!(r.non_manifold_edges, 1); // three faces on (0, 1)
    let s = PolySoup::from_faces(
        vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(0.0, -1.0, 0.0)],
        &[[0u32, 1, 2], [0, 1, 3]],
    );
    let r = validate_soup(s, Path::new("mem")).unwrap().report;
    assert_eq!(
        (r.non_manifold_edges, r.inconsistently_oriented_edges),
        (1, 1)
    );
    assert_eq!(r.zero_area_faces, 0);
    assert!(!r.manifold);
}

/// Rows of /work/shared/data/README.md: name, V, F, watertight, genus,
/// boundary edges, bbox diagonal (4 significant digits).
const MESHES: &[(&str, usize, usize, bool, i64, usize, f64)] = &[
    ("bunny", 35947, 69451, false, 0, 223, 0.2502),
    ("gargoyle", 24992, 49980, true, 0, 0, 212.6),
    ("fandisk", 6475, 12946, true, 0, 0, 7.616),
    ("block", 8771, 17550, true, 3, 0, 47.37),
    ("joint", 20902, 41808, true, 2, 0, 1.573),
    ("homer", 6002, 12000, true, 0, 0, 1.002),
    ("spot", 2930, 5856, true, 0, 0, 2.588),
    ("cheburashka", 6669, 13334, true, 0, 0, 1.274),
];

fn shared_data() -> Option<PathBuf> {
    common::data_dir()
}

#[test]
fn shared_meshes_match_their_readme() {
    let Some(dir) = shared_data() else { return };
    for &(name, nv, nf, watertight, genus, boundary, diag) in MESHES {
        let path = dir.join(format!("{name}.ply"));
        let t = Instant::now();
        let soup = io::read_soup(&path).unwrap();
        let t_read = t.elapsed();
        let t = Instant::now();
        let v = validate_soup(soup, &path).unwrap();
        let t_val = t.elapsed();
        let r = &v.report;
        println!("{name}: read {t_read:?}, validate {t_val:?}\n{r}");
        assert_eq!((r.input_vertices, r.input_faces), (nv, nf), "{name}");
        assert_eq!(r.triangles, nf, "{name}");
        assert_eq!(r.closed, watertight, "{name}");
        assert!(r.manifold, "{name}");
        assert_eq!(r.genus, Some(genus), "{name}");
        assert_eq!(r.boundary_edges, boundary, "{name}");
        assert_eq!(r.components, 1, "{name}");
        assert_eq!(r.face_sizes.get(&3), Some(&nf), "{name}");
        assert_eq!(
            (r.repeated_index_faces, r.duplicate_faces),
            (0, 0),
            "{name}"
        );
        // README rounds the diagonal to 4 significant digits.
        assert!(
            ((r.bbox_diagonal - diag) / diag).abs() < 5e-4,
            "{name}: {}",
            r.bbox_diagonal
        );
        // Closed triangle meshes: 3F = 2E; with boundary: 3F = 2E - b.
        assert_eq!(3 * r.triangles, 2 * r.edges - r.boundary_edges, "{name}");
        if name == "bunny" {
            assert_eq!((r.vertices, r.unreferenced_vertices), (34834, 1113));
            assert_eq!(r.boundary_loops, 5);
        } else {
            assert_eq!((r.vertices, r.unreferenced_vertices), (nv, 0), "{name}");
        }
    }
}

#[test]
fn rust_and_openmesh_agree_on_shared_meshes() {
    let Some(dir) = shared_data() else { return };
    let tmp = tempfile::tempdir().unwrap();
    for &(name, ..) in MESHES {
        let path = dir.join(format!("{name}.ply"));
        let a = io::read_soup_with(&path, Reader::Rust).unwrap();
        let b = io::read_soup_with(&path, Reader::OpenMesh).unwrap();
        assert_same_soup(&a, &b, name);
        // And through OBJ: our writer, both readers.
        let obj = tmp.path().join(format!("{name}.obj"));
        let faces: Vec<&[u32]> = a.faces().collect();
        io::write_obj(&obj, &a.positions, &faces, &[], &[]).unwrap();
        let c = io::read_soup_with(&obj, Reader::Rust).unwrap();
        assert_eq!(c, a, "{name}: OBJ round trip is exact");
        let d = io::read_soup_with(&obj, Reader::OpenMesh).unwrap();
        assert_same_soup(&c, &d, &format!("{name}.obj"));
    }
}

#[test]
fn bunny_reads_fast() {
    let Some(dir) = shared_data() else { return };
    let path = dir.join("bunny.ply");
    let mut best = std::time::Duration::MAX;
    for _ in 0..5 {
        let t = Instant::now();
        let s = io::read_soup(&path).unwrap();
        best = best.min(t.elapsed());
        assert_eq!(s.num_faces(), 69451);
    }
    println!("bunny.ply read: best of 5 {best:?}");
    // Generous bound for a loaded, unoptimised CI machine; a few ms is typical.
    assert!(best.as_millis() < 200, "bunny.ply took {best:?}");
}
