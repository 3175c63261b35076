//! The control mesh: a half-edge structure that owns its connectivity, with
//! typed ids, polygon faces of any size, open boundaries, per-edge crease
//! sharpness and per-vertex corner sharpness.
//!
//! Every edge owns two half-edges, `2e` and `2e + 1`, twins of each other. A
//! half-edge on the boundary has no face; boundary half-edges are linked by
//! `next`/`prev` into one loop per hole, so rotating around a vertex
//! (`twin(prev(h))`) visits every outgoing half-edge, boundary ones included.
//! A boundary vertex stores its outgoing *boundary* half-edge, so its fan of
//! faces starts at the boundary.

use std::collections::HashMap;
use std::fmt;

use crate::error::{Error, Result};
use crate::mesh::soup::bbox;
use crate::DVec3;

macro_rules! id_type {
    ($(#[$m:meta])* $name:ident, $prefix:literal) => {
        $(#[$m])*
        #[derive(Copy, Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
        pub struct $name(pub u32);
        impl $name {
            pub const INVALID: $name = $name(u32::MAX);
            #[inline]
            pub fn idx(self) -> usize {
                self.0 as usize
            }
            #[inline]
            pub fn is_valid(self) -> bool {
                self.0 != u32::MAX
            }
        }
        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, concat!($prefix, " {}"), self.0)
            }
        }
    };
}

id_type!(
    /// A control vertex, in file order.
    VertexId,
    "vertex"
);
id_type!(
    /// A face, in file order.
    FaceId,
    "face"
);
id_type!(
    /// A half-edge; `h ^ 1` is its twin.
    HalfedgeId,
    "half-edge"
);
id_type!(
    /// An edge (the pair of half-edges `2e`, `2e + 1`).
    EdgeId,
    "edge"
);

impl HalfedgeId {
    #[inline]
    pub fn twin(self) -> HalfedgeId {
        HalfedgeId(self.0 ^ 1)
    }
    #[inline]
    pub fn edge(self) -> EdgeId {
        EdgeId(self.0 >> 1)
    }
}

impl EdgeId {
    #[inline]
    pub fn halfedge(self) -> HalfedgeId {
        HalfedgeId(self.0 << 1)
    }
}

/// OpenSubdiv's value for an infinitely sharp crease or corner.
pub const INFINITELY_SHARP: f64 = 10.0;

/// Free slots, handed out smallest first: a min-heap, so that an edit costs
/// O(log n) however many slots are free (re-sorting a free list per edit
/// made long simplifications quadratic). Equality compares the sets.
#[derive(Clone, Debug)]
struct FreeList<T: Ord>(std::collections::BinaryHeap<std::cmp::Reverse<T>>);

impl<T: Ord> Default for FreeList<T> {
    fn default() -> Self {
        FreeList(std::collections::BinaryHeap::new())
    }
}

impl<T: Ord + Copy> FreeList<T> {
    fn push(&mut self, x: T) {
        self.0.push(std::cmp::Reverse(x));
    }
    fn pop(&mut self) -> Option<T> {
        self.0.pop().map(|r| r.0)
    }
    fn len(&self) -> usize {
        self.0.len()
    }
    fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    fn sorted(&self) -> Vec<T> {
        let mut v: Vec<T> = self.0.iter().map(|r| r.0).collect();
        v.sort_unstable();
        v
    }
}

impl<T: Ord + Copy> PartialEq for FreeList<T> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.sorted() == other.sorted()
    }
}

/// The half-edge tables of [`ControlMesh::from_polygons`] while its faces
/// are added one at a time (boundary half-edges not linked yet).
struct HalfedgeBuilder {
    he_vertex: Vec<VertexId>,
    he_face: Vec<FaceId>,
    he_next: Vec<HalfedgeId>,
    he_prev: Vec<HalfedgeId>,
    face_he: Vec<HalfedgeId>,
    face_size: Vec<u32>,
    /// Directed edge (a, b) -> half-edge id; the twin slot of an edge is
    /// created together with the first half-edge that uses the edge.
    directed: HashMap<(u32, u32), HalfedgeId>,
}

impl HalfedgeBuilder {
    fn with_faces(nf: usize) -> Self {
        HalfedgeBuilder {
            he_vertex: Vec::new(),
            he_face: Vec::new(),
            he_next: Vec::new(),
            he_prev: Vec::new(),
            face_he: Vec::with_capacity(nf),
            face_size: Vec::with_capacity(nf),
            directed: HashMap::new(),
        }
    }

    /// Adds face `fid` with the vertices `f` (of `nv`): fails on fewer
    /// than 3 vertices, an out-of-range or repeated one, and an edge
    /// already used in this direction (a third face on the edge, or
    /// inconsistent orientation).
    fn add_face(&mut self, fid: FaceId, f: &[u32], nv: usize) -> Result<()> {
        if f.len() < 3 {
            return Err(Error::topology(
                fid.to_string(),
                format!("has {} vertices, needs at least 3", f.len()),
            ));
        }
        for (k, &v) in f.iter().enumerate() {
            if v as usize >= nv {
                return Err(Error::topology(
                    fid.to_string(),
                    format!("vertex index {v} out of range (the mesh has {nv} vertices)"),
                ));
            }
            if f[..k].contains(&v) {
                return Err(Error::topology(
                    fid.to_string(),
                    format!("uses vertex {v} twice"),
                ));
            }
        }
        let n = f.len();
        let mut hs = Vec::with_capacity(n);
        for k in 0..n {
            let h = self.halfedge(fid, f[k], f[(k + 1) % n])?;
            hs.push(h);
        }
        for k in 0..n {
            self.he_next[hs[k].idx()] = hs[(k + 1) % n];
            self.he_prev[hs[(k + 1) % n].idx()] = hs[k];
        }
        self.face_he.push(hs[0]);
        self.face_size.push(n as u32);
        Ok(())
    }

    /// The half-edge `a → b` of face `fid`: the slot reserved by the
    /// opposite face, or a new edge (both half-edges).
    fn halfedge(&mut self, fid: FaceId, a: u32, b: u32) -> Result<HalfedgeId> {
        let h = match self.directed.get(&(a, b)) {
            Some(&h) if self.he_face[h.idx()] != FaceId::INVALID => {
                return Err(Error::topology(
                    fid.to_string(),
                    format!(
                        "edge ({a}, {b}) is already used in this direction by {}: \
                         an edge shared by more than two faces, or inconsistent orientation",
                        self.he_face[h.idx()]
                    ),
                ));
            }
            // The slot reserved when the opposite face created the edge.
            Some(&h) => h,
            None => {
                let h = HalfedgeId(self.he_vertex.len() as u32);
                self.he_vertex.push(VertexId(a));
                self.he_vertex.push(VertexId(b));
                self.he_face.extend([FaceId::INVALID; 2]);
                self.he_next.extend([HalfedgeId::INVALID; 2]);
                self.he_prev.extend([HalfedgeId::INVALID; 2]);
                self.directed.insert((b, a), h.twin());
                h
            }
        };
        self.directed.insert((a, b), h);
        self.he_face[h.idx()] = fid;
        Ok(h)
    }
}

