//! Non-manifold control meshes as OpenSubdiv treats them (issue 18): fins
//! (three or more faces on an edge), chains of such edges, closed cubes
//! sharing an edge or a vertex, bow-ties of open grids, unused vertices,
//! several components, triangle versions for Loop, semi-sharp creases,
//! under every boundary interpolation.
//!
//! OpenSubdiv is given the file's topology as it is
//! (`osd::OsdDescriptor::of_split`); the Rust evaluators the tagged
//! manifold copy (`mesh::SplitControl`). Measured:
//!
//! - **vertex limits**: the Rust evaluator's limit at every vertex of the
//!   file equals OpenSubdiv's `Limit` of the vertex's level-8 descendant in
//!   a uniform refinement of the original topology, to 1e-9 of the
//!   bounding-box diagonal;
//! - **surface**: the two evaluators agree to 1e-9 of the diagonal at
//!   control vertices and at random locations ≥ 0.01 from irregular
//!   corners (OpenSubdiv's patches are exact there), normals to 1e-6 rad;
//! - **teeth**: the same copy without the non-manifold tags (what a
//!   half-edge split alone gives) is far from OpenSubdiv on the same
//!   meshes, so the comparison can fail;
//! - **refusals**: what splitting cannot reproduce is an error naming the
//!   file and the element.

use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

use subdfit::mesh::{
    split_non_manifold_polygons, BoundaryInterpolation, ControlMesh, CreaseMethod, PolySoup,
    SchemeOptions, SplitControl, SubdivScheme, VertexId, VertexKind,
};
use subdfit::subdiv::diff::{
    compare_with_known, near_irregular_locations_with, random_locations_with,
};
use subdfit::subdiv::osd::{
    osd_refine_uniform_desc, patch_evaluated_vertices, OsdDescriptor, OsdParent, OsdScheme,
};
use subdfit::subdiv::{
    file_vertex_limits, known_differences_with, make_evaluator, make_split_evaluator,
    split_known_differences, Backend, EvalOptions,
};
use subdfit::DVec3;

/// Polygons under construction; vertices at bit-identical positions are
/// one vertex (that is how the pieces below are glued).
#[derive(Default, Clone)]
struct Builder {
    positions: Vec<DVec3>,
    faces: Vec<Vec<u32>>,
    index: HashMap<[u64; 3], u32>,
}

impl Builder {
    fn vertex(&mut self, p: DVec3) -> u32 {
        // -0.0 + 0.0 is +0.0: a sheet's row at sin θ < 0 still glues.
        let p = p + DVec3::ZERO;
        let key = [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
        *self.index.entry(key).or_insert_with(|| {
            self.positions.push(p);
            (self.positions.len() - 1) as u32
        })
    }

    /// An `nx` × `ny` grid of quads (or of triangle pairs), `at(i, j)` its
    /// points, oriented `(i, j) → (i+1, j) → (i+1, j+1)`.
    fn sheet(&mut self, nx: u32, ny: u32, tris: bool, at: impl Fn(f64, f64) -> DVec3) {
        let mut id = |i: u32, j: u32| self.vertex(at(i as f64 / nx as f64, j as f64 / ny as f64));
        let mut faces = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let q = [id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)];
                if tris {
                    faces.push(vec![q[0], q[1], q[2]]);
                    faces.push(vec![q[0], q[2], q[3]]);
                } else {
                    faces.push(q.to_vec());
                }
            }
        }
        self.faces.extend(faces);
    }

    /// The surface of the box `o + [0, s]³`, outward, `n` × `n` per side.
    fn cube(&mut self, o: DVec3, s: f64, n: u32, tris: bool) {
        let x = DVec3::X * s;
        let y = DVec3::Y * s;
        let z = DVec3::Z * s;
        for (c, u, v) in [
            (o, y, x),
            (o + z, x, y),
            (o, x, z),
            (o + y, z, x),
            (o, z, y),
            (o + x, y, z),
        ] {
            self.sheet(n, n, tris, |a, b| c + a * u + b * v);
        }
    }

    /// `k` sheets of `nx` × `ny` around the x axis, sharing the row
    /// `y = 0` from x = 0 to `len` (a fin: a chain of `nx` edges with `k`
    /// faces each).
    fn fin(&mut self, k: u32, nx: u32, ny: u32, len: f64, tris: bool) {
        for s in 0..k {
            let t = 2.0 * std::f64::consts::PI * (s as f64 + 0.1) / k as f64;
            let (c, sn) = (t.cos(), t.sin());
            self.sheet(nx, ny, tris, |a, b| DVec3::new(a * len, b * c, b * sn));
        }
    }

    fn id(&self, p: DVec3) -> u32 {
        let p = p + DVec3::ZERO;
        let key = [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
        self.index[&key]
    }

    /// The soup, every vertex moved by a smooth bump plus a fixed jitter
    /// (after gluing, so glued vertices stay one).
    fn soup(&self) -> PolySoup {
        let mut s = PolySoup {
            positions: Vec::new(),
            face_offsets: vec![0],
            face_indices: Vec::new(),
        };
        for (i, p) in self.positions.iter().enumerate() {
            let h = (i as f64 * 0.618_034).fract() - 0.5;
            let bump = DVec3::new(
                0.04 * (2.1 * p.y + 0.3).sin(),
                0.05 * (1.7 * p.z + 0.2 * p.x).cos(),
                0.06 * (1.3 * p.x).sin(),
            );
            s.positions
                .push(*p + bump + 0.02 * DVec3::new(h, -h, 0.5 * h));
        }
        for f in &self.faces {
            s.face_indices.extend_from_slice(f);
            s.face_offsets.push(s.face_indices.len() as u32);
        }
        s
    }
}

