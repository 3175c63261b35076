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
//! a non-finite coordinate on a used vertex, no face left.
//!
//! Everything is O(n) with hash maps keyed by vertex pairs (the 35,947-vertex
//! bunny validates in a few milliseconds).

use std::collections::{BTreeMap, HashMap};
use std::fmt;
use std::hash::{BuildHasherDefault, Hasher};
use std::path::Path;

use serde::Serialize;

use crate::error::{Error, Result};
use crate::mesh::soup::bbox;
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
pub fn validate_soup(soup: PolySoup, path: &Path) -> Result<ValidatedMesh> {
    let nv_in = soup.positions.len();
    let nf_in = soup.num_faces();
    let mut report = MeshReport {
        input_vertices: nv_in,
        input_faces: nf_in,
        ..MeshReport::default()
    };
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

    // ---- per-face checks, duplicate and degenerate faces ---------------
    let mut keep = Vec::with_capacity(nf_in);
    let mut seen_tris: FastMap<[u32; 3], u32> = FastMap::default();
    let mut seen_polys: FastMap<Vec<u32>, u32> = FastMap::default();
    let mut first_repeated = None;
    let mut first_duplicate = None;
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
        let repeated = if face.len() == 3 {
            face[0] == face[1] || face[1] == face[2] || face[0] == face[2]
        } else {
            let mut s = face.to_vec();
            s.sort_unstable();
            s.windows(2).any(|w| w[0] == w[1])
        };
        if repeated {
            report.repeated_index_faces += 1;
            first_repeated.get_or_insert(f);
            continue;
        }
        let dup_of = if face.len() == 3 {
            let mut k = [face[0], face[1], face[2]];
            k.sort_unstable();
            *seen_tris.entry(k).or_insert(f as u32)
        } else {
            let mut k = face.to_vec();
            k.sort_unstable();
            *seen_polys.entry(k).or_insert(f as u32)
        };
        if dup_of as usize != f {
            report.duplicate_faces += 1;
            first_duplicate.get_or_insert((f, dup_of));
            continue;
        }
        keep.push(f as u32);
    }
    drop(seen_tris);
    drop(seen_polys);
    if let Some(f) = first_repeated {
        report.notes.push(format!(
            "dropped {} face(s) that repeat a vertex index (first: face {f})",
            report.repeated_index_faces
        ));
    }
    if let Some((f, g)) = first_duplicate {
        report.notes.push(format!(
            "dropped {} face(s) with the same vertices as an earlier face (first: face {f} = face {g})",
            report.duplicate_faces
        ));
    }
    if keep.is_empty() {
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

    // ---- used vertices, renumbering, finiteness -------------------------
    const UNUSED: u32 = u32::MAX;
    let mut remap = vec![UNUSED; nv_in];
    for &f in &keep {
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
        if !p.is_finite() {
            let what = if p.is_nan() { "NaN" } else { "infinite" };
            return Err(Error::invalid_mesh(
                path,
                format!("vertex {i}"),
                format!("non-finite coordinate ({what}): {p}"),
            ));
        }
        *r = positions.len() as u32;
        positions.push(p);
    }
    report.vertices = positions.len();
    report.unreferenced_vertices = nv_in - positions.len();
    if report.unreferenced_vertices > 0 {
        let nonfinite = soup
            .positions
            .iter()
            .zip(&remap)
            .filter(|(p, &r)| r == UNUSED && !p.is_finite())
            .count();
        report.notes.push(format!(
            "dropped {} unreferenced vertices{}; the others are renumbered in their original order",
            report.unreferenced_vertices,
            if nonfinite > 0 {
                format!(" ({nonfinite} of them with non-finite coordinates)")
            } else {
                String::new()
            }
        ));
    }
    let (lo, hi) = bbox(&positions);
    report.bbox_min = lo.to_array();
    report.bbox_max = hi.to_array();
    report.bbox_diagonal = (hi - lo).length();
    let area_eps = zero_area_threshold(report.bbox_diagonal);

    // ---- triangulation ----------------------------------------------------
    let mut triangles = Vec::with_capacity(soup.face_indices.len());
    let mut polygons = 0usize;
    for &f in &keep {
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

    topology(&positions, &triangles, &mut report);
    Ok(ValidatedMesh {
        mesh: TriMesh {
            positions,
            triangles,
        },
        report,
    })
}

/// Uses of one undirected edge `(lo, hi)`.
#[derive(Clone, Copy)]
struct EdgeUse {
    count: u32,
    /// Uses traversing it from `lo` to `hi`.
    forward: u32,
    /// Corners (`3 t + k`) of `lo` and `hi` in the first two triangles.
    corners: [[u32; 2]; 2],
}

fn topology(positions: &[DVec3], tris: &[[u32; 3]], r: &mut MeshReport) {
    let nv = positions.len();
    let mut edges: FastMap<u64, EdgeUse> = FastMap::default();
    edges.reserve(tris.len() * 3 / 2 + 16);
    for (t, tri) in tris.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let (lo, hi, fwd) = if a < b { (a, b, 1) } else { (b, a, 0) };
            let (clo, chi) = {
                let (ca, cb) = (3 * t as u32 + k as u32, 3 * t as u32 + ((k + 1) % 3) as u32);
                if fwd == 1 {
                    (ca, cb)
                } else {
                    (cb, ca)
                }
            };
            let e = edges
                .entry(((lo as u64) << 32) | hi as u64)
                .or_insert(EdgeUse {
                    count: 0,
                    forward: 0,
                    corners: [[0; 2]; 2],
                });
            if e.count < 2 {
                e.corners[e.count as usize] = [clo, chi];
            }
            e.count += 1;
            e.forward += fwd;
        }
    }
    r.edges = edges.len();

    // Corners around a vertex joined across manifold edges: the fans.
    let mut corner_uf = UnionFind::new(3 * tris.len());
    let mut vertex_uf = UnionFind::new(nv);
    let mut boundary_out: Vec<(u32, u32)> = Vec::new(); // directed boundary edges
    let mut length_sum = 0.0;
    for (&key, e) in &edges {
        let (lo, hi) = ((key >> 32) as u32, key as u32);
        vertex_uf.union(lo as usize, hi as usize);
        length_sum += (positions[lo as usize] - positions[hi as usize]).length();
        match e.count {
            1 => {
                r.boundary_edges += 1;
                boundary_out.push(if e.forward == 1 { (lo, hi) } else { (hi, lo) });
            }
            2 => {
                if e.forward != 1 {
                    r.non_manifold_edges += 1;
                    r.inconsistently_oriented_edges += 1;
                }
                corner_uf.union(e.corners[0][0] as usize, e.corners[1][0] as usize);
                corner_uf.union(e.corners[0][1] as usize, e.corners[1][1] as usize);
            }
            _ => r.non_manifold_edges += 1,
        }
    }
    r.mean_edge_length = if edges.is_empty() {
        0.0
    } else {
        length_sum / edges.len() as f64
    };
    drop(edges);
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

