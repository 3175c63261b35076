//! Exactness of the pure-Rust Catmull-Clark limit evaluator, checked
//! against closed forms and against its own uniform refinement (the limit
//! surface of a refined mesh is the limit surface of the original).
//!
//! Tolerances are relative to the bounding-box diagonal: the computations are
//! exact up to round-off, so 1e-12 (positions) leaves room for the ~40
//! levels of local subdivision a location very close to an extraordinary
//! vertex can take.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subdfit::fixtures;
use subdfit::mesh::{ControlMesh, FaceId, VertexId};
use subdfit::subdiv::catmark::RustEvaluator;
use subdfit::subdiv::refine::refine_uniform;
use subdfit::subdiv::{EvalOptions, LimitEvaluator, LimitPoint, SurfaceLocation};
use subdfit::DVec3;

fn eval(m: &ControlMesh) -> RustEvaluator {
    RustEvaluator::new(m, &EvalOptions::default()).expect("evaluator")
}

/// Angle between two vectors, accurate near 0 (acos is not: ~1.5e-8).
fn angle(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

/// Whether `v` is interior, smooth or a dart (at most one sharp edge), all
/// its faces quads: a unique normal, comparable between masks and patches.
fn smooth_quad_vertex(m: &ControlMesh, v: VertexId) -> bool {
    !m.is_boundary_vertex(v)
        && m.vertex_sharpness(v) == 0.0
        && m.outgoing(v)
            .filter(|h| m.edge_sharpness(h.edge()) > 0.0)
            .count()
            <= 1
        && m.vertex_faces(v).all(|f| m.face_size(f) == 4)
}

/// A boundary vertex with at least two faces (a crease, not a corner),
/// nothing else sharp, all faces quads: one sector, one normal.
fn plain_boundary_vertex(m: &ControlMesh, v: VertexId) -> bool {
    m.is_boundary_vertex(v)
        && m.vertex_faces(v).count() >= 2
        && m.vertex_sharpness(v) == 0.0
        && m.outgoing(v).all(|h| m.edge_sharpness(h.edge()) == 0.0)
        && m.vertex_faces(v).all(|f| m.face_size(f) == 4)
}

/// Random locations, `per_face` per sub-face, fixed seed.
fn random_locations(m: &ControlMesh, per_face: usize, seed: u64) -> Vec<SurfaceLocation> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    for f in m.faces() {
        let n = m.face_size(f);
        let nsub = if n == 4 { 1 } else { n };
        for sub in 0..nsub {
            for _ in 0..per_face {
                out.push(SurfaceLocation {
                    face: f,
                    sub: sub as u16,
                    u: rng.gen(),
                    v: rng.gen(),
                });
            }
        }
    }
    out
}

#[test]
fn every_fixture_is_valid() {
    for (name, m) in fixtures::collection() {
        m.validate().unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(m.num_faces() <= 400, "{name}: {} faces", m.num_faces());
    }
    assert_eq!(fixtures::two_components(1).num_components(), 2);
    assert_eq!(fixtures::grid(3, 3, 1).num_boundary_loops(), 1);
}

#[test]
fn cube_corner_limit_is_half() {
    // (n²v + 4Σe + Σd)/(n(n+5)) with n = 3 at (1,1,1): (9 - 4 - 3·... ) = ±1/2.
    let m = fixtures::cube();
    let lim = eval(&m).vertex_limits(m.positions()).unwrap();
    for (v, l) in lim.iter().enumerate() {
        let expect = m.positions()[v] * 0.5;
        assert!(
            (l.position - expect).length() < 1e-15,
            "vertex {v}: {} vs {expect}",
            l.position
        );
        // By symmetry the normal is along the diagonal, outward.
        assert!(angle(l.normal(), expect) < 1e-12, "vertex {v}");
    }
}

/// Vertex limits are invariant under refinement: vertex i of the refined
/// mesh is the child of vertex i.
#[test]
fn vertex_limits_survive_refinement() {
    for (name, m) in fixtures::collection() {
        let diag = m.bbox_diagonal();
        let l0 = eval(&m).vertex_limits(m.positions()).unwrap();
        let r = refine_uniform(&m, 2).unwrap();
        r.validate().unwrap();
        let l2 = eval(&r).vertex_limits(r.positions()).unwrap();
        let mut worst = (0.0, 0);
        for v in 0..m.num_vertices() {
            let d = (l0[v].position - l2[v].position).length() / diag;
            if d > worst.0 {
                worst = (d, v);
            }
            if smooth_quad_vertex(&m, VertexId(v as u32)) {
                let a = angle(l0[v].normal(), l2[v].normal());
                assert!(a < 1e-9, "{name}: vertex {v}: normal differs by {a} rad");
            }
        }
        assert!(
            worst.0 < 1e-12,
            "{name}: vertex {} moves by {:e} of the diagonal",
            worst.1,
            worst.0
        );
    }
}