struct Case {
    name: String,
    soup: PolySoup,
    creases: Vec<(u32, u32, f64)>,
    corners: Vec<(u32, f64)>,
}

fn case(name: &str, b: &Builder) -> Case {
    Case {
        name: name.to_string(),
        soup: b.soup(),
        creases: Vec::new(),
        corners: Vec::new(),
    }
}

fn p3(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z)
}

/// The meshes of the suite, quads (`tris` false) or triangles.
fn cases(tris: bool) -> Vec<Case> {
    let mut out = Vec::new();
    let mut b = Builder::default();
    b.fin(3, 1, 1, 1.0, tris);
    out.push(case("fin of 3", &b));

    // 40 faces on one edge: its level-1 child has 80 faces and 42 edges,
    // more faces than OpenSubdiv's recorded max valence, where its own
    // `PrimvarRefiner::Limit` overruns a heap buffer (`cpp/osd_limit.h`).
    let mut b = Builder::default();
    b.fin(40, 1, 1, 1.0, tris);
    out.push(case("fin of 40", &b));

    let mut b = Builder::default();
    b.fin(3, 2, 2, 2.0, tris);
    let chain = case("chain of 2 edges, 3 sheets", &b);
    out.push(chain);

    // Long enough that faces along the chain survive boundary "none".
    let mut b = Builder::default();
    b.fin(4, 4, 2, 4.0, tris);
    out.push(case("chain of 4 edges, 4 sheets", &b));

    // Inconsistent orientation: the middle face of a grid reversed, its
    // edges each used twice in one direction.
    let mut b = Builder::default();
    b.sheet(3, 3, tris, |u, v| p3(3.0 * u, 3.0 * v, 0.0));
    let mid = if tris { 8 } else { 4 };
    b.faces[mid].reverse();
    out.push(case("grid with a reversed face", &b));

    let mut b = Builder::default();
    b.cube(DVec3::ZERO, 1.0, 2, tris);
    b.cube(p3(1.0, 1.0, 0.0), 1.0, 2, tris);
    out.push(case("two cubes sharing an edge", &b));

    let mut b = Builder::default();
    b.cube(DVec3::ZERO, 1.0, 1, tris);
    b.cube(p3(1.0, 1.0, 1.0), 1.0, 1, tris);
    out.push(case("two cubes sharing a vertex", &b));

    let mut b = Builder::default();
    b.sheet(2, 2, tris, |u, v| p3(2.0 * u, 2.0 * v, 0.0));
    b.sheet(2, 2, tris, |u, v| p3(2.0 + 2.0 * u, 2.0 + 2.0 * v, 0.3 * u));
    out.push(case("bow-tie of two grids", &b));

    let mut b = Builder::default();
    b.sheet(2, 2, tris, |u, v| p3(2.0 * u, 2.0 * v, 0.0));
    b.vertex(p3(5.0, -1.0, 2.0));
    b.vertex(p3(1.0, 1.0, 3.0));
    out.push(case("grid and two unused vertices", &b));

    // Several components: a fin, cubes on a vertex, a plain grid, an
    // unused vertex.
    let mut b = Builder::default();
    b.fin(3, 2, 1, 2.0, tris);
    b.cube(p3(4.0, 0.0, 0.0), 1.0, 1, tris);
    b.cube(p3(5.0, 1.0, 1.0), 1.0, 1, tris);
    b.sheet(2, 2, tris, |u, v| p3(-4.0 + 2.0 * u, 2.0 * v, 0.5));
    b.vertex(p3(0.0, 0.0, 9.0));
    out.push(case("several components", &b));

    // Semi-sharp creases: in one sheet away from the fin's crease
    // vertices, and at its sharpened ends (allowed there: the corner rule
    // does not count edges); a semi-sharp corner on a crease vertex.
    let mut b = Builder::default();
    b.fin(3, 2, 2, 2.0, tris);
    let mut c = case("chain with semi-sharp creases", &b);
    let t = 2.0 * std::f64::consts::PI * 0.1 / 3.0;
    let sheet0 = |a: f64, y: f64| p3(a * 2.0, y * t.cos(), y * t.sin());
    let end = b.id(p3(0.0, 0.0, 0.0));
    c.creases = vec![
        (b.id(sheet0(0.0, 0.5)), b.id(sheet0(0.5, 0.5)), 1.5),
        (b.id(sheet0(0.5, 0.5)), b.id(sheet0(1.0, 0.5)), 2.6),
        (b.id(sheet0(0.5, 1.0)), b.id(sheet0(1.0, 1.0)), 0.8),
        (end, b.id(sheet0(0.0, 0.5)), 1.2),
    ];
    c.corners = vec![(b.id(p3(1.0, 0.0, 0.0)), 1.7), (end, 0.5)];
    out.push(c);

    // An infinitely sharp edge in one sheet at a crease vertex of a chain:
    // three sharp edges, OpenSubdiv's corner rule in every sheet.
    let mut b = Builder::default();
    b.fin(3, 2, 2, 2.0, tris);
    let mut c = case("chain with a third sharp edge", &b);
    c.creases = vec![(b.id(p3(1.0, 0.0, 0.0)), b.id(sheet0(0.5, 0.5)), 10.0)];
    out.push(c);

    // Faces that repeat a corner, as in OpenSubdiv's
    // `catmark_nonman_quadpole*` and `catmark_nonman_edges`: a ring around
    // a pole written as quads with the pole twice (a degenerate edge), and
    // a face whose corners are all the pole; beside it a sheet with a face
    // folded through a vertex (it runs along two edges both ways). With
    // triangles: a degenerate triangle on a rim edge, one folded face.
    let mut b = Builder::default();
    let rim = |i: u32, r: f64| {
        let t = 2.0 * std::f64::consts::PI * i as f64 / 6.0;
        p3(r * t.cos(), r * t.sin(), 0.2 * r)
    };
    let pole = b.vertex(p3(0.0, 0.0, 0.5));
    for i in 0..6 {
        let (a, c) = (b.vertex(rim(i, 1.0)), b.vertex(rim(i + 1, 1.0)));
        let (a2, c2) = (b.vertex(rim(i, 2.0)), b.vertex(rim(i + 1, 2.0)));
        if tris {
            b.faces
                .extend([vec![a2, c2, c], vec![a2, c, a], vec![a, c, pole]]);
        } else {
            b.faces.extend([vec![a2, c2, c, a], vec![a, c, pole, pole]]);
        }
    }
    let (r0, r1) = (b.vertex(rim(0, 1.0)), b.vertex(rim(0, 2.0)));
    b.faces.push(if tris {
        vec![r0, r1, r1]
    } else {
        vec![pole; 4]
    });
    let first = b.positions.len() as u32;
    b.sheet(2, 1, tris, |u, v| p3(5.0 + 2.0 * u, v, 0.3 * u * v));
    let [v0, v1, v4] = [first, first + 1, first + 4];
    b.faces.push(if tris {
        vec![v0, v1, v0]
    } else {
        vec![v0, v1, v4, v1]
    });
    out.push(case("faces repeating a corner", &b));

    if !tris {
        // Two quads back to back on an edge of four faces (OpenSubdiv's
        // `catmark_val2_nonman`): the pair's copies close up around both
        // ends of the edge again, an infinitely sharp interior edge. (With
        // triangles that is a pillow, which Loop refuses.)
        let mut b = Builder::default();
        let q = [
            p3(0.0, 0.0, 0.0),
            p3(1.0, 0.0, 0.0),
            p3(1.0, 1.0, 0.1),
            p3(0.0, 1.0, 0.0),
        ]
        .map(|p| b.vertex(p));
        let up = [p3(0.0, -0.5, 0.6), p3(1.0, -0.5, 0.6)].map(|p| b.vertex(p));
        let down = [p3(0.0, -0.5, -0.6), p3(1.0, -0.5, -0.6)].map(|p| b.vertex(p));
        b.faces.extend([
            q.to_vec(),
            vec![q[3], q[2], q[1], q[0]],
            vec![q[0], q[1], up[1], up[0]],
            vec![q[1], q[0], down[0], down[1]],
        ]);
        out.push(case("two quads back to back on an edge of four", &b));
    }
    out
}

