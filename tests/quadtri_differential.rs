//! Differential and property tests of the quad/triangle scheme
//! (`subdiv::quadtri`, Stam & Loop 2003):
//! - all-quad meshes: uniform refinement to levels 1..=3 equals OpenSubdiv's
//!   Catmark refinement at every refined vertex within 1e-9 of the bounding
//!   box diagonal (both compute the same affine combinations; the margin is
//!   rounding, ~1e-15 in practice);
//! - all-triangle meshes: the same against OpenSubdiv's Loop scheme, and the
//!   exact vertex limits against `PrimvarRefiner::Limit`;
//! - mixed meshes: affine invariance (stencil rows sum to 1), planar
//!   reproduction, convergence, and the 1-6-1 rule on crease polylines.
//!
//! OpenSubdiv orders refined vertices its own way: the correspondence is
//! built level by level from each vertex's parent component.

mod common;

use std::collections::HashMap;

use subdfit::fixtures;
use subdfit::mesh::{ControlMesh, FaceId, VertexId, INFINITELY_SHARP};
use subdfit::subdiv::osd::{osd_refine_uniform, OsdParent, OsdScheme};
use subdfit::subdiv::quadtri::{
    averaging_weight, check_mesh, refine_quadtri, vertex_limit_stencils, Parent,
};
use subdfit::subdiv::{LimitEvaluator, QuadTriEvaluator, QuadTriRefiner, SurfaceLocation};
use subdfit::{DVec3, Error};

/// Refinement agreement, relative to the bbox diagonal (see the module doc).
const TOL: f64 = 1e-9;

fn tri_mesh(t: subdfit::mesh::TriMesh) -> ControlMesh {
    ControlMesh::from_polygons(t.positions, &t.triangles).expect("valid triangle mesh")
}

fn icosahedron() -> ControlMesh {
    fixtures::perturb(tri_mesh(common::icosphere(0, DVec3::ZERO, 1.0)), 0.03, 21)
}

fn tetrahedron() -> ControlMesh {
    let p = vec![
        DVec3::new(1.0, 1.0, 1.0),
        DVec3::new(1.0, -1.0, -1.0),
        DVec3::new(-1.0, 1.0, -1.0),
        DVec3::new(-1.0, -1.0, 1.0),
    ];
    let f = [[0u32, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]];
    fixtures::perturb(ControlMesh::from_polygons(p, &f).unwrap(), 0.02, 22)
}

/// An open `n × n` grid, every quad split into two triangles (alternating
/// diagonals, so interior valences are 4, 6 and 8), bumpy z; with `flat`, z = 0
/// and quads in the left half kept (a planar mixed mesh).
fn tri_grid(n: u32, mixed: bool, flat: bool) -> ControlMesh {
    let mut p = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as f64 + 0.13 * ((i * 7 + j * 3) % 5) as f64, j as f64);
            let z = if flat {
                0.0
            } else {
                0.3 * (0.9 * x).sin() * (0.6 * y).cos()
            };
            p.push(DVec3::new(x, y, z));
        }
    }
    let mut f: Vec<Vec<u32>> = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            let (b, c, d) = (a + 1, a + n + 2, a + n + 1);
            if mixed && i < n / 2 {
                f.push(vec![a, b, c, d]);
            } else if (i + j) % 2 == 0 {
                f.push(vec![a, b, c]);
                f.push(vec![a, c, d]);
            } else {
                f.push(vec![a, b, d]);
                f.push(vec![b, c, d]);
            }
        }
    }
    ControlMesh::from_polygons(p, &f).unwrap()
}

/// The perturbed icosahedron refined once (valence 5 and 6) with an
/// infinitely sharp closed crease loop (edges around a vertex's 1-ring),
/// an open crease chain ending in a dart, and an infinitely sharp corner.
fn creased_icosphere() -> ControlMesh {
    let mut m = tri_mesh(common::icosphere(1, DVec3::ZERO, 1.0));
    m = fixtures::perturb(m, 0.02, 23);
    // The 1-ring polygon of vertex 0 as a crease loop.
    let ring: Vec<VertexId> = m.outgoing(VertexId(0)).map(|h| m.head(h)).collect();
    for k in 0..ring.len() {
        let (a, b) = (ring[k], ring[(k + 1) % ring.len()]);
        if m.find_halfedge(a, b).is_some() {
            m.set_crease(a, b, INFINITELY_SHARP).unwrap();
        }
    }
    // A chain of two edges from vertex 3 (a dart at its free end).
    let n1 = m.outgoing(VertexId(3)).map(|h| m.head(h)).next().unwrap();
    m.set_crease(VertexId(3), n1, INFINITELY_SHARP).unwrap();
    m.set_corner(VertexId(7), INFINITELY_SHARP).unwrap();
    m
}

