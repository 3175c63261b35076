//! A small polygon mesh with generic per-vertex "points", and one level of
//! Catmull-Clark refinement on it with OpenSubdiv 3.5's rules (Sdc, Catmark
//! scheme) under the options of [`Rules`]: boundary corners sharpened or
//! not, uniform or Chaikin creasing, Catmark or smooth triangles.
//!
//! Sharpness is a 32-bit float, as everywhere in Sdc (`Sdc::Crease` takes
//! and returns `float`): values are rounded to f32 when a mesh is read in
//! ([`topo_from_mesh`]) and every sharpness update (decrement, Chaikin
//! average, fractional transition weight) is computed in f32, so both
//! evaluators subdivide the same surface. A sharpness such as 0.7 is thus
//! really 0.699999988 here and in OpenSubdiv.
//!
//! The same code refines whole meshes ([`crate::subdiv::refine`]) and the
//! local neighbourhoods the exact evaluator subdivides around a location.
//! A local neighbourhood is cut out of a larger mesh, so its rim looks like a
//! boundary: the rules read "boundary" from the topology (an edge with one
//! face), which is right for every vertex whose fan is complete. The
//! evaluator only ever uses points computed at such vertices (the 1-ring of a
//! face is enough to compute the 1-ring of each of its children), so the
//! garbage computed on the rim is never read.
//!
//! Points are generic ([`Pt`]): positions (`DVec3`) or sparse weights over
//! control vertices ([`Sparse`]), which turns the same code into a stencil
//! generator — subdivision is linear in the control points.

use std::collections::HashMap as StdHashMap;
use std::hash::{BuildHasherDefault, Hasher};

use crate::DVec3;

/// A multiplicative hasher for the small integer keys of local meshes
/// (FxHash's mixing step): SipHash dominated the cost of local subdivision.
#[derive(Default, Clone, Copy)]
pub(crate) struct IntHasher(u64);

impl Hasher for IntHasher {
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }
    #[inline]
    fn write_u32(&mut self, i: u32) {
        self.write_u64(i as u64);
    }
    #[inline]
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

pub(crate) type HashMap<K, V> = StdHashMap<K, V, BuildHasherDefault<IntHasher>>;

/// OpenSubdiv's `Sdc::Crease::SHARPNESS_INFINITE`.
pub(crate) const INF: f64 = 10.0;

/// Something subdivision can combine linearly.
pub(crate) trait Pt: Clone {
    fn zero() -> Self;
    /// `self += w * x`.
    fn axpy(&mut self, w: f64, x: &Self);
}

impl Pt for DVec3 {
    #[inline]
    fn zero() -> Self {
        DVec3::ZERO
    }
    #[inline]
    fn axpy(&mut self, w: f64, x: &Self) {
        *self += w * *x;
    }
}

/// Sparse weights over control vertices, sorted by index.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct Sparse(pub Vec<(u32, f64)>);

impl Sparse {
    pub fn unit(i: u32) -> Self {
        Sparse(vec![(i, 1.0)])
    }
}

impl Pt for Sparse {
    fn zero() -> Self {
        Sparse(Vec::new())
    }
    fn axpy(&mut self, w: f64, x: &Self) {
        if w == 0.0 {
            return;
        }
        let a = &self.0;
        let b = &x.0;
        let mut out = Vec::with_capacity(a.len() + b.len());
        let (mut i, mut j) = (0, 0);
        while i < a.len() || j < b.len() {
            if j == b.len() || (i < a.len() && a[i].0 < b[j].0) {
                out.push(a[i]);
                i += 1;
            } else if i == a.len() || b[j].0 < a[i].0 {
                out.push((b[j].0, w * b[j].1));
                j += 1;
            } else {
                out.push((a[i].0, a[i].1 + w * b[j].1));
                i += 1;
                j += 1;
            }
        }
        self.0 = out;
    }
}

