//! Face-varying data (UVs) evaluated exactly, under each of OpenSubdiv's
//! six `Sdc::Options::FVarLinearInterpolation` modes.
//!
//! OpenSubdiv refines face-varying values on the vertex topology, with
//! each value at a seam vertex (a vertex whose faces use more than one
//! value, or that ends a seam) treated as a crease along the seam, or as a
//! corner, by rules that depend on the mode (`Vtr::FVarLevel::
//! completeTopologyFromFaceValues` and `gatherValueSpans`, 3.5). The same
//! numbers come out of subdividing the *face-varying mesh* as if it were a
//! control mesh of its own: one vertex per (vertex, value) pair, the faces
//! of the control mesh (same ids, same corner order, so a location
//! `(face, sub, u, v)` means the same point), seams as boundary edges, the
//! interior edges keeping the control mesh's sharpness, and the vertex
//! sharpness of each value set as OpenSubdiv sets its value tag:
//!
//! - a vertex whose values all match its faces (no seam, and not made a
//!   seam by the mode, below) follows the vertex rules: its own sharpness,
//!   and an "edge and corner" boundary's corners;
//! - at a seam vertex every value is a corner if the mode is "boundaries"
//!   (or "all"), if the vertex is infinitely sharp, if "corners +1" or "+2"
//!   and it has more than two values, or if "corners +2" / "boundaries" and
//!   it is an interior vertex with one value (the end of a seam, a dart);
//!   with two values under "+1"/"+2", both are corners if either's faces are
//!   not one fan (a "disjoint" span) and, under "+2", if either is in one
//!   face only;
//! - otherwise a value is a corner when its faces do not form one fan, or
//!   contain an infinitely sharp edge, or (all modes but "none") it is in
//!   one face only; any other value is a crease along its two seam edges
//!   (the face-varying mesh's boundary rule), semi-sharp with the vertex's
//!   own sharpness and its fan's semi-sharp edges;
//! - values are counted as OpenSubdiv numbers them ([`osd_siblings`]):
//!   around a vertex whose values alternate (a UV bow-tie), the second
//!   value's spans are two values, smooth creases, and only the first's
//!   is one disjoint value, a corner;
//! - geometric boundary vertices are seam vertices too under "boundaries",
//!   and geometric corners under every mode but "none" when the boundary
//!   interpolation leaves corners smooth.
//!
//! "All" and the bilinear scheme interpolate linearly: the face-varying mesh
//! is evaluated as a bilinear one (Loop's triangles: barycentric).
//!
//! - under "corners +1/+2", a seam vertex with two values of which only
//!   one has semi-sharp edges: the other is "dependent sharp", a corner
//!   while the first is semi-sharp and a crease after, blended by the
//!   first's weight; under uniform creasing a vertex sharpness on it does
//!   exactly that ([`dependent_sharpness`]).
//!
//! Two combinations OpenSubdiv handles by looking across a seam are refused
//! with an error naming the vertex rather than answered approximately:
//! Chaikin creasing with semi-sharp edges on both sides of a seam (its
//! sharpness averaging sees all of them), and dependent sharpness under
//! Chaikin creasing (its timing follows Chaikin's averaged sharpness).

use std::collections::HashMap;

use crate::error::{Error, Result};
use crate::mesh::{
    split_non_manifold_polygons, BoundaryInterpolation, ControlMesh, CreaseMethod, FVarChannel,
    FVarLinear, FaceId, PolySoup, SchemeOptions, SubdivScheme, VertexId, INFINITELY_SHARP,
};
use crate::subdiv::{check_locations_for, SurfaceLocation};
use crate::subdiv::{make_evaluator, Backend, EvalOptions, LimitEvaluator, LimitPoint};
use crate::DVec3;

/// How the face-varying mesh is evaluated.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum FVarKind {
    /// By the control mesh's scheme, with the value sharpness of the module
    /// doc.
    Smooth,
    /// Linearly: bilinear patches (Catmark's and bilinear's faces).
    Bilinear,
    /// Linearly on Loop's triangles: barycentric.
    Barycentric,
}

