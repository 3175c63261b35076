//! Differential testing of two limit evaluators: the machinery behind
//! `subdfit diff-limit` and the differential tests, in one place so that the
//! tool and the tests measure the same thing.
//!
//! Deviations are relative to the control mesh's bounding-box diagonal;
//! normal deviations are angles in radians. Locations closer than a margin
//! to an irregular corner are reported apart: there OpenSubdiv's end-cap
//! patches only approximate the limit (and parametrise it differently), so
//! the two evaluators legitimately disagree by an amount that shrinks as the
//! isolation level grows.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::error::Result;
use crate::mesh::{
    BoundaryInterpolation, ControlMesh, FaceId, SchemeOptions, SubdivScheme, VertexId,
    INFINITELY_SHARP,
};
use crate::subdiv::{
    known_differences_with, KnownDifference, LimitEvaluator, LimitPoint, SurfaceLocation,
};
use crate::DVec3;

/// The worst deviation in one category and where it happened.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Worst {
    /// Number of samples compared.
    pub count: usize,
    /// Worst position deviation, relative to the bounding-box diagonal.
    pub position: f64,
    /// Where the worst position deviation happened.
    pub position_at: String,
    /// Worst angle between unit normals, radians.
    pub normal: f64,
    pub normal_at: String,
}

impl Worst {
    fn add(&mut self, at: impl Fn() -> String, dp: f64, dn: f64) {
        self.count += 1;
        if dp > self.position || (dp.is_nan() && !self.position.is_nan()) {
            self.position = dp;
            self.position_at = at();
        }
        if dn > self.normal || (dn.is_nan() && !self.normal.is_nan()) {
            self.normal = dn;
            self.normal_at = at();
        }
    }
}

/// Result of [`compare`].
#[derive(Clone, Debug, Default, Serialize)]
pub struct DiffReport {
    pub backends: [String; 2],
    /// The scheme options both evaluators followed.
    pub scheme: SchemeOptions,
    pub bbox_diagonal: f64,
    /// At control vertices, known differences excluded.
    pub vertices: Worst,
    /// At the known differences (see [`known_differences`]).
    pub known: Worst,
    pub known_differences: Vec<KnownDifference>,
    /// At locations at least `margin` away (in u or v) from every irregular corner.
    pub regular: Worst,
    /// At locations within `margin` of an irregular corner.
    pub near_irregular: Worst,
    /// At locations where the surface has no tangent plane in either
    /// evaluator ([`singular_at`]): positions compared, normals not.
    pub singular: Worst,
    pub margin: f64,
    /// Normals at control vertices OpenSubdiv evaluates on its patches
    /// ([`crate::subdiv::osd::patch_evaluated_vertices`]); their positions
    /// are in `vertices`.
    pub patch_vertices: Worst,
    /// OpenSubdiv's known approximations and deliberate differences, each
    /// with its measured size: reported, never a failure by themselves.
    pub approximations: Vec<Approximation>,
}

/// One known way OpenSubdiv departs from the exact limit, as measured.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Approximation {
    pub name: &'static str,
    /// Samples (or sharpness values) concerned.
    pub count: usize,
    /// Worst position deviation there, relative to the diagonal.
    pub position: f64,
    /// Worst normal deviation there, radians.
    pub normal: f64,
    pub why: String,
}

/// Largest rounding of a sharpness value to f32 and how many values are
/// not exact there.
fn f32_sharpness_rounding(mesh: &ControlMesh) -> (usize, f64) {
    let all = mesh
        .creases()
        .into_iter()
        .map(|c| c.2)
        .chain(mesh.corners().into_iter().map(|c| c.1));
    all.map(|s| (s - s as f32 as f64).abs())
        .filter(|&d| d > 0.0)
        .fold((0, 0.0), |(n, m), d| (n + 1, f64::max(m, d)))
}

