//! Closed-form Catmull-Clark quantities read straight off a
//! [`ControlMesh`], for callers that need one value at a time inside a
//! sequential loop (the greedy layout's collapses, Fitmaps §3.3–3.4) where
//! preparing an evaluator per edit would cost more than the answer: the
//! one-step face, edge and vertex points (Catmull and Clark 1978, with
//! boundary edges as creases: cubic B-spline rule, corners fixed), the
//! limit at a quad's centre, and the limit normal at a vertex (Halstead et
//! al. 1993's limit tangents). Smooth rules only: no semi-sharp creases.
//! The general evaluator, for any location and semi-sharp features, is
//! [`super::RustEvaluator`].

use crate::mesh::{ControlMesh, FaceId, HalfedgeId, VertexId};
use crate::subdiv::LimitPoint;
use crate::DVec3;

/// The Catmull-Clark face point of `f` (the centroid of its corners).
pub fn centroid(k: &ControlMesh, f: FaceId) -> DVec3 {
    let mut c = DVec3::ZERO;
    let mut n = 0.0;
    for v in k.face_vertices(f) {
        c += k.position(v);
        n += 1.0;
    }
    c / n
}

/// The Catmull-Clark vertex point of `v` after one step (smooth rules;
/// boundary edges are creases: cubic B-spline rule, corners fixed).
pub fn vertex_point(k: &ControlMesh, v: VertexId) -> DVec3 {
    vertex_point_with(k, v, |f| centroid(k, f))
}

/// [`vertex_point`] with the face points from `face_point` (a caller that
/// evaluates many neighbouring faces passes cached centroids; the same
/// values give the same bits).
pub fn vertex_point_with(
    k: &ControlMesh,
    v: VertexId,
    mut face_point: impl FnMut(FaceId) -> DVec3,
) -> DVec3 {
    let p = k.position(v);
    let h0 = k.vertex_halfedge(v);
    if k.is_boundary_halfedge(h0) {
        if k.valence(v) == 2 {
            return p;
        }
        let next = k.position(k.head(h0));
        let prev = k.position(k.tail(k.prev(h0)));
        return (prev + 6.0 * p + next) / 8.0;
    }
    let mut q = DVec3::ZERO;
    let mut r = DVec3::ZERO;
    let mut n = 0.0;
    for h in k.outgoing(v) {
        q += face_point(k.face_of(h).expect("interior"));
        r += 0.5 * (p + k.position(k.head(h)));
        n += 1.0;
    }
    (q / n + 2.0 * r / n + (n - 3.0) * p) / n
}

/// The Catmull-Clark edge point of the edge of `h`.
pub fn edge_point(k: &ControlMesh, h: HalfedgeId) -> DVec3 {
    edge_point_with(k, h, |f| centroid(k, f))
}

/// [`edge_point`] with the face points from `face_point` (see
/// [`vertex_point_with`]).
pub fn edge_point_with(
    k: &ControlMesh,
    h: HalfedgeId,
    mut face_point: impl FnMut(FaceId) -> DVec3,
) -> DVec3 {
    let a = k.position(k.tail(h));
    let b = k.position(k.head(h));
    match (k.face_of(h), k.face_of(h.twin())) {
        (Some(f), Some(g)) => (a + b + face_point(f) + face_point(g)) / 4.0,
        _ => 0.5 * (a + b),
    }
}

/// The limit point and tangents at the centre of the quad `f`, in closed
/// form: one Catmull-Clark step makes the face point a regular (valence 4)
/// vertex whose neighbours are the four edge points `E_i` and whose
/// diagonals are the four vertex points `V_i`, so its limit is
/// `(16 F + 4 Σ E_i + Σ V_i) / 36` and its tangents are those of the
/// bicubic B-spline at a knot. Exact for any valences around the face.
pub fn face_centre_limit(k: &ControlMesh, f: FaceId) -> LimitPoint {
    let mut e = [DVec3::ZERO; 4];
    let mut vp = [DVec3::ZERO; 4];
    for (i, h) in k.face_halfedges(f).enumerate().take(4) {
        e[i] = edge_point(k, h);
        vp[i] = vertex_point(k, k.tail(h));
    }
    debug_assert_eq!(k.face_halfedges(f).count(), 4);
    face_centre_limit_from(centroid(k, f), &e, &vp)
}