/// Per file vertex: OpenSubdiv's `Limit` of its descendant at `levels`
/// of a uniform refinement of the file's topology.
fn osd_vertex_reference(sc: &SplitControl, scheme: &SchemeOptions, levels: u32) -> Vec<DVec3> {
    let osd_scheme = if scheme.scheme == SubdivScheme::Loop {
        OsdScheme::Loop
    } else {
        OsdScheme::Catmark
    };
    let r = osd_refine_uniform_desc(
        &OsdDescriptor::of_split(sc),
        &sc.positions,
        osd_scheme,
        scheme,
        levels,
        true,
    )
    .unwrap();
    let mut at: Vec<u32> = (0..sc.positions.len() as u32).collect();
    for parents in &r.parents {
        let mut child = HashMap::new();
        for (i, p) in parents.iter().enumerate() {
            if let OsdParent::Vertex(v) = p {
                child.insert(*v, i as u32);
            }
        }
        at = at.iter().map(|v| child[v]).collect();
    }
    let limits = r.limits.unwrap();
    at.iter().map(|&i| limits[i as usize]).collect()
}

/// A chain of two edges shared by three sheets: its middle vertex (a
/// non-manifold crease vertex) and, per sheet, that vertex's neighbour
/// inside it.
fn fin_with_spokes() -> (Builder, u32, [u32; 3]) {
    let mut b = Builder::default();
    b.fin(3, 2, 2, 2.0, false);
    let mid = b.id(p3(1.0, 0.0, 0.0));
    let spoke = [0, 1, 2].map(|k| {
        let t = 2.0 * std::f64::consts::PI * (k as f64 + 0.1) / 3.0;
        b.id(p3(1.0, 0.5 * t.cos(), 0.5 * t.sin()))
    });
    (b, mid, spoke)
}

