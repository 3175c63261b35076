//! Stam and Loop's quad/triangle subdivision ("Quad/triangle subdivision",
//! CGF 22(1), 2003), the scheme of Lavoué et al.'s mechanical mode (§2):
//! Catmull-Clark on quads, Loop on triangles, C1 across the quad/triangle
//! boundary.
//!
//! One step is the two-stage factorisation of the paper:
//!
//! 1. **Linear subdivision**: every edge gets its midpoint, every quad its
//!    centroid; a quad splits into 4 quads `(v_k, e(k,k+1), c, e(k-1,k))`, a
//!    triangle into 3 corner triangles `(v_k, e(k,k+1), e(k-1,k))` and the
//!    centre triangle `(e01, e12, e20)`.
//! 2. **Averaging**: every vertex `w` of the linearly subdivided mesh is
//!    replaced by `w + γ (A - w)`, `A` being the mean over its faces of a
//!    per-face "centroid": the plain centroid of a quad, `¼ w + ⅜ (a + b)`
//!    for a triangle `(w, a, b)`.
//!
//! `γ` depends on the numbers of quads `n_q` and triangles `n_t` around `w`
//! (Lavoué et al. Fig. 5c; the ordering of the faces does not matter):
//! - `n_t = 0`: `γ = 4/n`. With it the step is *exactly* Catmull-Clark (with
//!   OpenSubdiv's smooth vertex rule `(n-2)/n v + Σe/n² + Σf/n²`, face
//!   centroids `f`): `A = v/2 + Σe/(4n) + Σf/(4n)`.
//! - `n_q = 0`: `γ = (8/3)(5/8 - (3/8 + ¼ cos 2π/n)²)`, which makes the step
//!   *exactly* Loop's rule `(1 - nβ) v + β Σe` with Loop's β (OpenSubdiv's
//!   `Sdc::Scheme<SCHEME_LOOP>`), since here `A = ⅝ v + ⅜ Σe/n`.
//! - the regular quad/triangle configuration (2 quads, 3 triangles, the
//!   configuration of every new vertex on a quad/triangle boundary): `γ = 1`.
//! - any other mixed vertex: the quad/triangle-share blend
//!   `γ = (n_q/n)(4/n) + (n_t/n) γ_Loop(n)` ("Loop-style" at triangle-heavy
//!   vertices, Catmull-Clark-style at quad-heavy ones). The paper's exact
//!   curvature-optimised weights for these vertices are not reproduced (the
//!   paper was not at hand); this choice is affine invariant, reduces to both
//!   parent schemes, and converges (tests/quadtri_differential.rs).
//!
//! Every new edge and face vertex has one of the configurations (4, 0),
//! (0, 6), (2, 3), all with `γ = 1`, which reproduces Catmull-Clark's and
//! Loop's edge and face rules; only control vertices (and their children)
//! are extraordinary.
//!
//! Sharp features (boundary "edge and corner" as in OpenSubdiv, see
//! [`crate::subdiv`]): boundary edges and infinitely sharp creases split into
//! two sharp halves; a vertex with two sharp edges is averaged along them
//! only (`½ w + ¼ (a + b)`, i.e. the 1-6-1 curve rule `¾ v + ⅛ (a + b)` with
//! midpoints on the edges, whatever the faces); three or more sharp edges,
//! an infinitely sharp corner or a boundary vertex with a single face stay
//! put; one sharp edge (a dart) is smooth. These are OpenSubdiv's rules for
//! both schemes. Semi-sharp creases and corners are refused with a typed
//! error ([`check_mesh`]).
//!
//! Refined vertices are numbered: children of vertices (same index as the
//! parent), then of edges (in order of first appearance in the face list),
//! then of quads (in face order). Child faces are numbered by parent face,
//! then by corner (and the centre triangle last).

mod limit;

pub use limit::{vertex_limit_stencils, QuadTriEvaluator, DEFAULT_EVAL_LEVEL};

use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, VertexId, INFINITELY_SHARP};
use crate::subdiv::catmark::topo::{key, topo_from_mesh, Adj, Pt, Rules, Sparse, Topo, INF};
use crate::DVec3;