/// Each vertex's stored half-edge (its outgoing boundary half-edge if it
/// has one) and its outgoing boundary half-edge. Fails on a vertex with
/// more than one (its faces form several fans: non-manifold) and on a
/// vertex no face uses.
fn vertex_halfedges(
    he_vertex: &[VertexId],
    he_face: &[FaceId],
    nv: usize,
) -> Result<(Vec<HalfedgeId>, Vec<HalfedgeId>)> {
    let mut vertex_he = vec![HalfedgeId::INVALID; nv];
    let mut boundary_out = vec![HalfedgeId::INVALID; nv];
    for h in 0..he_vertex.len() {
        let hid = HalfedgeId(h as u32);
        let v = he_vertex[h];
        if he_face[h] == FaceId::INVALID {
            if boundary_out[v.idx()].is_valid() {
                return Err(Error::topology(
                    v.to_string(),
                    "non-manifold vertex: its faces form more than one fan (two boundary edges leave it)",
                ));
            }
            boundary_out[v.idx()] = hid;
        } else if !vertex_he[v.idx()].is_valid() {
            vertex_he[v.idx()] = hid;
        }
    }
    for v in 0..nv {
        if boundary_out[v].is_valid() {
            vertex_he[v] = boundary_out[v];
        } else if !vertex_he[v].is_valid() {
            return Err(Error::topology(
                VertexId(v as u32).to_string(),
                "is used by no face (remove unreferenced vertices first)",
            ));
        }
    }
    Ok((vertex_he, boundary_out))
}