struct UnionFind {
    parent: Vec<u32>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
        }
    }
    fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] as usize != x {
            // Path halving.
            let g = self.parent[self.parent[x] as usize];
            self.parent[x] = g;
            x = g as usize;
        }
        x
    }
    fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            // Smaller root wins: deterministic, and roots stay vertex-ordered.
            let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
            self.parent[hi] = lo as u32;
        }
    }
}

/// FxHash-style multiplicative hasher: integer keys from a trusted source
/// (our own indices), so DoS resistance is not needed and SipHash's cost
/// (most of the validation time on the bunny) is avoided.
#[derive(Default, Clone, Copy)]
struct FxHasher(u64);

impl Hasher for FxHasher {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(8) {
            let mut b = [0u8; 8];
            b[..chunk.len()].copy_from_slice(chunk);
            self.write_u64(u64::from_le_bytes(b));
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
    #[inline]
    fn write_usize(&mut self, i: usize) {
        self.write_u64(i as u64);
    }
    #[inline]
    fn finish(&self) -> u64 {
        self.0
    }
}

type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<FxHasher>>;

impl fmt::Display for MeshReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let yn = |b: bool| if b { "yes" } else { "no" };
        writeln!(
            f,
            "vertices        {} ({} in the file, {} unreferenced dropped)",
            self.vertices, self.input_vertices, self.unreferenced_vertices
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