/// The most levels [`QuadTriRefiner`] accepts: each level multiplies the
/// face count by 4.
pub const MAX_LEVELS: u32 = 8;

/// The parent component of a refined vertex, in the parent level's indices.
#[derive(Copy, Clone, Debug, PartialEq, Eq)]
pub enum Parent {
    Vertex(u32),
    /// An edge by its two vertices (smaller index first).
    Edge(u32, u32),
    /// A quad (triangles have no child vertex).
    Face(u32),
}

/// Sparse rows (CSR): each row a weighted sum of the vertices of a coarser
/// level; indices sorted within a row, weights summing to 1.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SparseRows {
    /// `offsets[i]..offsets[i + 1]` indexes `indices` and `weights` for row i.
    pub offsets: Vec<u32>,
    pub indices: Vec<u32>,
    pub weights: Vec<f64>,
}

impl SparseRows {
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    pub fn row(&self, i: usize) -> impl Iterator<Item = (u32, f64)> + '_ {
        let r = self.offsets[i] as usize..self.offsets[i + 1] as usize;
        self.indices[r.clone()]
            .iter()
            .copied()
            .zip(self.weights[r].iter().copied())
    }
    /// The rows applied to coarse positions.
    pub fn apply(&self, coarse: &[DVec3]) -> Vec<DVec3> {
        (0..self.len())
            .map(|i| {
                self.row(i)
                    .fold(DVec3::ZERO, |acc, (j, w)| acc + w * coarse[j as usize])
            })
            .collect()
    }

    pub(crate) fn from_sparse(rows: &[Sparse]) -> Self {
        let mut s = SparseRows {
            offsets: Vec::with_capacity(rows.len() + 1),
            ..Default::default()
        };
        s.offsets.push(0);
        for r in rows {
            for &(i, w) in &r.0 {
                s.indices.push(i);
                s.weights.push(w);
            }
            s.offsets.push(s.indices.len() as u32);
        }
        s
    }

    /// `self · coarse`: rows of `self` over the columns of `coarse`
    /// (`ncols` of them).
    pub fn compose(&self, coarse: &SparseRows, ncols: usize) -> SparseRows {
        let mut acc = vec![0.0; ncols];
        let mut seen = vec![false; ncols];
        let mut touched: Vec<u32> = Vec::new();
        let mut out = SparseRows {
            offsets: vec![0],
            ..Default::default()
        };
        for i in 0..self.len() {
            for (j, w) in self.row(i) {
                for (k, x) in coarse.row(j as usize) {
                    if !seen[k as usize] {
                        seen[k as usize] = true;
                        touched.push(k);
                    }
                    acc[k as usize] += w * x;
                }
            }
            touched.sort_unstable();
            for &k in &touched {
                out.indices.push(k);
                out.weights.push(acc[k as usize]);
                acc[k as usize] = 0.0;
                seen[k as usize] = false;
            }
            touched.clear();
            out.offsets.push(out.indices.len() as u32);
        }
        out
    }
}

/// Checks that `mesh` is something the scheme refines: no deleted
/// elements, triangles and quads only, sharpness either 0 or infinite.
pub fn check_mesh(mesh: &ControlMesh) -> Result<()> {
    if mesh.has_deletions() {
        return Err(Error::InvalidArgument(
            "quad/triangle subdivision: the control mesh has deleted elements; compact it first"
                .into(),
        ));
    }
    mesh.validate()?;
    for f in mesh.faces() {
        let n = mesh.face_size(f);
        if n != 3 && n != 4 {
            return Err(Error::topology(
                f.to_string(),
                format!("has {n} corners; the quad/triangle scheme takes triangles and quads only"),
            ));
        }
    }
    for (a, b, s) in mesh.creases() {
        if s < INFINITELY_SHARP {
            return Err(Error::topology(
                format!("edge ({}, {})", a.0, b.0),
                format!(
                    "semi-sharp crease (sharpness {s}) is not supported by the quad/triangle \
                     scheme, only smooth (0) or infinitely sharp ({INFINITELY_SHARP}) edges"
                ),
            ));
        }
    }
    for (v, s) in mesh.corners() {
        if s < INFINITELY_SHARP {
            return Err(Error::topology(
                format!("{v}"),
                format!(
                    "semi-sharp corner (sharpness {s}) is not supported by the quad/triangle \
                     scheme, only infinitely sharp ({INFINITELY_SHARP}) corners"
                ),
            ));
        }
    }
    Ok(())
}