/// `Ok` when `ok`, else the topology error `msg` on element `el`
/// ([`ControlMesh::validate`]'s checks).
fn chk(ok: bool, el: String, msg: &str) -> Result<()> {
    if ok {
        Ok(())
    } else {
        Err(Error::topology(el, msg))
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct ControlMesh {
    positions: Vec<DVec3>,
    he_next: Vec<HalfedgeId>,
    he_prev: Vec<HalfedgeId>,
    /// Origin vertex of each half-edge.
    he_vertex: Vec<VertexId>,
    /// `FaceId::INVALID` on the boundary.
    he_face: Vec<FaceId>,
    face_he: Vec<HalfedgeId>,
    face_size: Vec<u32>,
    vertex_he: Vec<HalfedgeId>,
    edge_sharpness: Vec<f64>,
    vertex_sharpness: Vec<f64>,
    /// Deleted face slots, reused by [`ControlMesh::replace_faces`]. A
    /// deleted face has size 0.
    free_faces: FreeList<FaceId>,
    /// Deleted edge slots (both half-edges have origin `INVALID`).
    free_edges: FreeList<EdgeId>,
    /// Number of deleted vertices (their stored half-edge is `INVALID`).
    deleted_vertices: usize,
}

impl ControlMesh {
    /// Builds the mesh from polygons (indices into `positions`, any size
    /// ≥ 3, consistently oriented). Fails with the offending element on
    /// out-of-range indices, repeated vertices in a face, edges shared by more
    /// than two faces or by two faces with the same orientation, vertices
    /// whose faces do not form one fan, vertices used by no face, and
    /// non-finite coordinates.
    pub fn from_polygons<F: AsRef<[u32]>>(positions: Vec<DVec3>, faces: &[F]) -> Result<Self> {
        let nv = positions.len();
        for (i, p) in positions.iter().enumerate() {
            if !p.is_finite() {
                return Err(Error::topology(
                    format!("vertex {i}"),
                    format!("non-finite coordinates {p}"),
                ));
            }
        }
        if faces.is_empty() {
            return Err(Error::topology("mesh", "no faces"));
        }
        let mut b = HalfedgeBuilder::with_faces(faces.len());
        for (fi, f) in faces.iter().enumerate() {
            b.add_face(FaceId(fi as u32), f.as_ref(), nv)?;
        }
        let HalfedgeBuilder {
            he_vertex,
            he_face,
            mut he_next,
            mut he_prev,
            face_he,
            face_size,
            ..
        } = b;
        let (vertex_he, boundary_out) = vertex_halfedges(&he_vertex, &he_face, nv)?;
        // Link boundary half-edges into loops: the next boundary half-edge
        // after h (ending at v) is the one leaving v.
        for h in 0..he_vertex.len() {
            if he_face[h] == FaceId::INVALID {
                let end = he_vertex[h ^ 1];
                let n = boundary_out[end.idx()];
                he_next[h] = n;
                he_prev[n.idx()] = HalfedgeId(h as u32);
            }
        }
        let ne = he_vertex.len() / 2;
        let mesh = ControlMesh {
            positions,
            he_next,
            he_prev,
            he_vertex,
            he_face,
            face_he,
            face_size,
            vertex_he,
            edge_sharpness: vec![0.0; ne],
            vertex_sharpness: vec![0.0; nv],
            free_faces: FreeList::default(),
            free_edges: FreeList::default(),
            deleted_vertices: 0,
        };
        mesh.check_single_fans()?;
        Ok(mesh)
    }

    /// [`Self::from_polygons`]'s last check: a vertex whose interior faces
    /// form several closed fans (two cones touching at a point) has no
    /// boundary half-edge yet is non-manifold: rotation from its stored
    /// half-edge does not reach all the others.
    fn check_single_fans(&self) -> Result<()> {
        let nv = self.num_vertices();
        let seen: Vec<u32> = self
            .vertices()
            .map(|v| self.outgoing(v).count() as u32)
            .collect();
        let mut total = vec![0u32; nv];
        for h in 0..self.he_vertex.len() {
            total[self.he_vertex[h].idx()] += 1;
        }
        for v in 0..nv {
            if seen[v] != total[v] {
                return Err(Error::topology(
                    VertexId(v as u32).to_string(),
                    "non-manifold vertex: its faces form more than one fan",
                ));
            }
        }
        Ok(())
    }

    /// Builds from a [`crate::mesh::PolySoup`].
    pub fn from_soup(soup: &crate::mesh::PolySoup) -> Result<Self> {
        let faces: Vec<&[u32]> = soup.faces().collect();
        Self::from_polygons(soup.positions.clone(), &faces)
    }

    // ---- counts ------------------------------------------------------------

    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }
    pub fn num_faces(&self) -> usize {
        self.face_he.len()
    }
    pub fn num_edges(&self) -> usize {
        self.he_vertex.len() / 2
    }
    pub fn num_halfedges(&self) -> usize {
        self.he_vertex.len()
    }

    pub fn vertices(&self) -> impl Iterator<Item = VertexId> + Clone {
        (0..self.num_vertices() as u32).map(VertexId)
    }
    pub fn faces(&self) -> impl Iterator<Item = FaceId> + Clone {
        (0..self.num_faces() as u32).map(FaceId)
    }
    pub fn edges(&self) -> impl Iterator<Item = EdgeId> + Clone {
        (0..self.num_edges() as u32).map(EdgeId)
    }

    // ---- geometry ----------------------------------------------------------

    pub fn positions(&self) -> &[DVec3] {
        &self.positions
    }
    pub fn positions_mut(&mut self) -> &mut [DVec3] {
        &mut self.positions
    }
    pub fn position(&self, v: VertexId) -> DVec3 {
        self.positions[v.idx()]
    }
    pub fn set_positions(&mut self, p: Vec<DVec3>) -> Result<()> {
        if p.len() != self.positions.len() {
            return Err(Error::InvalidArgument(format!(
                "expected {} positions, got {}",
                self.positions.len(),
                p.len()
            )));
        }
        self.positions = p;
        Ok(())
    }
    pub fn bbox(&self) -> (DVec3, DVec3) {
        bbox(&self.positions)
    }
    pub fn bbox_diagonal(&self) -> f64 {
        let (lo, hi) = self.bbox();
        (hi - lo).length()
    }

    // ---- half-edge navigation ---------------------------------------------

    #[inline]
    pub fn next(&self, h: HalfedgeId) -> HalfedgeId {
        self.he_next[h.idx()]
    }
    #[inline]
    pub fn prev(&self, h: HalfedgeId) -> HalfedgeId {
        self.he_prev[h.idx()]
    }
    /// Origin of `h`.
    #[inline]
    pub fn tail(&self, h: HalfedgeId) -> VertexId {
        self.he_vertex[h.idx()]
    }
    /// Destination of `h`.
    #[inline]
    pub fn head(&self, h: HalfedgeId) -> VertexId {
        self.he_vertex[h.twin().idx()]
    }
    /// The face left of `h`, `None` on the boundary.
    #[inline]
    pub fn face_of(&self, h: HalfedgeId) -> Option<FaceId> {
        let f = self.he_face[h.idx()];
        f.is_valid().then_some(f)
    }
    #[inline]
    pub fn is_boundary_halfedge(&self, h: HalfedgeId) -> bool {
        !self.he_face[h.idx()].is_valid()
    }
    /// An outgoing half-edge of `v`; the boundary one if `v` is on the boundary.
    #[inline]
    pub fn vertex_halfedge(&self, v: VertexId) -> HalfedgeId {
        self.vertex_he[v.idx()]
    }
    #[inline]
    pub fn face_halfedge(&self, f: FaceId) -> HalfedgeId {
        self.face_he[f.idx()]
    }
    #[inline]
    pub fn face_size(&self, f: FaceId) -> usize {
        self.face_size[f.idx()] as usize
    }

    /// The limit patches of face `f`: one for a quad, `n` sub-patches for
    /// an n-gon (Catmull-Clark splits it into n quads first).
    #[inline]
    pub fn face_patches(&self, f: FaceId) -> usize {
        match self.face_size(f) {
            4 => 1,
            n => n,
        }
    }

    /// The limit patches of the whole mesh ([`Self::face_patches`] summed).
    pub fn num_patches(&self) -> usize {
        self.faces().map(|f| self.face_patches(f)).sum()
    }

    /// Half-edges of `f` in order, starting at the one leaving its first vertex.
    pub fn face_halfedges(&self, f: FaceId) -> impl Iterator<Item = HalfedgeId> + '_ {
        let h0 = self.face_he[f.idx()];
        let n = self.face_size(f);
        std::iter::successors(Some(h0), move |&h| Some(self.next(h))).take(n)
    }
    /// Vertices of `f` in file order.
    pub fn face_vertices(&self, f: FaceId) -> impl Iterator<Item = VertexId> + '_ {
        self.face_halfedges(f).map(move |h| self.tail(h))
    }

    /// Outgoing half-edges of `v`, rotating by `twin(prev(h))`, starting at
    /// [`Self::vertex_halfedge`]; boundary half-edges included.
    pub fn outgoing(&self, v: VertexId) -> impl Iterator<Item = HalfedgeId> + '_ {
        let h0 = self.vertex_he[v.idx()];
        let mut cur = Some(h0);
        let mut guard = self.he_vertex.len();
        std::iter::from_fn(move || {
            let h = cur?;
            let n = self.prev(h).twin();
            guard = guard.checked_sub(1)?;
            cur = (n != h0).then_some(n);
            Some(h)
        })
    }
    /// Faces around `v`, in rotation order.
    pub fn vertex_faces(&self, v: VertexId) -> impl Iterator<Item = FaceId> + '_ {
        self.outgoing(v).filter_map(move |h| self.face_of(h))
    }
    /// Number of edges at `v`.
    pub fn valence(&self, v: VertexId) -> usize {
        self.outgoing(v).count()
    }
    pub fn is_boundary_vertex(&self, v: VertexId) -> bool {
        self.is_boundary_halfedge(self.vertex_he[v.idx()])
    }
    pub fn is_boundary_edge(&self, e: EdgeId) -> bool {
        let h = e.halfedge();
        self.is_boundary_halfedge(h) || self.is_boundary_halfedge(h.twin())
    }
    pub fn edge_vertices(&self, e: EdgeId) -> (VertexId, VertexId) {
        let h = e.halfedge();
        (self.tail(h), self.head(h))
    }
    /// The half-edge from `a` to `b`, if they are joined by an edge.
    pub fn find_halfedge(&self, a: VertexId, b: VertexId) -> Option<HalfedgeId> {
        self.outgoing(a).find(|&h| self.head(h) == b)
    }

    // ---- sharpness ---------------------------------------------------------

    /// Crease sharpness of `e` (0 smooth, [`INFINITELY_SHARP`] infinitely sharp).
    pub fn edge_sharpness(&self, e: EdgeId) -> f64 {
        self.edge_sharpness[e.idx()]
    }
    pub fn vertex_sharpness(&self, v: VertexId) -> f64 {
        self.vertex_sharpness[v.idx()]
    }
    /// Sets the crease sharpness of the edge `(a, b)`.
    pub fn set_crease(&mut self, a: VertexId, b: VertexId, sharpness: f64) -> Result<()> {
        let h = self
            .find_halfedge(a, b)
            .ok_or_else(|| Error::topology(format!("edge ({}, {})", a.0, b.0), "no such edge"))?;
        check_sharpness(&format!("edge ({}, {})", a.0, b.0), sharpness)?;
        self.edge_sharpness[h.edge().idx()] = sharpness;
        Ok(())
    }
    pub fn set_corner(&mut self, v: VertexId, sharpness: f64) -> Result<()> {
        if v.idx() >= self.num_vertices() {
            return Err(Error::topology(v.to_string(), "out of range"));
        }
        check_sharpness(&v.to_string(), sharpness)?;
        self.vertex_sharpness[v.idx()] = sharpness;
        Ok(())
    }
    /// Creased edges as `(a, b, sharpness)`, for OpenSubdiv's descriptor and
    /// the shape-file `t crease` tags.
    pub fn creases(&self) -> Vec<(VertexId, VertexId, f64)> {
        self.edges()
            .filter(|&e| self.edge_sharpness(e) > 0.0)
            .map(|e| {
                let (a, b) = self.edge_vertices(e);
                (a, b, self.edge_sharpness(e))
            })
            .collect()
    }
    pub fn corners(&self) -> Vec<(VertexId, f64)> {
        self.vertices()
            .filter(|&v| self.vertex_sharpness(v) > 0.0)
            .map(|v| (v, self.vertex_sharpness(v)))
            .collect()
    }
    pub fn has_sharpness(&self) -> bool {
        self.edge_sharpness.iter().any(|&s| s > 0.0)
            || self.vertex_sharpness.iter().any(|&s| s > 0.0)
    }

    // ---- flat arrays (OpenSubdiv descriptor, writers) ----------------------

    pub fn face_sizes(&self) -> Vec<u32> {
        self.face_size.clone()
    }
    pub fn face_indices_flat(&self) -> Vec<u32> {
        self.faces()
            .flat_map(|f| self.face_vertices(f).map(|v| v.0))
            .collect()
    }
    pub fn to_polygons(&self) -> Vec<Vec<u32>> {
        self.faces()
            .map(|f| self.face_vertices(f).map(|v| v.0).collect())
            .collect()
    }
    pub fn is_all_quads(&self) -> bool {
        // Deleted slots (size 0) are not faces.
        self.face_size.iter().all(|&n| n == 4 || n == 0)
    }

    /// Connected components (by faces sharing vertices).
    pub fn num_components(&self) -> usize {
        let mut label = vec![u32::MAX; self.num_vertices()];
        let mut count = 0;
        let mut stack = Vec::new();
        for s in self.vertices() {
            if label[s.idx()] != u32::MAX || self.is_vertex_deleted(s) {
                continue;
            }
            label[s.idx()] = count;
            stack.push(s);
            while let Some(v) = stack.pop() {
                for h in self.outgoing(v) {
                    let w = self.head(h);
                    if label[w.idx()] == u32::MAX {
                        label[w.idx()] = count;
                        stack.push(w);
                    }
                }
            }
            count += 1;
        }
        count as usize
    }

    /// Number of boundary loops (holes).
    pub fn num_boundary_loops(&self) -> usize {
        let mut seen = vec![false; self.num_halfedges()];
        let mut loops = 0;
        for h in 0..self.num_halfedges() {
            let hid = HalfedgeId(h as u32);
            if seen[h] || self.is_halfedge_deleted(hid) || !self.is_boundary_halfedge(hid) {
                continue;
            }
            loops += 1;
            let mut c = hid;
            while !seen[c.idx()] {
                seen[c.idx()] = true;
                c = self.next(c);
            }
        }
        loops
    }

    /// Checks every connectivity invariant; tests call it after every
    /// operation. Returns the first violation, naming the element.
    pub fn validate(&self) -> Result<()> {
        chk(
            self.num_halfedges() % 2 == 0,
            "mesh".into(),
            "odd number of half-edges",
        )?;
        for (i, p) in self.positions.iter().enumerate() {
            chk(p.is_finite(), format!("vertex {i}"), "non-finite position")?;
        }
        for h in 0..self.num_halfedges() {
            self.validate_halfedge(HalfedgeId(h as u32))?;
        }
        for f in self.faces() {
            if !self.is_face_deleted(f) {
                self.validate_face(f)?;
            }
        }
        let nv = self.num_vertices();
        let mut out_count = vec![0usize; nv];
        for h in 0..self.num_halfedges() {
            if !self.is_halfedge_deleted(HalfedgeId(h as u32)) {
                out_count[self.he_vertex[h].idx()] += 1;
            }
        }
        for v in self.vertices() {
            if !self.is_vertex_deleted(v) {
                self.validate_vertex(v, out_count[v.idx()])?;
            }
        }
        self.validate_free_lists()?;
        for e in self.edges() {
            let s = self.edge_sharpness[e.idx()];
            chk(
                s.is_finite() && s >= 0.0,
                e.to_string(),
                "crease sharpness must be finite and >= 0",
            )?;
        }
        Ok(())
    }

    /// [`Self::validate`]'s checks of one half-edge: a deleted one has a
    /// deleted twin; a live one has in-range links forming a face loop of
    /// distinct consecutive vertices, a face on at least one side, and no
    /// deleted neighbour.
    fn validate_halfedge(&self, hid: HalfedgeId) -> Result<()> {
        let (nh, nv, nf) = (self.num_halfedges(), self.num_vertices(), self.num_faces());
        let h = hid.idx();
        let el = || hid.to_string();
        if self.is_halfedge_deleted(hid) {
            return chk(
                self.is_halfedge_deleted(hid.twin()),
                el(),
                "deleted half-edge with a live twin",
            );
        }
        chk(
            self.he_next[h].idx() < nh && self.he_prev[h].idx() < nh,
            el(),
            "dangling next/prev",
        )?;
        chk(self.prev(self.next(hid)) == hid, el(), "prev(next(h)) != h")?;
        chk(self.he_vertex[h].idx() < nv, el(), "origin out of range")?;
        chk(
            self.head(self.next(hid)) != self.head(hid),
            el(),
            "degenerate next",
        )?;
        chk(
            self.tail(self.next(hid)) == self.head(hid),
            el(),
            "next does not start where h ends",
        )?;
        chk(self.tail(hid) != self.head(hid), el(), "edge is a loop")?;
        chk(
            self.he_face[h] == self.he_face[self.he_next[h].idx()],
            el(),
            "next lies in another face",
        )?;
        chk(
            !(self.is_boundary_halfedge(hid) && self.is_boundary_halfedge(hid.twin())),
            el(),
            "edge with no face on either side",
        )?;
        chk(
            !self.is_vertex_deleted(self.tail(hid)),
            el(),
            "leaves a deleted vertex",
        )?;
        chk(
            !self.is_halfedge_deleted(self.next(hid)),
            el(),
            "next is a deleted half-edge",
        )?;
        if let Some(f) = self.face_of(hid) {
            chk(f.idx() < nf, el(), "face out of range")?;
            chk(!self.is_face_deleted(f), el(), "lies in a deleted face")?;
        }
        Ok(())
    }

    /// [`Self::validate`]'s checks of one live face: its stored half-edge
    /// is its own, and its loop has its size and distinct vertices.
    fn validate_face(&self, f: FaceId) -> Result<()> {
        let h0 = self.face_he[f.idx()];
        chk(
            self.face_of(h0) == Some(f),
            f.to_string(),
            "first half-edge belongs to another face",
        )?;
        let n = self.face_size(f);
        chk(n >= 3, f.to_string(), "fewer than 3 vertices")?;
        let mut h = h0;
        let mut vs = Vec::with_capacity(n);
        for _ in 0..n {
            vs.push(self.tail(h));
            h = self.next(h);
        }
        chk(
            h == h0,
            f.to_string(),
            "half-edge loop length differs from the face size",
        )?;
        vs.sort_unstable();
        chk(
            vs.windows(2).all(|w| w[0] != w[1]),
            f.to_string(),
            "repeated vertex",
        )
    }

    /// [`Self::validate`]'s checks of one live vertex (`out_count` live
    /// half-edges leave it): manifold (one fan reaching them all, at most
    /// one boundary edge out, and that one stored), no double edge, and a
    /// valid corner sharpness.
    fn validate_vertex(&self, v: VertexId, out_count: usize) -> Result<()> {
        let h = self.vertex_he[v.idx()];
        chk(
            h.idx() < self.num_halfedges() && self.tail(h) == v,
            v.to_string(),
            "stored half-edge does not leave the vertex",
        )?;
        let fan = self.outgoing(v).count();
        chk(
            fan == out_count,
            v.to_string(),
            "non-manifold: more than one fan",
        )?;
        let nb = self
            .outgoing(v)
            .filter(|&h| self.is_boundary_halfedge(h))
            .count();
        chk(
            nb <= 1,
            v.to_string(),
            "non-manifold: several boundary edges leave it",
        )?;
        chk(
            (nb == 1) == self.is_boundary_halfedge(h),
            v.to_string(),
            "boundary vertex must store its boundary half-edge",
        )?;
        // No two edges joining the same pair of vertices.
        let mut heads: Vec<VertexId> = self.outgoing(v).map(|h| self.head(h)).collect();
        heads.sort_unstable();
        chk(
            heads.windows(2).all(|w| w[0] != w[1]),
            v.to_string(),
            "two edges join the same vertices",
        )?;
        let s = self.vertex_sharpness[v.idx()];
        chk(
            s.is_finite() && s >= 0.0,
            v.to_string(),
            "corner sharpness must be finite and >= 0",
        )
    }

    /// [`Self::validate`]'s bookkeeping checks: the free lists and the
    /// deleted-vertex count match the deleted elements.
    fn validate_free_lists(&self) -> Result<()> {
        let dead_f = self.faces().filter(|&f| self.is_face_deleted(f)).count();
        chk(
            dead_f == self.free_faces.len(),
            "mesh".into(),
            "deleted faces and the free list disagree",
        )?;
        let dead_e = self.edges().filter(|&e| self.is_edge_deleted(e)).count();
        chk(
            dead_e == self.free_edges.len(),
            "mesh".into(),
            "deleted edges and the free list disagree",
        )?;
        let dead_v = self
            .vertices()
            .filter(|&v| self.is_vertex_deleted(v))
            .count();
        chk(
            dead_v == self.deleted_vertices,
            "mesh".into(),
            "deleted vertex count disagrees",
        )
    }
}

