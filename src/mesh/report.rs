//! Validation of a freshly read polygon soup: the defects real scans carry
//! are counted and reported (not repaired silently), the few that would break
//! everything downstream are hard errors naming the element.
//!
//! Cleanup done here, each with a note in the report:
//! - vertices referenced by no face are dropped and the rest renumbered in
//!   their original order;
//! - faces that repeat a vertex index are dropped (no half-edge structure can
//!   hold them); exact duplicates of an earlier face (same vertex set) are
//!   dropped too, since they would turn every one of their edges into a
//!   non-manifold edge;
//! - polygons are fan-triangulated from their first corner.
//!
//! Hard errors: a face index out of range, a face with fewer than 3 corners,
//! a non-finite coordinate on any vertex, no face left.
//!
//! Everything is O(n): faces and edges are grouped by their smallest vertex
//! with a counting sort instead of hash maps (cache-friendly and in a fixed
//! order; the 35,947-vertex bunny validates in a few milliseconds).

use std::collections::BTreeMap;
use std::fmt;
use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::mesh::soup::{bbox, weld_identical};
use crate::mesh::{PolySoup, TriMesh};
use crate::DVec3;

/// What `subdfit info` prints: counts and defects found on load.
///
/// Topological figures (edges, components, boundary, manifoldness, Euler
/// characteristic) are those of the cleaned, triangulated mesh; fan
/// triangulation adds as many edges as faces, so it changes neither the
/// Euler characteristic nor the boundary.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct MeshReport {
    /// Vertices in the file.
    pub input_vertices: usize,
    /// Faces (polygons) in the file.
    pub input_faces: usize,
    /// Number of input faces per corner count, e.g. `{3: 69451}`.
    pub face_sizes: BTreeMap<usize, usize>,
    /// Vertices kept (used by at least one face).
    pub vertices: usize,
    /// Polygons kept after dropping degenerate and duplicate faces.
    pub faces: usize,
    /// Triangles of the returned mesh.
    pub triangles: usize,
    /// Distinct edges of the returned mesh.
    pub edges: usize,
    /// Vertices used by no face, dropped.
    pub unreferenced_vertices: usize,
    /// Vertices at the bit-identical position of an earlier one, merged
    /// into it before anything else (a triangle soup, a mesh split along
    /// its UV seams; see [`crate::mesh::Weld`]).
    pub welded_vertices: usize,
    /// Faces repeating a vertex index, dropped.
    pub repeated_index_faces: usize,
    /// Kept faces with (numerically) zero area: area below
    /// `(f32::EPSILON * bbox_diagonal)^2`, see [`zero_area_threshold`].
    pub zero_area_faces: usize,
    /// Faces with the same vertex set as an earlier face, dropped.
    pub duplicate_faces: usize,
    /// Connected components (through shared vertices).
    pub components: usize,
    /// Edges used by exactly one triangle.
    pub boundary_edges: usize,
    /// Closed chains of boundary edges.
    pub boundary_loops: usize,
    /// Edges used by more than two triangles, or by two triangles that
    /// traverse it in the same direction (inconsistent orientation).
    pub non_manifold_edges: usize,
    /// Of `non_manifold_edges`, those with exactly two triangles of
    /// inconsistent orientation.
    pub inconsistently_oriented_edges: usize,
    /// Vertices whose triangles form more than one fan (joined through edges
    /// with exactly two triangles): pinched or "bow-tie" vertices, and the
    /// vertices of non-manifold edges.
    pub non_manifold_vertices: usize,
    pub bbox_min: [f64; 3],
    pub bbox_max: [f64; 3],
    pub bbox_diagonal: f64,
    /// Mean length of the distinct edges.
    pub mean_edge_length: f64,
    /// V − E + F of the returned mesh.
    pub euler_characteristic: i64,
    /// No boundary edge.
    pub closed: bool,
    /// No non-manifold edge or vertex and consistent orientation.
    pub manifold: bool,
    /// Total genus (sum over components), when the mesh is manifold:
    /// `χ = Σ (2 − 2 g_i − b_i)`, so `g = (2 C − χ − b) / 2`.
    pub genus: Option<i64>,
    /// Human-readable remarks about what was cleaned up.
    pub notes: Vec<String>,
}