/// The face-varying mesh of a channel (module doc): positions `(u, v, 0)`.
#[derive(Clone, Debug)]
pub struct FVarMesh {
    pub mesh: ControlMesh,
    /// The rules it is evaluated with (the control mesh's, with boundary
    /// "edge only" and the control mesh's holes as tags).
    pub scheme: SchemeOptions,
    pub kind: FVarKind,
    /// Per vertex of `mesh`: the control-mesh vertex it is a value of.
    pub vertex_of: Vec<u32>,
}

/// Per vertex of the face-varying mesh: what decides its sharpness.
#[derive(Copy, Clone, Default)]
struct ValueSpan {
    /// Its faces are not one fan, or hold an infinitely sharp edge.
    disjoint: bool,
    faces: usize,
    semi_sharp: bool,
}

/// Builds the face-varying mesh of `channel` on `mesh` under `scheme`.
pub fn fvar_mesh(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    channel: &FVarChannel,
) -> Result<FVarMesh> {
    fvar_mesh_with(mesh, scheme, channel, &[], &[])
}

/// [`fvar_mesh`] with every value of the control vertices flagged in
/// `sharpened` an infinitely sharp corner (OpenSubdiv's rule for the
/// values of a non-manifold vertex whose values do not all match,
/// [`crate::subdiv::nonmanifold`]), and the control vertices flagged in
/// `spanning` taken as OpenSubdiv takes the vertex they copy, a
/// non-manifold crease vertex: interior (its non-manifold edges are
/// boundaries of the copy only) and never a corner by its face count (it
/// has more faces than edges; a copy can have one).
pub fn fvar_mesh_with(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    channel: &FVarChannel,
    sharpened: &[bool],
    spanning: &[bool],
) -> Result<FVarMesh> {
    channel.check(mesh)?;
    let (soup, pair_vertex) = pair_soup(mesh, channel);
    let (split, _, origin) = split_non_manifold_polygons(&soup);
    let vertex_of: Vec<u32> = origin.iter().map(|&o| pair_vertex[o as usize]).collect();
    let mut fm = ControlMesh::from_soup(&split).map_err(|e| e.context("face-varying mesh"))?;
    let linear = scheme.scheme == SubdivScheme::Bilinear || scheme.fvar == FVarLinear::All;
    let kind = match (linear, scheme.scheme) {
        (false, _) => FVarKind::Smooth,
        (true, SubdivScheme::Loop) => FVarKind::Barycentric,
        (true, _) => FVarKind::Bilinear,
    };
    let holes: Vec<FaceId> = scheme
        .effective_holes(mesh)
        .iter()
        .enumerate()
        .filter(|(_, &h)| h)
        .map(|(f, _)| FaceId(f as u32))
        .collect();
    let mut fscheme = scheme
        .clone()
        .with_boundary(BoundaryInterpolation::EdgeOnly)
        .with_fvar(FVarLinear::All)
        .with_holes(holes);
    if kind != FVarKind::Smooth {
        fscheme = fscheme.with_scheme(SubdivScheme::Bilinear);
    } else {
        copy_edge_sharpness(mesh, &mut fm)?;
        set_value_sharpness(mesh, scheme, &mut fm, &vertex_of, &origin, spanning)?;
        for (c, &v) in vertex_of.iter().enumerate() {
            if sharpened.get(v as usize).copied().unwrap_or(false) {
                fm.set_corner(VertexId(c as u32), INFINITELY_SHARP)?;
            }
        }
    }
    Ok(FVarMesh {
        mesh: fm,
        scheme: fscheme,
        kind,
        vertex_of,
    })
}

/// The polygons of the (vertex, value) pairs, numbered in order of first
/// use, and the control vertex of each pair.
fn pair_soup(mesh: &ControlMesh, channel: &FVarChannel) -> (PolySoup, Vec<u32>) {
    let mut ids: HashMap<(u32, u32), u32> = HashMap::new();
    let mut soup = PolySoup::new();
    let mut pair_vertex = Vec::new();
    let mut c = 0;
    for f in mesh.faces() {
        for v in mesh.face_vertices(f) {
            let value = channel.indices[c];
            c += 1;
            let id = *ids.entry((v.0, value)).or_insert_with(|| {
                let uv = channel.values[value as usize];
                soup.positions.push(DVec3::new(uv.x, uv.y, 0.0));
                pair_vertex.push(v.0);
                (soup.positions.len() - 1) as u32
            });
            soup.face_indices.push(id);
        }
        soup.face_offsets.push(soup.face_indices.len() as u32);
    }
    (soup, pair_vertex)
}