impl DiffReport {
    fn summarise_approximations(&mut self, mesh: &ControlMesh) {
        let from = |name, w: &Worst, why: &str| Approximation {
            name,
            count: w.count,
            position: w.position,
            normal: w.normal,
            why: why.to_string(),
        };
        let mut out = vec![
            from(
                "end caps near irregular corners",
                &self.near_irregular,
                "OpenSubdiv covers the last isolation level around an irregular vertex with \
                 Gregory patches, which approximate (and reparametrise) the limit; shrinks as \
                 --isolation grows",
            ),
            from(
                "end caps at semi-sharp control vertices",
                &self.patch_vertices,
                "a vertex whose semi-sharp feature is still sharp at level 1 is evaluated on \
                 OpenSubdiv's patches; where it is extraordinary once the feature runs out, \
                 that is an end cap: its tangent plane is approximate, and so is its position \
                 where the vertex is irregular (shrinks as --isolation grows)",
            ),
            from(
                "deliberate differences at control vertices",
                &self.known,
                "interior valence-2 vertices (corner mask), darts (smooth masks) and boundary \
                 tangent masks of OpenSubdiv are not the exact limit; listed per vertex",
            ),
        ];
        let (n, r) = f32_sharpness_rounding(mesh);
        out.push(Approximation {
            name: "float32 sharpness",
            count: n,
            position: 0.0,
            normal: 0.0,
            why: format!(
                "OpenSubdiv stores sharpness as f32 ({n} value(s) here are not exact, rounded \
                 by up to {r:.1e}); the Rust evaluator follows the same f32 values and rules, \
                 so the backends agree; the size given is how far that (f32) surface is from \
                 the one with the sharpness as written"
            ),
        });
        self.approximations = out;
    }

    /// Records the measured effect of f32 sharpness
    /// ([`f32_sharpness_effect`]) as that approximation's size.
    pub fn set_f32_effect(&mut self, position: f64, normal: f64) {
        if let Some(a) = self
            .approximations
            .iter_mut()
            .find(|a| a.name == "float32 sharpness")
        {
            a.position = position;
            a.normal = normal;
        }
    }
}

/// How far the surface with OpenSubdiv's f32 sharpness is from the one with
/// the sharpness as written: the Rust evaluator both ways, at the control
/// vertices and `locations` (worst position relative to the diagonal, worst
/// normal angle). Zero when every sharpness is exact in f32.
pub fn f32_sharpness_effect(
    mesh: &ControlMesh,
    options: &crate::subdiv::EvalOptions,
    locations: &[SurfaceLocation],
) -> Result<(f64, f64)> {
    use crate::subdiv::{make_evaluator, Backend};
    if f32_sharpness_rounding(mesh).0 == 0 || options.scheme.scheme == SubdivScheme::Bilinear {
        return Ok((0.0, 0.0));
    }
    let a = make_evaluator(
        Backend::Rust,
        mesh,
        &options.clone().with_exact_sharpness(false),
    )?;
    let b = make_evaluator(
        Backend::Rust,
        mesh,
        &options.clone().with_exact_sharpness(true),
    )?;
    let p = mesh.positions();
    let diag = mesh.bbox_diagonal().max(f64::MIN_POSITIVE);
    let mut pairs = a
        .vertex_limits(p)?
        .into_iter()
        .zip(b.vertex_limits(p)?)
        .collect::<Vec<_>>();
    pairs.extend(
        a.evaluate(p, locations)?
            .into_iter()
            .zip(b.evaluate(p, locations)?),
    );
    Ok(pairs.iter().fold((0.0f64, 0.0f64), |(dp, dn), (x, y)| {
        (
            dp.max((x.position - y.position).length() / diag),
            dn.max(angle_between(x.normal(), y.normal())),
        )
    }))
}