/// A soup that passed validation, as a triangle mesh, with its report.
#[derive(Clone, Debug)]
pub struct ValidatedMesh {
    pub mesh: TriMesh,
    pub report: MeshReport,
}

/// Area below which a face counts as degenerate, for a mesh whose bounding
/// box has diagonal `diag`.
///
/// Most inputs store `f32` coordinates, whose resolution at the scale of the
/// model is about `f32::EPSILON * diag`; a triangle whose two sides are both
/// within that resolution has an area below `(f32::EPSILON * diag)^2` and its
/// shape is pure rounding noise. A sliver with one side at model scale and
/// height at the noise level (area ≈ ε · diag²) stays above the threshold: it
/// is badly shaped, but it does have a plane and a normal.
pub fn zero_area_threshold(diag: f64) -> f64 {
    let e = f32::EPSILON as f64 * diag;
    e * e
}

/// Validates `soup` read from `path` (named in errors).
///
/// Vertices at identical positions are welded first
/// ([`crate::mesh::weld_identical`]), so a triangle soup or a mesh split
/// along its seams is read as the surface it describes; faces the weld
/// collapsed (two corners merged) are then dropped with the other faces
/// that repeat a vertex. A mesh without area, or whose vertices all lie on
/// one line, is refused ([`check_extent`]).
pub fn validate_soup(soup: PolySoup, path: &Path) -> Result<ValidatedMesh> {
    validate(soup, path, true)
}

/// [`validate_soup`] without the weld: for a mesh whose coincident
/// vertices are copies made on purpose (the manifold split of
/// [`ValidatedMesh::into_manifold`], which the weld would undo).
pub(crate) fn validate_soup_unwelded(soup: PolySoup, path: &Path) -> Result<ValidatedMesh> {
    validate(soup, path, false)
}

fn validate(mut soup: PolySoup, path: &Path, weld: bool) -> Result<ValidatedMesh> {
    let mut report = MeshReport {
        input_vertices: soup.positions.len(),
        input_faces: soup.num_faces(),
        ..MeshReport::default()
    };
    check_faces(&soup, path, &mut report)?;
    // A non-finite coordinate is an error even on an unreferenced vertex:
    // it means the file is corrupt, and the rest of it cannot be trusted.
    // The readers already reject them with the line; this guards soups
    // built in memory (and comes before the weld, so it names the file's
    // vertex index).
    if let Some(i) = soup.positions.iter().position(|p| !p.is_finite()) {
        return Err(Error::invalid_mesh(
            path,
            format!("vertex {i}"),
            non_finite(soup.positions[i]).unwrap_or_default(),
        ));
    }
    if weld {
        weld_soup(&mut soup, &mut report);
    }
    let keep = drop_bad_faces(&soup, &mut report);
    if keep.is_empty() {
        let nf_in = soup.num_faces();
        return Err(Error::invalid_mesh(
            path,
            "mesh",
            if nf_in == 0 {
                "has no faces".to_string()
            } else {
                format!("none of its {nf_in} faces is usable (all degenerate or duplicate)")
            },
        ));
    }
    report.faces = keep.len();
    let (positions, remap) = used_vertices(&soup, &keep, &mut report);
    let triangles = triangulate(&soup, &keep, &positions, &remap, &mut report);
    check_extent(&positions, &triangles, &report, path)?;
    topology(&positions, &triangles, &mut report);
    Ok(ValidatedMesh {
        mesh: TriMesh {
            positions,
            triangles,
        },
        report,
    })
}