/// `Σ w_i x_i`.
#[inline]
pub(crate) fn comb<P: Pt>(terms: &[(f64, &P)]) -> P {
    let mut r = P::zero();
    for (w, x) in terms {
        r.axpy(*w, x);
    }
    r
}

/// The Sdc options that change the refinement of positions.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) struct Rules {
    /// `VTX_BOUNDARY_EDGE_AND_CORNER`: a boundary vertex with one face is
    /// an infinitely sharp corner (`Sdc::Crease::SharpenBoundaryVertex`).
    /// Boundary edges are infinitely sharp under every option (Sdc's
    /// `SharpenBoundaryEdge`, even for "none").
    pub sharpen_corners: bool,
    /// `CREASE_CHAIKIN`.
    pub chaikin: bool,
    /// `TRI_SUB_SMOOTH`.
    pub smooth_triangles: bool,
    /// Sharpness as OpenSubdiv's f32 (the default). Off, the sharpness as
    /// written (f64) is followed instead: only to measure what the f32
    /// rounding does to a surface.
    pub f32_sharpness: bool,
}

impl Default for Rules {
    /// The crate's conventions: edge and corner, uniform, Catmark.
    fn default() -> Self {
        Rules {
            sharpen_corners: true,
            chaikin: false,
            smooth_triangles: false,
            f32_sharpness: true,
        }
    }
}

impl Rules {
    pub fn from_scheme(s: &crate::mesh::SchemeOptions) -> Self {
        use crate::mesh::{BoundaryInterpolation, CreaseMethod, TriangleSubdivision};
        Rules {
            sharpen_corners: s.boundary == BoundaryInterpolation::EdgeAndCorner,
            chaikin: s.crease_method == CreaseMethod::Chaikin,
            smooth_triangles: s.triangles == TriangleSubdivision::Smooth,
            f32_sharpness: true,
        }
    }

    /// A sharpness value or the result of one operation on sharpness
    /// values, as Sdc computes it: rounded to f32. (One f64 operation on f32
    /// operands rounded to f32 is the f32 operation: f64 has more than
    /// 2·24 + 2 bits.)
    #[inline]
    pub fn sharp(self, s: f64) -> f64 {
        if self.f32_sharpness {
            s as f32 as f64
        } else {
            s
        }
    }
}

/// Sharpness of the child of an edge of sharpness `s` at a vertex whose
/// incident edges have sharpness `at_vertex` (`s` among them):
/// `Sdc::Crease::SubdivideEdgeSharpnessAtVertex`. Uniform: [`decrement`].
/// Chaikin: `0.75 s + 0.25 avg(other semi-sharp edges at the vertex) - 1`,
/// in f32 like Sdc.
pub(crate) fn child_edge_sharpness(rules: Rules, s: f64, at_vertex: &[f64]) -> f64 {
    if !rules.chaikin || at_vertex.len() < 2 {
        return decrement(s);
    }
    if s <= 0.0 {
        return 0.0;
    }
    if s >= INF {
        return INF;
    }
    let r = |x: f64| rules.sharp(x);
    let (mut sum, mut count) = (0.0, 0u32);
    for &x in at_vertex {
        if x > 0.0 && x < INF {
            sum = r(sum + x);
            count += 1;
        }
    }
    let mut e = s;
    if count > 1 {
        let avg = r(r(sum - e) / (count - 1) as f64);
        e = r(r(0.75 * e) + r(0.25 * avg));
    }
    e = r(e - 1.0);
    if e > 0.0 {
        e
    } else {
        0.0
    }
}

/// `Sdc::Crease::SubdivideUniformSharpness`: infinite stays infinite,
/// otherwise one less per level, clamped at 0.
#[inline]
pub(crate) fn decrement(s: f64) -> f64 {
    if s >= INF {
        s
    } else if s > 1.0 {
        s - 1.0
    } else {
        0.0
    }
}

#[inline]
pub(crate) fn key(a: u32, b: u32) -> (u32, u32) {
    if a < b {
        (a, b)
    } else {
        (b, a)
    }
}

