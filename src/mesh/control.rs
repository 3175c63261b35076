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
        let mut he_vertex = Vec::new();
        let mut he_face = Vec::new();
        let mut he_next = Vec::new();
        let mut he_prev = Vec::new();
        let mut face_he = Vec::with_capacity(faces.len());
        let mut face_size = Vec::with_capacity(faces.len());
        // Directed edge (a, b) -> half-edge id; the twin slot of an edge is
        // created together with the first half-edge that uses the edge.
        let mut directed: HashMap<(u32, u32), HalfedgeId> = HashMap::new();

        for (fi, f) in faces.iter().enumerate() {
            let f = f.as_ref();
            let fid = FaceId(fi as u32);
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
                let (a, b) = (f[k], f[(k + 1) % n]);
                let h = match directed.get(&(a, b)) {
                    Some(&h) if he_face[h.idx()] != FaceId::INVALID => {
                        return Err(Error::topology(
                            fid.to_string(),
                            format!(
                                "edge ({a}, {b}) is already used in this direction by {}: \
                                 an edge shared by more than two faces, or inconsistent orientation",
                                he_face[h.idx()]
                            ),
                        ));
                    }
                    // The slot reserved when the opposite face created the edge.
                    Some(&h) => h,
                    None => {
                        let h = HalfedgeId(he_vertex.len() as u32);
                        he_vertex.push(VertexId(a));
                        he_vertex.push(VertexId(b));
                        he_face.extend([FaceId::INVALID; 2]);
                        he_next.extend([HalfedgeId::INVALID; 2]);
                        he_prev.extend([HalfedgeId::INVALID; 2]);
                        directed.insert((b, a), h.twin());
                        h
                    }
                };
                directed.insert((a, b), h);
                he_face[h.idx()] = fid;
                hs.push(h);
            }
            for k in 0..n {
                he_next[hs[k].idx()] = hs[(k + 1) % n];
                he_prev[hs[(k + 1) % n].idx()] = hs[k];
            }
            face_he.push(hs[0]);
            face_size.push(n as u32);
        }

        // Outgoing boundary half-edges per vertex: more than one means the
        // faces around the vertex form several fans (non-manifold vertex).
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
        };
        // A vertex whose interior faces form several closed fans (two cones
        // touching at a point) has no boundary half-edge yet is non-manifold:
        // rotation from its stored half-edge does not reach all the others.
        let seen: Vec<u32> = mesh
            .vertices()
            .map(|v| mesh.outgoing(v).count() as u32)
            .collect();
        let mut total = vec![0u32; nv];
        for h in 0..mesh.he_vertex.len() {
            total[mesh.he_vertex[h].idx()] += 1;
        }
        for v in 0..nv {
            if seen[v] != total[v] {
                return Err(Error::topology(
                    VertexId(v as u32).to_string(),
                    "non-manifold vertex: its faces form more than one fan",
                ));
            }
        }
        Ok(mesh)
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
        self.face_size.iter().all(|&n| n == 4)
    }

    /// Connected components (by faces sharing vertices).
    pub fn num_components(&self) -> usize {
        let mut label = vec![u32::MAX; self.num_vertices()];
        let mut count = 0;
        let mut stack = Vec::new();
        for s in self.vertices() {
            if label[s.idx()] != u32::MAX {
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
            if seen[h] || !self.is_boundary_halfedge(hid) {
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
        let nh = self.num_halfedges();
        let nv = self.num_vertices();
        let nf = self.num_faces();
        let chk = |ok: bool, el: String, msg: &str| {
            if ok {
                Ok(())
            } else {
                Err(Error::topology(el, msg))
            }
        };
        chk(nh % 2 == 0, "mesh".into(), "odd number of half-edges")?;
        for (i, p) in self.positions.iter().enumerate() {
            chk(p.is_finite(), format!("vertex {i}"), "non-finite position")?;
        }
        for h in 0..nh {
            let hid = HalfedgeId(h as u32);
            let el = || hid.to_string();
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
            if let Some(f) = self.face_of(hid) {
                chk(f.idx() < nf, el(), "face out of range")?;
            }
        }
        for f in self.faces() {
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
            )?;
        }
        let mut out_count = vec![0usize; nv];
        for h in 0..nh {
            out_count[self.he_vertex[h].idx()] += 1;
        }
        for v in self.vertices() {
            let h = self.vertex_he[v.idx()];
            chk(
                h.idx() < nh && self.tail(h) == v,
                v.to_string(),
                "stored half-edge does not leave the vertex",
            )?;
            let fan = self.outgoing(v).count();
            chk(
                fan == out_count[v.idx()],
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
            )?;
        }
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

    fn cube() -> ControlMesh {
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
        ControlMesh::from_polygons(p, &f).unwrap()
    }

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