/// Merges the vertices of `soup` at identical positions (see
/// [`crate::mesh::Weld`] for why identical and not close); notes the count.
fn weld_soup(soup: &mut PolySoup, report: &mut MeshReport) {
    let weld = weld_identical(&soup.positions);
    report.welded_vertices = weld.merged();
    if report.welded_vertices == 0 {
        return;
    }
    for i in soup.face_indices.iter_mut() {
        *i = weld.remap[*i as usize];
    }
    soup.positions = weld.positions;
    report.notes.push(format!(
        "welded {} vertices at the identical position of an earlier one (a triangle soup or seams split in the file); vertices that are only close are left apart",
        report.welded_vertices
    ));
}

/// Refuses a mesh that spans no surface: every face of (numerically) zero
/// area, or every vertex within rounding of one line. Both thresholds are
/// the input's own resolution: `f32` coordinates at the model's scale are
/// resolved to about `f32::EPSILON * diag` ([`zero_area_threshold`]), so a
/// mesh whose faces are all below that area, or whose vertices all lie
/// within that distance of one line, has its second dimension made of
/// rounding noise, and no surface (no normal, no fit) can be built on it.
/// A flat plate passes: it has area, and it needs no third dimension.
fn check_extent(
    positions: &[DVec3],
    triangles: &[[u32; 3]],
    report: &MeshReport,
    path: &Path,
) -> Result<()> {
    let diag = report.bbox_diagonal;
    if diag == 0.0 {
        return Err(Error::invalid_mesh(
            path,
            "mesh",
            format!(
                "has no extent: all {} vertices are at one point",
                positions.len()
            ),
        ));
    }
    let resolution = f32::EPSILON as f64 * diag;
    // The line through the two vertices farthest apart along the longest
    // bounding-box axis: if any vertex is off it by more than the
    // resolution, the mesh spans two directions.
    let axis = {
        let d = DVec3::from(report.bbox_max) - DVec3::from(report.bbox_min);
        if d.x >= d.y && d.x >= d.z {
            0
        } else if d.y >= d.z {
            1
        } else {
            2
        }
    };
    let by = |p: &&DVec3| p[axis];
    let lo = *positions
        .iter()
        .min_by(|a, b| by(a).total_cmp(&by(b)))
        .unwrap();
    let hi = *positions
        .iter()
        .max_by(|a, b| by(a).total_cmp(&by(b)))
        .unwrap();
    let dir = (hi - lo).normalize();
    let off_line = positions
        .iter()
        .map(|&p| (p - lo).reject_from_normalized(dir).length())
        .fold(0.0, f64::max);
    if off_line <= resolution {
        return Err(Error::invalid_mesh(
            path,
            "mesh",
            format!(
                "has no area: all {} vertices lie on one line (within {resolution:.3e}, the coordinates' resolution at its size {diag:.3e}); a surface needs two directions",
                positions.len()
            ),
        ));
    }
    if report.zero_area_faces == report.faces {
        return Err(Error::invalid_mesh(
            path,
            "mesh",
            format!(
                "has no area: all {} of its faces ({} triangles) have zero area (below {:.3e})",
                report.faces,
                triangles.len(),
                zero_area_threshold(diag)
            ),
        ));
    }
    Ok(())
}

/// Hard errors on the faces: inconsistent offsets, fewer than 3 corners, an
/// index out of range. Counts the face sizes.
fn check_faces(soup: &PolySoup, path: &Path, report: &mut MeshReport) -> Result<()> {
    let nv_in = soup.positions.len();
    if soup.face_offsets.first().copied().unwrap_or(0) != 0
        || soup.face_offsets.windows(2).any(|w| w[1] < w[0])
        || soup.face_offsets.last().map_or(0, |&e| e as usize) != soup.face_indices.len()
    {
        return Err(Error::invalid_mesh(
            path,
            "faces",
            "inconsistent face offsets",
        ));
    }
    for (f, face) in soup.faces().enumerate() {
        *report.face_sizes.entry(face.len()).or_default() += 1;
        if face.len() < 3 {
            return Err(Error::invalid_mesh(
                path,
                format!("face {f}"),
                format!("has {} vertices, needs at least 3", face.len()),
            ));
        }
        if let Some(&i) = face.iter().find(|&&i| i as usize >= nv_in) {
            return Err(Error::invalid_mesh(
                path,
                format!("face {f}"),
                format!("vertex index {i} out of range (the mesh has {nv_in} vertices)"),
            ));
        }
    }
    Ok(())
}