/// `Sdc::Crease::Rule` (dart merged into smooth: both use the smooth masks).
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub(crate) enum Rule {
    Smooth,
    Crease,
    Corner,
}

/// `Sdc::Crease::DetermineVertexVertexRule`.
pub(crate) fn vertex_rule(vertex_sharpness: f64, edge_sharpness: &[f64]) -> Rule {
    if vertex_sharpness > 0.0 {
        return Rule::Corner;
    }
    match edge_sharpness.iter().filter(|&&s| s > 0.0).count() {
        0 | 1 => Rule::Smooth,
        2 => Rule::Crease,
        _ => Rule::Corner,
    }
}

/// A polygon mesh with per-vertex points and user sharpness (boundaries are
/// read from the topology, see the module doc).
#[derive(Clone, Debug)]
pub(crate) struct Topo<P> {
    pub pts: Vec<P>,
    pub vsharp: Vec<f64>,
    pub foff: Vec<u32>,
    pub fv: Vec<u32>,
    /// Non-zero crease sharpness by sorted vertex pair.
    pub esharp: HashMap<(u32, u32), f64>,
    pub rules: Rules,
    /// Per face corner (parallel to `fv`): the id of the edge from it to
    /// the next corner, where refinement knows it; empty when an edge is
    /// its pair of vertices. One Loop step of two triangles on the same
    /// three vertices (back to back) joins their edge points by two
    /// distinct edges, which OpenSubdiv's `Vtr` keeps apart and a pair key
    /// would merge. (Such doubled edges are never sharp: they are children
    /// of face interiors, and of such children.)
    pub fe: Vec<u32>,
}

/// Adjacency derived from a [`Topo`].
pub(crate) struct Adj {
    pub edges: Vec<(u32, u32)>,
    pub edge_id: HashMap<(u32, u32), u32>,
    pub edge_faces: Vec<[u32; 2]>,
    pub edge_nfaces: Vec<u8>,
    /// Directed edge `a -> b` to the face that contains it (one of them,
    /// for a doubled edge: walk with `corner_edge` there).
    pub directed: HashMap<(u32, u32), u32>,
    /// Per face corner (parallel to `Topo::fv`): the edge from it to the
    /// next corner.
    pub corner_edge: Vec<u32>,
    pub vedges: Vec<Vec<u32>>,
    pub vfaces: Vec<Vec<u32>>,
}

impl<P> Topo<P> {
    pub fn num_faces(&self) -> usize {
        self.foff.len() - 1
    }
    #[inline]
    pub fn face(&self, f: u32) -> &[u32] {
        &self.fv[self.foff[f as usize] as usize..self.foff[f as usize + 1] as usize]
    }

    pub fn adjacency(&self) -> Adj {
        let nv = self.pts.len();
        let mut a = Adj {
            edges: Vec::new(),
            edge_id: HashMap::default(),
            edge_faces: Vec::new(),
            edge_nfaces: Vec::new(),
            directed: HashMap::default(),
            vedges: vec![Vec::new(); nv],
            vfaces: vec![Vec::new(); nv],
            corner_edge: Vec::with_capacity(self.fv.len()),
        };
        // Explicit edge ids (`fe`): slot `e` is edge `e`, made on its first
        // use, as the pair keys make theirs.
        let mut made: Vec<bool> = Vec::new();
        for f in 0..self.num_faces() as u32 {
            let fv = self.face(f);
            let n = fv.len();
            let base = self.foff[f as usize] as usize;
            for k in 0..n {
                let (p, q) = (fv[k], fv[(k + 1) % n]);
                a.vfaces[p as usize].push(f);
                a.directed.insert((p, q), f);
                let kk = key(p, q);
                let e = if self.fe.is_empty() {
                    *a.edge_id.entry(kk).or_insert_with(|| {
                        a.edges.push(kk);
                        a.edge_faces.push([u32::MAX; 2]);
                        a.edge_nfaces.push(0);
                        a.vedges[p as usize].push(a.edges.len() as u32 - 1);
                        a.vedges[q as usize].push(a.edges.len() as u32 - 1);
                        a.edges.len() as u32 - 1
                    }) as usize
                } else {
                    let e = self.fe[base + k] as usize;
                    if e >= made.len() {
                        made.resize(e + 1, false);
                        a.edges.resize(e + 1, (u32::MAX, u32::MAX));
                        a.edge_faces.resize(e + 1, [u32::MAX; 2]);
                        a.edge_nfaces.resize(e + 1, 0);
                    }
                    if !made[e] {
                        made[e] = true;
                        a.edges[e] = kk;
                        a.edge_id.entry(kk).or_insert(e as u32);
                        a.vedges[p as usize].push(e as u32);
                        a.vedges[q as usize].push(e as u32);
                    }
                    e
                };
                a.corner_edge.push(e as u32);
                let c = a.edge_nfaces[e] as usize;
                if c < 2 {
                    a.edge_faces[e][c] = f;
                }
                a.edge_nfaces[e] = a.edge_nfaces[e].saturating_add(1);
            }
        }
        a
    }