/// `γ(n_q, n_t)` of the averaging step; see the module doc.
pub fn averaging_weight(nq: usize, nt: usize) -> f64 {
    let n = (nq + nt) as f64;
    if nt == 0 {
        4.0 / n
    } else if nq == 0 {
        loop_gamma(nt)
    } else if (nq, nt) == (2, 3) {
        1.0
    } else {
        (nq as f64 / n) * (4.0 / n) + (nt as f64 / n) * loop_gamma(nq + nt)
    }
}

/// `γ` that turns centroid averaging into Loop's vertex rule, with
/// OpenSubdiv's β (`Sdc::Scheme<SCHEME_LOOP>::assignSmoothMaskForVertex`):
/// `β n = 5/8 - (3/8 + ¼ cos 2π/n)²` and `γ = 8 β n / 3`; exactly 1 at
/// valence 6.
fn loop_gamma(n: usize) -> f64 {
    if n == 6 {
        return 1.0;
    }
    let b = 0.25 * (2.0 * std::f64::consts::PI / n as f64).cos() + 0.375;
    (0.625 - b * b) * 8.0 / 3.0
}

/// One refinement level's topology (points unused: sharpness and faces).
pub(crate) struct Level {
    pub topo: Topo<()>,
    pub adj: Adj,
}

impl Level {
    pub fn new(topo: Topo<()>) -> Self {
        let adj = topo.adjacency();
        Level { topo, adj }
    }
    pub fn num_vertices(&self) -> usize {
        self.topo.pts.len()
    }
    /// Incident sharp edges' other ends (boundary edges included).
    pub fn sharp_neighbours(&self, w: u32) -> Vec<u32> {
        self.adj.vedges[w as usize]
            .iter()
            .filter(|&&e| self.topo.edge_sharp(&self.adj, e) > 0.0)
            .map(|&e| self.topo.other(&self.adj, e, w))
            .collect()
    }
    pub fn is_corner(&self, w: u32) -> bool {
        self.topo.vert_sharp(&self.adj, w) > 0.0
    }
    /// Numbers of quads and triangles around `w`.
    pub fn face_counts(&self, w: u32) -> (usize, usize) {
        let mut q = 0;
        let mut t = 0;
        for &f in &self.adj.vfaces[w as usize] {
            if self.topo.face(f).len() == 4 {
                q += 1;
            } else {
                t += 1;
            }
        }
        (q, t)
    }
}

/// One step: the child level, its rows over the parent's vertices, the
/// children's parents, and the first child face of every parent face.
pub(crate) struct Step {
    pub child: Level,
    pub rows: Vec<Sparse>,
    pub parents: Vec<Parent>,
    pub face_base: Vec<u32>,
}