/// The faces kept: those that repeat no vertex index and are no duplicate
/// (same vertex set) of an earlier face. Counts and notes the others.
fn drop_bad_faces(soup: &PolySoup, report: &mut MeshReport) -> Vec<u32> {
    let (nv_in, nf_in) = (soup.positions.len(), soup.num_faces());
    // Each face's vertex set, sorted: a repeated index shows as two equal
    // neighbours, a duplicate face as an equal key.
    let mut sorted = soup.face_indices.clone();
    for f in 0..nf_in {
        let (a, b) = (
            soup.face_offsets[f] as usize,
            soup.face_offsets[f + 1] as usize,
        );
        sorted[a..b].sort_unstable();
    }
    let key = |f: u32| {
        &sorted[soup.face_offsets[f as usize] as usize..soup.face_offsets[f as usize + 1] as usize]
    };
    let mut drop_face = vec![false; nf_in];
    let mut first_repeated = None;
    for (f, d) in drop_face.iter_mut().enumerate() {
        if key(f as u32).windows(2).any(|w| w[0] == w[1]) {
            *d = true;
            report.repeated_index_faces += 1;
            first_repeated.get_or_insert(f);
        }
    }
    // Duplicates: bucket the faces by their smallest vertex (counting sort,
    // O(n)), then compare keys inside each bucket, which holds about the
    // valence of that vertex.
    let by_min = Buckets::new(
        nv_in,
        (0..nf_in as u32)
            .filter(|&f| !drop_face[f as usize])
            .map(|f| (key(f)[0], f)),
    );
    let mut first_duplicate = None;
    let mut bucket: Vec<u32> = Vec::new();
    for v in 0..nv_in {
        let b = by_min.get(v);
        if b.len() < 2 {
            continue;
        }
        bucket.clear();
        bucket.extend_from_slice(b);
        bucket.sort_unstable_by(|&f, &g| key(f).cmp(key(g)).then(f.cmp(&g)));
        // Sorted by (key, face): the first face of each run of equal keys
        // is kept, the later ones are its duplicates.
        let mut run = 0;
        for w in 1..bucket.len() {
            if key(bucket[w]) != key(bucket[run]) {
                run = w;
                continue;
            }
            drop_face[bucket[w] as usize] = true;
            report.duplicate_faces += 1;
            let cand = (bucket[w] as usize, bucket[run] as usize);
            if first_duplicate.map_or(true, |(f, _)| cand.0 < f) {
                first_duplicate = Some(cand);
            }
        }
    }
    if let Some(f) = first_repeated {
        report.notes.push(format!(
            "dropped {} face(s) that repeat a vertex index (first: face {f}){}",
            report.repeated_index_faces,
            if report.welded_vertices > 0 {
                ", counting those the weld collapsed"
            } else {
                ""
            }
        ));
    }
    if let Some((f, g)) = first_duplicate {
        report.notes.push(format!(
            "dropped {} face(s) with the same vertices as an earlier face (first: face {f} = face {g})",
            report.duplicate_faces
        ));
    }
    (0..nf_in as u32)
        .filter(|&f| !drop_face[f as usize])
        .collect()
}

/// The vertices used by the kept faces, in their original order, and the
/// old-to-new index map (`u32::MAX` for dropped ones). Sets the bounding box.
fn used_vertices(soup: &PolySoup, keep: &[u32], report: &mut MeshReport) -> (Vec<DVec3>, Vec<u32>) {
    let nv_in = soup.positions.len();
    const UNUSED: u32 = u32::MAX;
    let mut remap = vec![UNUSED; nv_in];
    for &f in keep {
        for &i in soup.face(f as usize) {
            remap[i as usize] = 0;
        }
    }
    let mut positions = Vec::with_capacity(nv_in);
    for (i, r) in remap.iter_mut().enumerate() {
        if *r == UNUSED {
            continue;
        }
        let p = soup.positions[i];
        *r = positions.len() as u32;
        positions.push(p);
    }
    report.vertices = positions.len();
    report.unreferenced_vertices = nv_in - positions.len();
    if report.unreferenced_vertices > 0 {
        report.notes.push(format!(
            "dropped {} unreferenced vertices; the others are renumbered in their original order",
            report.unreferenced_vertices
        ));
    }
    let (lo, hi) = bbox(&positions);
    report.bbox_min = lo.to_array();
    report.bbox_max = hi.to_array();
    report.bbox_diagonal = (hi - lo).length();
    (positions, remap)
}