    /// Effective sharpness of edge `e`: boundary edges are infinitely sharp.
    #[inline]
    pub fn edge_sharp(&self, adj: &Adj, e: u32) -> f64 {
        if adj.edge_nfaces[e as usize] < 2 {
            INF
        } else {
            let (p, q) = adj.edges[e as usize];
            self.esharp.get(&(p, q)).copied().unwrap_or(0.0)
        }
    }
    /// Effective corner sharpness: with `VTX_BOUNDARY_EDGE_AND_CORNER` a
    /// boundary vertex with a single face is an infinitely sharp corner.
    #[inline]
    pub fn vert_sharp(&self, adj: &Adj, v: u32) -> f64 {
        let vi = v as usize;
        if self.rules.sharpen_corners && adj.vfaces[vi].len() == 1 && adj.vedges[vi].len() == 2 {
            INF
        } else {
            self.vsharp[vi]
        }
    }
    /// The face across the edge from corner `k` of face `f` to the next
    /// corner (`None` on a boundary): walks go face to face this way, not
    /// by vertex pairs, since two edges can join one pair (`fe`).
    pub fn across(&self, adj: &Adj, f: u32, k: usize) -> Option<u32> {
        let e = adj.corner_edge[self.foff[f as usize] as usize + k] as usize;
        let [a, b] = adj.edge_faces[e];
        (adj.edge_nfaces[e] == 2).then_some(if a == f { b } else { a })
    }

    pub fn other(&self, adj: &Adj, e: u32, v: u32) -> u32 {
        let (p, q) = adj.edges[e as usize];
        if p == v {
            q
        } else {
            p
        }
    }

    /// The sub-mesh made of `first` (if any, it becomes face 0 with the
    /// same vertex rotation) and all faces around `verts`. Returns it and the
    /// old-to-new vertex map (`u32::MAX` for vertices left out).
    pub fn ring(&self, adj: &Adj, verts: &[u32], first: Option<u32>) -> (Topo<P>, Vec<u32>)
    where
        P: Clone,
    {
        let mut faces: Vec<u32> = Vec::with_capacity(16);
        if let Some(f) = first {
            faces.push(f);
        }
        for &v in verts {
            for &f in &adj.vfaces[v as usize] {
                if !faces.contains(&f) {
                    faces.push(f);
                }
            }
        }
        let mut map = vec![u32::MAX; self.pts.len()];
        let mut t = Topo {
            pts: Vec::new(),
            vsharp: Vec::new(),
            foff: vec![0],
            fv: Vec::new(),
            esharp: HashMap::default(),
            rules: self.rules,
            fe: Vec::new(),
        };
        // Explicit edges keep their identity, renumbered densely.
        let mut emap: HashMap<u32, u32> = HashMap::default();
        for &f in &faces {
            let base = self.foff[f as usize] as usize;
            for (k, &v) in self.face(f).iter().enumerate() {
                if map[v as usize] == u32::MAX {
                    map[v as usize] = t.pts.len() as u32;
                    t.pts.push(self.pts[v as usize].clone());
                    t.vsharp.push(self.vsharp[v as usize]);
                }
                t.fv.push(map[v as usize]);
                if !self.fe.is_empty() {
                    let next = emap.len() as u32;
                    t.fe.push(*emap.entry(self.fe[base + k]).or_insert(next));
                }
            }
            t.foff.push(t.fv.len() as u32);
        }
        for (&(p, q), &s) in &self.esharp {
            let (a, b) = (map[p as usize], map[q as usize]);
            if a != u32::MAX && b != u32::MAX && adj.edge_id.contains_key(&(p, q)) {
                t.esharp.insert(key(a, b), s);
            }
        }
        (t, map)
    }
}