/// The cube refined once with infinitely sharp creases only: a crease
/// chain around the top face, a dart, and a corner.
fn sharp_cube() -> ControlMesh {
    let mut m = subdfit::subdiv::refine::refine_uniform(&fixtures::cube(), 1).unwrap();
    let top = [4u32, 5, 7, 6];
    for k in 0..4 {
        let (a, b) = (VertexId(top[k]), VertexId(top[(k + 1) % 4]));
        // Each original edge is a chain of two edges through its edge point.
        let mid = m
            .outgoing(a)
            .map(|h| m.head(h))
            .find(|&x| m.find_halfedge(x, b).is_some())
            .unwrap();
        m.set_crease(a, mid, INFINITELY_SHARP).unwrap();
        m.set_crease(mid, b, INFINITELY_SHARP).unwrap();
    }
    let d = m.outgoing(VertexId(0)).map(|h| m.head(h)).next().unwrap();
    m.set_crease(VertexId(0), d, INFINITELY_SHARP).unwrap();
    m.set_corner(VertexId(1), INFINITELY_SHARP).unwrap();
    fixtures::perturb(m, 0.03, 24)
}

/// Matches OpenSubdiv's refined vertices with ours level by level and
/// returns the worst distance over levels 1..=levels relative to the bbox
/// diagonal, and the OSD last-level index -> ours map.
fn compare_with_osd(
    name: &str,
    mesh: &ControlMesh,
    scheme: OsdScheme,
    levels: u32,
) -> (f64, Vec<usize>) {
    let r = QuadTriRefiner::new(mesh, levels).unwrap_or_else(|e| panic!("{name}: {e}"));
    let ours = r.refine_positions(mesh.positions()).unwrap();
    let osd =
        osd_refine_uniform(mesh, scheme, levels, false).unwrap_or_else(|e| panic!("{name}: {e}"));
    let diag = mesh.bbox_diagonal();
    let mut perm: Vec<usize> = (0..mesh.num_vertices()).collect();
    let mut worst = 0.0f64;
    for l in 1..=levels {
        let parents = r.parents(l);
        let mut by_vertex = HashMap::new();
        let mut by_edge = HashMap::new();
        let mut by_face = HashMap::new();
        for (c, p) in parents.iter().enumerate() {
            match *p {
                Parent::Vertex(v) => by_vertex.insert(v, c),
                Parent::Edge(a, b) => by_edge.insert((a.min(b), a.max(b)), c),
                Parent::Face(f) => {
                    let mut k = r.face(l - 1, f).to_vec();
                    k.sort_unstable();
                    by_face.insert(k, c)
                }
            };
        }
        let ol = &osd.levels[l as usize];
        assert_eq!(
            ol.len(),
            ours[l as usize].len(),
            "{name}: level {l} vertex count"
        );
        let mut next = vec![usize::MAX; ol.len()];
        for (i, p) in osd.parents[l as usize - 1].iter().enumerate() {
            let m = |x: u32| perm[x as usize] as u32;
            let c = match p {
                OsdParent::Vertex(v) => by_vertex.get(&m(*v)),
                OsdParent::Edge(a, b) => {
                    let (a, b) = (m(*a), m(*b));
                    by_edge.get(&(a.min(b), a.max(b)))
                }
                OsdParent::Face(f) => {
                    let mut k: Vec<u32> = f.iter().map(|&x| m(x)).collect();
                    k.sort_unstable();
                    by_face.get(&k)
                }
            };
            let c = *c.unwrap_or_else(|| {
                panic!("{name}: level {l}: no match for OSD vertex {i} ({p:?})")
            });
            next[i] = c;
            let d = (ol[i] - ours[l as usize][c]).length() / diag;
            worst = worst.max(d);
        }
        let mut seen = next.clone();
        seen.sort_unstable();
        seen.dedup();
        assert_eq!(
            seen.len(),
            next.len(),
            "{name}: level {l}: correspondence is not one-to-one"
        );
        perm = next;
    }
    (worst, perm)
}