#[test]
fn face_corners_are_vertex_limits() {
    for (name, m) in fixtures::collection() {
        let diag = m.bbox_diagonal();
        let ev = eval(&m);
        let lim = ev.vertex_limits(m.positions()).unwrap();
        let mut locs = Vec::new();
        let mut verts = Vec::new();
        for f in m.faces() {
            let vs: Vec<VertexId> = m.face_vertices(f).collect();
            if vs.len() == 4 {
                for (k, (u, v)) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
                    .into_iter()
                    .enumerate()
                {
                    locs.push(SurfaceLocation::quad(f, u, v));
                    verts.push(vs[k]);
                }
            } else {
                for (k, &v) in vs.iter().enumerate() {
                    locs.push(SurfaceLocation {
                        face: f,
                        sub: k as u16,
                        u: 0.0,
                        v: 0.0,
                    });
                    verts.push(v);
                }
            }
        }
        let got = ev.evaluate(m.positions(), &locs).unwrap();
        // Just inside the face, the surface is evaluated by local
        // subdivision down to a regular patch (~47 levels), not by the masks:
        // the normal must converge to the mask normal (continuity), at the
        // rate (λ3/λ2)^levels: 0.82^47 ≈ 1e-4 for valence 8 (λ2 = 0.61,
        // λ3 = 1/2), ~1e-10 at valence 3. Positions within |du|·1e-14.
        let eps = 1e-14;
        let near: Vec<SurfaceLocation> = locs
            .iter()
            .map(|l| SurfaceLocation {
                u: if l.u == 0.0 { eps } else { 1.0 - eps },
                v: if l.v == 0.0 { eps } else { 1.0 - eps },
                ..*l
            })
            .collect();
        let near = ev.evaluate(m.positions(), &near).unwrap();
        for ((l, g), v) in locs.iter().zip(&near).zip(&verts) {
            let d = (g.position - lim[v.idx()].position).length() / diag;
            assert!(d < 1e-6, "{name}: near {l:?} vs {v}: {d:e}");
            if smooth_quad_vertex(&m, *v) || plain_boundary_vertex(&m, *v) {
                let a = angle(g.normal(), lim[v.idx()].normal());
                assert!(a < 1e-4, "{name}: near {l:?} vs {v}: normal {a} rad");
            }
        }
        for ((l, g), v) in locs.iter().zip(&got).zip(&verts) {
            let d = (g.position - lim[v.idx()].position).length() / diag;
            assert!(d < 1e-13, "{name}: {l:?} vs {v}: {d:e}");
            if smooth_quad_vertex(&m, *v) {
                let a = angle(g.normal(), lim[v.idx()].normal());
                assert!(a < 1e-9, "{name}: {l:?} vs {v}: normal {a} rad");
            }
        }
    }
}

/// The parent `(u, v)` of child quad `k` of a quad at its `(s, t)`, and the
/// Jacobian `∂(u, v)/∂(s, t)` (see the evaluator's sub-quad orientation).
fn parent_uv(k: usize, s: f64, t: f64) -> (f64, f64, [[f64; 2]; 2]) {
    match k {
        0 => (s / 2.0, t / 2.0, [[0.5, 0.0], [0.0, 0.5]]),
        1 => (1.0 - t / 2.0, s / 2.0, [[0.0, -0.5], [0.5, 0.0]]),
        2 => (1.0 - s / 2.0, 1.0 - t / 2.0, [[-0.5, 0.0], [0.0, -0.5]]),
        _ => (t / 2.0, 1.0 - s / 2.0, [[0.0, 0.5], [-0.5, 0.0]]),
    }
}