impl<P: Pt> Topo<P> {
    /// Index of the child vertex of edge `e` in the refined mesh.
    #[inline]
    pub fn edge_child(&self, e: u32) -> u32 {
        self.pts.len() as u32 + e
    }
    /// The corner and crease vertex masks, which Catmark and Loop share
    /// (Sdc `assignCornerMaskForVertex`, `assignCreaseMaskForVertex`:
    /// 3/4 of the vertex, 1/8 of each end of its two sharp edges); `None`
    /// for a smooth vertex, whose mask is the scheme's own.
    pub(crate) fn sharp_vertex_mask(
        &self,
        adj: &Adj,
        v: u32,
        rule: Rule,
        sharp: &[f64],
    ) -> Option<P> {
        let vi = v as usize;
        let x = &self.pts[vi];
        match rule {
            Rule::Corner => Some(x.clone()),
            Rule::Crease => {
                let mut r = P::zero();
                r.axpy(0.75, x);
                for (k, &e) in adj.vedges[vi].iter().enumerate() {
                    if sharp[k] > 0.0 {
                        r.axpy(0.125, &self.pts[self.other(adj, e, v) as usize]);
                    }
                }
                Some(r)
            }
            Rule::Smooth => None,
        }
    }

    fn vertex_mask(&self, adj: &Adj, v: u32, rule: Rule, sharp: &[f64], fpts: &[P]) -> P {
        if let Some(r) = self.sharp_vertex_mask(adj, v, rule, sharp) {
            return r;
        }
        let vi = v as usize;
        let x = &self.pts[vi];
        // Catmark smooth vertex rule with face centroids
        // (Sdc `assignSmoothMaskForVertex`): (n-2)/n v + Σe/n² + ΣF/n².
        let n = adj.vedges[vi].len() as f64;
        let mut r = P::zero();
        r.axpy((n - 2.0) / n, x);
        let w = 1.0 / (n * n);
        for &e in &adj.vedges[vi] {
            r.axpy(w, &self.pts[self.other(adj, e, v) as usize]);
        }
        for &f in &adj.vfaces[vi] {
            r.axpy(w, &fpts[f as usize]);
        }
        r
    }

    /// Edge point of edge `e`: smooth `(v0 + v1 + F0 + F1)/4`, sharp
    /// midpoint, and a fractional sharpness in (0, 1) blends the two (Sdc
    /// `ComputeEdgeVertexMask`). `fpts` are the face points.
    fn edge_point(&self, adj: &Adj, e: u32, fpts: &[P]) -> P {
        let (a, b) = adj.edges[e as usize];
        let s = self.edge_sharp(adj, e);
        let mid = comb(&[(0.5, &self.pts[a as usize]), (0.5, &self.pts[b as usize])]);
        if adj.edge_nfaces[e as usize] != 2 || self.edge_child_is_crease(adj, e) {
            return mid;
        }
        let [f0, f1] = adj.edge_faces[e as usize];
        // TRI_SUB_SMOOTH (`Sdc::Scheme<CATMARK>::assignSmoothMaskForEdge`,
        // Hbr's order of operations): a triangle's face weight 0.47 instead
        // of 0.25, both faces get the average, the vertices the rest. Only
        // level 0 has triangles.
        let tri = |f: u32| self.rules.smooth_triangles && self.face(f).len() == 3;
        let (fw, vw) = if tri(f0) || tri(f1) {
            let w = |f: u32| if tri(f) { 0.470 } else { 0.25 };
            let fw = 0.5 * (w(f0) + w(f1));
            (fw, 0.5 * (1.0 - 2.0 * fw))
        } else {
            (0.25, 0.25)
        };
        let smooth = comb(&[
            (vw, &self.pts[a as usize]),
            (vw, &self.pts[b as usize]),
            (fw, &fpts[f0 as usize]),
            (fw, &fpts[f1 as usize]),
        ]);
        if s > 0.0 {
            comb(&[(s, &mid), (1.0 - s, &smooth)])
        } else {
            smooth
        }
    }