/// Interior edges of the face-varying mesh keep the control mesh's
/// sharpness (OpenSubdiv refines face-varying values with the vertex
/// topology's edge sharpness); seams are its boundary, infinitely sharp.
fn copy_edge_sharpness(mesh: &ControlMesh, fm: &mut ControlMesh) -> Result<()> {
    let mut tags = Vec::new();
    for f in mesh.faces() {
        for (h, g) in mesh.face_halfedges(f).zip(fm.face_halfedges(f)) {
            let s = mesh.edge_sharpness(h.edge());
            if s > 0.0 && !fm.is_boundary_edge(g.edge()) && fm.tail(g) < fm.head(g) {
                tags.push((fm.tail(g), fm.head(g), s));
            }
        }
    }
    for (a, b, s) in tags {
        fm.set_crease(a, b, s)?;
    }
    Ok(())
}

/// Whether control vertex `v` has a seam in the sense of OpenSubdiv's
/// `vertexMismatch`: an interior edge whose two faces disagree on a value
/// at either end, or a geometric boundary the mode linearises.
fn is_seam_vertex(
    mesh: &ControlMesh,
    v: VertexId,
    scheme: &SchemeOptions,
    pair_edges_seam: &[bool],
    spanning: bool,
) -> bool {
    let seam = mesh.outgoing(v).any(|h| pair_edges_seam[h.edge().idx()]);
    if seam || spanning || !mesh.is_boundary_vertex(v) {
        return seam;
    }
    let faces = face_count(mesh, v, spanning);
    let linear_boundaries = matches!(scheme.fvar, FVarLinear::Boundaries | FVarLinear::All);
    let corners_smooth = scheme.boundary != BoundaryInterpolation::EdgeAndCorner;
    (linear_boundaries && faces > 0)
        || (faces == 1 && corners_smooth && scheme.fvar != FVarLinear::None)
}

/// Faces at `v` as OpenSubdiv counts them for its corner rules: at least
/// two for a vertex `spanning` more faces than its own (see
/// [`fvar_mesh_with`]).
fn face_count(mesh: &ControlMesh, v: VertexId, spanning: bool) -> usize {
    let n = mesh.vertex_faces(v).count();
    if spanning {
        n.max(2)
    } else {
        n
    }
}

