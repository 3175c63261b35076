//! Non-manifold control meshes as OpenSubdiv takes them (issue 18): edges
//! of three or more faces (or two of the same orientation), vertices where
//! several fans touch, vertices no face uses. OpenSubdiv refines such a
//! mesh as it is; the half-edge [`ControlMesh`] cannot hold it, so a
//! [`SplitControl`] keeps both: the file's topology for OpenSubdiv, and a
//! manifold copy for the exact Rust evaluators, tagged so that it has the
//! same limit surface.
//!
//! OpenSubdiv's rules (`far/topologyRefinerFactory.cpp`,
//! `prepareComponentTagsAndSharpness`, with `sharpenNonManFeatures` always
//! on):
//! - every non-manifold edge is infinitely sharp;
//! - every non-manifold vertex is infinitely sharp, except on an interior
//!   non-manifold crease: exactly two non-manifold edges, no boundary edge
//!   and more faces than edges (a fin); its rule is then
//!   `DetermineVertexVertexRule(vSharpness, sharpEdgeCount)` over all its
//!   sharp edges, i.e. a crease along the two non-manifold edges (a third
//!   infinitely sharp edge there makes it the corner rule at every level:
//!   the copies get an infinitely sharp corner, the same surface);
//! - holes of boundary interpolation "none" are decided before that
//!   sharpening, from edges with exactly one face;
//! - a vertex no face uses is refined as an isolated point;
//! - a face that repeats a corner (a triangle written as a quad, `f 4 3 5
//!   5`) gets a degenerate edge of its own, and a face that runs along an
//!   edge twice gets a second edge there (`vtr/level.cpp`,
//!   `completeTopologyFromFaceVertices`): both non-manifold, each with one
//!   face, so their ends are infinitely sharp corners; the degenerate
//!   edge's point is the vertex itself at every level.
//!
//! The copy ([`super::foreign`]'s `manifold_copy`: one vertex copy per fan,
//! an edge of three or more faces pulled apart, a face's repeated corners
//! separate copies, so a degenerate edge becomes a zero-length boundary
//! edge between two copies at one position) gets the split edges
//! infinitely sharp and every copy of a sharpened vertex an infinitely
//! sharp corner. Then each copy's vertex rule, each edge's and each face's
//! are OpenSubdiv's, at every level: an infinitely sharp vertex keeps the
//! corner rule, a crease vertex's mask reads only its two crease edges
//! (whose copies run to copies at the same positions), and the split edges
//! make no holes (they are infinitely sharp). Faces keep their ids and
//! corner order, so surface locations mean the same in both.
//!
//! Where splitting cannot reproduce OpenSubdiv, [`SplitControl::new`] or
//! [`SplitControl::check_scheme`] refuses, naming the element:
//! - a face whose repeated corners lie in one fan of faces joined by
//!   manifold edges (no copy separates them);
//! - Chaikin creasing with semi-sharp edges at a non-manifold crease
//!   vertex. (Under uniform creasing they are matched: OpenSubdiv counts
//!   them with both crease edges at the vertex every fan shares, the corner
//!   rule until the last runs out, then a transition blended over all of
//!   them; each copy gets the vertex sharpness that gives it the same
//!   timing and blend, [`crease_copy_sharpness`], refused in the rare case
//!   no f32 sharpness carries the weight exactly);
//! - Chaikin creasing with semi-sharp edges in two fans of one non-manifold
//!   vertex: Chaikin averages the sharpness of a vertex's semi-sharp edges
//!   (`sdc/crease.cpp`, `SubdivideEdgeSharpnessesAroundVertex`) across all
//!   of them in OpenSubdiv, within one fan in the copy.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::foreign::manifold_copy;
use super::{ControlMesh, CreaseMethod, PolySoup, SchemeOptions, VertexId, INFINITELY_SHARP};
use crate::error::{Error, Result};
use crate::DVec3;

/// How OpenSubdiv treats one vertex of the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum VertexKind {
    /// One fan, no non-manifold edge: as in any manifold mesh.
    Manifold,
    /// Non-manifold and sharpened: an infinitely sharp corner.
    SharpCorner,
    /// On an interior non-manifold crease (two non-manifold edges, more
    /// faces than edges): the crease rule along them.
    Crease,
    /// Used by no face: an isolated point, its limit itself.
    Unused,
}