/// The renumbering done by [`ControlMesh::compact`]: `old → new`, `None`
/// for deleted elements.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Compaction {
    pub vertex_map: Vec<Option<VertexId>>,
    pub face_map: Vec<Option<FaceId>>,
}

/// Local editing (used by the simplification operators of `crate::quad`).
///
/// Elements are deleted by flags, so ids of the others stay stable while a
/// simplification runs: `num_vertices`/`num_faces`/`num_edges` and the
/// `vertices`/`faces`/`edges` iterators count *slots*, deleted ones
/// included; [`ControlMesh::is_vertex_deleted`] and friends tell them
/// apart, and [`ControlMesh::compact`] renumbers the survivors densely.
/// The rest of the crate (evaluators, writers) expects a compact mesh.
impl ControlMesh {
    #[inline]
    pub fn is_vertex_deleted(&self, v: VertexId) -> bool {
        !self.vertex_he[v.idx()].is_valid()
    }
    #[inline]
    pub fn is_face_deleted(&self, f: FaceId) -> bool {
        self.face_size[f.idx()] == 0
    }
    #[inline]
    pub fn is_edge_deleted(&self, e: EdgeId) -> bool {
        self.is_halfedge_deleted(e.halfedge())
    }
    #[inline]
    pub fn is_halfedge_deleted(&self, h: HalfedgeId) -> bool {
        !self.he_vertex[h.idx()].is_valid()
    }
    /// Whether some element was deleted and [`ControlMesh::compact`] has not
    /// run since.
    pub fn has_deletions(&self) -> bool {
        self.deleted_vertices > 0 || !self.free_faces.is_empty() || !self.free_edges.is_empty()
    }
    pub fn num_live_vertices(&self) -> usize {
        self.num_vertices() - self.deleted_vertices
    }
    pub fn num_live_faces(&self) -> usize {
        self.num_faces() - self.free_faces.len()
    }
    pub fn num_live_edges(&self) -> usize {
        self.num_edges() - self.free_edges.len()
    }
    pub fn live_vertices(&self) -> impl Iterator<Item = VertexId> + '_ {
        self.vertices().filter(move |&v| !self.is_vertex_deleted(v))
    }
    pub fn live_faces(&self) -> impl Iterator<Item = FaceId> + '_ {
        self.faces().filter(move |&f| !self.is_face_deleted(f))
    }

    /// Replaces the faces `remove` by the polygons `add` (vertex lists,
    /// oriented like their neighbours) and deletes the vertices `delete`,
    /// which must lose all their faces. Edges left with no face are deleted;
    /// edges the new faces need are reused when they exist, created
    /// otherwise. Returns the ids of the new faces, in the order of `add`.
    ///
    /// Everything is checked *before* anything changes, so on error the
    /// mesh is untouched: out-of-range or deleted elements, repeated vertices
    /// in a polygon, a directed edge used twice (more than two faces on an
    /// edge, or inconsistent orientation), a vertex whose faces would no
    /// longer form a single fan (non-manifold), a vertex left with no face
    /// that is not in `delete`, or a vertex in `delete` that keeps a face.
    /// Only vertices of the removed and added faces are looked at, so the
    /// cost is that of their 1-rings.
    pub fn replace_faces(
        &mut self,
        remove: &[FaceId],
        add: &[&[VertexId]],
        delete: &[VertexId],
    ) -> Result<Vec<FaceId>> {
        self.replace_impl(remove, add, delete, &[])
    }

    /// The inverse of a [`ControlMesh::replace_faces`] that deleted
    /// vertices: replaces the faces `remove` by `add`, where `add` may use
    /// the deleted vertices `revive`, which come back to life (each must get
    /// a face; their positions are whatever they were, their corner
    /// sharpness 0). Lets a caller undo a local edit (e.g. a refused
    /// collapse) without copying the mesh. Checked before anything changes,
    /// like [`ControlMesh::replace_faces`].
    pub fn restore_faces(
        &mut self,
        remove: &[FaceId],
        add: &[&[VertexId]],
        revive: &[VertexId],
    ) -> Result<Vec<FaceId>> {
        for (i, &v) in revive.iter().enumerate() {
            if v.idx() >= self.num_vertices()
                || !self.is_vertex_deleted(v)
                || revive[..i].contains(&v)
            {
                return Err(Error::topology(
                    v.to_string(),
                    "cannot revive: out of range, live, or listed twice",
                ));
            }
        }
        self.replace_impl(remove, add, &[], revive)
    }

    fn replace_impl(
        &mut self,
        remove: &[FaceId],
        add: &[&[VertexId]],
        delete: &[VertexId],
        revive: &[VertexId],
    ) -> Result<Vec<FaceId>> {
        // Every vertex whose half-edges may change (the check's too).
        let touched = self.replace_touched(remove, add, delete);
        self.check_replace(remove, add, delete, revive, &touched)?;
        // All half-edges leaving touched vertices (and their twins): every
        // edge the new faces can reuse joins two touched vertices.
        let mut local: Vec<HalfedgeId> = Vec::new();
        for &v in &touched {
            if self.is_vertex_deleted(v) {
                continue; // a revived vertex: no half-edge yet
            }
            local.extend(self.outgoing(v).flat_map(|h| [h, h.twin()]));
        }
        for &f in remove {
            let hs: Vec<HalfedgeId> = self.face_halfedges(f).collect();
            for h in hs {
                self.he_face[h.idx()] = FaceId::INVALID;
            }
            self.face_size[f.idx()] = 0;
            self.face_he[f.idx()] = HalfedgeId::INVALID;
            self.free_faces.push(f);
        }
        // Freed slots are reused from the smallest id (a min-heap), so the
        // result does not depend on the order of `remove`.
        let mut new_faces = Vec::with_capacity(add.len());
        for p in add {
            let f = match self.free_faces.pop() {
                Some(f) => f,
                None => {
                    self.face_he.push(HalfedgeId::INVALID);
                    self.face_size.push(0);
                    FaceId(self.face_he.len() as u32 - 1)
                }
            };
            let n = p.len();
            let mut hs = Vec::with_capacity(n);
            for k in 0..n {
                let (a, b) = (p[k], p[(k + 1) % n]);
                let found = local
                    .iter()
                    .copied()
                    .find(|&h| self.tail(h) == a && self.head(h) == b);
                let h = match found {
                    Some(h) => h,
                    None => {
                        let e = self.new_edge(a, b);
                        let h = e.halfedge();
                        local.push(h);
                        local.push(h.twin());
                        h
                    }
                };
                self.he_face[h.idx()] = f;
                hs.push(h);
            }
            for k in 0..n {
                self.he_next[hs[k].idx()] = hs[(k + 1) % n];
                self.he_prev[hs[(k + 1) % n].idx()] = hs[k];
            }
            self.face_he[f.idx()] = hs[0];
            self.face_size[f.idx()] = n as u32;
            new_faces.push(f);
        }
        // Edges with no face left on either side disappear.
        local.sort_unstable();
        local.dedup();
        for &h in &local {
            if !self.is_halfedge_deleted(h)
                && self.is_boundary_halfedge(h)
                && self.is_boundary_halfedge(h.twin())
            {
                let e = h.edge();
                for x in [e.halfedge(), e.halfedge().twin()] {
                    self.he_vertex[x.idx()] = VertexId::INVALID;
                    self.he_next[x.idx()] = HalfedgeId::INVALID;
                    self.he_prev[x.idx()] = HalfedgeId::INVALID;
                }
                self.edge_sharpness[e.idx()] = 0.0;
                self.free_edges.push(e);
            }
        }
        for &v in delete {
            self.vertex_he[v.idx()] = HalfedgeId::INVALID;
            self.vertex_sharpness[v.idx()] = 0.0;
            self.deleted_vertices += 1;
        }
        // Stored half-edges and boundary links of the touched vertices. A
        // boundary vertex stores its (unique, by the check) outgoing
        // boundary half-edge; the incoming boundary half-edge links to it.
        self.deleted_vertices -= revive.len();
        for &v in &touched {
            if self.is_vertex_deleted(v) && !revive.contains(&v) {
                continue;
            }
            let mut any = HalfedgeId::INVALID;
            let mut bout = HalfedgeId::INVALID;
            for &h in &local {
                if self.is_halfedge_deleted(h) || self.tail(h) != v {
                    continue;
                }
                if !any.is_valid() {
                    any = h;
                }
                if self.is_boundary_halfedge(h) {
                    bout = h;
                }
            }
            self.vertex_he[v.idx()] = if bout.is_valid() { bout } else { any };
        }
        for &h in &local {
            if !self.is_halfedge_deleted(h) && self.is_boundary_halfedge(h) {
                let n = self.vertex_he[self.head(h).idx()];
                self.he_next[h.idx()] = n;
                self.he_prev[n.idx()] = h;
            }
        }
        Ok(new_faces)
    }

    fn new_edge(&mut self, a: VertexId, b: VertexId) -> EdgeId {
        let e = match self.free_edges.pop() {
            Some(e) => e,
            None => {
                self.he_vertex.extend([VertexId::INVALID; 2]);
                self.he_face.extend([FaceId::INVALID; 2]);
                self.he_next.extend([HalfedgeId::INVALID; 2]);
                self.he_prev.extend([HalfedgeId::INVALID; 2]);
                self.edge_sharpness.push(0.0);
                EdgeId(self.edge_sharpness.len() as u32 - 1)
            }
        };
        let h = e.halfedge();
        self.he_vertex[h.idx()] = a;
        self.he_vertex[h.twin().idx()] = b;
        self.he_face[h.idx()] = FaceId::INVALID;
        self.he_face[h.twin().idx()] = FaceId::INVALID;
        self.edge_sharpness[e.idx()] = 0.0;
        e
    }

    /// The vertices of the faces `remove` and `add` and the vertices
    /// `delete` (sorted, once each): those whose fans a replacement can
    /// change. Faces out of range or deleted contribute nothing (the check
    /// refuses them).
    fn replace_touched(
        &self,
        remove: &[FaceId],
        add: &[&[VertexId]],
        delete: &[VertexId],
    ) -> Vec<VertexId> {
        let mut touched: Vec<VertexId> = Vec::with_capacity(4 * (remove.len() + add.len()) + 2);
        for &f in remove {
            if f.idx() < self.num_faces() && !self.is_face_deleted(f) {
                touched.extend(self.face_vertices(f));
            }
        }
        for p in add {
            touched.extend_from_slice(p);
        }
        touched.extend_from_slice(delete);
        touched.sort_unstable();
        touched.dedup();
        touched
    }

    /// The dry run of [`ControlMesh::replace_faces`]: simulates the fans of
    /// the touched vertices (`touched`: [`ControlMesh::replace_touched`])
    /// after the change.
    fn check_replace(
        &self,
        remove: &[FaceId],
        add: &[&[VertexId]],
        delete: &[VertexId],
        revive: &[VertexId],
        touched: &[VertexId],
    ) -> Result<()> {
        let live_v = |v: VertexId| {
            v.idx() < self.num_vertices() && (!self.is_vertex_deleted(v) || revive.contains(&v))
        };
        for (i, &f) in remove.iter().enumerate() {
            if f.idx() >= self.num_faces() || self.is_face_deleted(f) || remove[..i].contains(&f) {
                return Err(Error::topology(
                    f.to_string(),
                    "cannot remove: out of range, deleted or listed twice",
                ));
            }
        }
        for (i, p) in add.iter().enumerate() {
            if p.len() < 3 {
                return Err(Error::topology(
                    format!("new face {i}"),
                    "fewer than 3 vertices",
                ));
            }
            for (k, &v) in p.iter().enumerate() {
                if !live_v(v) || delete.contains(&v) || p[..k].contains(&v) {
                    return Err(Error::topology(
                        format!("new face {i}"),
                        format!("{v} is out of range, deleted, or repeated"),
                    ));
                }
            }
        }
        for &v in delete {
            if !live_v(v) {
                return Err(Error::topology(
                    v.to_string(),
                    "cannot delete: out of range or deleted",
                ));
            }
        }
        // Directed edges that will carry a face: those of kept faces at
        // touched vertices, and those of the new faces; each at most once.
        let mut used: Vec<(VertexId, VertexId)> = Vec::with_capacity(4 * touched.len());
        // A revived vertex has no half-edge yet, hence no kept face.
        let kept = |v: VertexId| !self.is_vertex_deleted(v);
        for &v in touched {
            for h in self.outgoing(v).take(if kept(v) { usize::MAX } else { 0 }) {
                if let Some(f) = self.face_of(h) {
                    if !remove.contains(&f) {
                        used.push((v, self.head(h)));
                    }
                }
            }
        }
        for p in add {
            let n = p.len();
            for k in 0..n {
                let d = (p[k], p[(k + 1) % n]);
                if used.contains(&d) {
                    return Err(Error::topology(
                        format!("edge ({}, {})", d.0 .0, d.1 .0),
                        "would be used twice in the same direction (more than two faces, or inconsistent orientation)",
                    ));
                }
                used.push(d);
            }
        }
        // Fan of each touched vertex after the change: each face at v links
        // the neighbour after v (out) to the one before v (in). Manifold iff
        // those links form a single chain or a single cycle.
        // One buffer for every vertex's links (a replacement touches a few
        // dozen vertices, each with a handful of faces).
        let mut links: Vec<(VertexId, VertexId)> = Vec::with_capacity(16);
        for &v in touched {
            links.clear();
            for h in self.outgoing(v).take(if kept(v) { usize::MAX } else { 0 }) {
                if let Some(f) = self.face_of(h) {
                    if !remove.contains(&f) {
                        links.push((self.head(h), self.tail(self.prev(h))));
                    }
                }
            }
            for p in add {
                if let Some(k) = p.iter().position(|&x| x == v) {
                    let n = p.len();
                    links.push((p[(k + 1) % n], p[(k + n - 1) % n]));
                }
            }
            let deleting = delete.contains(&v);
            if deleting != links.is_empty() {
                return Err(Error::topology(
                    v.to_string(),
                    if deleting {
                        "is to be deleted but keeps faces"
                    } else {
                        "would be left with no face"
                    },
                ));
            }
            if links.is_empty() {
                continue;
            }
            // Rotation: the face whose `out` is this face's `in` comes next.
            let mut starts = (0..links.len()).filter(|&i| !links.iter().any(|l| l.1 == links[i].0));
            let first = starts.next();
            if starts.next().is_some() {
                return Err(Error::topology(
                    v.to_string(),
                    "would become non-manifold (its faces would form several fans)",
                ));
            }
            let mut cur = first.unwrap_or(0);
            let mut seen = 1;
            while let Some(nx) = links.iter().position(|l| l.0 == links[cur].1) {
                if nx == first.unwrap_or(0) || seen > links.len() {
                    break;
                }
                cur = nx;
                seen += 1;
            }
            if seen != links.len() {
                return Err(Error::topology(
                    v.to_string(),
                    "would become non-manifold (its faces would form several fans)",
                ));
            }
        }
        Ok(())
    }

    /// Renumbers the live vertices and faces densely (in id order), drops
    /// deleted slots, and returns the renumbering. Crease and corner
    /// sharpness follow their elements.
    pub fn compact(&mut self) -> Result<Compaction> {
        let (polys, compaction) = self.live_polygons();
        *self = polys.build()?;
        Ok(compaction)
    }

    /// The live part of the mesh as plain polygons, densely renumbered as
    /// [`Self::compact`] does, without building its half-edges
    /// ([`LivePolygons::build`] does): a pass over the live elements, for
    /// copies that may never be used (the simplification's checkpoints).
    pub fn live_polygons(&self) -> (LivePolygons, Compaction) {
        let mut vertex_map = vec![None; self.num_vertices()];
        let mut positions = Vec::with_capacity(self.num_live_vertices());
        let mut vertex_sharpness = Vec::with_capacity(self.num_live_vertices());
        for v in self.vertices() {
            if !self.is_vertex_deleted(v) {
                vertex_map[v.idx()] = Some(VertexId(positions.len() as u32));
                positions.push(self.position(v));
                vertex_sharpness.push(self.vertex_sharpness(v));
            }
        }
        let mut face_map = vec![None; self.num_faces()];
        let mut polygons: Vec<Vec<u32>> = Vec::with_capacity(self.num_live_faces());
        for f in self.faces() {
            if !self.is_face_deleted(f) {
                face_map[f.idx()] = Some(FaceId(polygons.len() as u32));
                polygons.push(
                    self.face_vertices(f)
                        .map(|v| vertex_map[v.idx()].expect("live face uses live vertices").0)
                        .collect(),
                );
            }
        }
        let creases: Vec<(u32, u32, f64)> = self
            .edges()
            .filter(|&e| !self.is_edge_deleted(e) && self.edge_sharpness(e) > 0.0)
            .map(|e| {
                let (a, b) = self.edge_vertices(e);
                (
                    vertex_map[a.idx()].expect("live").0,
                    vertex_map[b.idx()].expect("live").0,
                    self.edge_sharpness(e),
                )
            })
            .collect();
        (
            LivePolygons {
                positions,
                vertex_sharpness,
                polygons,
                creases,
            },
            Compaction {
                vertex_map,
                face_map,
            },
        )
    }
}