fn quad_fixtures() -> Vec<(&'static str, ControlMesh)> {
    let all = fixtures::collection();
    let mut v: Vec<(&'static str, ControlMesh)> = all
        .into_iter()
        .filter(|(n, _)| {
            [
                "cube",
                "sphere3",
                "sphere5",
                "sphere6",
                "sphere7",
                "grid",
                "disk5",
                "open_fan3",
                "open_fan1",
                "two_components",
                "valence2",
            ]
            .contains(n)
        })
        .collect();
    v.push(("sharp_cube", sharp_cube()));
    v
}

fn tri_fixtures() -> Vec<(&'static str, ControlMesh)> {
    vec![
        ("icosahedron", icosahedron()),
        ("tetrahedron", tetrahedron()),
        (
            "icosphere2",
            fixtures::perturb(tri_mesh(common::icosphere(2, DVec3::ZERO, 1.0)), 0.01, 25),
        ),
        ("tri_grid", tri_grid(5, false, false)),
        ("creased_icosphere", creased_icosphere()),
    ]
}

#[test]
fn all_quad_meshes_refine_as_opensubdiv_catmark() {
    for (name, m) in quad_fixtures() {
        assert!(m.is_all_quads(), "{name}");
        let (worst, _) = compare_with_osd(name, &m, OsdScheme::Catmark, 3);
        eprintln!("catmark {name}: worst refined-vertex distance {worst:.2e} of the diagonal");
        assert!(worst <= TOL, "{name}: {worst:e}");
    }
}

#[test]
fn all_triangle_meshes_refine_as_opensubdiv_loop() {
    for (name, m) in tri_fixtures() {
        let (worst, _) = compare_with_osd(name, &m, OsdScheme::Loop, 3);
        eprintln!("loop {name}: worst refined-vertex distance {worst:.2e} of the diagonal");
        assert!(worst <= TOL, "{name}: {worst:e}");
    }
}

/// Exact vertex limits on triangle meshes equal OpenSubdiv's Loop limit
/// masks (`PrimvarRefiner::Limit`), darts excepted: Sdc applies the smooth
/// masks there, which are not the limit (as for Catmark, see
/// `subdiv::known_differences`). Compared on level 2, where every vertex
/// of the control mesh and the refined ones are covered.
#[test]
fn loop_vertex_limits_match_opensubdiv() {
    for (name, m) in tri_fixtures() {
        let levels = 2;
        let osd = osd_refine_uniform(&m, OsdScheme::Loop, levels, true).unwrap();
        let (_, perm) = compare_with_osd(name, &m, OsdScheme::Loop, levels);
        let fine = refine_quadtri(&m, levels).unwrap();
        let lim = vertex_limit_stencils(&fine)
            .unwrap()
            .apply(fine.positions());
        let diag = m.bbox_diagonal();
        let mut worst = 0.0f64;
        let mut darts = 0;
        for (i, p) in osd.limits.as_ref().unwrap().iter().enumerate() {
            let v = VertexId(perm[i] as u32);
            let sharp = fine
                .outgoing(v)
                .filter(|&h| fine.edge_sharpness(h.edge()) > 0.0)
                .count();
            if sharp == 1 && !fine.is_boundary_vertex(v) && fine.vertex_sharpness(v) == 0.0 {
                darts += 1;
                continue;
            }
            worst = worst.max((*p - lim[v.idx()]).length() / diag);
        }
        eprintln!("loop limits {name}: worst {worst:.2e} ({darts} darts skipped)");
        assert!(worst <= TOL, "{name}: {worst:e}");
    }
}

/// Same for Catmull-Clark on quad meshes without darts or interior
/// valence-2 vertices (OpenSubdiv's deliberate departures).
#[test]
fn catmark_vertex_limits_match_opensubdiv() {
    for (name, m) in quad_fixtures() {
        if name == "valence2" || name == "sharp_cube" {
            continue;
        }
        let osd = osd_refine_uniform(&m, OsdScheme::Catmark, 1, true).unwrap();
        let (_, perm) = compare_with_osd(name, &m, OsdScheme::Catmark, 1);
        let fine = refine_quadtri(&m, 1).unwrap();
        let lim = vertex_limit_stencils(&fine)
            .unwrap()
            .apply(fine.positions());
        let diag = m.bbox_diagonal();
        let worst = osd
            .limits
            .unwrap()
            .iter()
            .enumerate()
            .map(|(i, p)| (*p - lim[perm[i]]).length() / diag)
            .fold(0.0, f64::max);
        eprintln!("catmark limits {name}: worst {worst:.2e}");
        assert!(worst <= TOL, "{name}: {worst:e}");
    }
}

/// A closed mixed mesh: the perturbed cube with two faces split into
/// triangles and one into four triangles around a new vertex (valences
/// mixing quads and triangles: (2,2), (3,1), (1,4), (0,4)...).
fn mixed_cube() -> ControlMesh {
    let c = fixtures::cube();
    let mut p = c.positions().to_vec();
    p.push(DVec3::new(0.0, 0.0, 1.3)); // 8: apex over the top face 4 5 7 6
    let f: Vec<Vec<u32>> = vec![
        vec![0, 2, 3],
        vec![0, 3, 1],
        vec![4, 5, 8],
        vec![5, 7, 8],
        vec![7, 6, 8],
        vec![6, 4, 8],
        vec![0, 1, 5, 4],
        vec![2, 6, 7, 3],
        vec![0, 4, 6, 2],
        vec![1, 3, 7],
        vec![1, 7, 5],
    ];
    fixtures::perturb(ControlMesh::from_polygons(p, &f).unwrap(), 0.03, 26)
}

#[test]
fn mixed_stencils_are_affine_combinations() {
    for (name, m) in [
        ("mixed_cube", mixed_cube()),
        ("mixed_grid", tri_grid(6, true, false)),
    ] {
        let r = QuadTriRefiner::new(&m, 3).unwrap();
        let s = r.stencils(3);
        let worst = (0..s.len())
            .map(|i| (s.row(i).map(|(_, w)| w).sum::<f64>() - 1.0).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-12, "{name}: stencil row sums off by {worst:e}");
        // The stencils reproduce the level-by-level positions.
        let lv = r.refine_positions(m.positions()).unwrap();
        let via = s.apply(m.positions());
        let d = lv[3]
            .iter()
            .zip(&via)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0, f64::max);
        assert!(d < 1e-12 * m.bbox_diagonal(), "{name}: {d:e}");
        // Translation invariance of the limit stencils too.
        let l = vertex_limit_stencils(&m).unwrap();
        for i in 0..l.len() {
            let sum: f64 = l.row(i).map(|(_, w)| w).sum();
            assert!(
                (sum - 1.0).abs() < 1e-12,
                "{name}: limit row {i} sums to {sum}"
            );
        }
    }
}