/// A control mesh in OpenSubdiv's terms (see the module docs).
#[derive(Clone, Debug)]
pub struct SplitControl {
    /// The file, named in errors.
    pub path: PathBuf,
    /// The file's vertices, faces and tags, as OpenSubdiv gets them.
    pub positions: Vec<DVec3>,
    pub face_sizes: Vec<u32>,
    pub face_indices: Vec<u32>,
    pub creases: Vec<(u32, u32, f64)>,
    pub corners: Vec<(u32, f64)>,
    /// The manifold copy the Rust evaluators get; same faces, same order.
    pub manifold: ControlMesh,
    /// Per vertex of `manifold`: the file's vertex it copies.
    pub origin: Vec<u32>,
    /// Per file vertex: its vertices in `manifold` (none when unused).
    pub copies: Vec<Vec<u32>>,
    pub kinds: Vec<VertexKind>,
    /// Per file vertex: how many of its copies (fans) have a semi-sharp
    /// edge other than a boundary one (Chaikin's refusal).
    semi_sharp_fans: Vec<usize>,
    /// The first crease vertex with a copy of one face ("edge and corner"'s
    /// refusal).
    single_face_crease: Option<u32>,
    /// The first crease vertex with semi-sharp edges (Chaikin's refusal).
    semi_sharp_crease: Option<u32>,
    /// Per file vertex: whether OpenSubdiv counts it a boundary vertex with
    /// an edge of one face not infinitely sharp by its own tag (boundary
    /// "none" makes all its faces holes, in every fan).
    soft_boundary: Vec<bool>,
}

/// Vertex sharpness for each copy (fan) of a non-manifold crease vertex
/// with corner sharpness `own` and, per fan, the sharpness of its
/// semi-sharp edges, under uniform creasing; `None` where no sharpness
/// reproduces OpenSubdiv exactly.
///
/// OpenSubdiv counts every fan's semi-sharp edges with the two crease
/// edges: the corner rule while any edge (or `own`) is still sharp, then
/// the crease rule from level T = ceil(max), the step blended by Sdc's
/// fractional weight w, the mean of `x - (T - 1)` over the sharpness that
/// runs out at T (`Crease::ComputeFractionalWeightAtVertex`). A copy sees
/// only its own fan. With vertex sharpness σ = T - 1 + f it also keeps the
/// corner rule up to T, and its weight is the mean over its own dying
/// edges and f: f = w for a fan with none, or whose dying edges have mean
/// w; with one dying edge x, f = 2w - x when that lies in (0, 1]. All in
/// f32, as OpenSubdiv keeps sharpness; more than two distinct terms in a
/// mean are refused (their f32 sum depends on the order).
pub fn crease_copy_sharpness(own: f64, fans: &[Vec<f64>]) -> Option<Vec<f64>> {
    let semi = |x: f32| x > 0.0 && x < INFINITELY_SHARP as f32;
    let own = own as f32;
    let fans: Vec<Vec<f32>> = fans
        .iter()
        .map(|f| f.iter().map(|&x| x as f32).filter(|&x| semi(x)).collect())
        .collect();
    let mut all: Vec<f32> = fans.iter().flatten().copied().collect();
    if semi(own) {
        all.push(own);
    }
    let top = all.iter().copied().fold(0.0f32, f32::max).ceil();
    let base = top - 1.0;
    let dying = |xs: &[f32]| -> Vec<f32> {
        xs.iter()
            .filter(|&&x| x > base)
            .map(|&x| x - base)
            .collect()
    };
    let everywhere = dying(&all);
    let distinct = |d: &[f32]| d.len() > 2 && d.iter().any(|&x| x != d[0]);
    if everywhere.is_empty() || distinct(&everywhere) {
        return None;
    }
    let w = (everywhere.iter().sum::<f32>() / everywhere.len() as f32).min(1.0);
    fans.iter()
        .map(|fan| {
            let mine = dying(fan);
            let f = if mine.iter().all(|&x| x == w) {
                w
            } else if mine.len() == 1 {
                2.0 * w - mine[0]
            } else {
                return None;
            };
            let sigma = base + f;
            let fits = f > 0.0 && f <= 1.0 && sigma - base == f;
            let mean = if mine.is_empty() {
                f
            } else {
                (mine.iter().sum::<f32>() + f) / (mine.len() + 1) as f32
            };
            (fits && mean == w).then_some(sigma as f64)
        })
        .collect()
}