/// [`face_centre_limit`] from the quad's face point `fp`, its edge points
/// `e` and its corners' vertex points `vp` (in the face's half-edge order,
/// starting at its first half-edge), for a caller that has them cached.
pub fn face_centre_limit_from(fp: DVec3, e: &[DVec3; 4], vp: &[DVec3; 4]) -> LimitPoint {
    let position =
        (16.0 * fp + 4.0 * (e[0] + e[1] + e[2] + e[3]) + vp[0] + vp[1] + vp[2] + vp[3]) / 36.0;
    // E_0 lies on edge (v0, v1), so E_0 − E_2 runs along "v" and E_1 − E_3
    // along "u" of the face; the B-spline derivative at a knot weighs the
    // middle row 4 and the corner rows 1 (scale irrelevant for the normal).
    let du = 4.0 * (e[1] - e[3]) + (vp[1] + vp[2] - vp[3] - vp[0]);
    let dv = 4.0 * (e[2] - e[0]) + (vp[2] + vp[3] - vp[0] - vp[1]);
    LimitPoint { position, du, dv }
}

/// Unit normal of the limit surface at the control vertex `v`: Halstead et
/// al.'s limit tangents for an interior vertex with quads; for a boundary
/// vertex the area-weighted normal of its control quads (a proxy, used only
/// as the direction of φ).
pub fn vertex_normal(k: &ControlMesh, v: VertexId) -> DVec3 {
    if !k.is_boundary_vertex(v) {
        let hs: Vec<_> = k.outgoing(v).collect();
        let ring = HalsteadRing::of(hs.len());
        let (mut t1, mut t2) = (DVec3::ZERO, DVec3::ZERO);
        for (i, &h) in hs.iter().enumerate() {
            let (c0, s0) = ring.cos_sin[i];
            let (c1, s1) = ring.cos_sin[i + 1];
            let e = k.position(k.head(h));
            let d = k.position(k.head(k.next(h)));
            t1 += ring.a * c0 * e + (c0 + c1) * d;
            t2 += ring.a * s0 * e + (s0 + s1) * d;
        }
        let nrm = t1.cross(t2).normalize_or_zero();
        if nrm != DVec3::ZERO {
            return nrm;
        }
    }
    let mut nrm = DVec3::ZERO;
    for f in k.vertex_faces(v) {
        let q = quad_positions(k, f);
        nrm += (q[2] - q[0]).cross(q[3] - q[1]);
    }
    nrm.normalize_or_zero()
}

/// The valence-`n` constants of [`vertex_normal`]'s Halstead tangents:
/// `a` and `(cos θ_j, sin θ_j)`, `θ_j = 2πj / n` for `j = 0..=n`. The greedy
/// simplification asks for a vertex normal tens of times per collapse, and
/// the sines and cosines had been a tenth of its own time; the table holds
/// the same f64 values the expressions give, so normals are bit-identical.
#[derive(Clone)]
struct HalsteadRing {
    a: f64,
    cos_sin: Vec<(f64, f64)>,
}

/// Valences with a precomputed [`HalsteadRing`]; larger ones compute theirs.
const HALSTEAD_TABLE: usize = 32;

impl HalsteadRing {
    fn new(valence: usize) -> HalsteadRing {
        let n = valence as f64;
        let c1 = (2.0 * std::f64::consts::PI / n).cos();
        let a = 1.0 + c1 + (std::f64::consts::PI / n).cos() * (2.0 * (9.0 + c1)).sqrt();
        let cos_sin = (0..=valence)
            .map(|j| {
                let th = 2.0 * std::f64::consts::PI * j as f64 / n;
                (th.cos(), th.sin())
            })
            .collect();
        HalsteadRing { a, cos_sin }
    }

    fn of(valence: usize) -> std::borrow::Cow<'static, HalsteadRing> {
        static TABLE: std::sync::OnceLock<Vec<HalsteadRing>> = std::sync::OnceLock::new();
        if valence >= HALSTEAD_TABLE {
            return std::borrow::Cow::Owned(HalsteadRing::new(valence));
        }
        let t = TABLE.get_or_init(|| (0..HALSTEAD_TABLE).map(HalsteadRing::new).collect());
        std::borrow::Cow::Borrowed(&t[valence])
    }
}

/// The four corner positions of the quad `f`, from its first half-edge.
fn quad_positions(k: &ControlMesh, f: FaceId) -> [DVec3; 4] {
    let h0 = k.face_halfedge(f);
    let h1 = k.next(h0);
    let h2 = k.next(h1);
    let h3 = k.next(h2);
    [h0, h1, h2, h3].map(|h| k.position(k.tail(h)))
}
