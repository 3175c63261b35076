//! Test helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subdfit::analysis::Fitmap;
use subdfit::mesh::TriMesh;
use subdfit::DVec3;

/// The shared test meshes: `$SUBDFIT_DATA`, else `../shared/data` beside the
/// repository. `None` (with a message saying so) when absent: tests that need
/// the large meshes skip instead of failing on a machine without them.
pub fn data_dir() -> Option<PathBuf> {
    let d = std::env::var_os("SUBDFIT_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!(
            "SKIPPED: test data directory {} is absent (set SUBDFIT_DATA)",
            d.display()
        );
        None
    }
}

/// Reads a triangle mesh as it is in the file (no cleanup: unreferenced
/// vertices are kept, so vertex indices match the file).
pub fn load_ply(path: &Path) -> TriMesh {
    let soup = subdfit::io::read_soup(path).unwrap_or_else(|e| panic!("{e}"));
    let triangles = soup
        .faces()
        .map(|f| {
            assert_eq!(f.len(), 3, "{}: not a triangle mesh", path.display());
            [f[0], f[1], f[2]]
        })
        .collect();
    TriMesh {
        positions: soup.positions,
        triangles,
    }
}

/// Loads a mesh of the shared data set (validated: unreferenced vertices
/// dropped), or `None` if the data is absent.
pub fn load_data_mesh(name: &str) -> Option<TriMesh> {
    let path = data_dir()?.join(name);
    Some(
        subdfit::io::read_mesh(&path)
            .unwrap_or_else(|e| panic!("{e}"))
            .mesh,
    )
}
/// Deterministic hash noise in [-1, 1] for procedural meshes.
fn hash_noise(i: u64) -> f64 {
    let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x ^= x >> 31;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 29;
    (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
}

/// A closed torus (major radius `r_major`, minor `r_minor`), `n` x `m` quads
/// split into `2 n m` triangles, each vertex moved radially (around the tube)
/// by up to `noise * r_minor`: a curved, irregular, watertight test mesh.
pub fn perturbed_torus(n: u32, m: u32, r_major: f64, r_minor: f64, noise: f64) -> TriMesh {
    let mut positions = Vec::with_capacity((n * m) as usize);
    for i in 0..n {
        let a = i as f64 / n as f64 * std::f64::consts::TAU;
        for j in 0..m {
            let b = j as f64 / m as f64 * std::f64::consts::TAU;
            let r = r_minor * (1.0 + noise * hash_noise((i * m + j) as u64));
            let ring = r_major + r * b.cos();
            positions.push(DVec3::new(ring * a.cos(), ring * a.sin(), r * b.sin()));
        }
    }
    let id = |i: u32, j: u32| (i % n) * m + (j % m);
    let mut triangles = Vec::with_capacity((2 * n * m) as usize);
    for i in 0..n {
        for j in 0..m {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// Icosphere of radius `r` centred at `c`: the icosahedron with each face
/// split `4^level` times, vertices projected onto the sphere (so every face
/// plane lies inside the sphere).
pub fn icosphere(level: u32, c: DVec3, r: f64) -> TriMesh {
    let p = (1.0 + 5f64.sqrt()) / 2.0;
    let mut pos: Vec<DVec3> = [
        (-1.0, p, 0.0),
        (1.0, p, 0.0),
        (-1.0, -p, 0.0),
        (1.0, -p, 0.0),
        (0.0, -1.0, p),
        (0.0, 1.0, p),
        (0.0, -1.0, -p),
        (0.0, 1.0, -p),
        (p, 0.0, -1.0),
        (p, 0.0, 1.0),
        (-p, 0.0, -1.0),
        (-p, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let mut tris: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid = std::collections::HashMap::new();
        let mut midpoint = |a: u32, b: u32, pos: &mut Vec<DVec3>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                pos.push((pos[a as usize] + pos[b as usize]).normalize());
                pos.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(tris.len() * 4);
        for [a, b, c] in tris {
            let ab = midpoint(a, b, &mut pos);
            let bc = midpoint(b, c, &mut pos);
            let ca = midpoint(c, a, &mut pos);
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    TriMesh {
        positions: pos.into_iter().map(|q| c + r * q).collect(),
        triangles: tris,
    }
}

/// An `n` x `n` grid of unit squares in the plane z = 0 (corner at the
/// origin), two triangles per square; all coordinates are small integers, so
/// vertices and edge midpoints are exactly representable (watertight tests).
pub fn flat_grid(n: u32) -> TriMesh {
    subdfit::fixtures::tri_grid(n, |i, j| DVec3::new(i as f64, j as f64, 0.0), |_, _| true)
}

pub fn seeded_rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// Uniform direction on the unit sphere.
pub fn random_dir(rng: &mut ChaCha8Rng) -> DVec3 {
    let z: f64 = rng.gen_range(-1.0..1.0);
    let phi: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
    let s = (1.0 - z * z).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// Uniform point in the mesh bounding box grown by `grow` of its size.
pub fn random_point_in_bbox(rng: &mut ChaCha8Rng, mesh: &TriMesh, grow: f64) -> DVec3 {
    let (lo, hi) = mesh.bbox();
    let c = 0.5 * (lo + hi);
    let h = 0.5 * (hi - lo) * (1.0 + grow);
    c + DVec3::new(
        rng.gen_range(-1.0..1.0) * h.x,
        rng.gen_range(-1.0..1.0) * h.y,
        rng.gen_range(-1.0..1.0) * h.z,
    )
}

/// A random point on a random non-degenerate triangle, with that triangle's
/// unit normal.
pub fn random_surface_point(rng: &mut ChaCha8Rng, mesh: &TriMesh) -> (DVec3, DVec3) {
    loop {
        let t = rng.gen_range(0..mesh.triangles.len());
        let [a, b, c] = mesh.triangle(t);
        let n = (b - a).cross(c - a);
        if n.length() == 0.0 {
            continue;
        }
        let (mut u, mut v): (f64, f64) = (rng.gen(), rng.gen());
        if u + v > 1.0 {
            u = 1.0 - u;
            v = 1.0 - v;
        }
        return ((1.0 - u - v) * a + u * b + v * c, n.normalize());
    }
}

/// A fixture of the repository's `data/` folder.
pub fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

/// `subdfit convert --quiet --mode organic INPUT -o OUT ARGS…`, asserted to
/// succeed; its `report.json`.
pub fn convert_organic(input: &Path, out: &Path, args: &[&str]) -> serde_json::Value {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .arg("convert")
        .arg(input)
        .arg("-o")
        .arg(out)
        .args(["--quiet", "--mode", "organic"])
        .args(args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

/// Largest distance from a point of `a` to its nearest point in `b`
/// (both the same size; OpenSubdiv numbers refined vertices its own way).
pub fn max_nearest(a: &[DVec3], b: &[DVec3]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .map(|p| {
            b.iter()
                .map(|q| p.distance_squared(*q))
                .fold(f64::MAX, f64::min)
        })
        .fold(0.0, f64::max)
        .sqrt()
}

/// A Fitmap that asks for nothing (F_S undefined, F_M the largest
/// radius): with `FieldOptions::uniform_size` set the field layout does
/// not read it.
pub fn flat_fitmap(n: usize) -> Fitmap {
    Fitmap {
        radii: vec![0.01, 1.0],
        s: vec![0.0; n],
        m: vec![1.0; n],
        m_step: vec![1; n],
        tolerance: 0.01,
        stats: Default::default(),
    }
}

/// Distance from `p` to triangle (a, b, c), by projecting onto the plane
/// and else onto the three edges (a method independent of the casters'
/// code, for brute-force references; a degenerate triangle is its edges).
pub fn point_triangle_distance(p: DVec3, a: DVec3, b: DVec3, c: DVec3) -> f64 {
    let n = (b - a).cross(c - a);
    let seg = |x: DVec3, y: DVec3| {
        let d = y - x;
        let s = ((p - x).dot(d) / d.length_squared()).clamp(0.0, 1.0);
        (p - (x + s * d)).length()
    };
    let edges = seg(a, b).min(seg(b, c)).min(seg(c, a));
    if n.length_squared() == 0.0 {
        return edges;
    }
    let q = p - n * ((p - a).dot(n) / n.length_squared());
    let inside = [(a, b), (b, c), (c, a)]
        .iter()
        .all(|&(x, y)| (y - x).cross(q - x).dot(n) >= 0.0);
    if inside {
        (p - q).length()
    } else {
        edges
    }
}

/// A rayon pool of one thread: what the thread-count tests compare against.
pub fn one_thread_pool() -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
}

/// An `n × n` grid over the unit square at height `h(u, v)`, quads split
/// along alternating diagonals (no preferred direction for a field).
pub fn alternating_grid(n: usize, h: impl Fn(f64, f64) -> f64) -> TriMesh {
    let mut positions = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (u, v) = (i as f64 / (n - 1) as f64, j as f64 / (n - 1) as f64);
            positions.push(DVec3::new(u, v, h(u, v)));
        }
    }
    let id = |i: usize, j: usize| (j * n + i) as u32;
    let mut triangles = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                triangles.extend([[a, b, c], [a, c, d]]);
            } else {
                triangles.extend([[a, b, d], [b, c, d]]);
            }
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// Plants a spurious pair of singularity pairs in a regular 10 × 10 quad
/// grid (vertex ids row by row, 11 a row): one rotation of an interior
/// edge makes two valence 3–5 pairs (energy 4), then an energy-neutral
/// rotation beside them pulls one pair apart, so no single operation
/// removes them (a move of two or more rotations does).
pub fn dislocate(k: &mut subdfit::mesh::ControlMesh) {
    dislocate_grid(k, 10);
}

/// [`dislocate`] on a regular `n × n` quad grid (n + 1 vertices a row),
/// at its centre.
pub fn dislocate_grid(k: &mut subdfit::mesh::ControlMesh, n: u32) {
    use subdfit::mesh::VertexId;
    use subdfit::quad::ops::{
        can_rotate_edge, rotate_edge, rotation_energy_gain, Rotation, ValenceTargets,
    };
    let c = n / 2;
    let (a, b) = (VertexId(c * (n + 1) + c), VertexId(c * (n + 1) + c + 1));
    let h = k.outgoing(a).find(|&h| k.head(h) == b).unwrap();
    rotate_edge(k, h, Rotation::Ccw).unwrap();
    let vt = ValenceTargets::new(k);
    let (h, dir) = k
        .edges()
        .map(|e| e.halfedge())
        .flat_map(|h| [(h, Rotation::Ccw), (h, Rotation::Cw)])
        .find(|&(h, d)| {
            can_rotate_edge(k, h, d).is_ok_and(|x| rotation_energy_gain(k, &vt, &x, d) == 0)
        })
        .expect("an energy-neutral rotation beside a pair");
    rotate_edge(k, h, dir).unwrap();
}

/// `subdfit convert MESH -o OUT --mode organic --layout field --tolerance
/// 0.01 --faces n --quiet`, ready for the caller's own arguments and
/// switches: the field layout at a face target, as issue 40's bars ask it.
pub fn field_convert_at(mesh: &Path, out: &Path, n: usize) -> std::process::Command {
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_subdfit"));
    cmd.arg("convert")
        .arg(mesh)
        .arg("-o")
        .arg(out)
        .args([
            "--mode",
            "organic",
            "--layout",
            "field",
            "--tolerance",
            "0.01",
        ])
        .args(["--faces", &n.to_string(), "--quiet"]);
    cmd
}

/// A finished `convert` folder's control-mesh face count and report.json.
pub fn faces_and_report(out: &Path) -> (usize, serde_json::Value) {
    let report = std::fs::read_to_string(out.join("report.json")).expect("report.json reads");
    let report: serde_json::Value = serde_json::from_str(&report).expect("report.json parses");
    let control =
        subdfit::io::read_control_mesh(&out.join("control.obj")).expect("control.obj reads");
    (control.num_faces(), report)
}