#[test]
fn planar_mixed_mesh_stays_planar() {
    let m = tri_grid(6, true, true);
    let r = QuadTriRefiner::new(&m, 3).unwrap();
    let lv = r.refine_positions(m.positions()).unwrap();
    let z = lv[3].iter().map(|p| p.z.abs()).fold(0.0, f64::max);
    assert!(z < 1e-14, "refined z {z:e}");
    let lim = vertex_limit_stencils(&m).unwrap().apply(m.positions());
    assert!(lim.iter().all(|p| p.z.abs() < 1e-14));
    // Linear precision: the boundary of an affine image of the plane is
    // still in the plane (tilted plane z = 0.3 x - 0.2 y + 1).
    let tilted: Vec<DVec3> = m
        .positions()
        .iter()
        .map(|p| DVec3::new(p.x, p.y, 0.3 * p.x - 0.2 * p.y + 1.0))
        .collect();
    let lv = r.refine_positions(&tilted).unwrap();
    let off = lv[3]
        .iter()
        .map(|p| (p.z - (0.3 * p.x - 0.2 * p.y + 1.0)).abs())
        .fold(0.0, f64::max);
    assert!(off < 1e-13, "tilted plane: {off:e}");
}

/// Refined control-vertex positions converge geometrically to the exact
/// limit; the evaluator is exact at level-L vertices (face centres of
/// control quads are level-1 vertices) and close in between.
#[test]
fn mixed_mesh_converges_to_its_limit() {
    let m = mixed_cube();
    let diag = m.bbox_diagonal();
    let lim = vertex_limit_stencils(&m).unwrap().apply(m.positions());
    let r = QuadTriRefiner::new(&m, 6).unwrap();
    let lv = r.refine_positions(m.positions()).unwrap();
    let dist = |l: usize| {
        (0..m.num_vertices())
            .map(|v| (lv[l][v] - lim[v]).length() / diag)
            .fold(0.0, f64::max)
    };
    let (d5, d6) = (dist(5), dist(6));
    eprintln!("mixed_cube: |refined - limit| level 5 {d5:.2e}, level 6 {d6:.2e}");
    assert!(d6 < 0.75 * d5, "no geometric convergence: {d5:e} -> {d6:e}");
    assert!(d6 < 5e-3, "level 6 still {d6:e} from the limit");

    // Evaluator: exact at the control vertices and at quad centres.
    let ev = QuadTriEvaluator::new(&m, 4).unwrap();
    let vl = ev.vertex_limits(m.positions()).unwrap();
    for v in 0..m.num_vertices() {
        assert!((vl[v].position - lim[v]).length() < 1e-12 * diag);
        assert!(
            vl[v].normal().dot((lim[v] - DVec3::ZERO).normalize()) > 0.5,
            "outward normal at {v}"
        );
    }
    let l1 = refine_quadtri(&m, 1).unwrap();
    let lim1 = vertex_limit_stencils(&l1).unwrap().apply(l1.positions());
    let r1 = QuadTriRefiner::new(&m, 1).unwrap();
    for (c, p) in r1.parents(1).iter().enumerate() {
        if let Parent::Face(f) = *p {
            let e = ev
                .evaluate(m.positions(), &[SurfaceLocation::quad(FaceId(f), 0.5, 0.5)])
                .unwrap()[0];
            assert!(
                (e.position - lim1[c]).length() < 1e-12 * diag,
                "face {f} centre"
            );
        }
    }
    // In between: level 4 against level 6 at random locations, and the
    // stencils against evaluate.
    let ev6 = QuadTriEvaluator::new(&m, 6).unwrap();
    let locs = subdfit::subdiv::diff::random_locations(&m, 500, 7);
    let a = ev.evaluate(m.positions(), &locs).unwrap();
    let b = ev6.evaluate(m.positions(), &locs).unwrap();
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x.position - y.position).length() / diag)
        .fold(0.0, f64::max);
    eprintln!("mixed_cube: evaluator level 4 vs level 6: {worst:.2e} of the diagonal");
    assert!(worst < 5e-3, "{worst:e}");
    let st = ev.stencils(&locs).unwrap().apply(m.positions());
    for (x, y) in a.iter().zip(&st) {
        assert!((x.position - y.position).length() < 1e-12 * diag);
        assert!((x.du - y.du).length() < 1e-9 * diag && (x.dv - y.dv).length() < 1e-9 * diag);
    }
    // Derivatives against central differences, on quads away from the
    // level-4 cell borders (the interpolant is smooth inside a cell).
    let h = 1e-7;
    let mut checked = 0;
    for l in locs.iter().filter(|l| m.face_size(l.face) == 4) {
        let near = |t: f64| ((t * 16.0) - (t * 16.0).round()).abs() < 1e-4;
        if near(l.u) || near(l.v) {
            continue;
        }
        let at = |u: f64, v: f64| {
            ev.evaluate(m.positions(), &[SurfaceLocation { u, v, ..*l }])
                .unwrap()[0]
        };
        let p = at(l.u, l.v);
        let fu = (at(l.u + h, l.v).position - at(l.u - h, l.v).position) / (2.0 * h);
        let fv = (at(l.u, l.v + h).position - at(l.u, l.v - h).position) / (2.0 * h);
        assert!(
            (fu - p.du).length() < 1e-6 * diag,
            "du at {l:?}: {fu} vs {}",
            p.du
        );
        assert!(
            (fv - p.dv).length() < 1e-6 * diag,
            "dv at {l:?}: {fv} vs {}",
            p.dv
        );
        checked += 1;
    }
    assert!(checked > 50, "only {checked} derivative checks");
}

