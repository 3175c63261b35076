//! Procedural control meshes for tests and benchmarks: closed meshes with
//! extraordinary vertices of valence 3 to 8, open meshes with boundaries,
//! semi-sharp and infinitely sharp creases, corners, darts, triangles and
//! n-gons, two components, an interior valence-2 vertex. Positions are
//! perturbed with a fixed seed so that symmetry cannot hide a bug.
//!
//! Every fixture is small (at most a few hundred faces) and passes
//! [`ControlMesh::validate`]; construction failures are bugs of this module
//! and panic with the fixture's name.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::mesh::{ControlMesh, TriMesh, VertexId, INFINITELY_SHARP};
use crate::subdiv::refine::refine_uniform;
use crate::DVec3;

/// Adds uniform noise in `[-amp, amp]³` to every position (fixed seed).
pub fn perturb(mut mesh: ControlMesh, amp: f64, seed: u64) -> ControlMesh {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for p in mesh.positions_mut() {
        *p += DVec3::new(
            rng.gen_range(-amp..=amp),
            rng.gen_range(-amp..=amp),
            rng.gen_range(-amp..=amp),
        );
    }
    mesh
}

fn build(name: &str, p: Vec<DVec3>, f: &[Vec<u32>]) -> ControlMesh {
    ControlMesh::from_polygons(p, f).unwrap_or_else(|e| panic!("fixture {name}: {e}"))
}

/// The cube `[-1, 1]^3` as six quads, outward orientation.
pub fn cube() -> ControlMesh {
    let p: Vec<DVec3> = (0..8)
        .map(|i| {
            DVec3::new(
                (i & 1) as f64 * 2.0 - 1.0,
                ((i >> 1) & 1) as f64 * 2.0 - 1.0,
                ((i >> 2) & 1) as f64 * 2.0 - 1.0,
            )
        })
        .collect();
    let f = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    ControlMesh::from_polygons(p, &f).expect("cube is a valid control mesh")
}

/// A closed prism over a regular n-gon (two n-gon caps, n quads), outward.
pub fn prism(n: usize) -> ControlMesh {
    let mut p = Vec::new();
    for z in [-1.0, 1.0] {
        for i in 0..n {
            let a = 2.0 * std::f64::consts::PI * i as f64 / n as f64;
            p.push(DVec3::new(a.cos(), a.sin(), z));
        }
    }
    let n32 = n as u32;
    let mut f: Vec<Vec<u32>> = vec![(0..n32).rev().collect(), (n32..2 * n32).collect()];
    for i in 0..n32 {
        let j = (i + 1) % n32;
        f.push(vec![i, j, j + n32, i + n32]);
    }
    build("prism", p, &f)
}

/// An all-quad closed "polar" sphere: the n-prism refined once and
/// projected onto the unit sphere, so its two poles are interior vertices
/// of valence n and the prism corners have valence 3; perturbed.
pub fn polar_sphere(n: usize, seed: u64) -> ControlMesh {
    let mut m = refine_uniform(&prism(n), 1).expect("prism refines");
    for p in m.positions_mut() {
        *p = p.normalize();
    }
    perturb(m, 0.03, seed)
}

/// An open, flat `nx × ny` grid of unit quads in the plane z = 0 (corner at
/// the origin, vertex `j (nx + 1) + i` at `(i, j)`): patch boundaries at
/// integer coordinates.
pub fn flat_grid(nx: u32, ny: u32) -> ControlMesh {
    let mut p = Vec::new();
    for j in 0..=ny {
        for i in 0..=nx {
            p.push(DVec3::new(i as f64, j as f64, 0.0));
        }
    }
    let mut f = Vec::new();
    for j in 0..ny {
        for i in 0..nx {
            let a = j * (nx + 1) + i;
            f.push(vec![a, a + 1, a + nx + 2, a + nx + 1]);
        }
    }
    build("flat grid", p, &f)
}