/// The limit surface on a child face of the refined mesh equals the limit
/// surface of the parent at the mapped location: checks exactness of the
/// local subdivision near extraordinary vertices and creases, and the
/// derivative chain rule.
#[test]
fn refined_subfaces_match_parent() {
    for (name, m) in fixtures::collection() {
        let diag = m.bbox_diagonal();
        let r = refine_uniform(&m, 1).unwrap();
        let (ep, er) = (eval(&m), eval(&r));
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        let (mut child_locs, mut parent_locs, mut jacs) = (Vec::new(), Vec::new(), Vec::new());
        let mut cf = 0u32;
        for f in m.faces() {
            let n = m.face_size(f);
            for k in 0..n {
                for _ in 0..6 {
                    // Include locations very close to the corners.
                    let (s, t): (f64, f64) = if rng.gen_bool(0.3) {
                        (rng.gen::<f64>() * 1e-4, rng.gen::<f64>() * 1e-4)
                    } else {
                        (rng.gen(), rng.gen())
                    };
                    child_locs.push(SurfaceLocation::quad(FaceId(cf), s, t));
                    if n == 4 {
                        let (u, v, j) = parent_uv(k, s, t);
                        parent_locs.push(SurfaceLocation::quad(f, u, v));
                        jacs.push(j);
                    } else {
                        parent_locs.push(SurfaceLocation {
                            face: f,
                            sub: k as u16,
                            u: s,
                            v: t,
                        });
                        jacs.push([[1.0, 0.0], [0.0, 1.0]]);
                    }
                }
                cf += 1;
            }
        }
        assert_eq!(cf as usize, r.num_faces());
        let c = er.evaluate(r.positions(), &child_locs).unwrap();
        let p = ep.evaluate(m.positions(), &parent_locs).unwrap();
        let mut worst = (0.0, 0);
        let mut worst_d = (0.0, 0);
        for i in 0..c.len() {
            let d = (c[i].position - p[i].position).length() / diag;
            if d > worst.0 {
                worst = (d, i);
            }
            let j = jacs[i];
            let ds = j[0][0] * p[i].du + j[1][0] * p[i].dv;
            let dt = j[0][1] * p[i].du + j[1][1] * p[i].dv;
            let dd = ((c[i].du - ds).length() + (c[i].dv - dt).length()) / diag;
            if dd > worst_d.0 {
                worst_d = (dd, i);
            }
        }
        assert!(
            worst.0 < 1e-12,
            "{name}: position differs by {:e} at {:?}",
            worst.0,
            child_locs[worst.1]
        );
        assert!(
            worst_d.0 < 1e-10,
            "{name}: derivatives differ by {:e} at {:?}",
            worst_d.0,
            child_locs[worst_d.1]
        );
    }
}

#[test]
fn stencils_apply_equals_evaluate() {
    for (name, m) in fixtures::collection() {
        let diag = m.bbox_diagonal();
        let ev = eval(&m);
        let locs = random_locations(&m, 3, 5);
        let st = ev.stencils(&locs).unwrap();
        assert_eq!(st.len(), locs.len());
        let a = st.apply(m.positions());
        let b = ev.evaluate(m.positions(), &locs).unwrap();
        for i in 0..locs.len() {
            let w: f64 = st.row(i).map(|k| st.weights[k]).sum();
            assert!((w - 1.0).abs() < 1e-12, "{name}: weights sum to {w}");
            let d = (a[i].position - b[i].position).length()
                + (a[i].du - b[i].du).length()
                + (a[i].dv - b[i].dv).length();
            assert!(d / diag < 1e-12, "{name}: {:?}: {d:e}", locs[i]);
        }
    }
}

fn bspline(t: f64) -> [f64; 4] {
    [
        (1.0 - t).powi(3) / 6.0,
        (3.0 * t.powi(3) - 6.0 * t * t + 4.0) / 6.0,
        (-3.0 * t.powi(3) + 3.0 * t * t + 3.0 * t + 1.0) / 6.0,
        t.powi(3) / 6.0,
    ]
}