fn case_named(tris: bool, name: &str) -> Case {
    let mut all = cases(tris);
    let i = all
        .iter()
        .position(|c| c.name == name)
        .expect("no such case");
    all.swap_remove(i)
}

fn with_boundary(scheme: SubdivScheme, b: BoundaryInterpolation) -> SchemeOptions {
    SchemeOptions::default()
        .with_scheme(scheme)
        .with_boundary(b)
}

/// The two measurements of the module docs on one case and scheme;
/// returns (vertex deviation vs the refined reference, surface deviation
/// away from irregular corners), relative to the diagonal, and the number
/// of locations compared away from irregular corners.
fn measure(c: &Case, scheme: &SchemeOptions) -> (f64, f64, usize) {
    let sc = SplitControl::new(&c.soup, &c.creases, &c.corners, Path::new(&c.name)).unwrap();
    // Boundary "none" holes, as OpenSubdiv decides them on the file.
    let scheme = &sc.with_file_holes(scheme.clone());
    let opts = EvalOptions::default().with_scheme(scheme.clone());
    let mesh = &sc.manifold;
    let diag = mesh.bbox_diagonal();
    let rust = make_split_evaluator(Backend::Rust, &sc, &opts).unwrap();
    let osd = make_split_evaluator(Backend::Osd, &sc, &opts).unwrap();
    let holes = scheme.effective_holes(mesh);
    let on_patches = patch_evaluated_vertices(mesh, scheme);
    // Vertices of the file with a surface, and without a known deliberate
    // difference in position (darts, valence 2) at any copy.
    let known: Vec<u32> = known_differences_with(mesh, scheme)
        .iter()
        .filter(|k| !k.normal_only)
        .map(|k| sc.origin[k.vertex as usize])
        .collect();
    let mut dv: f64 = 0.0;
    if scheme.scheme != SubdivScheme::Bilinear {
        let reference = osd_vertex_reference(&sc, scheme, 8);
        let rust_v = file_vertex_limits(&sc, &rust.vertex_limits(mesh.positions()).unwrap());
        let osd_v = file_vertex_limits(&sc, &osd.vertex_limits(mesh.positions()).unwrap());
        for v in 0..sc.positions.len() {
            let surfaced = sc.copies[v]
                .iter()
                .any(|&c| mesh.vertex_faces(VertexId(c)).any(|f| !holes[f.idx()]));
            let unused = sc.kinds[v] == VertexKind::Unused;
            if (!surfaced && !unused) || known.contains(&(v as u32)) {
                continue;
            }
            let d = (rust_v[v].position - reference[v]).length() / diag;
            let d_osd = (osd_v[v].position - reference[v]).length() / diag;
            // (Vertices OpenSubdiv evaluates on a Gregory end cap only
            // approximate the limit: `osd::patch_evaluated_vertices`.)
            let on_patch = sc.copies[v].iter().any(|&c| on_patches[c as usize]);
            assert!(
                on_patch || d_osd < 1e-9,
                "{}: OpenSubdiv's own vertex {v} {d_osd:e}",
                c.name
            );
            if unused {
                // OpenSubdiv leaves an isolated vertex where it is.
                assert_eq!(reference[v], sc.positions[v], "{}: unused {v}", c.name);
                assert_eq!(rust_v[v].position, sc.positions[v]);
            }
            dv = dv.max(d);
        }
    }
    let mut locs = random_locations_with(mesh, scheme, 3000, 7);
    locs.extend(near_irregular_locations_with(mesh, scheme, 4, 0.01, 7));
    let report = compare_with_known(
        mesh,
        scheme,
        osd.as_ref(),
        rust.as_ref(),
        &locs,
        0.01,
        split_known_differences(&sc),
    )
    .unwrap();
    assert!(
        report.regular.normal < 1e-6,
        "{} {scheme}: normal {:e} at {}",
        c.name,
        report.regular.normal,
        report.regular.normal_at
    );
    let ds = report.regular.position.max(report.vertices.position);
    (dv, ds, report.regular.count)
}