    /// Whether the edge point of sharp edge `e` follows the crease rule: Vtr
    /// gives `ComputeEdgeVertexMask` the child vertex's rule, a crease when
    /// both child edges are still sharp. Uniform creasing: `s > 1`. Chaikin:
    /// each child edge's sharpness comes from the rule at its end vertex, so
    /// an edge of sharpness above 1 can end smooth (then the smooth mask is
    /// blended by the parent sharpness, above 1 too, as Sdc does without a
    /// clamp) and one below 1 can stay a crease.
    pub(crate) fn edge_child_is_crease(&self, adj: &Adj, e: u32) -> bool {
        let s = self.edge_sharp(adj, e);
        if s >= INF {
            return true;
        }
        if !self.rules.chaikin {
            return decrement(s) > 0.0;
        }
        let (a, b) = adj.edges[e as usize];
        let at = |v: u32| -> Vec<f64> {
            adj.vedges[v as usize]
                .iter()
                .map(|&g| self.edge_sharp(adj, g))
                .collect()
        };
        child_edge_sharpness(self.rules, s, &at(a)) > 0.0
            && child_edge_sharpness(self.rules, s, &at(b)) > 0.0
    }

    /// The child of vertex `v` (Sdc `ComputeVertexVertexMask`, shared by
    /// Catmark and Loop): the parent rule's mask, or for a transition between
    /// rules (a semi-sharp feature running out at this level) a blend of the
    /// parent and child masks weighted by
    /// `Crease::ComputeFractionalWeightAtVertex`. `mask(rule, sharpness of
    /// the incident edges in `adj.vedges` order)` is the scheme's mask.
    pub(crate) fn vertex_point(&self, adj: &Adj, v: u32, mask: impl Fn(Rule, &[f64]) -> P) -> P {
        let vi = v as usize;
        let ps: Vec<f64> = adj.vedges[vi]
            .iter()
            .map(|&e| self.edge_sharp(adj, e))
            .collect();
        let cs: Vec<f64> = if self.rules.chaikin {
            ps.iter()
                .map(|&s| child_edge_sharpness(self.rules, s, &ps))
                .collect()
        } else {
            ps.iter().map(|&s| decrement(s)).collect()
        };
        let psv = self.vert_sharp(adj, v);
        let csv = decrement(psv);
        let prule = vertex_rule(psv, &ps);
        let crule = vertex_rule(csv, &cs);
        if prule == Rule::Smooth || prule == crule {
            return mask(prule, &ps);
        }
        // In f32 like Sdc (`ComputeFractionalWeightAtVertex`). Sdc sums the
        // edges in its own order around the vertex: with three or more
        // distinct sharpness values running out at once the f32 sum may
        // differ in the last bit (a weight error of ~6e-8, far below the
        // tolerance); the suite has none.
        let r = |x: f64| self.rules.sharp(x);
        let mut count = 0u32;
        let mut sum = 0.0;
        if psv > 0.0 && csv <= 0.0 {
            count += 1;
            sum = r(sum + psv);
        }
        for k in 0..ps.len() {
            if ps[k] > 0.0 && cs[k] <= 0.0 {
                count += 1;
                sum = r(sum + ps[k]);
            }
        }
        let w = if count == 0 {
            0.0
        } else {
            r(sum / count as f64).min(1.0)
        };
        let pm = mask(prule, &ps);
        let cm = mask(crule, &cs);
        comb(&[(w, &pm), (1.0 - w, &cm)])
    }