/// Whether the surface at `x` has no tangent plane: the parallelogram of
/// its derivatives is narrower than 1e-12 of the bounding-box diagonal
/// (`|∂u × ∂v| / max(|∂u|, |∂v|)`). That is where a face collapses to a
/// point or a curve (OpenSubdiv's shapes have a quad whose four corners are
/// one vertex, and quads of two repeated corners): the derivative across
/// is rounding noise there, 1e-16 of the diagonal or less, while a sample
/// a relative 1e-6 away from a degenerate edge still has a width near 1e-6.
pub fn singular_at(x: &LimitPoint, diag: f64) -> bool {
    let longest = x.du.length().max(x.dv.length());
    x.du.cross(x.dv).length() <= 1e-12 * diag * longest
}

/// Angle between two vectors' directions (0 when both are zero).
pub fn angle_between(a: DVec3, b: DVec3) -> f64 {
    let (a, b) = (a.normalize_or_zero(), b.normalize_or_zero());
    if a == DVec3::ZERO && b == DVec3::ZERO {
        return 0.0;
    }
    // atan2 of |a×b| and a·b stays accurate for tiny angles, unlike acos.
    a.cross(b).length().atan2(a.dot(b))
}

/// Whether patches around `v` are irregular for a feature-adaptive
/// evaluator (extraordinary valence, darts, uneven creases, corners with a
/// face count other than one): the places where end caps are used.
pub fn is_irregular_vertex(mesh: &ControlMesh, v: VertexId) -> bool {
    is_irregular_vertex_with(mesh, &SchemeOptions::default(), v)
}

/// [`is_irregular_vertex`] under `scheme`: without corner sharpening
/// (boundary "edge only" or "none"), a boundary vertex with one face is a
/// crease vertex of valence 2, irregular.
pub fn is_irregular_vertex_with(mesh: &ControlMesh, scheme: &SchemeOptions, v: VertexId) -> bool {
    if scheme.scheme == SubdivScheme::Bilinear {
        return false; // every patch is an exact bilinear one
    }
    if scheme.scheme == SubdivScheme::Loop {
        return is_irregular_loop_vertex(mesh, v);
    }
    let valence = mesh.valence(v);
    if scheme.boundary != BoundaryInterpolation::EdgeAndCorner
        && mesh.is_boundary_vertex(v)
        && valence == 2
    {
        return true;
    }
    let sharp: Vec<f64> = mesh
        .outgoing(v)
        .filter(|&h| !mesh.is_boundary_edge(h.edge()))
        .map(|h| mesh.edge_sharpness(h.edge()))
        .filter(|&s| s > 0.0)
        .collect();
    if mesh.vertex_sharpness(v) > 0.0 && !(mesh.is_boundary_vertex(v) && valence == 2) {
        return true;
    }
    if mesh.is_boundary_vertex(v) {
        return !sharp.is_empty() || !(valence == 2 || valence == 3);
    }
    match sharp.len() {
        0 => valence != 4,
        2 if sharp.iter().all(|&s| s >= INFINITELY_SHARP) => {
            // A regular crease splits the ring into two halves of two faces.
            let hs: Vec<_> = mesh.outgoing(v).collect();
            let k: Vec<usize> = (0..hs.len())
                .filter(|&i| mesh.edge_sharpness(hs[i].edge()) > 0.0)
                .collect();
            valence != 4 || k[1] - k[0] != 2
        }
        _ => true,
    }
}

/// Loop: regular vertices have six faces and no sharpness, or sit on a
/// boundary or infinitely sharp crease with three faces on each side (the
/// box-spline patches of `loop_scheme::patch`); every other vertex, corners
/// included, is irregular.
fn is_irregular_loop_vertex(mesh: &ControlMesh, v: VertexId) -> bool {
    let hs: Vec<_> = mesh.outgoing(v).collect();
    let sharp: Vec<usize> = (0..hs.len())
        .filter(|&i| mesh.is_boundary_edge(hs[i].edge()) || mesh.edge_sharpness(hs[i].edge()) > 0.0)
        .collect();
    if mesh.vertex_sharpness(v) > 0.0
        || sharp.iter().any(|&i| {
            !mesh.is_boundary_edge(hs[i].edge())
                && mesh.edge_sharpness(hs[i].edge()) < INFINITELY_SHARP
        })
    {
        return true;
    }
    if mesh.is_boundary_vertex(v) {
        return hs.len() != 4 || sharp.len() != 2;
    }
    match sharp.len() {
        0 => hs.len() != 6,
        2 => hs.len() != 6 || sharp[1] - sharp[0] != 3,
        _ => true,
    }
}