/// Sets the vertex sharpness of every value (module doc). `pair[c]` is the
/// (vertex, value) pair face-varying vertex `c` copies.
fn set_value_sharpness(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    fm: &mut ControlMesh,
    vertex_of: &[u32],
    pair: &[u32],
    spanning: &[bool],
) -> Result<()> {
    // Per control edge: interior there but a boundary of the face-varying mesh.
    let mut seam_edge = vec![false; mesh.num_edges()];
    for f in mesh.faces() {
        for (h, g) in mesh.face_halfedges(f).zip(fm.face_halfedges(f)) {
            if !mesh.is_boundary_edge(h.edge()) && fm.is_boundary_edge(g.edge()) {
                seam_edge[h.edge().idx()] = true;
            }
        }
    }
    let mut copies_of: Vec<Vec<u32>> = vec![Vec::new(); mesh.num_vertices()];
    for (c, &v) in vertex_of.iter().enumerate() {
        copies_of[v as usize].push(c as u32);
    }
    let mut sharp = vec![0.0f64; fm.num_vertices()];
    for v in mesh.vertices() {
        let own = mesh.vertex_sharpness(v);
        let spans_more = spanning.get(v.idx()).copied().unwrap_or(false);
        let corner_rule = scheme.boundary == BoundaryInterpolation::EdgeAndCorner
            && face_count(mesh, v, spans_more) == 1
            && mesh.valence(v) == 2;
        let vertex_sharp = if corner_rule { INFINITELY_SHARP } else { own };
        let cs = &copies_of[v.idx()];
        if !is_seam_vertex(mesh, v, scheme, &seam_edge, spans_more) {
            for &c in cs {
                sharp[c as usize] = vertex_sharp;
            }
            continue;
        }
        // The values of `v` as OpenSubdiv counts them: its copies grouped
        // by the sibling its walk assigns ([`osd_siblings`]); a copy
        // sharing its sibling with another is a disjoint span.
        let sibling = osd_siblings(mesh, fm, v, pair, cs)?;
        let mut spans_v = Vec::with_capacity(cs.len());
        for (k, &c) in cs.iter().enumerate() {
            let shared = sibling.iter().filter(|&&s| s == sibling[k]).count() > 1;
            let mut span = value_span(fm, VertexId(c), shared);
            if spans_more {
                span.faces = span.faces.max(2);
            }
            spans_v.push(span);
        }
        let mut values: Vec<(u32, ValueSpan)> = Vec::new();
        for (k, _) in cs.iter().enumerate() {
            let s = spans_v[k];
            match values.iter_mut().find(|(p, _)| *p == sibling[k]) {
                Some((_, t)) => {
                    t.faces += s.faces;
                    t.semi_sharp |= s.semi_sharp;
                }
                None => values.push((sibling[k], s)),
            }
        }
        let values: Vec<ValueSpan> = values.into_iter().map(|(_, s)| s).collect();
        check_reproducible(mesh, fm, scheme, v, cs, &values)?;
        let all = all_values_sharp(mesh, scheme, v, vertex_sharp, &values);
        for (k, &c) in cs.iter().enumerate() {
            let s = &spans_v[k];
            let corner = all || s.disjoint || (s.faces == 1 && scheme.fvar != FVarLinear::None);
            sharp[c as usize] = if corner { INFINITELY_SHARP } else { own };
        }
        if !all && own == 0.0 && has_dependent_value(scheme, &values) {
            // Two values, one copy each (a disjoint span would have made
            // both corners): the one without semi-sharp edges follows.
            let (s_copy, d_copy) = if spans_v[0].semi_sharp {
                (cs[0], cs[1])
            } else {
                (cs[1], cs[0])
            };
            let seams: Vec<f64> = mesh
                .outgoing(v)
                .filter(|h| seam_edge[h.edge().idx()])
                .map(|h| mesh.edge_sharpness(h.edge()))
                .collect();
            if sharp[d_copy as usize] < INFINITELY_SHARP {
                sharp[d_copy as usize] = dependent_sharpness(fm, v, VertexId(s_copy), &seams)?;
            }
        }
    }
    for (c, &s) in sharp.iter().enumerate() {
        if s > 0.0 {
            fm.set_corner(VertexId(c as u32), s)?;
        }
    }
    Ok(())
}