/// A triangle mesh on an `n × n` grid of cells: vertex `j (n + 1) + i` at
/// `pos(i, j)` for `0 ≤ i, j ≤ n`, two triangles per cell split along its
/// `(i, j)`–`(i + 1, j + 1)` diagonal, counter-clockwise in (i, j). Cells
/// where `keep(i, j)` is false are left out (holes; their vertices stay,
/// unreferenced where no kept cell uses them).
pub fn tri_grid(
    n: u32,
    pos: impl Fn(u32, u32) -> DVec3,
    keep: impl Fn(u32, u32) -> bool,
) -> TriMesh {
    let positions = (0..=n)
        .flat_map(|j| (0..=n).map(move |i| (i, j)))
        .map(|(i, j)| pos(i, j))
        .collect();
    let mut triangles = Vec::new();
    for j in 0..n {
        for i in 0..n {
            if !keep(i, j) {
                continue;
            }
            let a = j * (n + 1) + i;
            triangles.push([a, a + 1, a + n + 2]);
            triangles.push([a, a + n + 2, a + n + 1]);
        }
    }
    TriMesh {
        positions,
        triangles,
    }
}

/// An open `nx × ny` grid of quads in the xy plane with a bumpy z; its
/// boundary has regular (valence 3) vertices and four corners.
pub fn grid(nx: u32, ny: u32, seed: u64) -> ControlMesh {
    let mut mesh = flat_grid(nx, ny);
    for q in mesh.positions_mut() {
        q.z = 0.3 * (0.7 * q.x).sin() * (0.5 * q.y).cos();
    }
    perturb(mesh, 0.05, seed)
}

/// A fan of `k` quads around a centre vertex spanning `angle` radians:
/// closed (an interior vertex of valence k) when `angle` is 2π, otherwise a
/// boundary vertex with k faces. Refined once, so the extraordinary vertex
/// sits next to (closed) or on (open) the boundary of a larger mesh.
pub fn fan(k: usize, angle: f64, seed: u64) -> ControlMesh {
    let closed = (angle - 2.0 * std::f64::consts::PI).abs() < 1e-12;
    let na = if closed { k } else { k + 1 };
    let mut p = vec![DVec3::ZERO];
    for i in 0..na {
        let a = angle * i as f64 / k as f64;
        p.push(DVec3::new(a.cos(), a.sin(), 0.1));
    }
    for i in 0..k {
        let a = angle * (i as f64 + 0.5) / k as f64;
        p.push(1.6 * DVec3::new(a.cos(), a.sin(), -0.2));
    }
    let ai = |i: usize| 1 + (i % na) as u32;
    let bi = |i: usize| (1 + na + i) as u32;
    let f: Vec<Vec<u32>> = (0..k).map(|i| vec![0, ai(i), bi(i), ai(i + 1)]).collect();
    let m = refine_uniform(&build("fan", p, &f), 1).expect("fan refines");
    perturb(m, 0.02, seed)
}

/// The edge point of edge `(a, b)` of an unrefined mesh in its one-level
/// refinement: the one neighbour that `a` and `b` share.
fn edge_child(refined: &ControlMesh, a: u32, b: u32) -> VertexId {
    let (a, b) = (VertexId(a), VertexId(b));
    refined
        .outgoing(a)
        .map(|h| refined.head(h))
        .find(|&m| refined.find_halfedge(m, b).is_some())
        .expect("edge point exists")
}

/// The cube refined once with creases along its original edges: sharpness
/// 0.5, 1.5, 2.0 and infinite chains (each original edge becomes a chain of
/// two edges through a regular vertex), a dart (an infinitely sharp chain
/// ending inside a face), and a semi-sharp (2.5) and an infinitely sharp
/// corner.
pub fn creased_cube(seed: u64) -> ControlMesh {
    let mut m = refine_uniform(&cube(), 1).expect("cube refines");
    let mut set = |a: u32, b: u32, s: f64| {
        let e = edge_child(&m, a, b);
        m.set_crease(VertexId(a), e, s).expect("edge exists");
        m.set_crease(e, VertexId(b), s).expect("edge exists");
    };
    set(0, 1, 0.5);
    set(2, 3, 1.5);
    set(4, 5, 2.0);
    // Two edges of the top face z = +1 (4 5 7 6), infinitely sharp: vertex 7
    // becomes a crease vertex of valence 3, vertex 6 a dart tip and vertex 5
    // a crease between an infinite and a 2.0 edge.
    set(5, 7, INFINITELY_SHARP);
    set(7, 6, INFINITELY_SHARP);
    // Dart: from the edge point of (0, 2) into the face centre of the
    // bottom face (0 2 3 1).
    let e02 = edge_child(&m, 0, 2);
    let centre = m
        .outgoing(e02)
        .map(|h| m.head(h))
        .find(|&c| {
            m.valence(c) == 4 && c.0 >= 20 && m.find_halfedge(c, edge_child(&m, 2, 3)).is_some()
        })
        .expect("bottom face centre");
    m.set_crease(e02, centre, INFINITELY_SHARP).expect("edge");
    m.set_corner(VertexId(3), 2.5).expect("vertex");
    m.set_corner(VertexId(1), INFINITELY_SHARP).expect("vertex");
    perturb(m, 0.03, seed)
}