/// Whether the limit surface has one normal at `v`: not on an infinitely
/// sharp crease (two or more such edges) nor at an infinitely sharp corner
/// (boundary corners included).
pub fn normal_is_defined(mesh: &ControlMesh, v: VertexId) -> bool {
    normal_is_defined_with(mesh, &SchemeOptions::default(), v)
}

/// [`normal_is_defined`] under `scheme` (a boundary vertex with one face is
/// a corner only when boundary corners are sharpened).
pub fn normal_is_defined_with(mesh: &ControlMesh, scheme: &SchemeOptions, v: VertexId) -> bool {
    if scheme.scheme == SubdivScheme::Bilinear {
        return false; // a polyhedral surface has no normal at its vertices
    }
    let sharpened = scheme.boundary == BoundaryInterpolation::EdgeAndCorner;
    let sharp = mesh
        .outgoing(v)
        .filter(|&h| {
            !mesh.is_boundary_edge(h.edge()) && mesh.edge_sharpness(h.edge()) >= INFINITELY_SHARP
        })
        .count();
    let boundary_corner = sharpened && mesh.is_boundary_vertex(v) && mesh.valence(v) == 2;
    let corner = mesh.vertex_sharpness(v) >= INFINITELY_SHARP;
    let sharp_on_boundary = mesh.is_boundary_vertex(v) && sharp > 0;
    sharp < 2 && !(boundary_corner || corner || sharp_on_boundary)
}

/// Corners of the sub-quad of `loc` that are irregular, as `(u, v)` corners
/// of the unit square. A non-quad face's centre is always irregular.
fn irregular_corners(
    mesh: &ControlMesh,
    irregular: &[bool],
    loc: &SurfaceLocation,
    loop_tris: bool,
) -> Vec<(f64, f64)> {
    let verts: Vec<VertexId> = mesh.face_vertices(loc.face).collect();
    let mut out = Vec::new();
    if loop_tris {
        // A Loop triangle: (0,0), (1,0), (0,1) at its corners.
        for (k, c) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)].into_iter().enumerate() {
            if irregular[verts[k].idx()] {
                out.push(c);
            }
        }
    } else if verts.len() == 4 {
        for (k, c) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
            .into_iter()
            .enumerate()
        {
            if irregular[verts[k].idx()] {
                out.push(c);
            }
        }
    } else {
        // Sub-quad k: (0,0) at corner k, (1,1) at the face centre.
        if irregular[verts[loc.sub as usize].idx()] {
            out.push((0.0, 0.0));
        }
        out.push((1.0, 1.0));
    }
    out
}

/// `n` random locations, uniform in `(u, v)` over uniformly chosen
/// sub-quads (ptex faces), from a fixed seed.
pub fn random_locations(mesh: &ControlMesh, n: usize, seed: u64) -> Vec<SurfaceLocation> {
    random_locations_with(mesh, &SchemeOptions::default(), n, seed)
}

/// [`random_locations`] on the faces that have a limit surface under
/// `scheme` (none if every face is a hole).
pub fn random_locations_with(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    n: usize,
    seed: u64,
) -> Vec<SurfaceLocation> {
    let holes = scheme.effective_holes(mesh);
    let mut ptex: Vec<(FaceId, u16)> = Vec::new();
    for f in mesh.faces().filter(|f| !holes[f.idx()]) {
        let k = mesh.face_size(f);
        if k == 4 || scheme.scheme == SubdivScheme::Loop {
            ptex.push((f, 0));
        } else {
            ptex.extend((0..k as u16).map(|s| (f, s)));
        }
    }
    if ptex.is_empty() {
        return Vec::new();
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let (face, sub) = ptex[rng.gen_range(0..ptex.len())];
            let (mut u, mut v) = (rng.gen::<f64>(), rng.gen::<f64>());
            if scheme.scheme == SubdivScheme::Loop && u + v > 1.0 {
                // Fold the square onto the triangle: uniform over it.
                (u, v) = (1.0 - u, 1.0 - v);
            }
            SurfaceLocation { face, sub, u, v }
        })
        .collect()
}