/// Fan-triangulates the kept faces; counts zero-area faces and polygons.
fn triangulate(
    soup: &PolySoup,
    keep: &[u32],
    positions: &[DVec3],
    remap: &[u32],
    report: &mut MeshReport,
) -> Vec<[u32; 3]> {
    let area_eps = zero_area_threshold(report.bbox_diagonal);
    let mut triangles = Vec::with_capacity(soup.face_indices.len());
    let mut polygons = 0usize;
    for &f in keep {
        let face = soup.face(f as usize);
        let mut area2 = DVec3::ZERO;
        let p0 = positions[remap[face[0] as usize] as usize];
        for k in 1..face.len() - 1 {
            let (a, b) = (remap[face[k] as usize], remap[face[k + 1] as usize]);
            // Vector area of the fan: exact for planar polygons.
            area2 += (positions[a as usize] - p0).cross(positions[b as usize] - p0);
            triangles.push([remap[face[0] as usize], a, b]);
        }
        if 0.5 * area2.length() < area_eps {
            report.zero_area_faces += 1;
        }
        if face.len() > 3 {
            polygons += 1;
        }
    }
    report.triangles = triangles.len();
    if polygons > 0 {
        report.notes.push(format!(
            "fan-triangulated {polygons} polygon(s) with more than 3 corners into {} triangles",
            triangles.len()
        ));
    }
    if report.zero_area_faces > 0 {
        report.notes.push(format!(
            "{} face(s) have zero area (below {area_eps:.3e}); they are kept",
            report.zero_area_faces
        ));
    }
    triangles
}