fn run_suite(tris: bool, schemes: &[SubdivScheme]) {
    use BoundaryInterpolation as B;
    let mut worst: (f64, f64) = (0.0, 0.0);
    for c in cases(tris) {
        for &s in schemes {
            for b in [B::None, B::EdgeOnly, B::EdgeAndCorner] {
                let scheme = with_boundary(s, b);
                let (dv, ds, n) = measure(&c, &scheme);
                eprintln!(
                    "{} {scheme}: vertices {dv:.2e}, surface {ds:.2e} ({n} locations)",
                    c.name
                );
                if c.name.starts_with("chain of 4") || c.name.starts_with("two cubes") {
                    // Faces with a surface under every rule.
                    assert!(n > 100, "{} {scheme}: {n} locations", c.name);
                }
                assert!(dv <= 1e-9, "{} {scheme}: vertex limits {dv:e}", c.name);
                assert!(ds <= 1e-9, "{} {scheme}: surface {ds:e}", c.name);
                worst = (worst.0.max(dv), worst.1.max(ds));
            }
        }
    }
    eprintln!("worst: vertices {:.2e}, surface {:.2e}", worst.0, worst.1);
}

#[test]
fn catmark_and_bilinear_on_non_manifold_quads_match_opensubdiv() {
    run_suite(false, &[SubdivScheme::Catmark, SubdivScheme::Bilinear]);
}

#[test]
fn loop_on_non_manifold_triangles_matches_opensubdiv() {
    run_suite(true, &[SubdivScheme::Loop]);
}

#[test]
fn catmark_on_non_manifold_triangles_matches_opensubdiv() {
    let c = &case_named(true, "chain of 2 edges, 3 sheets");
    for b in [
        BoundaryInterpolation::EdgeOnly,
        BoundaryInterpolation::EdgeAndCorner,
    ] {
        let (dv, ds, _) = measure(c, &with_boundary(SubdivScheme::Catmark, b));
        assert!(dv <= 1e-9 && ds <= 1e-9, "{dv:e} {ds:e}");
    }
}

/// Chaikin creasing with the semi-sharp edges of each non-manifold vertex
/// in one fan: the averaging sees the same edges in both.
#[test]
fn chaikin_with_semi_sharp_edges_in_one_fan_matches() {
    let c = case_named(false, "chain with semi-sharp creases");
    let scheme = SchemeOptions::default().with_crease_method(CreaseMethod::Chaikin);
    let (dv, ds, _) = measure(&c, &scheme);
    assert!(dv <= 1e-9 && ds <= 1e-9, "{dv:e} {ds:e}");
}

/// The copy without the non-manifold tags (split alone, boundary rules)
/// is far from OpenSubdiv: the suite's tolerance can fail.
#[test]
fn an_untagged_split_is_far_from_opensubdiv() {
    for c in cases(false).iter().take(5) {
        let sc = SplitControl::new(&c.soup, &[], &[], Path::new(&c.name)).unwrap();
        let (split, _, _) = split_non_manifold_polygons(&c.soup);
        let plain = ControlMesh::from_soup(&split).unwrap();
        assert_eq!(plain.num_vertices(), sc.manifold.num_vertices());
        let scheme = SchemeOptions::default().with_boundary(BoundaryInterpolation::EdgeOnly);
        let opts = EvalOptions::default().with_scheme(scheme.clone());
        let naive = make_evaluator(Backend::Rust, &plain, &opts).unwrap();
        let reference = osd_vertex_reference(&sc, &scheme, 8);
        let lim = naive.vertex_limits(plain.positions()).unwrap();
        let (_, _, origin) = split_non_manifold_polygons(&c.soup);
        let worst = lim
            .iter()
            .zip(&origin)
            .map(|(l, &o)| (l.position - reference[o as usize]).length())
            .fold(0.0, f64::max)
            / plain.bbox_diagonal();
        eprintln!("{}: untagged split {worst:.2e}", c.name);
        assert!(worst > 1e-3, "{}: {worst:e}", c.name);
    }
}

fn refusal(soup: &PolySoup, creases: &[(u32, u32, f64)], scheme: &SchemeOptions) -> String {
    let sc = SplitControl::new(soup, creases, &[], Path::new("nm.obj"));
    let e = match sc {
        Err(e) => e,
        Ok(sc) => sc.check_scheme(scheme).expect_err("must be refused"),
    };
    let msg = e.to_string();
    assert!(msg.contains("nm.obj"), "{msg}");
    msg
}