pub(crate) fn refine_step(p: &Level) -> Step {
    let (t, adj) = (&p.topo, &p.adj);
    let nv = t.pts.len();
    let nf = t.num_faces();
    let ev = |a: u32, b: u32| nv as u32 + adj.edge_id[&key(a, b)];

    // Linear subdivision: child vertices and their (linear) points.
    let mut parents: Vec<Parent> = (0..nv as u32).map(Parent::Vertex).collect();
    let mut lin: Vec<Sparse> = (0..nv as u32).map(Sparse::unit).collect();
    for &(a, b) in &adj.edges {
        parents.push(Parent::Edge(a, b));
        lin.push(Sparse(vec![(a, 0.5), (b, 0.5)]));
    }
    let mut fchild = vec![u32::MAX; nf];
    for f in 0..nf as u32 {
        let c = t.face(f);
        if c.len() == 4 {
            fchild[f as usize] = lin.len() as u32;
            parents.push(Parent::Face(f));
            let mut s: Vec<(u32, f64)> = c.iter().map(|&v| (v, 0.25)).collect();
            s.sort_by_key(|x| x.0);
            lin.push(Sparse(s));
        }
    }
    let nc = lin.len();
    let mut foff = vec![0u32];
    let mut fv = Vec::with_capacity(4 * t.fv.len());
    let mut face_base = Vec::with_capacity(nf);
    for f in 0..nf as u32 {
        face_base.push(foff.len() as u32 - 1);
        let c = t.face(f);
        let n = c.len();
        for k in 0..n {
            let (a, b, d) = (c[(k + n - 1) % n], c[k], c[(k + 1) % n]);
            if n == 4 {
                fv.extend_from_slice(&[b, ev(b, d), fchild[f as usize], ev(a, b)]);
            } else {
                fv.extend_from_slice(&[b, ev(b, d), ev(a, b)]);
            }
            foff.push(fv.len() as u32);
        }
        if n == 3 {
            fv.extend_from_slice(&[ev(c[0], c[1]), ev(c[1], c[2]), ev(c[2], c[0])]);
            foff.push(fv.len() as u32);
        }
    }
    let mut esharp = crate::subdiv::catmark::topo::HashMap::default();
    for (&(a, b), &s) in &t.esharp {
        if s >= INF {
            let m = ev(a, b);
            esharp.insert(key(a, m), INF);
            esharp.insert(key(b, m), INF);
        }
    }
    let mut vsharp = t.vsharp.clone();
    vsharp.resize(nc, 0.0);
    let child = Level::new(Topo {
        pts: vec![(); nc],
        vsharp,
        foff,
        fv,
        esharp,
        rules: Rules::default(),
        fe: Vec::new(),
    });

    // Averaging.
    let rows = (0..nc as u32)
        .map(|w| {
            let sharp = child.sharp_neighbours(w);
            let lw = &lin[w as usize];
            if child.is_corner(w) || sharp.len() >= 3 {
                lw.clone()
            } else if sharp.len() == 2 {
                let mut r = Sparse::zero();
                r.axpy(0.5, lw);
                r.axpy(0.25, &lin[sharp[0] as usize]);
                r.axpy(0.25, &lin[sharp[1] as usize]);
                r
            } else {
                let (nq, nt) = child.face_counts(w);
                let g = averaging_weight(nq, nt);
                let gf = g / (nq + nt) as f64;
                let mut r = Sparse::zero();
                r.axpy(1.0 - g, lw);
                for &f in &child.adj.vfaces[w as usize] {
                    let c = child.topo.face(f);
                    if c.len() == 4 {
                        for &x in c {
                            r.axpy(0.25 * gf, &lin[x as usize]);
                        }
                    } else {
                        for &x in c {
                            let wx = if x == w { 0.25 } else { 0.375 };
                            r.axpy(wx * gf, &lin[x as usize]);
                        }
                    }
                }
                r
            }
        })
        .collect();
    Step {
        child,
        rows,
        parents,
        face_base,
    }
}

/// A control mesh's topology refined `levels` times by the quad/triangle
/// scheme, with the subdivision matrices of every step. Positions are given
/// per call, so a fitting loop refines without re-preparing.
pub struct QuadTriRefiner {
    pub(crate) levels: Vec<Level>,
    /// `steps[l]`: level `l + 1`'s vertices over level `l`'s.
    steps: Vec<SparseRows>,
    parents: Vec<Vec<Parent>>,
    pub(crate) face_base: Vec<Vec<u32>>,
}