/// Locations within `margin` (in u and v) of irregular corners: `per_corner`
/// for every (face, corner) pair that touches one, log-uniform in distance
/// from 1e-6·margin to margin so the end-cap region is covered at every
/// scale. Uniform random locations rarely land there.
pub fn near_irregular_locations(
    mesh: &ControlMesh,
    per_corner: usize,
    margin: f64,
    seed: u64,
) -> Vec<SurfaceLocation> {
    near_irregular_locations_with(mesh, &SchemeOptions::default(), per_corner, margin, seed)
}

/// [`near_irregular_locations`] under `scheme` (holes skipped).
pub fn near_irregular_locations_with(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    per_corner: usize,
    margin: f64,
    seed: u64,
) -> Vec<SurfaceLocation> {
    let irregular: Vec<bool> = mesh
        .vertices()
        .map(|v| is_irregular_vertex_with(mesh, scheme, v))
        .collect();
    let holes = scheme.effective_holes(mesh);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::new();
    for face in mesh.faces().filter(|f| !holes[f.idx()]) {
        let subs = if mesh.face_size(face) == 4 || scheme.scheme == SubdivScheme::Loop {
            1
        } else {
            mesh.face_size(face) as u16
        };
        for sub in 0..subs {
            let probe = SurfaceLocation {
                face,
                sub,
                u: 0.5,
                v: 0.5,
            };
            let loop_tris = scheme.scheme == SubdivScheme::Loop;
            for (cu, cv) in irregular_corners(mesh, &irregular, &probe, loop_tris) {
                for _ in 0..per_corner {
                    let mut d = || margin * 10f64.powf(-6.0 * rng.gen::<f64>());
                    let (du, dv) = (d(), d());
                    // Towards the inside of the triangle or square.
                    let (u, v) = if loop_tris && cu == 1.0 {
                        (1.0 - du - dv, dv)
                    } else if loop_tris && cv == 1.0 {
                        (du, 1.0 - du - dv)
                    } else {
                        ((cu - du).abs(), (cv - dv).abs())
                    };
                    out.push(SurfaceLocation { face, sub, u, v });
                }
            }
        }
    }
    out
}

/// Compares `a` and `b` at every control vertex and at `locations`.
pub fn compare(
    mesh: &ControlMesh,
    a: &dyn LimitEvaluator,
    b: &dyn LimitEvaluator,
    locations: &[SurfaceLocation],
    margin: f64,
) -> Result<DiffReport> {
    compare_with(mesh, &SchemeOptions::default(), a, b, locations, margin)
}

/// [`compare`] of two evaluators built with `scheme`: vertices whose faces
/// are all holes have no surface and are not compared.
pub fn compare_with(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    a: &dyn LimitEvaluator,
    b: &dyn LimitEvaluator,
    locations: &[SurfaceLocation],
    margin: f64,
) -> Result<DiffReport> {
    compare_with_known(mesh, scheme, a, b, locations, margin, Vec::new())
}