#[test]
fn what_splitting_cannot_reproduce_is_refused_by_name() {
    // A face whose repeated corners one fan joins: a triangle written as
    // a quad, glued to the triangle on its three vertices.
    let mut b = Builder::default();
    for p in [p3(0.0, 0.0, 0.0), p3(1.0, 0.0, 0.0), p3(0.0, 1.0, 0.0)] {
        b.vertex(p);
    }
    b.faces.extend([vec![0, 1, 2, 2], vec![1, 0, 2]]);
    let msg = refusal(&b.soup(), &[], &SchemeOptions::default());
    assert!(msg.contains("face 0") && msg.contains("one fan"), "{msg}");

    // A semi-sharp edge at a crease vertex of the fin: Chaikin refuses it
    // (the copies' sharpness follows uniform creasing's timing).
    let (b, mid, spoke) = fin_with_spokes();
    let chaikin = SchemeOptions::default().with_crease_method(CreaseMethod::Chaikin);
    let msg = refusal(&b.soup(), &[(mid, spoke[0], 1.5)], &chaikin);
    assert!(msg.contains(&format!("vertex {mid}")), "{msg}");

    // Chaikin with semi-sharp edges in two fans of one vertex: two cubes
    // touching at a corner, an edge of each creased there.
    let mut b = Builder::default();
    b.cube(DVec3::ZERO, 1.0, 1, false);
    b.cube(p3(1.0, 1.0, 1.0), 1.0, 1, false);
    let apex = b.id(p3(1.0, 1.0, 1.0));
    let fans = [
        (apex, b.id(p3(1.0, 1.0, 0.0)), 1.5),
        (apex, b.id(p3(2.0, 1.0, 1.0)), 2.5),
    ];
    let msg = refusal(&b.soup(), &fans, &chaikin);
    assert!(
        msg.contains(&format!("vertex {apex}")) && msg.contains("Chaikin"),
        "{msg}"
    );
    // ... which uniform creasing accepts, and matches; one fan's alone
    // Chaikin accepts too.
    let mut c = case("cubes on a vertex, creased", &b);
    c.creases = fans.to_vec();
    let (dv, ds, _) = measure(&c, &SchemeOptions::default());
    assert!(dv <= 1e-9 && ds <= 1e-9, "{dv:e} {ds:e}");
    c.creases.pop();
    let (dv, ds, _) = measure(&c, &chaikin);
    assert!(dv <= 1e-9 && ds <= 1e-9, "{dv:e} {ds:e}");
}

/// Two sheets along a chain of two edges and a quad spanning both: the
/// chain's middle is a crease vertex with a fan of one face.
fn fin_with_a_spanning_quad() -> Builder {
    let mut fin = Builder::default();
    fin.fin(2, 2, 1, 2.0, false);
    let ends = [p3(0.0, 0.0, 0.0), p3(2.0, 0.0, 0.0), p3(1.0, 0.0, 0.0)];
    let [a, b, mid] = ends.map(|p| fin.id(p));
    let x = fin.vertex(p3(1.0, -0.7, -0.6));
    fin.faces.push(vec![a, x, b, mid]);
    fin
}

/// A crease vertex whose fans have one face each (a bent chain a-b-c with
/// three quads (a, b, c, x_k)), or one of them: a copy of one face and two
/// edges is a topological corner, which "edge and corner" would sharpen,
/// while OpenSubdiv's vertex (more faces than edges) keeps the crease rule.
/// The exact evaluators get OpenSubdiv's decision on the file as tags
/// (`SplitControl::exact_copy_for`) and match in every boundary mode; left
/// to the copy's own topology, "edge and corner" is far off.
#[test]
fn a_crease_vertex_with_fans_of_one_face_matches() {
    let mut bent = Builder::default();
    let (a, m, c) = (p3(0.0, 0.0, 0.0), p3(1.0, 0.0, 0.0), p3(1.0, 1.0, 0.0));
    for k in 0..3 {
        let t = k as f64 * 2.0;
        let x = p3(0.2 * t.cos(), 0.5, 0.8 * t.sin());
        let f = vec![
            bent.vertex(a),
            bent.vertex(m),
            bent.vertex(c),
            bent.vertex(x),
        ];
        bent.faces.push(f);
    }
    let fin = fin_with_a_spanning_quad();
    let corner = with_boundary(SubdivScheme::Catmark, BoundaryInterpolation::EdgeAndCorner);
    for (name, b) in [("bent chain", &bent), ("fin with a spanning quad", &fin)] {
        let c = case(name, b);
        for bound in [
            BoundaryInterpolation::None,
            BoundaryInterpolation::EdgeOnly,
            BoundaryInterpolation::EdgeAndCorner,
        ] {
            for scheme in [SubdivScheme::Catmark, SubdivScheme::Bilinear] {
                let (dv, ds, _) = measure(&c, &with_boundary(scheme, bound));
                eprintln!("{name} {scheme:?} {bound:?}: {dv:.2e} {ds:.2e}");
                assert!(dv <= 1e-9 && ds <= 1e-9, "{name} {bound:?}: {dv:e} {ds:e}");
            }
        }
        // The copy as it is, under "edge and corner": sharpened corners.
        let sc = SplitControl::new(&c.soup, &[], &[], Path::new(name)).unwrap();
        let opts = EvalOptions::default().with_scheme(corner.clone());
        let plain = make_evaluator(Backend::Rust, &sc.manifold, &opts).unwrap();
        let exact = make_split_evaluator(Backend::Rust, &sc, &opts).unwrap();
        let locs = random_locations_with(&sc.manifold, &corner, 500, 3);
        let p = sc.manifold.positions();
        let worst = plain
            .evaluate(p, &locs)
            .unwrap()
            .iter()
            .zip(exact.evaluate(p, &locs).unwrap())
            .map(|(x, y)| (x.position - y.position).length())
            .fold(0.0, f64::max)
            / sc.manifold.bbox_diagonal();
        assert!(worst > 1e-3, "{name}: the copy alone is {worst:e} off");
    }
}