fn topology(positions: &[DVec3], tris: &[[u32; 3]], r: &mut MeshReport) {
    let nv = positions.len();
    // Half-edge h = 3 t + k runs from corner h to the next corner of t.
    let corner_vertex = |c: u32| tris[c as usize / 3][c as usize % 3];
    let next_corner = |c: u32| c - c % 3 + (c % 3 + 1) % 3;
    // Undirected edges: bucket the half-edges by their smaller endpoint
    // (counting sort), then sort each small bucket by the larger endpoint.
    let ends = |h: u32| {
        let (a, b) = (corner_vertex(h), corner_vertex(next_corner(h)));
        if a < b {
            (a, b)
        } else {
            (b, a)
        }
    };
    // Items are `hi << 32 | h`, so sorting a bucket groups by edge and keeps
    // the half-edges of each edge in input order.
    let by_lo = Buckets::new(
        nv,
        (0..3 * tris.len() as u32).map(|h| {
            let (lo, hi) = ends(h);
            (lo, (hi as u64) << 32 | h as u64)
        }),
    );

    // Corners around a vertex joined across manifold edges: the fans.
    let mut corner_uf = UnionFind::new(3 * tris.len());
    let mut vertex_uf = UnionFind::new(nv);
    let mut boundary_out: Vec<(u32, u32)> = Vec::new(); // directed boundary edges
    let mut length_sum = 0.0;
    let mut bucket: Vec<u64> = Vec::new();
    let mut uses: Vec<u32> = Vec::new();
    for lo in 0..nv {
        bucket.clear();
        bucket.extend_from_slice(by_lo.get(lo));
        bucket.sort_unstable();
        let mut i = 0;
        while i < bucket.len() {
            let hi = (bucket[i] >> 32) as u32;
            let mut j = i + 1;
            while j < bucket.len() && (bucket[j] >> 32) as u32 == hi {
                j += 1;
            }
            uses.clear();
            uses.extend(bucket[i..j].iter().map(|&x| x as u32));
            i = j;
            r.edges += 1;
            vertex_uf.union(lo, hi as usize);
            length_sum += (positions[lo] - positions[hi as usize]).length();
            let forward = |h: u32| corner_vertex(h) as usize == lo;
            match uses.len() {
                1 => {
                    r.boundary_edges += 1;
                    let h = uses[0];
                    boundary_out.push((corner_vertex(h), corner_vertex(next_corner(h))));
                }
                2 => {
                    let (h, g) = (uses[0], uses[1]);
                    if forward(h) == forward(g) {
                        r.non_manifold_edges += 1;
                        r.inconsistently_oriented_edges += 1;
                    }
                    // Join the two corners at each endpoint.
                    let corner_of_g = |v: u32| {
                        if corner_vertex(g) == v {
                            g
                        } else {
                            next_corner(g)
                        }
                    };
                    for ch in [h, next_corner(h)] {
                        corner_uf.union(ch as usize, corner_of_g(corner_vertex(ch)) as usize);
                    }
                }
                _ => r.non_manifold_edges += 1,
            }
        }
    }
    r.mean_edge_length = if r.edges == 0 {
        0.0
    } else {
        length_sum / r.edges as f64
    };
    drop(by_lo);
    r.components = (0..nv).filter(|&v| vertex_uf.find(v) == v).count();

    // Fans per vertex: distinct corner roots among its corners.
    let mut fan_root = vec![u32::MAX; nv];
    let mut nm_vertex = vec![false; nv];
    for (c, &v) in tris.iter().flatten().enumerate() {
        let root = corner_uf.find(c) as u32;
        let slot = &mut fan_root[v as usize];
        if *slot == u32::MAX {
            *slot = root;
        } else if *slot != root {
            nm_vertex[v as usize] = true;
        }
    }
    r.non_manifold_vertices = nm_vertex.iter().filter(|&&b| b).count();

    r.boundary_loops = count_loops(nv, &boundary_out);
    r.closed = r.boundary_edges == 0;
    r.manifold = r.non_manifold_edges == 0 && r.non_manifold_vertices == 0;
    r.euler_characteristic = nv as i64 - r.edges as i64 + tris.len() as i64;
    r.genus = if r.manifold {
        let twice = 2 * r.components as i64 - r.euler_characteristic - r.boundary_loops as i64;
        (twice >= 0 && twice % 2 == 0).then_some(twice / 2)
    } else {
        None
    };
    if !r.manifold {
        r.notes.push(format!(
            "not manifold: {} non-manifold edge(s) ({} of them inconsistently oriented), {} non-manifold vertex(es)",
            r.non_manifold_edges, r.inconsistently_oriented_edges, r.non_manifold_vertices
        ));
    }
}

/// Counts closed walks over the directed boundary edges: from each unused
/// edge, follow an unused edge leaving its head until none is left. On a
/// manifold boundary each walk is exactly one hole.
fn count_loops(nv: usize, out: &[(u32, u32)]) -> usize {
    if out.is_empty() {
        return 0;
    }
    // CSR of boundary edges by tail vertex.
    let mut start = vec![0u32; nv + 1];
    for &(a, _) in out {
        start[a as usize + 1] += 1;
    }
    for v in 0..nv {
        start[v + 1] += start[v];
    }
    let mut fill = start.clone();
    let mut heads = vec![0u32; out.len()];
    for &(a, b) in out {
        heads[fill[a as usize] as usize] = b;
        fill[a as usize] += 1;
    }
    // Per vertex, how many of its outgoing edges are used so far.
    let mut used = vec![0u32; nv];
    let mut loops = 0;
    for v0 in 0..nv {
        while used[v0] < start[v0 + 1] - start[v0] {
            loops += 1;
            let mut v = v0;
            while used[v] < start[v + 1] - start[v] {
                let h = heads[(start[v] + used[v]) as usize] as usize;
                used[v] += 1;
                v = h;
            }
        }
    }
    loops
}