    /// Sharpness of the child edges of the sharp edges (keyed by child
    /// vertex pairs, edge points numbered `nv + edge id` as in both
    /// refinements): each child edge takes its sharpness from the rule at
    /// its parent end vertex (Vtr `Refinement::subdivideEdgeSharpness`).
    pub(crate) fn child_edge_sharpness(&self, adj: &Adj) -> HashMap<(u32, u32), f64> {
        let nv = self.pts.len();
        let mut esharp = HashMap::default();
        let mut around = Vec::new();
        for &(a, b) in self.esharp.keys() {
            let Some(&e) = adj.edge_id.get(&(a, b)) else {
                continue;
            };
            let s = self.edge_sharp(adj, e);
            let ep = nv as u32 + e;
            for end in [a, b] {
                let d = if self.rules.chaikin {
                    around.clear();
                    around.extend(
                        adj.vedges[end as usize]
                            .iter()
                            .map(|&x| self.edge_sharp(adj, x)),
                    );
                    child_edge_sharpness(self.rules, s, &around)
                } else {
                    decrement(s)
                };
                if d > 0.0 {
                    esharp.insert(key(end, ep), d);
                }
            }
        }
        esharp
    }

    /// One level of Catmull-Clark refinement. Child vertices are numbered
    /// vertex points, then edge points (by edge id), then face points; child
    /// face `foff[f] + k` of face `f` is the quad at its corner k,
    /// `(v_k, e(k, k+1), f, e(k-1, k))`.
    pub fn refine(&self, adj: &Adj) -> Topo<P> {
        let nv = self.pts.len();
        let ne = adj.edges.len();
        let nf = self.num_faces();
        let mut pts = Vec::with_capacity(nv + ne + nf);
        let fpts: Vec<P> = (0..nf as u32)
            .map(|f| {
                let fv = self.face(f);
                let w = 1.0 / fv.len() as f64;
                let mut r = P::zero();
                for &v in fv {
                    r.axpy(w, &self.pts[v as usize]);
                }
                r
            })
            .collect();
        for v in 0..nv as u32 {
            let p = self.vertex_point(adj, v, |rule, sharp| {
                self.vertex_mask(adj, v, rule, sharp, &fpts)
            });
            pts.push(p);
        }
        for e in 0..ne as u32 {
            let p = self.edge_point(adj, e, &fpts);
            pts.push(p);
        }
        pts.extend(fpts);

        let mut fv = Vec::with_capacity(4 * self.fv.len());
        let mut foff = Vec::with_capacity(self.fv.len() + 1);
        foff.push(0u32);
        for f in 0..nf as u32 {
            let c = self.face(f);
            let n = c.len();
            let fp = (nv + ne) as u32 + f;
            for k in 0..n {
                let (p, q, r) = (c[(k + n - 1) % n], c[k], c[(k + 1) % n]);
                fv.extend_from_slice(&[
                    q,
                    nv as u32 + adj.edge_id[&key(q, r)],
                    fp,
                    nv as u32 + adj.edge_id[&key(p, q)],
                ]);
                foff.push(fv.len() as u32);
            }
        }
        let esharp = self.child_edge_sharpness(adj);
        let mut vsharp: Vec<f64> = self.vsharp.iter().map(|&s| decrement(s)).collect();
        vsharp.resize(nv + ne + nf, 0.0);
        Topo {
            pts,
            vsharp,
            foff,
            fv,
            esharp,
            rules: self.rules,
            fe: Vec::new(),
        }
    }
}