/// [`compare_with`] with known differences besides
/// [`known_differences_with`]'s (a non-manifold mesh's copies,
/// [`crate::subdiv::split_known_differences`]).
pub fn compare_with_known(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    a: &dyn LimitEvaluator,
    b: &dyn LimitEvaluator,
    locations: &[SurfaceLocation],
    margin: f64,
    extra_known: Vec<KnownDifference>,
) -> Result<DiffReport> {
    let diag = mesh.bbox_diagonal().max(f64::MIN_POSITIVE);
    let mut known = known_differences_with(mesh, scheme);
    known.extend(extra_known);
    let holes = scheme.effective_holes(mesh);
    let on_patches = crate::subdiv::osd::patch_evaluated_vertices(mesh, scheme);
    // 0: no known difference, 1: normal only, 2: position and normal.
    let mut is_known = vec![0u8; mesh.num_vertices()];
    for k in &known {
        let level = if k.normal_only { 1 } else { 2 };
        let at = &mut is_known[k.vertex as usize];
        *at = (*at).max(level);
    }
    let mut report = DiffReport {
        backends: [a.name().to_string(), b.name().to_string()],
        scheme: scheme.clone(),
        bbox_diagonal: diag,
        known_differences: known,
        margin,
        ..Default::default()
    };
    let irregular: Vec<bool> = mesh
        .vertices()
        .map(|v| is_irregular_vertex_with(mesh, scheme, v))
        .collect();
    let p = mesh.positions();
    let (va, vb) = (a.vertex_limits(p)?, b.vertex_limits(p)?);
    for (i, (x, y)) in va.iter().zip(&vb).enumerate() {
        if mesh
            .vertex_faces(VertexId(i as u32))
            .all(|f| holes[f.idx()])
        {
            continue;
        }
        let dp = (x.position - y.position).length() / diag;
        // On an infinitely sharp crease or corner the normal jumps: each
        // evaluator picks one side, so there is nothing to compare.
        let dn = if normal_is_defined_with(mesh, scheme, VertexId(i as u32)) {
            angle_between(x.normal(), y.normal())
        } else {
            0.0
        };
        let at = || format!("vertex {i}");
        match is_known[i] {
            // Irregular there (a boundary vertex of one face under "edge
            // only", say): the patch at the vertex is an end cap, whose
            // corner is approximate too (OpenSubdiv's catmark_edgeonly:
            // 1.7e-2 of the diagonal at isolation 2, 2.5e-7 at 10).
            0 if on_patches[i] && irregular[i] => report.patch_vertices.add(at, dp, dn),
            0 if on_patches[i] => {
                report.vertices.add(at, dp, 0.0);
                report.patch_vertices.add(at, 0.0, dn);
            }
            0 => report.vertices.add(at, dp, dn),
            1 => {
                report.vertices.add(at, dp, 0.0);
                report.known.add(at, 0.0, dn);
            }
            _ => report.known.add(at, dp, dn),
        }
    }
    let (la, lb): (Vec<LimitPoint>, Vec<LimitPoint>) =
        (a.evaluate(p, locations)?, b.evaluate(p, locations)?);
    for (i, loc) in locations.iter().enumerate() {
        let (x, y) = (la[i], lb[i]);
        let dp = (x.position - y.position).length() / diag;
        if singular_at(&x, diag) && singular_at(&y, diag) {
            let at = || format!("face {} sub {}", loc.face.0, loc.sub);
            report.singular.add(at, dp, 0.0);
            continue;
        }
        let dn = angle_between(x.normal(), y.normal());
        let near = irregular_corners(mesh, &irregular, loc, scheme.scheme == SubdivScheme::Loop)
            .iter()
            .any(|&(cu, cv)| (loc.u - cu).abs() < margin && (loc.v - cv).abs() < margin);
        let at = || {
            format!(
                "face {} sub {} (u, v) = ({:.6}, {:.6})",
                loc.face.0, loc.sub, loc.u, loc.v
            )
        };
        if near {
            report.near_irregular.add(at, dp, dn);
        } else {
            report.regular.add(at, dp, dn);
        }
    }
    report.summarise_approximations(mesh);
    Ok(report)
}