/// Disjoint sets with union by size and path halving (near-constant time
/// per operation). Only the partition is used, never which element is the
/// root, so the result does not depend on tie-breaking.
struct UnionFind {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
            size: vec![1; n],
        }
    }
    fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] as usize != x {
            let g = self.parent[self.parent[x] as usize];
            self.parent[x] = g;
            x = g as usize;
        }
        x
    }
    fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            let (big, small) = if self.size[ra] >= self.size[rb] {
                (ra, rb)
            } else {
                (rb, ra)
            };
            self.parent[small] = big as u32;
            self.size[big] += self.size[small];
        }
    }
}

/// Items grouped by a vertex key in O(n) (counting sort): compressed rows,
/// each row in input order.
struct Buckets<T> {
    start: Vec<u32>,
    items: Vec<T>,
}

impl<T: Copy + Default> Buckets<T> {
    fn new(nkeys: usize, pairs: impl Iterator<Item = (u32, T)> + Clone) -> Self {
        let mut start = vec![0u32; nkeys + 1];
        for (k, _) in pairs.clone() {
            start[k as usize + 1] += 1;
        }
        for k in 0..nkeys {
            start[k + 1] += start[k];
        }
        let mut fill = start.clone();
        let mut items = vec![T::default(); start[nkeys] as usize];
        for (k, x) in pairs {
            items[fill[k as usize] as usize] = x;
            fill[k as usize] += 1;
        }
        Buckets { start, items }
    }

    fn get(&self, k: usize) -> &[T] {
        &self.items[self.start[k] as usize..self.start[k + 1] as usize]
    }
}

impl fmt::Display for MeshReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let yn = |b: bool| if b { "yes" } else { "no" };
        writeln!(
            f,
            "vertices        {} ({} in the file, {} welded, {} unreferenced dropped)",
            self.vertices, self.input_vertices, self.welded_vertices, self.unreferenced_vertices
        )?;
        let sizes: Vec<String> = self
            .face_sizes
            .iter()
            .map(|(n, c)| format!("{c} with {n} corners"))
            .collect();
        writeln!(
            f,
            "faces           {} ({} in the file: {})",
            self.faces,
            self.input_faces,
            sizes.join(", ")
        )?;
        writeln!(f, "triangles       {}", self.triangles)?;
        writeln!(f, "edges           {}", self.edges)?;
        writeln!(
            f,
            "degenerate      {} repeating a vertex (dropped), {} of zero area (kept)",
            self.repeated_index_faces, self.zero_area_faces
        )?;
        writeln!(f, "duplicate faces {} (dropped)", self.duplicate_faces)?;
        writeln!(f, "components      {}", self.components)?;
        writeln!(
            f,
            "boundary        {} loop(s), {} edge(s); closed: {}",
            self.boundary_loops,
            self.boundary_edges,
            yn(self.closed)
        )?;
        writeln!(
            f,
            "manifold        {} ({} non-manifold edge(s), {} inconsistently oriented; {} non-manifold vertex(es))",
            yn(self.manifold),
            self.non_manifold_edges,
            self.inconsistently_oriented_edges,
            self.non_manifold_vertices
        )?;
        let genus = self
            .genus
            .map_or_else(|| "n/a (not manifold)".to_string(), |g| g.to_string());
        writeln!(
            f,
            "euler / genus   {} / {}",
            self.euler_characteristic, genus
        )?;
        let [a, b, c] = self.bbox_min;
        let [d, e, g] = self.bbox_max;
        writeln!(
            f,
            "bbox            [{a:.6}, {b:.6}, {c:.6}] .. [{d:.6}, {e:.6}, {g:.6}], diagonal {:.6}",
            self.bbox_diagonal
        )?;
        write!(f, "mean edge       {:.6}", self.mean_edge_length)?;
        for n in &self.notes {
            write!(f, "\nnote: {n}")?;
        }
        Ok(())
    }
}

