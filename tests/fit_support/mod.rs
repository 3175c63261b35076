//! Shared helpers of the `fit_*` tests: a small closed test mesh with
//! features at several scales, its initial control mesh (Fitmaps §3.2), and
//! an independent brute-force point-to-triangle distance.
#![allow(dead_code)]

use subdfit::mesh::{ControlMesh, TriMesh};
use subdfit::quad::{interpolate_limit, quadrangulate, InterpolationOptions, QuadrangulateOptions};
use subdfit::DVec3;

/// A bumpy sphere: an octahedron subdivided `levels` times (8·4^levels
/// triangles), projected to a sphere of radius 1 with bumps of 5 %.
pub fn bumpy_sphere(levels: u32) -> TriMesh {
    let mut pos = vec![
        DVec3::X,
        -DVec3::X,
        DVec3::Y,
        -DVec3::Y,
        DVec3::Z,
        -DVec3::Z,
    ];
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    for _ in 0..levels {
        let mut mid = std::collections::HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        let mut m = |a: u32, b: u32, pos: &mut Vec<DVec3>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                pos.push((pos[a as usize] + pos[b as usize]).normalize());
                pos.len() as u32 - 1
            })
        };
        for [a, b, c] in tris {
            let ab = m(a, b, &mut pos);
            let bc = m(b, c, &mut pos);
            let ca = m(c, a, &mut pos);
            next.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
        }
        tris = next;
    }
    let positions = pos
        .into_iter()
        .map(|p| {
            let p = p.normalize();
            p * (1.0 + 0.05 * (3.0 * p.x).sin() * (2.0 * p.y).cos() + 0.03 * (5.0 * p.z).sin())
        })
        .collect();
    TriMesh {
        positions,
        triangles: tris,
    }
}

/// The initial control mesh of §3.2: quadrangulation of `mesh`, limit
/// interpolating its vertices.
pub fn initial_control(mesh: &TriMesh) -> ControlMesh {
    let q = quadrangulate(mesh, &QuadrangulateOptions::default()).unwrap();
    let mut c = q.mesh;
    let t = c.positions().to_vec();
    interpolate_limit(&mut c, &t, &InterpolationOptions::default()).unwrap();
    c
}

/// Distance from `p` to triangle `(a, b, c)` (Ericson, Real-Time Collision
/// Detection §5.1.5), written here independently of the ray casters.
pub fn point_triangle_distance(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return ap.length();
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return bp.length();
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return (p - (a + v * ab)).length();
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return cp.length();
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return (p - (a + w * ac)).length();
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return (p - (b + w * (c - b))).length();
    }
    let denom = 1.0 / (va + vb + vc);
    let v = vb * denom;
    let w = vc * denom;
    (p - (a + ab * v + ac * w)).length()
}

/// Brute force: distance from `p` to the closest triangle of `mesh`.
pub fn brute_distance(p: DVec3, mesh: &TriMesh) -> f64 {
    (0..mesh.triangles.len())
        .map(|t| {
            let [a, b, c] = mesh.triangle(t);
            point_triangle_distance(p, a, b, c)
        })
        .fold(f64::INFINITY, f64::min)
}

/// Area-weighted RMS, mean and max (in ‰ of `diag`) of brute-force
/// distances from weighted points to `mesh`.
pub fn brute_stats(points: &[DVec3], w: &[f64], mesh: &TriMesh, diag: f64) -> (f64, f64, f64) {
    let (mut sw, mut s1, mut s2, mut mx) = (0.0, 0.0, 0.0, 0.0f64);
    for (&p, &wi) in points.iter().zip(w) {
        if wi <= 0.0 {
            continue;
        }
        let d = brute_distance(p, mesh);
        sw += wi;
        s1 += wi * d;
        s2 += wi * d * d;
        mx = mx.max(d);
    }
    let k = 1000.0 / diag;
    (k * (s2 / sw).sqrt(), k * s1 / sw, k * mx)
}

/// A shared test mesh (`$SUBDFIT_DATA`, else `../shared/data` beside the
/// crate), or `None` when the data is not there.
pub fn data_mesh(name: &str) -> Option<TriMesh> {
    let dir = std::env::var_os("SUBDFIT_DATA")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    let p = dir.join(name);
    p.exists().then(|| {
        subdfit::io::read_mesh(&p)
            .expect("shared test mesh reads")
            .mesh
    })
}