#[test]
fn regular_patch_is_bicubic_bspline() {
    let (nx, ny) = (5u32, 4u32);
    let m = fixtures::grid(nx, ny, 6);
    let ev = eval(&m);
    let face = |i: u32, j: u32| FaceId(j * nx + i);
    let vid = |i: u32, j: u32| (j * (nx + 1) + i) as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for j in 0..ny {
        for i in 0..nx {
            assert!(
                ev.is_regular_face(face(i, j)),
                "boundary and corner patches are regular too"
            );
        }
    }
    // Interior faces have a full 4x4 grid of real control points.
    for j in 1..ny - 1 {
        for i in 1..nx - 1 {
            for _ in 0..10 {
                let (u, v): (f64, f64) = (rng.gen(), rng.gen());
                let (bu, bv) = (bspline(u), bspline(v));
                let mut expect = DVec3::ZERO;
                for b in 0..4u32 {
                    for a in 0..4u32 {
                        expect += bu[a as usize]
                            * bv[b as usize]
                            * m.positions()[vid(i + a - 1, j + b - 1)];
                    }
                }
                let got = ev
                    .evaluate(m.positions(), &[SurfaceLocation::quad(face(i, j), u, v)])
                    .unwrap()[0];
                assert!((got.position - expect).length() < 1e-14);
            }
        }
    }
    // A boundary patch: the boundary is the cubic B-spline curve of the
    // boundary row (v = 0 on the bottom row of faces).
    let u = 0.37;
    let got = ev
        .evaluate(m.positions(), &[SurfaceLocation::quad(face(2, 0), u, 0.0)])
        .unwrap()[0];
    let bu = bspline(u);
    let expect: DVec3 = (0..4u32)
        .map(|a| bu[a as usize] * m.positions()[vid(1 + a, 0)])
        .sum();
    assert!(
        (got.position - expect).length() < 1e-14,
        "{} vs {expect}",
        got.position
    );
}

#[test]
fn derivatives_match_finite_differences() {
    let h = 1e-6;
    for (name, m) in fixtures::collection() {
        let diag = m.bbox_diagonal();
        let ev = eval(&m);
        let mut locs = random_locations(&m, 2, 17);
        for l in locs.iter_mut() {
            l.u = l.u.clamp(0.01, 0.99);
            l.v = l.v.clamp(0.01, 0.99);
        }
        let mut shifted = Vec::new();
        for l in &locs {
            for (du, dv) in [(h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h)] {
                shifted.push(SurfaceLocation {
                    u: l.u + du,
                    v: l.v + dv,
                    ..*l
                });
            }
        }
        let p = ev.evaluate(m.positions(), &locs).unwrap();
        let s = ev.evaluate(m.positions(), &shifted).unwrap();
        for i in 0..locs.len() {
            let fu = (s[4 * i].position - s[4 * i + 1].position) / (2.0 * h);
            let fv = (s[4 * i + 2].position - s[4 * i + 3].position) / (2.0 * h);
            // Central differences: O(h²) truncation plus round-off ~1e-16/h.
            let e = ((fu - p[i].du).length() + (fv - p[i].dv).length()) / diag;
            assert!(e < 1e-6, "{name}: {:?}: {e:e}", locs[i]);
        }
    }
}

#[test]
fn normals_point_outward_on_closed_meshes() {
    for (name, m) in fixtures::collection() {
        if m.num_boundary_loops() != 0 || m.num_components() != 1 || m.has_sharpness() {
            continue;
        }
        let ev = eval(&m);
        let centre: DVec3 = m.positions().iter().sum::<DVec3>() / m.num_vertices() as f64;
        let locs = random_locations(&m, 4, 23);
        let pts = ev.evaluate(m.positions(), &locs).unwrap();
        let lim = ev.vertex_limits(m.positions()).unwrap();
        let check = |p: &LimitPoint, what: String| {
            let n = p.normal();
            assert!(n.length() > 0.5, "{name}: {what}: no normal");
            assert!(
                n.dot((p.position - centre).normalize()) > 0.2,
                "{name}: {what}: inward normal"
            );
        };
        for (l, p) in locs.iter().zip(&pts) {
            check(p, format!("{l:?}"));
        }
        for (v, p) in lim.iter().enumerate() {
            check(p, format!("vertex {v}"));
        }
    }
}

#[test]
fn bad_input_is_an_error() {
    let m = fixtures::cube();
    let ev = eval(&m);
    assert!(ev.evaluate(&m.positions()[..3], &[]).is_err());
    for l in [
        SurfaceLocation::quad(FaceId(6), 0.5, 0.5),
        SurfaceLocation::quad(FaceId(0), 1.5, 0.5),
        SurfaceLocation::quad(FaceId(0), f64::NAN, 0.5),
        SurfaceLocation {
            face: FaceId(0),
            sub: 1,
            u: 0.5,
            v: 0.5,
        },
    ] {
        assert!(ev.evaluate(m.positions(), &[l]).is_err(), "{l:?}");
        assert!(ev.stencils(&[l]).is_err(), "{l:?}");
    }
}
