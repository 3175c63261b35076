//! Writers: exact OBJ round trips (tags included), PLY with extra vertex
//! properties and colours, and atomicity (a failed write leaves nothing).

use std::path::Path;

use subdfit::io::{self, Reader};
use subdfit::mesh::{PolySoup, VertexId, INFINITELY_SHARP};
use subdfit::{DVec3, Error};

fn awkward_positions() -> Vec<DVec3> {
    vec![
        DVec3::new(1.0 / 3.0, -2.0 / 7.0, 0.1),
        DVec3::new(1e-300, -4.9e-324, 1.7976931348623157e308),
        DVec3::new(-0.0, 123456789.12345679, 1e16),
        DVec3::new(3.0e-5, 9.999999e-6, -1e-7),
        DVec3::new(
            std::f64::consts::PI,
            std::f64::consts::E,
            1.0 + f64::EPSILON,
        ),
    ]
}

#[test]
fn obj_round_trip_is_bit_exact_with_tags() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.obj");
    let p = awkward_positions();
    let faces = vec![vec![0u32, 1, 2], vec![0, 2, 3, 4]];
    let creases = [(0u32, 1u32, 2.5), (2, 3, INFINITELY_SHARP)];
    let corners = [(4u32, 0.125)];
    io::write_obj(&path, &p, &faces, &creases, &corners).unwrap();
    let o = io::read_obj(&path).unwrap();
    for (a, b) in o.soup.positions.iter().zip(&p) {
        for k in 0..3 {
            assert_eq!(a[k].to_bits(), b[k].to_bits(), "{a} vs {b}");
        }
    }
    assert_eq!(o.soup, PolySoup::from_faces(p, &faces));
    assert_eq!(o.creases, creases);
    assert_eq!(o.corners, corners);
}

#[test]
fn control_obj_round_trip_keeps_sharpness() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cube.obj");
    let mut cube = subdfit::fixtures::cube();
    cube.set_crease(VertexId(0), VertexId(1), 3.0).unwrap();
    cube.set_crease(VertexId(7), VertexId(5), INFINITELY_SHARP)
        .unwrap();
    cube.set_corner(VertexId(6), 1.5).unwrap();
    io::write_control_obj(&path, &cube).unwrap();
    let back = io::read_control_mesh(&path).unwrap();
    assert_eq!(back, cube);
}

#[test]
fn ply_round_trip_with_properties_and_colours() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.ply");
    let cube = subdfit::fixtures::cube();
    let p: Vec<DVec3> = cube
        .positions()
        .iter()
        .map(|&q| q * 0.3 + DVec3::splat(1.0 / 3.0))
        .collect();
    let faces = cube.to_polygons();
    let error: Vec<f32> = (0..8).map(|i| i as f32 * 0.25).collect();
    let curvature: Vec<f32> = (0..8).map(|i| -(i as f32)).collect();
    let colors: Vec<[u8; 3]> = (0..8)
        .map(|i| [i as u8, 2 * i as u8, 255 - i as u8])
        .collect();
    io::write_ply(
        &path,
        &p,
        &faces,
        &[("error", &error), ("curvature", &curvature)],
        Some(&colors),
    )
    .unwrap();

    for reader in [Reader::Rust, Reader::OpenMesh] {
        let s = io::read_soup_with(&path, reader).unwrap();
        // Positions are stored as f32: equal to the f32 rounding.
        let want: Vec<DVec3> = p.iter().map(|q| q.as_vec3().as_dvec3()).collect();
        assert_eq!(s.positions, want, "{reader:?}");
        assert_eq!(
            s.faces().map(|f| f.to_vec()).collect::<Vec<_>>(),
            faces,
            "{reader:?}"
        );
    }

    // The layout itself: header, then records x y z error curvature r g b.
    let bytes = std::fs::read(&path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let header = std::str::from_utf8(&bytes[..end]).unwrap();
    assert!(header.contains("format binary_little_endian 1.0\n"));
    assert!(header.contains("property float error\nproperty float curvature\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"));
    let rec = 5 * 4 + 3;
    assert_eq!(bytes.len(), end + 8 * rec + 6 * (1 + 16));
    for i in 0..8 {
        let r = &bytes[end + i * rec..end + (i + 1) * rec];
        let f = |k: usize| f32::from_le_bytes(r[4 * k..4 * k + 4].try_into().unwrap());
        assert_eq!((f(3), f(4)), (error[i], curvature[i]));
        assert_eq!(&r[20..23], &colors[i]);
    }
}

#[test]
fn failed_writes_leave_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.obj");
    // The body fails after writing: no file, no temporary.
    let e = io::write_atomically(&path, |w| {
        w.write_all(b"partial").unwrap();
        Err(Error::InvalidArgument("stop".into()))
    })
    .unwrap_err();
    assert!(matches!(e, Error::InvalidArgument(_)));
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);

    // An existing file survives a failed overwrite untouched.
    std::fs::write(&path, "old").unwrap();
    let _ = io::write_atomically(&path, |_| Err(Error::InvalidArgument("stop".into())));
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "old");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

    // Invalid input is refused before any file is created.
    let bad = dir.path().join("bad.obj");
    let e = io::write_obj(&bad, &[DVec3::ZERO; 3], &[[0u32, 1, 5]], &[], &[]).unwrap_err();
    assert!(e.to_string().contains("face 0"), "{e}");
    let e = io::write_ply(
        &bad.with_extension("ply"),
        &[DVec3::ZERO; 3],
        &[[0u32, 1, 2]],
        &[("q", &[1.0][..])],
        None,
    )
    .unwrap_err();
    assert!(e.to_string().contains("'q'"), "{e}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);

    // A directory that does not exist: an I/O error naming the target.
    let e = io::write_obj(
        Path::new("/nonexistent-dir/x.obj"),
        &[DVec3::ZERO; 3],
        &[[0u32, 1, 2]],
        &[],
        &[],
    )
    .unwrap_err();
    assert!(
        matches!(e, Error::Io { .. }) && e.to_string().contains("x.obj"),
        "{e}"
    );

    // Success replaces the old content.
    io::write_atomically(&path, |w| {
        w.write_all(b"new")
            .map_err(|e| Error::InvalidArgument(e.to_string()))
    })
    .unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), "new");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}