/// Per undirected edge of the file: its uses `(face, forward)`.
type EdgeUses = HashMap<(u32, u32), Vec<(u32, bool)>>;

fn edge_uses(soup: &PolySoup) -> EdgeUses {
    let mut uses: EdgeUses = HashMap::new();
    for (f, face) in soup.faces().enumerate() {
        for k in 0..face.len() {
            let (a, b) = (face[k], face[(k + 1) % face.len()]);
            uses.entry((a.min(b), a.max(b)))
                .or_default()
                .push((f as u32, a < b));
        }
    }
    uses
}

/// Whether an edge joins its faces as a manifold (`vtr/level.cpp` tags the
/// others non-manifold): exactly two, traversing it in opposite directions.
fn manifold_edge(uses: &[(u32, bool)]) -> bool {
    uses.len() == 2 && uses[0].1 != uses[1].1 && !runs_twice(uses)
}

/// Per use of an edge (in `uses`' face order): whether OpenSubdiv puts it
/// on the edge's first instance. `findEdge` returns the first instance, and
/// a face that finds itself already there gets a new instance of its own
/// (`completeTopologyFromFaceVertices`); every other use joins the first.
fn on_first_instance(uses: &[(u32, bool)]) -> Vec<bool> {
    let mut last = None;
    uses.iter()
        .map(|&(f, _)| {
            let first = last != Some(f);
            if first {
                last = Some(f);
            }
            first
        })
        .collect()
}

/// Whether one face runs along the edge more than once. OpenSubdiv then
/// gives each further run an edge of its own, tagged non-manifold with the
/// first (`completeTopologyFromFaceVertices`: "if the edge already occurs
/// in this face, create a new instance"), so its ends are non-manifold
/// vertices with a boundary edge: infinitely sharp corners.
fn runs_twice(uses: &[(u32, bool)]) -> bool {
    uses.windows(2).any(|w| w[0].0 == w[1].0)
}

impl SplitControl {
    /// The file's polygons `soup` with creases `(a, b, s)` and corners
    /// `(v, s)` on its vertex ids; `path` names the file in errors.
    pub fn new(
        soup: &PolySoup,
        creases: &[(u32, u32, f64)],
        corners: &[(u32, f64)],
        path: &Path,
    ) -> Result<Self> {
        let bad = |element: String, msg: &str| Error::invalid_mesh(path, element, msg.to_string());
        let n = soup.positions.len();
        for (f, face) in soup.faces().enumerate() {
            if let Some(&v) = face.iter().find(|&&v| v as usize >= n) {
                return Err(bad(
                    format!("face {f}"),
                    &format!("vertex {v} out of range"),
                ));
            }
            if face.len() < 3 {
                return Err(bad(
                    format!("face {f}"),
                    "a face with fewer than three corners",
                ));
            }
        }
        let uses = edge_uses(soup);
        for &(a, b, _) in creases {
            if !uses.contains_key(&(a.min(b), a.max(b))) {
                return Err(bad(
                    format!("edge ({a}, {b})"),
                    "crease on an edge no face has",
                ));
            }
        }
        let faces: Vec<Vec<u32>> = soup.faces().map(|f| f.to_vec()).collect();
        let copy =
            manifold_copy(&soup.positions, &faces, creases, corners).map_err(|e| match e {
                Error::Topology { element, msg } => {
                    // The copy keeps a face's repeated corners apart unless
                    // manifold edges join them around the vertex.
                    let folded = element
                        .strip_prefix("face ")
                        .and_then(|f| faces.get(f.parse::<usize>().ok()?))
                        .is_some_and(|f| {
                            let mut s = f.clone();
                            s.sort_unstable();
                            s.windows(2).any(|w| w[0] == w[1])
                        });
                    let msg = if folded {
                        "a face whose repeated corners lie in one fan of faces joined by \
                         manifold edges: no manifold copy keeps them apart, as OpenSubdiv's \
                         separate edge instances do"
                            .to_string()
                    } else {
                        msg
                    };
                    Error::invalid_mesh(path, element, msg)
                }
                e => e,
            })?;
        let mut copies = vec![Vec::new(); n];
        for (v, &o) in copy.origin.iter().enumerate() {
            copies[o as usize].push(v as u32);
        }
        let mut sc = SplitControl {
            path: path.to_path_buf(),
            positions: soup.positions.clone(),
            face_sizes: soup.faces().map(|f| f.len() as u32).collect(),
            face_indices: soup.face_indices.clone(),
            creases: creases.to_vec(),
            corners: corners.to_vec(),
            manifold: copy.mesh,
            origin: copy.origin,
            copies,
            kinds: vec![VertexKind::Manifold; n],
            semi_sharp_fans: vec![0; n],
            single_face_crease: None,
            semi_sharp_crease: None,
            soft_boundary: vec![false; n],
        };
        sc.tag(&uses, path)?;
        Ok(sc)
    }