/// Vertices of an infinitely sharp crease polyline follow the 1-6-1 curve
/// rule whatever the faces around them: the child of a crease vertex is
/// `¾ v + ⅛ (a + b)`, the child of a crease edge its midpoint.
#[test]
fn crease_polyline_follows_the_curve_rule() {
    let mut m = tri_grid(6, true, false);
    // The row y = 3 (vertices 21..=27) crosses the quad and triangle halves.
    let row: Vec<u32> = (0..=6).map(|i| 3 * 7 + i).collect();
    for w in row.windows(2) {
        m.set_crease(VertexId(w[0]), VertexId(w[1]), INFINITELY_SHARP)
            .unwrap();
    }
    let r = QuadTriRefiner::new(&m, 1).unwrap();
    let p1 = &r.refine_positions(m.positions()).unwrap()[1];
    let x = m.positions();
    for k in 1..row.len() - 1 {
        let (a, v, b) = (row[k - 1], row[k], row[k + 1]);
        let want = 0.75 * x[v as usize] + 0.125 * (x[a as usize] + x[b as usize]);
        assert!(
            (p1[v as usize] - want).length() < 1e-14,
            "crease vertex {v}"
        );
    }
    for (c, p) in r.parents(1).iter().enumerate() {
        if let Parent::Edge(a, b) = *p {
            if m.edge_sharpness(m.find_halfedge(VertexId(a), VertexId(b)).unwrap().edge()) > 0.0 {
                let want = 0.5 * (x[a as usize] + x[b as usize]);
                assert!((p1[c] - want).length() < 1e-14, "crease edge ({a}, {b})");
            }
        }
    }
    // Limit of the crease: the cubic B-spline of the polyline, (a + 4v + b)/6.
    let lim = vertex_limit_stencils(&m).unwrap().apply(x);
    for k in 1..row.len() - 1 {
        let (a, v, b) = (row[k - 1], row[k], row[k + 1]);
        let want = (x[a as usize] + 4.0 * x[v as usize] + x[b as usize]) / 6.0;
        assert!((lim[v as usize] - want).length() < 1e-14);
    }
}