/// Per copy in `cs` (the face-varying vertices of control vertex `v`):
/// the sibling OpenSubdiv gives its value (`FVarLevel::
/// completeTopologyFromFaceValues`). OpenSubdiv walks `v`'s faces from its
/// lowest-numbered one (the leading boundary face on a boundary) across
/// each face's edge into `v` (`Level::orderVertexFacesAndEdges`), and
/// numbers the values as they come; while it has seen two, a value other
/// than the first is taken as new without comparing it with the second. So
/// around a vertex whose values alternate (A B A B, a UV bow-tie) the
/// second value gets two siblings: its two spans become two values (smooth
/// creases), while the first value's spans stay one disjoint value (a
/// corner). Copies whose faces get different siblings are refused.
fn osd_siblings(
    mesh: &ControlMesh,
    fm: &ControlMesh,
    v: VertexId,
    pair: &[u32],
    cs: &[u32],
) -> Result<Vec<u32>> {
    // The face-varying vertex at `v`'s corner of face `f`.
    let copy_at = |f: FaceId| -> u32 {
        let k = mesh.face_vertices(f).position(|w| w == v).unwrap_or(0);
        fm.face_vertices(f).nth(k).map_or(u32::MAX, |c| c.0)
    };
    let out: Vec<_> = mesh
        .outgoing(v)
        .filter(|&h| mesh.face_of(h).is_some())
        .collect();
    let start = match out.iter().find(|&&h| mesh.face_of(h.twin()).is_none()) {
        Some(&h) => h,
        None => *out
            .iter()
            .min_by_key(|&&h| mesh.face_of(h).map_or(u32::MAX, |f| f.0))
            .expect("a seam vertex has faces"),
    };
    let mut ring = Vec::new();
    let mut h = start;
    while let Some(f) = mesh.face_of(h) {
        ring.push((f, copy_at(f)));
        h = mesh.prev(h).twin();
        if h == start || ring.len() > out.len() {
            break;
        }
    }
    let mut unique: Vec<u32> = Vec::new();
    let mut sib: Vec<u32> = Vec::with_capacity(ring.len());
    for (i, &(_, c)) in ring.iter().enumerate() {
        let value = pair[c as usize];
        if i > 0 && value == pair[ring[i - 1].1 as usize] {
            sib.push(sib[i - 1]);
            continue;
        }
        // (`value` differs from the previous face's: with one value seen it
        // is new; with two, OpenSubdiv only compares it with the first.)
        let found = match unique.len() {
            1 => None,
            2 if unique[0] != value => None,
            _ => unique.iter().position(|&u| u == value),
        };
        match found {
            Some(k) => sib.push(k as u32),
            None => {
                sib.push(unique.len() as u32);
                unique.push(value);
            }
        }
    }
    cs.iter()
        .map(|&c| {
            let mut of = ring
                .iter()
                .zip(&sib)
                .filter(|((_, k), _)| *k == c)
                .map(|(_, &s)| s);
            let first = of.next().unwrap_or(u32::MAX);
            if of.all(|s| s == first) {
                Ok(first)
            } else {
                Err(Error::invalid_data(
                    "face-varying data",
                    format!("vertex {}", v.0),
                    "a value span that OpenSubdiv's sibling \
                     numbering splits in two; not reproduced exactly, so not evaluated",
                ))
            }
        })
        .collect()
}

/// The span of one value: its faces, and whether an infinitely sharp or
/// semi-sharp edge lies inside it (`gatherValueSpans`).
fn value_span(fm: &ControlMesh, c: VertexId, split: bool) -> ValueSpan {
    let mut s = ValueSpan {
        disjoint: split,
        faces: fm.vertex_faces(c).count(),
        semi_sharp: false,
    };
    for h in fm.outgoing(c) {
        if fm.is_boundary_edge(h.edge()) {
            continue;
        }
        let e = fm.edge_sharpness(h.edge());
        if e >= INFINITELY_SHARP {
            s.disjoint = true;
        } else if e > 0.0 {
            s.semi_sharp = true;
        }
    }
    s
}

/// OpenSubdiv's `allCornersAreSharp` for seam vertex `v` with `values`.
fn all_values_sharp(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    v: VertexId,
    vertex_sharp: f64,
    values: &[ValueSpan],
) -> bool {
    let dependent = matches!(
        scheme.fvar,
        FVarLinear::CornersPlus1 | FVarLinear::CornersPlus2
    );
    let plus2 = scheme.fvar == FVarLinear::CornersPlus2;
    let linear_boundaries = matches!(scheme.fvar, FVarLinear::Boundaries | FVarLinear::All);
    let n = values.len();
    if linear_boundaries
        || vertex_sharp >= INFINITELY_SHARP
        || (dependent && n > 2)
        || (plus2 && n == 1 && !mesh.is_boundary_vertex(v))
    {
        return true;
    }
    if dependent && n == 2 {
        let disjoint = values.iter().any(|s| s.disjoint);
        let single = values.iter().any(|s| s.faces == 1);
        return disjoint || (plus2 && single);
    }
    false
}