    /// The file's faces, in order, as its vertex ids.
    pub fn file_faces(&self) -> impl Iterator<Item = &[u32]> + '_ {
        self.face_sizes.iter().scan(0usize, |at, &k| {
            let face = &self.face_indices[*at..*at + k as usize];
            *at += k as usize;
            Some(face)
        })
    }

    /// Whether the file is a manifold mesh without unused vertices (then
    /// `manifold` is exactly the file's mesh).
    pub fn is_manifold(&self) -> bool {
        self.kinds.iter().all(|&k| k == VertexKind::Manifold)
    }

    /// Classifies the file's vertices as OpenSubdiv does and tags the copy
    /// (module docs).
    fn tag(&mut self, uses: &EdgeUses, path: &Path) -> Result<()> {
        let n = self.positions.len();
        // Per vertex: non-manifold edges, boundary edges, edges, faces.
        let mut counts = vec![[0usize; 4]; n];
        for (&(a, b), u) in uses {
            for v in [a, b] {
                let c = &mut counts[v as usize];
                c[0] += usize::from(!manifold_edge(u) && u.len() != 1);
                c[1] += usize::from(u.len() == 1);
                c[2] += 1;
            }
        }
        for &v in &self.face_indices {
            counts[v as usize][3] += 1;
        }
        // Ends of an edge one face runs along twice, and of a degenerate
        // edge (a face repeating a corner: always an edge of its own, with
        // one face), are infinitely sharp (`runs_twice`).
        let mut forced = vec![false; n];
        for (&(a, b), u) in uses {
            if a == b || runs_twice(u) {
                forced[a as usize] = true;
                forced[b as usize] = true;
            }
        }
        for (v, &[nm_edges, boundary, edges, faces]) in counts.iter().enumerate() {
            self.kinds[v] = if faces == 0 {
                VertexKind::Unused
            } else if forced[v] {
                VertexKind::SharpCorner
            } else if nm_edges == 0 && self.copies[v].len() == 1 {
                VertexKind::Manifold
            } else if nm_edges == 2 && boundary == 0 && faces > edges {
                VertexKind::Crease
            } else {
                VertexKind::SharpCorner
            };
        }
        // Non-manifold edges: every copy infinitely sharp. A copy can join
        // two faces again where their fans close around both its ends (two
        // faces back to back on an edge of four): infinitely sharp between
        // infinitely sharp or crease vertices, it keeps their surfaces as
        // apart as OpenSubdiv's non-manifold edge does; so do degenerate
        // edges, whose copies can meet again too. The further instances a
        // face that runs along an edge twice gets, and degenerate edges,
        // are boundary edges of one face in OpenSubdiv (infinitely sharp
        // like every boundary edge there): `soft` records them for the
        // holes of boundary "none" ([`SplitControl::with_file_holes`]).
        let mut first_use: HashMap<(u32, u32), (Vec<bool>, usize)> = HashMap::new();
        let mut soft = vec![false; n];
        let crease_of: HashMap<(u32, u32), f64> = self
            .creases
            .iter()
            .map(|&(a, b, s)| ((a.min(b), a.max(b)), s))
            .collect();
        let faces: Vec<Vec<u32>> = self.file_faces().map(|f| f.to_vec()).collect();
        for (f, face) in faces.iter().enumerate() {
            let copy: Vec<u32> = self
                .manifold
                .face_vertices(super::FaceId(f as u32))
                .map(|v| v.0)
                .collect();
            for k in 0..face.len() {
                let (a, b) = (face[k], face[(k + 1) % face.len()]);
                let key = (a.min(b), a.max(b));
                let u = &uses[&key];
                let (firsts, next) = first_use
                    .entry(key)
                    .or_insert_with(|| (on_first_instance(u), 0));
                let first = a != b && firsts[*next];
                *next += 1;
                let one_face = if first {
                    firsts.iter().filter(|&&x| x).count() == 1
                } else {
                    true
                };
                let tagged = if first {
                    crease_of.get(&key).copied()
                } else {
                    None
                };
                if one_face && tagged.unwrap_or(0.0) < INFINITELY_SHARP {
                    soft[a as usize] = true;
                    soft[b as usize] = true;
                }
                if a == b || (u.len() != 1 && !manifold_edge(u)) {
                    let (x, y) = (copy[k], copy[(k + 1) % copy.len()]);
                    self.manifold
                        .set_crease(VertexId(x), VertexId(y), INFINITELY_SHARP)?;
                }
            }
        }
        self.soft_boundary = soft;
        for v in 0..n {
            let copies = self.copies[v].clone();
            // A copy's boundary edges are the file's boundary edges (always
            // infinitely sharp in OpenSubdiv, whatever the tag) or copies
            // of non-manifold ones: only its other edges count.
            let sharp = |m: &ControlMesh, c: u32, semi: bool| {
                m.outgoing(VertexId(c)).any(|h| {
                    let s = m.edge_sharpness(h.edge());
                    let wanted = if semi {
                        s > 0.0 && s < INFINITELY_SHARP
                    } else {
                        s >= INFINITELY_SHARP
                    };
                    wanted && !m.is_boundary_edge(h.edge())
                })
            };
            let m = &self.manifold;
            self.semi_sharp_fans[v] = copies.iter().filter(|&&c| sharp(m, c, true)).count();
            if self.kinds[v] == VertexKind::Crease && copies.iter().any(|&c| sharp(m, c, false)) {
                // A third infinitely sharp edge: OpenSubdiv's rule is the
                // corner's at every level (`DetermineVertexVertexRule` with
                // three sharp edges), the surface of an infinitely sharp
                // vertex.
                self.kinds[v] = VertexKind::SharpCorner;
            }
            match self.kinds[v] {
                VertexKind::SharpCorner => {
                    for &c in &copies {
                        self.manifold.set_corner(VertexId(c), INFINITELY_SHARP)?;
                    }
                }
                VertexKind::Crease => {
                    if self.semi_sharp_fans[v] > 0 {
                        self.tag_semi_sharp_crease(v, &copies, path)?;
                    }
                    let one_face = copies
                        .iter()
                        .any(|&c| self.manifold.vertex_faces(VertexId(c)).count() == 1);
                    if one_face && self.single_face_crease.is_none() {
                        self.single_face_crease = Some(v as u32);
                    }
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// Gives every copy of crease vertex `v`, which has semi-sharp edges,
    /// the vertex sharpness [`crease_copy_sharpness`] finds (module docs).
    fn tag_semi_sharp_crease(&mut self, v: usize, copies: &[u32], path: &Path) -> Result<()> {
        let m = &self.manifold;
        let own = m.vertex_sharpness(VertexId(copies[0]));
        let fans: Vec<Vec<f64>> = copies
            .iter()
            .map(|&c| {
                m.outgoing(VertexId(c))
                    .filter(|h| !m.is_boundary_edge(h.edge()))
                    .map(|h| m.edge_sharpness(h.edge()))
                    .filter(|&s| s > 0.0 && s < INFINITELY_SHARP)
                    .collect()
            })
            .collect();
        let sigma = crease_copy_sharpness(own, &fans).ok_or_else(|| {
            Error::invalid_mesh(
                path,
                format!("vertex {v}"),
                "semi-sharp edges at a non-manifold crease vertex whose transition weight no \
                 vertex sharpness on its copies carries exactly (OpenSubdiv blends over the \
                 edges of every fan, a copy over its own)",
            )
        })?;
        for (&c, s) in copies.iter().zip(sigma) {
            self.manifold.set_corner(VertexId(c), s)?;
        }
        self.semi_sharp_crease.get_or_insert(v as u32);
        Ok(())
    }

    /// Refuses scheme options under which the copy departs from
    /// OpenSubdiv (module docs).
    pub fn check_scheme(&self, scheme: &SchemeOptions) -> Result<()> {
        let path = &self.path;
        if scheme.crease_method == CreaseMethod::Chaikin {
            if let Some(v) = (0..self.positions.len()).find(|&v| self.semi_sharp_fans[v] > 1) {
                return Err(Error::invalid_mesh(
                    path,
                    format!("vertex {v}"),
                    "Chaikin creasing with semi-sharp edges in two fans of a non-manifold \
                     vertex: OpenSubdiv averages their sharpness across the fans, a manifold \
                     copy within one",
                ));
            }
        }
        if let (CreaseMethod::Chaikin, Some(v)) = (scheme.crease_method, self.semi_sharp_crease) {
            return Err(Error::invalid_mesh(
                path,
                format!("vertex {v}"),
                "Chaikin creasing with semi-sharp edges at a non-manifold crease vertex: the \
                 copies' vertex sharpness follows uniform creasing's timing",
            ));
        }
        Ok(())
    }

    /// Per vertex of `manifold`: whether it copies a non-manifold crease
    /// vertex ([`VertexKind::Crease`]).
    pub fn crease_copies(&self) -> Vec<bool> {
        self.origin
            .iter()
            .map(|&o| self.kinds[o as usize] == VertexKind::Crease)
            .collect()
    }

    /// The copy and scheme the exact evaluators get under `scheme`, where
    /// they differ from `manifold` and `scheme`: boundary "edge and corner"
    /// with a crease vertex's copy of one face. Corner sharpening is
    /// topological (one face, two edges), and that copy would be sharpened
    /// while OpenSubdiv's vertex (more faces than edges) keeps the crease
    /// rule. OpenSubdiv decides it once on the file
    /// (`prepareComponentTagsAndSharpness`: a boundary vertex of one face
    /// and two edges gets infinite sharpness), so the copy gets that
    /// decision as tags instead: an infinitely sharp corner on every copy
    /// of the file's topological corners, under "edge only", which
    /// differs from "edge and corner" by nothing else.
    pub fn exact_copy_for(&self, scheme: &SchemeOptions) -> Option<(ControlMesh, SchemeOptions)> {
        use super::BoundaryInterpolation;
        if scheme.boundary != BoundaryInterpolation::EdgeAndCorner
            || self.single_face_crease.is_none()
        {
            return None;
        }
        let mut faces = vec![0usize; self.positions.len()];
        for &v in &self.face_indices {
            faces[v as usize] += 1;
        }
        let mut edges = vec![0usize; self.positions.len()];
        let mut seen = std::collections::HashSet::new();
        for face in self.file_faces() {
            for i in 0..face.len() {
                let (a, b) = (face[i], face[(i + 1) % face.len()]);
                if a != b && seen.insert((a.min(b), a.max(b))) {
                    edges[a as usize] += 1;
                    edges[b as usize] += 1;
                }
            }
        }
        let mut copy = self.manifold.clone();
        for v in 0..self.positions.len() {
            if faces[v] == 1 && edges[v] == 2 {
                for &c in &self.copies[v] {
                    copy.set_corner(VertexId(c), INFINITELY_SHARP).ok()?;
                }
            }
        }
        Some((
            copy,
            scheme
                .clone()
                .with_boundary(BoundaryInterpolation::EdgeOnly),
        ))
    }

    /// `scheme` with the holes boundary interpolation "none" makes on the
    /// file added to its hole list: every face at a vertex OpenSubdiv finds
    /// on a soft boundary (`makeBoundaryFacesHoles`), in all of its fans,
    /// where the copy alone would hole only the fan with the boundary edge.
    /// Other schemes come back unchanged.
    pub fn with_file_holes(&self, scheme: SchemeOptions) -> SchemeOptions {
        use super::{BoundaryInterpolation, FaceId, SubdivScheme};
        if scheme.boundary != BoundaryInterpolation::None
            || scheme.scheme == SubdivScheme::Bilinear
            || self.is_manifold()
        {
            return scheme;
        }
        let mut holes = scheme.holes.clone();
        for (f, face) in self.file_faces().enumerate() {
            if face.iter().any(|&v| self.soft_boundary[v as usize]) {
                holes.push(FaceId(f as u32));
            }
        }
        scheme.with_holes(holes)
    }

    /// Positions over `manifold`'s vertices of positions over the file's.
    pub fn split_positions(&self, positions: &[DVec3]) -> Vec<DVec3> {
        self.origin.iter().map(|&o| positions[o as usize]).collect()
    }

    /// Positions over the file's vertices of positions over `manifold`'s;
    /// unused vertices keep the file's. Fails if two copies of a vertex
    /// are apart (OpenSubdiv has one point for them).
    pub fn file_positions(&self, split: &[DVec3]) -> Result<Vec<DVec3>> {
        let mut out = self.positions.clone();
        for (v, copies) in self.copies.iter().enumerate() {
            let Some(&first) = copies.first() else {
                continue;
            };
            let p = split[first as usize];
            if copies.iter().any(|&c| split[c as usize] != p) {
                return Err(Error::InvalidArgument(format!(
                    "the copies of non-manifold vertex {v} are at different positions: \
                     OpenSubdiv has one point for them"
                )));
            }
            out[v] = p;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn soup(n: usize, faces: &[&[u32]]) -> PolySoup {
        let mut s = PolySoup {
            positions: (0..n)
                .map(|i| DVec3::new(i as f64, (i * i % 5) as f64, (i % 3) as f64))
                .collect(),
            face_offsets: vec![0],
            face_indices: Vec::new(),
        };
        for f in faces {
            s.face_indices.extend_from_slice(f);
            s.face_offsets.push(s.face_indices.len() as u32);
        }
        s
    }

    #[test]
    fn opensubdiv_kinds_of_a_fin_chain_and_an_unused_vertex() {
        // Three quads on each of the edges 0-1 and 1-2 (a chain), vertex
        // 15 unused.
        let mut faces: Vec<Vec<u32>> = Vec::new();
        for k in 0..3u32 {
            let (a, b, c) = (3 + 4 * k, 4 + 4 * k, 5 + 4 * k);
            faces.push(vec![0, 1, b, a]);
            faces.push(vec![1, 2, c, b]);
        }
        let f: Vec<&[u32]> = faces.iter().map(|f| f.as_slice()).collect();
        let s = soup(16, &f);
        let sc = SplitControl::new(&s, &[], &[], Path::new("fin.obj")).unwrap();
        assert!(!sc.is_manifold());
        assert_eq!(sc.kinds[0], VertexKind::SharpCorner);
        assert_eq!(sc.kinds[1], VertexKind::Crease);
        assert_eq!(sc.kinds[2], VertexKind::SharpCorner);
        assert_eq!(sc.kinds[4], VertexKind::Manifold);
        assert_eq!(sc.kinds[15], VertexKind::Unused);
        assert_eq!(sc.copies[1].len(), 3);
        assert!(sc.copies[15].is_empty());
        // Every copy of the chain's edges is infinitely sharp, every copy
        // of its ends an infinitely sharp corner, the crease vertex not.
        let m = &sc.manifold;
        for &c in &sc.copies[0] {
            assert_eq!(m.vertex_sharpness(VertexId(c)), INFINITELY_SHARP);
        }
        for &c in &sc.copies[1] {
            assert_eq!(m.vertex_sharpness(VertexId(c)), 0.0);
        }
        assert_eq!(
            m.creases().len(),
            6,
            "two edges, three copies each: {:?}",
            m.creases()
        );
        assert_eq!(m.num_faces(), 6);
        // Positions round-trip; copies apart are refused.
        let mut p = sc.split_positions(&s.positions);
        assert_eq!(sc.file_positions(&p).unwrap(), s.positions);
        p[sc.copies[1][1] as usize].x += 1.0;
        assert!(sc.file_positions(&p).is_err());
    }

    #[test]
    fn a_manifold_file_is_its_control_mesh() {
        let s = soup(6, &[&[0, 1, 4, 3], &[1, 2, 5, 4]]);
        let sc = SplitControl::new(&s, &[(1, 4, 2.0)], &[(0, 1.0)], Path::new("m.obj")).unwrap();
        assert!(sc.is_manifold());
        assert_eq!(sc.origin, (0..6).collect::<Vec<u32>>());
        assert_eq!(sc.manifold.creases().len(), 1);
        assert_eq!(sc.manifold.corners().len(), 1);
        let e = SplitControl::new(&s, &[(0, 5, 1.0)], &[], Path::new("m.obj")).unwrap_err();
        assert!(e.to_string().contains("edge (0, 5)"), "{e}");
    }
}