/// The faces `faces` of `mesh` (all of them when `None`) as a [`Topo`] whose
/// points are global vertex ids, vertices renumbered in order of appearance
/// (face `faces[0]` keeps its vertex rotation). Returns the local-to-global
/// vertex map in `pts`.
pub(crate) fn topo_from_mesh(
    mesh: &crate::mesh::ControlMesh,
    faces: Option<&[crate::mesh::FaceId]>,
    rules: Rules,
) -> Topo<u32> {
    use crate::mesh::FaceId;
    let all: Vec<FaceId>;
    let faces = match faces {
        Some(f) => f,
        None => {
            all = mesh.faces().collect();
            &all
        }
    };
    let whole = faces.len() == mesh.num_faces();
    let mut map: HashMap<u32, u32> = HashMap::default();
    let mut t = Topo {
        pts: Vec::new(),
        vsharp: Vec::new(),
        foff: vec![0],
        fv: Vec::new(),
        esharp: HashMap::default(),
        rules,
        fe: Vec::new(),
    };
    if whole {
        t.pts = (0..mesh.num_vertices() as u32).collect();
        t.vsharp = mesh
            .vertices()
            .map(|v| rules.sharp(mesh.vertex_sharpness(v)))
            .collect();
    }
    for &f in faces {
        for h in mesh.face_halfedges(f) {
            let v = mesh.tail(h);
            let id = if whole {
                v.0
            } else {
                *map.entry(v.0).or_insert_with(|| {
                    t.pts.push(v.0);
                    t.vsharp.push(rules.sharp(mesh.vertex_sharpness(v)));
                    t.pts.len() as u32 - 1
                })
            };
            t.fv.push(id);
        }
        t.foff.push(t.fv.len() as u32);
    }
    for f in faces {
        for h in mesh.face_halfedges(*f) {
            let s = rules.sharp(mesh.edge_sharpness(h.edge()));
            if s > 0.0 {
                let (a, b) = (mesh.tail(h).0, mesh.head(h).0);
                let (a, b) = if whole { (a, b) } else { (map[&a], map[&b]) };
                t.esharp.insert(key(a, b), s);
            }
        }
    }
    t
}

/// Faces of the 1-ring of face `f`: `f` first, then the faces around each
/// of its vertices — the neighbourhood both exact evaluators (Catmark and
/// Loop) subdivide around a location.
pub(crate) fn face_ring(
    mesh: &crate::mesh::ControlMesh,
    f: crate::mesh::FaceId,
) -> Vec<crate::mesh::FaceId> {
    let mut faces = vec![f];
    for v in mesh.face_vertices(f) {
        for g in mesh.vertex_faces(v) {
            if !faces.contains(&g) {
                faces.push(g);
            }
        }
    }
    faces
}

impl Topo<u32> {
    /// The same topology with point `f(i)` for control vertex `i`:
    /// positions to evaluate, or unit [`Sparse`] rows to build stencils.
    pub(crate) fn with_points<P>(self, f: impl Fn(u32) -> P) -> Topo<P> {
        Topo {
            pts: self.pts.iter().map(|&i| f(i)).collect(),
            vsharp: self.vsharp,
            foff: self.foff,
            fv: self.fv,
            esharp: self.esharp,
            rules: self.rules,
            fe: self.fe,
        }
    }
}

/// Sparse rows (position, du, dv) merged into one index list, sorted, with
/// three weights per index.
pub(crate) fn merge3(rows: [&Sparse; 3]) -> Vec<(u32, [f64; 3])> {
    let mut all: Vec<(u32, [f64; 3])> = Vec::with_capacity(rows.iter().map(|s| s.0.len()).sum());
    for (k, s) in rows.into_iter().enumerate() {
        for &(i, w) in &s.0 {
            let mut x = [0.0; 3];
            x[k] = w;
            all.push((i, x));
        }
    }
    all.sort_by_key(|e| e.0);
    let mut out: Vec<(u32, [f64; 3])> = Vec::with_capacity(all.len());
    for (i, w) in all {
        match out.last_mut() {
            Some(l) if l.0 == i => {
                for (a, b) in l.1.iter_mut().zip(w) {
                    *a += b;
                }
            }
            _ => out.push((i, w)),
        }
    }
    out
}