/// A closed mesh with triangles, a pentagon and hexagons: a hexagonal prism
/// with one side quad split into two triangles and the bottom hexagon split
/// into a triangle and a pentagon.
pub fn mixed_ngons(seed: u64) -> ControlMesh {
    let n = 6u32;
    let pr = prism(6);
    let p = pr.positions().to_vec();
    let mut f: Vec<Vec<u32>> = vec![
        vec![5, 4, 3, 2, 0], // bottom pentagon (reversed order = outward)
        vec![2, 1, 0],       // bottom triangle
        (n..2 * n).collect(),
    ];
    for i in 0..n {
        let j = (i + 1) % n;
        if i == 2 {
            f.push(vec![i, j, j + n]);
            f.push(vec![i, j + n, i + n]);
        } else {
            f.push(vec![i, j, j + n, i + n]);
        }
    }
    perturb(build("mixed_ngons", p, &f), 0.03, seed)
}

/// Two disjoint components: a cube and a valence-5 polar sphere beside it.
pub fn two_components(seed: u64) -> ControlMesh {
    let a = cube();
    let b = polar_sphere(5, seed);
    let off = a.num_vertices() as u32;
    let mut p = a.positions().to_vec();
    p.extend(b.positions().iter().map(|&x| x + DVec3::new(4.0, 0.0, 0.0)));
    let mut f = a.to_polygons();
    f.extend(
        b.to_polygons()
            .into_iter()
            .map(|q| q.into_iter().map(|i| i + off).collect()),
    );
    perturb(build("two_components", p, &f), 0.02, seed)
}

/// A cube whose top face is split into two quads by an inner vertex of
/// valence 2 (interior, smooth).
pub fn valence2(seed: u64) -> ControlMesh {
    let c = cube();
    let mut p = c.positions().to_vec();
    p.push(DVec3::new(0.1, -0.1, 1.0)); // vertex 8, inside the top face 4 5 7 6
    let mut f: Vec<Vec<u32>> = c.to_polygons();
    f.retain(|q| q != &vec![4, 5, 7, 6]);
    f.push(vec![4, 5, 7, 8]);
    f.push(vec![4, 8, 7, 6]);
    perturb(build("valence2", p, &f), 0.03, seed)
}

/// The collection used by the tests, by name.
pub fn collection() -> Vec<(&'static str, ControlMesh)> {
    vec![
        ("cube", cube()),
        ("sphere3", perturb(cube(), 0.05, 1)),
        ("sphere5", polar_sphere(5, 2)),
        ("sphere6", polar_sphere(6, 3)),
        ("sphere7", polar_sphere(7, 4)),
        ("sphere8", polar_sphere(8, 5)),
        ("grid", grid(5, 4, 6)),
        ("disk5", fan(5, 2.0 * std::f64::consts::PI, 7)),
        ("open_fan3", fan(3, 1.5 * std::f64::consts::PI, 8)),
        ("open_fan1", fan(1, 0.5 * std::f64::consts::PI, 9)),
        ("creased_cube", creased_cube(10)),
        ("mixed_ngons", mixed_ngons(11)),
        ("two_components", two_components(12)),
        ("valence2", valence2(13)),
    ]
}