/// Result of [`compare_fvar`]: face-varying values (UVs) of two evaluators.
/// `position` is the UV deviation and `normal` the derivative deviation
/// (`|Δ∂/∂u| + |Δ∂/∂v|`), both relative to the channel's UV extent.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FVarDiffReport {
    pub uv_extent: f64,
    /// Away (by the margin) from irregular corners of the face-varying
    /// mesh: seam junctions, extraordinary values, darts.
    pub regular: Worst,
    /// Near them, where OpenSubdiv's face-varying end caps approximate.
    pub near_irregular: Worst,
}

/// Compares face-varying evaluators `a` and `b` at `locations`; the
/// irregular corners are those of `fvar` (its [`is_irregular_vertex_with`]
/// under `fvar`'s own rules), the face-varying mesh of the channel.
pub fn compare_fvar(
    fvar: &crate::subdiv::fvar::FVarMesh,
    a: &dyn crate::subdiv::fvar::FVarEvaluator,
    b: &dyn crate::subdiv::fvar::FVarEvaluator,
    locations: &[SurfaceLocation],
    margin: f64,
) -> Result<FVarDiffReport> {
    let m = &fvar.mesh;
    let (lo, hi) = m.bbox();
    let extent = (hi - lo).length().max(f64::MIN_POSITIVE);
    let irregular: Vec<bool> = m
        .vertices()
        .map(|v| is_irregular_vertex_with(m, &fvar.scheme, v))
        .collect();
    let loop_tris = fvar.scheme.scheme == SubdivScheme::Loop
        || (fvar.kind == crate::subdiv::fvar::FVarKind::Barycentric);
    let (la, lb) = (a.evaluate(locations)?, b.evaluate(locations)?);
    let mut r = FVarDiffReport {
        uv_extent: extent,
        ..Default::default()
    };
    for (i, loc) in locations.iter().enumerate() {
        let (x, y) = (la[i], lb[i]);
        let dp = (x.position - y.position).length() / extent;
        let dd = ((x.du - y.du).length() + (x.dv - y.dv).length()) / extent;
        let near = irregular_corners(m, &irregular, loc, loop_tris)
            .iter()
            .any(|&(cu, cv)| (loc.u - cu).abs() < margin && (loc.v - cv).abs() < margin);
        let at = || {
            format!(
                "face {} sub {} (u, v) = ({:.6}, {:.6})",
                loc.face.0, loc.sub, loc.u, loc.v
            )
        };
        if near {
            r.near_irregular.add(at, dp, dd);
        } else {
            r.regular.add(at, dp, dd);
        }
    }
    Ok(r)
}

impl std::fmt::Display for DiffReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} vs {} (deviations relative to the bbox diagonal {:.6e}; normals in rad)",
            self.backends[0], self.backends[1], self.bbox_diagonal
        )?;
        writeln!(f, "  scheme: {}", self.scheme)?;
        let line = |f: &mut std::fmt::Formatter<'_>, name: &str, w: &Worst| {
            if w.count == 0 {
                return writeln!(f, "  {name:<28} (none)");
            }
            writeln!(
                f,
                "  {name:<28} n={:<7} position {:.3e} at {}\n  {:<28}           normal   {:.3e} at {}",
                w.count, w.position, w.position_at, "", w.normal, w.normal_at
            )
        };
        line(f, "control vertices", &self.vertices)?;
        line(f, "random locations", &self.regular)?;
        let near = format!("near irregular (< {})", self.margin);
        line(f, &near, &self.near_irregular)?;
        line(f, "patch-evaluated vertices", &self.patch_vertices)?;
        if self.singular.count > 0 {
            line(f, "no tangent plane", &self.singular)?;
        }
        if !self.known_differences.is_empty() {
            line(f, "known differences", &self.known)?;
            for k in &self.known_differences {
                writeln!(f, "    vertex {}: {}", k.vertex, k.reason)?;
            }
        }
        writeln!(f, "  OpenSubdiv's approximations (reported, not failures):")?;
        for a in &self.approximations {
            writeln!(
                f,
                "    {}: n={} position {:.3e} normal {:.3e} rad ({})",
                a.name, a.count, a.position, a.normal, a.why
            )?;
        }
        Ok(())
    }
}