/// Semi-sharp edges at the crease vertex of a fin (OpenSubdiv counts them
/// with the crease edges of every fan): one edge, edges in two fans
/// running out together with different weights, one outliving the other,
/// with a corner sharpness on the vertex; each copy's vertex sharpness
/// (`mesh::nonmanifold::crease_copy_sharpness`) reproduces the corner rule
/// and its blend, to ≤ 1e-9 of the diagonal under every boundary rule.
#[test]
fn semi_sharp_edges_at_a_non_manifold_crease_vertex_match() {
    let (b, mid, spoke) = fin_with_spokes();
    type Creases = Vec<(u32, u32, f64)>;
    let configs: [(&str, Creases, f64); 4] = [
        ("one edge", vec![(mid, spoke[0], 1.5)], 0.0),
        (
            "two fans, 1.3 and 1.7",
            vec![(mid, spoke[0], 1.3), (mid, spoke[1], 1.7)],
            0.0,
        ),
        (
            "two fans, 1.3 and 2.6",
            vec![(mid, spoke[0], 1.3), (mid, spoke[2], 2.6)],
            0.0,
        ),
        (
            "three fans and a corner",
            vec![
                (mid, spoke[0], 0.4),
                (mid, spoke[1], 0.4),
                (mid, spoke[2], 0.9),
            ],
            1.2,
        ),
    ];
    let untagged = SplitControl::new(&b.soup(), &[], &[], Path::new("fin")).unwrap();
    for (name, creases, corner) in configs {
        let mut c = case(name, &b);
        c.creases = creases;
        if corner > 0.0 {
            c.corners = vec![(mid, corner)];
        }
        for bnd in [
            BoundaryInterpolation::EdgeOnly,
            BoundaryInterpolation::EdgeAndCorner,
        ] {
            let (dv, ds, _) = measure(&c, &with_boundary(SubdivScheme::Catmark, bnd));
            eprintln!("{name} {bnd:?}: vertices {dv:.2e}, surface {ds:.2e}");
            assert!(dv <= 1e-9 && ds <= 1e-9, "{name}: {dv:e} {ds:e}");
        }
        // The copies do carry a sharpness the file does not have.
        let sc = SplitControl::new(&c.soup, &c.creases, &c.corners, Path::new(name)).unwrap();
        assert!(sc.copies[mid as usize]
            .iter()
            .all(|&k| sc.manifold.vertex_sharpness(VertexId(k)) > 0.0));
        assert!(untagged.copies[mid as usize]
            .iter()
            .all(|&k| untagged.manifold.vertex_sharpness(VertexId(k)) == 0.0));
    }
}

fn write_obj(path: &Path, c: &Case) {
    let mut s = String::new();
    for p in &c.soup.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for f in c.soup.faces() {
        s += "f";
        for v in f {
            s += &format!(" {}", v + 1);
        }
        s += "\n";
    }
    for &(a, b, w) in &c.creases {
        s += &format!("t crease 2/1/0 {a} {b} {w}\n");
    }
    for &(v, w) in &c.corners {
        s += &format!("t corner 1/1/0 {v} {w}\n");
    }
    std::fs::write(path, s).unwrap();
}