/// Refuses what the module doc says cannot be reproduced exactly.
fn check_reproducible(
    mesh: &ControlMesh,
    fm: &ControlMesh,
    scheme: &SchemeOptions,
    v: VertexId,
    cs: &[u32],
    values: &[ValueSpan],
) -> Result<()> {
    let semi_at_vertex = mesh
        .outgoing(v)
        .filter(|h| {
            let s = mesh.edge_sharpness(h.edge());
            s > 0.0 && s < INFINITELY_SHARP
        })
        .count();
    if scheme.crease_method == CreaseMethod::Chaikin {
        for &c in cs {
            let inside = fm
                .outgoing(VertexId(c))
                .filter(|h| {
                    let s = fm.edge_sharpness(h.edge());
                    !fm.is_boundary_edge(h.edge()) && s > 0.0 && s < INFINITELY_SHARP
                })
                .count();
            if inside > 0 && inside != semi_at_vertex {
                return Err(Error::invalid_data(
                    "face-varying data",
                    format!("vertex {}", v.0),
                    "Chaikin creasing with semi-sharp edges on \
                     both sides of a face-varying seam (OpenSubdiv averages their sharpness \
                     across the seam); not reproduced exactly, so not evaluated",
                ));
            }
        }
    }
    if scheme.crease_method == CreaseMethod::Chaikin && has_dependent_value(scheme, values) {
        return Err(Error::invalid_data(
            "face-varying data",
            format!("vertex {}", v.0),
            format!(
                "under {} with Chaikin creasing one of its two values \
             is semi-sharp and the other follows it (OpenSubdiv's dependent sharpness, timed by \
             Chaikin's averaged sharpness); not reproduced exactly, so not evaluated",
                scheme.fvar.name()
            ),
        ));
    }
    Ok(())
}

/// Whether one of the two values of a seam vertex is "dependent sharp"
/// (`FVarLevel::completeTopologyFromFaceValues`, corners +1/+2): neither
/// span sharpened, exactly one with semi-sharp edges inside.
fn has_dependent_value(scheme: &SchemeOptions, values: &[ValueSpan]) -> bool {
    let dependent = matches!(
        scheme.fvar,
        FVarLinear::CornersPlus1 | FVarLinear::CornersPlus2
    );
    if !dependent || values.len() != 2 {
        return false;
    }
    let (a, b) = (&values[0], &values[1]);
    let plus2 = scheme.fvar == FVarLinear::CornersPlus2;
    let sharpened = a.disjoint || b.disjoint || (plus2 && (a.faces == 1 || b.faces == 1));
    !sharpened && a.semi_sharp != b.semi_sharp
}

/// The vertex sharpness that makes the dependent value D of seam vertex
/// `v` behave as OpenSubdiv's, under uniform creasing: D is a corner while
/// the other value S is semi-sharp, then a crease, the transition weighted
/// by *S's* fractional weight (`PrimvarRefiner::interpFVarFromVerts`);
/// if a seam edge is still semi-sharp when S's edges run out,
/// `FVarRefinement::reclassifySemisharpValues` only clears D's dependency
/// at that level and D turns to a crease one level later, unblended.
///
/// With S's span edges `s_i` (f32, as OpenSubdiv keeps them) S runs out at
/// level L = ceil(max s_i); its weight is the mean of `s_i - (L - 1)` over
/// the edges that run out then. A vertex sharpness σ with `σ - (L - 1)`
/// equal to that weight gives D the corner rule up to L - 1 and the same
/// blend (Sdc's fractional weight of a vertex whose own sharpness is the
/// only one to run out is that sharpness); σ = L gives the later, unblended
/// turn. Refuses the rare weights f32 cannot carry through σ exactly.
fn dependent_sharpness(fm: &ControlMesh, v: VertexId, s: VertexId, seams: &[f64]) -> Result<f64> {
    let semi = |x: f32| x > 0.0 && x < INFINITELY_SHARP as f32;
    let edges: Vec<f32> = fm
        .outgoing(s)
        .filter(|h| !fm.is_boundary_edge(h.edge()))
        .map(|h| fm.edge_sharpness(h.edge()) as f32)
        .filter(|&x| semi(x))
        .collect();
    let last = edges.iter().copied().fold(0.0f32, f32::max).ceil();
    if seams.iter().any(|&x| semi(x as f32) && x as f32 > last) {
        return Ok(last as f64);
    }
    let dying: Vec<f32> = edges
        .iter()
        .filter(|&&x| x > last - 1.0)
        .map(|&x| x - (last - 1.0))
        .collect();
    // Sdc sums in the vertex's edge order; two terms commute exactly.
    let distinct = dying.iter().any(|&x| x != dying[0]);
    let weight = (dying.iter().sum::<f32>() / dying.len() as f32).min(1.0);
    let sigma = weight + (last - 1.0);
    if (dying.len() > 2 && distinct) || sigma - (last - 1.0) != weight {
        return Err(Error::invalid_data(
            "face-varying data",
            format!("vertex {}", v.0),
            format!(
                "a value whose sharpness depends on the other's \
             (OpenSubdiv's dependent sharpness) with a transition weight ({weight}) that f32 \
             vertex sharpness cannot carry exactly; not evaluated",
            ),
        ));
    }
    Ok(sigma as f64)
}