/// A control mesh as plain polygons ([`ControlMesh::live_polygons`]).
#[derive(Clone, Debug, PartialEq)]
pub struct LivePolygons {
    pub positions: Vec<DVec3>,
    pub vertex_sharpness: Vec<f64>,
    pub polygons: Vec<Vec<u32>>,
    /// `(a, b, sharpness)` of every edge with a positive sharpness.
    pub creases: Vec<(u32, u32, f64)>,
}

impl LivePolygons {
    /// Faces.
    pub fn num_faces(&self) -> usize {
        self.polygons.len()
    }

    /// The half-edge mesh of these polygons, with their sharpness.
    pub fn build(self) -> Result<ControlMesh> {
        let mut m = ControlMesh::from_polygons(self.positions, &self.polygons)?;
        m.vertex_sharpness = self.vertex_sharpness;
        for (a, b, s) in self.creases {
            m.set_crease(VertexId(a), VertexId(b), s)?;
        }
        Ok(m)
    }
}

fn check_sharpness(el: &str, s: f64) -> Result<()> {
    if s.is_finite() && s >= 0.0 {
        Ok(())
    } else {
        Err(Error::topology(
            el,
            format!("sharpness {s} must be finite and >= 0"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::fixtures::cube;

    #[test]
    fn cube_is_valid_and_closed() {
        let m = cube();
        m.validate().unwrap();
        assert_eq!(m.num_edges(), 12);
        assert!(m
            .vertices()
            .all(|v| m.valence(v) == 3 && !m.is_boundary_vertex(v)));
        assert_eq!(m.num_boundary_loops(), 0);
        assert_eq!(m.num_components(), 1);
    }

    #[test]
    fn open_grid_has_one_loop() {
        // 2x2 quads.
        let p: Vec<DVec3> = (0..9)
            .map(|i| DVec3::new((i % 3) as f64, (i / 3) as f64, 0.0))
            .collect();
        let f = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]];
        let m = ControlMesh::from_polygons(p, &f).unwrap();
        m.validate().unwrap();
        assert_eq!(m.num_boundary_loops(), 1);
        assert_eq!(m.valence(VertexId(4)), 4);
        assert_eq!(m.valence(VertexId(0)), 2);
        assert_eq!(m.valence(VertexId(1)), 3);
        assert!(m.is_boundary_vertex(VertexId(1)));
        assert!(!m.is_boundary_vertex(VertexId(4)));
        assert_eq!(m.vertex_faces(VertexId(4)).count(), 4);
    }

    #[test]
    fn rejects_bad_topology() {
        let p: Vec<DVec3> = (0..5)
            .map(|i| DVec3::new(i as f64, (i * i) as f64, 0.0))
            .collect();
        // Three faces on one edge.
        let e =
            ControlMesh::from_polygons(p.clone(), &[[0, 1, 2], [1, 0, 3], [0, 1, 4]]).unwrap_err();
        assert!(e.to_string().contains("face 2"), "{e}");
        // Out of range.
        let e = ControlMesh::from_polygons(p.clone(), &[[0, 1, 7]]).unwrap_err();
        assert!(e.to_string().contains("out of range"), "{e}");
        // Unreferenced vertex.
        let e = ControlMesh::from_polygons(p.clone(), &[[0, 1, 2]]).unwrap_err();
        assert!(e.to_string().contains("vertex 3"), "{e}");
        // Bow-tie: two triangles touching at vertex 0.
        let p: Vec<DVec3> = (0..5)
            .map(|i| DVec3::new(i as f64, (i * i) as f64, 0.0))
            .collect();
        let e = ControlMesh::from_polygons(p, &[[0, 1, 2], [0, 3, 4]]).unwrap_err();
        assert!(e.to_string().contains("vertex 0"), "{e}");
    }

    #[test]
    fn creases_round_trip() {
        let mut m = cube();
        m.set_crease(VertexId(0), VertexId(1), 2.5).unwrap();
        m.set_corner(VertexId(7), INFINITELY_SHARP).unwrap();
        assert_eq!(m.creases().len(), 1);
        assert_eq!(m.corners(), vec![(VertexId(7), INFINITELY_SHARP)]);
        assert!(m.set_crease(VertexId(0), VertexId(7), 1.0).is_err());
        m.validate().unwrap();
    }
}