/// Why `p` cannot be a vertex position, if it cannot: NaN or infinite
/// coordinates poison every bounding box, distance and solve downstream.
pub(crate) fn non_finite(p: DVec3) -> Option<String> {
    if p.is_finite() {
        return None;
    }
    let what = if p.is_nan() { "NaN" } else { "infinite" };
    Some(format!("non-finite coordinate ({what}): {p}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad_soup(positions: Vec<DVec3>, faces: &[[u32; 3]]) -> Result<ValidatedMesh> {
        validate_soup(PolySoup::from_faces(positions, faces), Path::new("mem.obj"))
    }

    #[test]
    fn identical_vertices_weld_close_ones_do_not() {
        let (a, b, c, d) = (DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::new(1.0, 1.0, 0.0));
        // Two triangles as a soup (six vertices), a seventh vertex a hair
        // off `c` used by a third triangle, and `-0` beside `+0`.
        let near_c = c + DVec3::new(0.0, 1e-12, 0.0);
        let neg_a = DVec3::new(-0.0, 0.0, -0.0);
        let v = quad_soup(
            vec![a, b, d, neg_a, d, c, near_c, b, d],
            &[[0, 1, 2], [3, 4, 5], [6, 7, 8]],
        )
        .unwrap();
        assert_eq!(v.report.welded_vertices, 4, "{:?}", v.report.notes);
        assert_eq!(v.mesh.positions, vec![a, b, d, c, near_c]);
        assert_eq!(v.mesh.triangles, vec![[0, 1, 2], [0, 2, 3], [4, 1, 2]]);
        assert!(
            v.report.notes[0].contains("welded 4 vertices"),
            "{:?}",
            v.report.notes
        );
    }

    #[test]
    fn triangles_collapsed_by_the_weld_are_dropped_and_counted() {
        // A triangle whose corners 0 and 2 are at one position: after the
        // weld it repeats a vertex.
        let v = quad_soup(
            vec![
                DVec3::ZERO,
                DVec3::X,
                DVec3::Y,
                DVec3::ZERO,
                DVec3::X,
                DVec3::ZERO,
            ],
            &[[0, 1, 2], [3, 4, 5]],
        )
        .unwrap();
        assert_eq!(v.report.repeated_index_faces, 1);
        assert_eq!(v.mesh.triangles.len(), 1);
        assert!(
            v.report
                .notes
                .iter()
                .any(|n| n.contains("the weld collapsed")),
            "{:?}",
            v.report.notes
        );
    }

    #[test]
    fn meshes_without_area_are_refused() {
        // Colinear, with positive face "areas" only from rounding: all
        // vertices on the line through (1, 2, 3) scaled by thirds.
        let line: Vec<DVec3> = (0..9)
            .map(|i| DVec3::new(1.0, 2.0, 3.0) * (i as f64 / 3.0))
            .collect();
        let faces: Vec<[u32; 3]> = (0..7).map(|i| [i, i + 1, i + 2]).collect();
        let e = quad_soup(line, &faces).unwrap_err().to_string();
        assert!(e.contains("mem.obj") && e.contains("one line"), "{e}");
        // Spanning a plane, every triangle flat.
        let p: Vec<DVec3> = (0..9)
            .map(|i| DVec3::new((i % 3) as f64, (i / 3) as f64, 0.0))
            .collect();
        let e = quad_soup(p.clone(), &[[0, 1, 2], [3, 4, 5], [6, 7, 8]])
            .unwrap_err()
            .to_string();
        assert!(e.contains("all 3 of its faces"), "{e}");
        // One point.
        let e = quad_soup(vec![DVec3::ONE; 3], &[[0, 1, 2]])
            .unwrap_err()
            .to_string();
        assert!(e.contains("mem.obj"), "{e}");
        // A flat plate has area: accepted, and so is one good triangle
        // among the flat ones.
        quad_soup(p.clone(), &[[0, 1, 4], [0, 4, 3]]).unwrap();
        quad_soup(p, &[[0, 1, 2], [3, 4, 5], [0, 1, 4]]).unwrap();
    }
}