/// `diff-limit` on non-manifold files with UVs (seams around every third
/// face, or one value per vertex) under the smooth face-varying modes:
/// OpenSubdiv evaluates them on the file's own topology, the Rust side on
/// the manifold copy, and they agree. With one value per vertex a crease
/// vertex is interior for OpenSubdiv ("boundaries" leaves it smooth), and
/// its fan of one face is no corner.
#[test]
fn cli_diff_limit_compares_uvs_on_the_files_own_topology() {
    let dir = tempfile::tempdir().unwrap();
    for (name, tris, seams) in [
        ("chain with semi-sharp creases", false, true),
        ("two cubes sharing a vertex", false, true),
        ("several components", false, true),
        ("two cubes sharing an edge", true, true),
        ("chain of 2 edges, 3 sheets", false, false),
        ("fin with a spanning quad", false, false),
    ] {
        let c = if name.starts_with("fin with") {
            case(name, &fin_with_a_spanning_quad())
        } else {
            case_named(tris, name)
        };
        let n = c.soup.positions.len();
        let p = dir.path().join("uv.obj");
        write_obj(&p, &c);
        let mut text = std::fs::read_to_string(&p).unwrap();
        let mut vts = String::new();
        for shift in [0.0, 0.37] {
            for q in &c.soup.positions {
                vts += &format!(
                    "vt {} {}\n",
                    0.7 * q.x + 0.2 * q.z + shift,
                    0.6 * q.y - 0.3 * q.z
                );
            }
        }
        let mut faces = String::new();
        for (f, face) in c.soup.faces().enumerate() {
            let off = if seams && f % 3 == 0 { n } else { 0 };
            faces += "f";
            for &v in face {
                faces += &format!(" {}/{}", v + 1, v as usize + 1 + off);
            }
            faces += "\n";
        }
        let body: String = text
            .lines()
            .filter(|l| !l.starts_with("f "))
            .map(|l| format!("{l}\n"))
            .collect();
        text = body + &vts + &faces;
        std::fs::write(&p, text).unwrap();
        let scheme = if tris { "loop" } else { "catmark" };
        let modes = [
            "none",
            "corners-only",
            "corners-plus1",
            "corners-plus2",
            "boundaries",
        ];
        for mode in modes {
            let o = subdfit(&[
                "diff-limit",
                p.to_str().unwrap(),
                "--scheme",
                scheme,
                "--fvar",
                mode,
                "--samples",
                "1500",
                "--json",
            ]);
            let err = String::from_utf8_lossy(&o.stderr);
            assert!(
                o.status.success(),
                "{name} {mode}: {err}\n{}",
                String::from_utf8_lossy(&o.stdout)
            );
            let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
            let fv = &j["face_varying"]["regular"];
            assert!(fv["count"].as_u64() > Some(500), "{name} {mode}: {j}");
            assert!(fv["position"].as_f64() < Some(1e-9), "{name} {mode}: {fv}");
        }
    }
}

fn subdfit(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(args)
        .output()
        .unwrap()
}

/// `diff-limit` passes on non-manifold files (quads and Loop), and
/// `limit` writes one row per vertex of the file, unused ones included.
#[test]
fn cli_diff_limit_accepts_non_manifold_files() {
    let dir = tempfile::tempdir().unwrap();
    for (c, scheme) in [
        (&case_named(false, "several components"), "catmark"),
        (
            &case_named(false, "chain with semi-sharp creases"),
            "catmark",
        ),
        (&case_named(true, "two cubes sharing an edge"), "loop"),
        (&case_named(false, "faces repeating a corner"), "catmark"),
        (&case_named(true, "faces repeating a corner"), "loop"),
    ] {
        let p = dir.path().join("nm.obj");
        write_obj(&p, c);
        let ps = p.to_str().unwrap();
        let o = subdfit(&[
            "diff-limit",
            ps,
            "--scheme",
            scheme,
            "--samples",
            "2000",
            "--json",
        ]);
        assert!(
            o.status.success(),
            "{}: {}\n{}",
            c.name,
            String::from_utf8_lossy(&o.stderr),
            String::from_utf8_lossy(&o.stdout)
        );
        let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert!(j["regular"]["count"].as_u64() > Some(100), "{j}");
        let out = dir.path().join("limits.csv");
        let o = subdfit(&[
            "limit",
            ps,
            "--scheme",
            scheme,
            "--backend",
            "rust",
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let rows = std::fs::read_to_string(&out).unwrap().lines().count() - 1;
        assert_eq!(rows, c.soup.positions.len(), "{}", c.name);
    }
    // A refusal is an error naming the file, not a panic.
    let mut b = Builder::default();
    for p in [p3(0.0, 0.0, 0.0), p3(1.0, 0.0, 0.0), p3(0.0, 1.0, 0.0)] {
        b.vertex(p);
    }
    b.faces.extend([vec![0, 1, 2, 2], vec![1, 0, 2]]);
    let p = dir.path().join("folded.obj");
    write_obj(&p, &case("folded", &b));
    let o = subdfit(&["diff-limit", p.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("folded.obj") && err.contains("face 0"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}