impl QuadTriRefiner {
    /// Refines the topology of `mesh` (see [`check_mesh`] for what is
    /// accepted) `levels` times, `levels <= MAX_LEVELS`.
    pub fn new(mesh: &ControlMesh, levels: u32) -> Result<Self> {
        if levels > MAX_LEVELS {
            return Err(Error::InvalidArgument(format!(
                "quad/triangle subdivision: {levels} levels requested, at most {MAX_LEVELS} supported"
            )));
        }
        check_mesh(mesh)?;
        let t0 = topo_from_mesh(mesh, None, Rules::default());
        let mut cur = Level::new(Topo {
            pts: vec![(); t0.pts.len()],
            vsharp: t0.vsharp,
            foff: t0.foff,
            fv: t0.fv,
            esharp: t0.esharp,
            rules: t0.rules,
            fe: Vec::new(),
        });
        let mut r = QuadTriRefiner {
            levels: Vec::new(),
            steps: Vec::new(),
            parents: Vec::new(),
            face_base: Vec::new(),
        };
        for _ in 0..levels {
            let s = refine_step(&cur);
            r.steps.push(SparseRows::from_sparse(&s.rows));
            r.parents.push(s.parents);
            r.face_base.push(s.face_base);
            r.levels.push(std::mem::replace(&mut cur, s.child));
        }
        r.levels.push(cur);
        Ok(r)
    }

    /// Number of refinement steps (the finest level's index).
    pub fn num_levels(&self) -> u32 {
        self.steps.len() as u32
    }
    pub fn num_vertices(&self, level: u32) -> usize {
        self.levels[level as usize].num_vertices()
    }
    pub fn num_faces(&self, level: u32) -> usize {
        self.levels[level as usize].topo.num_faces()
    }
    /// Vertices of face `f` of `level`.
    pub fn face(&self, level: u32, f: u32) -> &[u32] {
        self.levels[level as usize].topo.face(f)
    }
    /// Parent components of the vertices of `level` (1..=num_levels).
    pub fn parents(&self, level: u32) -> &[Parent] {
        &self.parents[level as usize - 1]
    }
    /// The subdivision matrix from `level - 1` to `level`.
    pub fn step(&self, level: u32) -> &SparseRows {
        &self.steps[level as usize - 1]
    }
    /// First child face of each face of `level` in `level + 1`; a quad has
    /// 4 children (by corner), a triangle 3 corner children and the centre.
    pub fn child_faces(&self, level: u32) -> &[u32] {
        &self.face_base[level as usize]
    }

    /// Stencils of `level`'s vertices over the control vertices.
    pub fn stencils(&self, level: u32) -> SparseRows {
        let n0 = self.num_vertices(0);
        let mut s = SparseRows {
            offsets: (0..=n0 as u32).collect(),
            indices: (0..n0 as u32).collect(),
            weights: vec![1.0; n0],
        };
        for l in 0..level as usize {
            s = self.steps[l].compose(&s, n0);
        }
        s
    }

    /// Positions of every level `0..=num_levels`.
    pub fn refine_positions(&self, control: &[DVec3]) -> Result<Vec<Vec<DVec3>>> {
        crate::subdiv::check_positions(self.num_vertices(0), control)?;
        let mut out = vec![control.to_vec()];
        for s in &self.steps {
            let next = s.apply(out.last().expect("level 0 is there"));
            out.push(next);
        }
        Ok(out)
    }

    /// `level` as a control mesh with `positions` (of that level), creases
    /// and corners carried over (a new mesh, e.g. to write or to refine
    /// further).
    pub fn level_mesh(&self, level: u32, positions: Vec<DVec3>) -> Result<ControlMesh> {
        let l = &self.levels[level as usize];
        let polys: Vec<&[u32]> = (0..l.topo.num_faces() as u32)
            .map(|f| l.topo.face(f))
            .collect();
        let mut m = ControlMesh::from_polygons(positions, &polys)?;
        for (&(a, b), &s) in &l.topo.esharp {
            m.set_crease(VertexId(a), VertexId(b), s)?;
        }
        for (v, &s) in l.topo.vsharp.iter().enumerate() {
            if s > 0.0 {
                m.set_corner(VertexId(v as u32), s)?;
            }
        }
        Ok(m)
    }
}

/// `mesh` refined `levels` times by the quad/triangle scheme, as a control
/// mesh (see the module doc for the numbering).
pub fn refine_quadtri(mesh: &ControlMesh, levels: u32) -> Result<ControlMesh> {
    let r = QuadTriRefiner::new(mesh, levels)?;
    let p = r.refine_positions(mesh.positions())?;
    r.level_mesh(levels, p.into_iter().last().expect("level 0 is there"))
}