#[test]
fn averaging_weights_reduce_to_the_parent_schemes() {
    for n in 3..12 {
        assert_eq!(averaging_weight(n, 0), 4.0 / n as f64);
    }
    assert_eq!(averaging_weight(4, 0), 1.0);
    assert_eq!(averaging_weight(0, 6), 1.0);
    assert_eq!(averaging_weight(2, 3), 1.0);
    // Loop, valence 3: β = 3/16 → γ = 8 · 3 · (3/16) / 3 = 3/2.
    assert!((averaging_weight(0, 3) - 1.5).abs() < 1e-15);
}

#[test]
fn bad_input_is_a_typed_error() {
    let pent = ControlMesh::from_polygons(
        (0..5)
            .map(|i| {
                let a = i as f64 * 1.2566;
                DVec3::new(a.cos(), a.sin(), 0.0)
            })
            .collect(),
        &[[0u32, 1, 2, 3, 4]],
    )
    .unwrap();
    match check_mesh(&pent) {
        Err(Error::Topology { element, msg }) => {
            assert!(
                element.contains('0') && msg.contains("5 corners"),
                "{element}: {msg}"
            )
        }
        other => panic!("expected a topology error, got {other:?}"),
    }
    let mut m = fixtures::cube();
    m.set_crease(VertexId(0), VertexId(1), 2.0).unwrap();
    match QuadTriRefiner::new(&m, 1) {
        Err(e @ Error::Topology { .. }) => {
            assert!(e.to_string().contains("semi-sharp"), "{e}");
            assert_eq!(e.kind(), subdfit::ErrorKind::Input);
        }
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("semi-sharp crease accepted"),
    }
    assert!(matches!(
        QuadTriRefiner::new(&fixtures::cube(), 99),
        Err(Error::InvalidArgument(_))
    ));
    // OpenSubdiv refuses quads under Loop: an error, not a crash.
    assert!(osd_refine_uniform(&fixtures::cube(), OsdScheme::Loop, 1, false).is_err());
}