/// Evaluates a face-varying channel at surface locations: the `position`
/// of each result is `(u, v, 0)` of the data, `du` and `dv` its
/// derivatives with respect to the location's parameters.
pub trait FVarEvaluator: Send + Sync {
    fn evaluate(&self, locations: &[SurfaceLocation]) -> Result<Vec<LimitPoint>>;
}

/// The pure-Rust face-varying evaluator: the control mesh's evaluators on
/// the face-varying mesh.
pub struct RustFVarEvaluator {
    fvar: FVarMesh,
    /// `None` for [`FVarKind::Barycentric`].
    eval: Option<Box<dyn LimitEvaluator>>,
    face_sizes: Vec<u32>,
    scheme: SchemeOptions,
    holes: Vec<bool>,
}

impl RustFVarEvaluator {
    pub fn new(mesh: &ControlMesh, options: &EvalOptions, channel: &FVarChannel) -> Result<Self> {
        Self::with_sharpened(mesh, options, channel, &[], &[])
    }

    /// With the values of the vertices flagged in `sharpened` corners and
    /// those flagged in `spanning` counted with more faces
    /// ([`fvar_mesh_with`]).
    pub fn with_sharpened(
        mesh: &ControlMesh,
        options: &EvalOptions,
        channel: &FVarChannel,
        sharpened: &[bool],
        spanning: &[bool],
    ) -> Result<Self> {
        let fvar = fvar_mesh_with(mesh, &options.scheme, channel, sharpened, spanning)?;
        let eval = match fvar.kind {
            FVarKind::Barycentric => None,
            _ => {
                let opts = options.clone().with_scheme(fvar.scheme.clone());
                Some(make_evaluator(Backend::Rust, &fvar.mesh, &opts)?)
            }
        };
        Ok(RustFVarEvaluator {
            fvar,
            eval,
            face_sizes: mesh.face_sizes(),
            scheme: options.scheme.clone(),
            holes: crate::subdiv::checked_holes(mesh, &options.scheme)?,
        })
    }

    pub fn fvar_mesh(&self) -> &FVarMesh {
        &self.fvar
    }
}

impl FVarEvaluator for RustFVarEvaluator {
    fn evaluate(&self, locations: &[SurfaceLocation]) -> Result<Vec<LimitPoint>> {
        check_locations_for(self.scheme.scheme, &self.face_sizes, locations)?;
        crate::subdiv::check_not_holes(&self.holes, locations)?;
        let m = &self.fvar.mesh;
        match &self.eval {
            Some(e) => e.evaluate(m.positions(), locations),
            None => Ok(locations
                .iter()
                .map(|l| {
                    let p: Vec<DVec3> = m.face_vertices(l.face).map(|v| m.position(v)).collect();
                    LimitPoint {
                        position: (1.0 - l.u - l.v) * p[0] + l.u * p[1] + l.v * p[2],
                        du: p[1] - p[0],
                        dv: p[2] - p[0],
                    }
                })
                .collect()),
        }
    }
}

/// Prepares the chosen face-varying evaluator for `channel` on `mesh`.
pub fn make_fvar_evaluator(
    backend: Backend,
    mesh: &ControlMesh,
    options: &EvalOptions,
    channel: &FVarChannel,
) -> Result<Box<dyn FVarEvaluator>> {
    Ok(match backend {
        Backend::Rust => Box::new(RustFVarEvaluator::new(mesh, options, channel)?),
        Backend::Osd => Box::new(crate::subdiv::osd::OsdFVarEvaluator::new(
            mesh, options, channel,
        )?),
    })
}
