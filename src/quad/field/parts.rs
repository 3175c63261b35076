//! Inputs people really have (issue 40 item 4): several parts, any vertex
//! order.
//!
//! **Parts.** A scan with several connected components is laid out one
//! component at a time: each gets its own cross field (the Knöppel et al.
//! solve normalises over its mesh, so one part's field must not be scaled
//! by another's), its own position field, extraction and topology check
//! against its own components / boundary loops / Euler characteristic,
//! and its share of a face target is the share of the sizing field's
//! predicted count `∫ dA / h²` (the sizing's scale α stays global, so
//! every part aims at the patches the Fitmap asks for there). The control
//! meshes are then joined. A part too small to carry a lattice at the
//! requested size gets a smaller size of its own ([`MIN_PART_FACES`], then
//! more refinements), and as a last resort its own triangles split into
//! quads ([`split_triangles`]): kept, never dropped or refused.
//!
//! **Vertex order.** Gauss–Seidel sweeps (cross and position fields), the
//! hierarchy's tie-breaks, union-find roots and the extraction's walks
//! all run in vertex order, and the lattice is chaotic in its inputs (a
//! welded soup of spot, the same surface renumbered, laid 43 patches
//! where spot laid 33). So each part's vertices are renumbered in an
//! order keyed by position alone ([`canonical_order`]: Morton order of
//! the part's bounding cube, exact coordinates on ties) and its
//! triangles sorted, before anything is solved: the same surface gives
//! the same part, bit for bit, whatever the input's numbering; only the
//! inputs computed on the whole mesh before the field (the Fitmap) can
//! still differ, by float noise.

use rayon::prelude::*;

use crate::error::Result;
use crate::mesh::{ControlMesh, TriMesh};
use crate::DVec3;

use super::{FieldOptions, Surface, UnionFind};

/// A connected component of M, renumbered in [`canonical_order`].
pub(super) struct Part {
    /// The vertex of M behind each of the part's vertices.
    pub(super) vertices: Vec<u32>,
    pub(super) mesh: TriMesh,
    pub(super) surf: Surface,
    /// The part's own cross field ([`super::cross::cross_field`]).
    pub(super) dirs: Vec<DVec3>,
    /// The part's area (its vertex areas' sum).
    pub(super) area: f64,
}

impl Part {
    /// `values` (per vertex of M) on the part's vertices.
    pub(super) fn gather<T: Copy>(&self, values: &[T]) -> Vec<T> {
        self.vertices.iter().map(|&v| values[v as usize]).collect()
    }
}

/// The parts of `mesh` with their cross fields, in an order keyed by
/// position ([`split`]).
pub(super) fn parts(mesh: &TriMesh, opts: &FieldOptions) -> Result<Vec<Part>> {
    let mut pieces = split(mesh);
    // One part, and no order asked for (`SUBDFIT_FIELD_ORDER` unset): M as
    // it is, in its own numbering, as before parts existed. A renumbered
    // one-part M is just another draw of the lattice, and on the shared
    // meshes it drew worse (docs/status.md "Field-aligned layout",
    // session 13).
    if pieces.len() == 1 && Order::from_env().is_none() {
        pieces = vec![((0..mesh.positions.len() as u32).collect(), mesh.clone())];
    }
    // Each part's cross field reads only the part: solved side by side
    // (issue 39), collected in part order, the first failed part's error
    // returned as one after the other would.
    let parts: Vec<Result<Part>> = pieces
        .into_par_iter()
        .map(|(vertices, sub)| {
            let surf = Surface::new(&sub)?;
            let dirs = super::cross::cross_field(&surf, opts)?;
            let area = surf.areas.iter().sum();
            Ok(Part {
                vertices,
                mesh: sub,
                surf,
                dirs,
                area,
            })
        })
        .collect();
    parts.into_iter().collect()
}

/// The connected components of `mesh` (vertices joined by its triangles;
/// vertices on no triangle are left out), each as (the vertices of M in
/// the part's order, the part's mesh). The parts come in the order of
/// their lowest vertex (x, then y, then z), so that their order too is
/// the surface's, not the numbering's.
pub(super) fn split(mesh: &TriMesh) -> Vec<(Vec<u32>, TriMesh)> {
    let n = mesh.positions.len();
    let mut uf = UnionFind::new(n);
    let mut used = vec![false; n];
    for t in &mesh.triangles {
        uf.union(t[0] as usize, t[1] as usize);
        uf.union(t[0] as usize, t[2] as usize);
        for &v in t {
            used[v as usize] = true;
        }
    }
    let mut slot = vec![usize::MAX; n];
    let mut members: Vec<Vec<u32>> = Vec::new();
    for v in (0..n).filter(|&v| used[v]) {
        let r = uf.find(v);
        if slot[r] == usize::MAX {
            slot[r] = members.len();
            members.push(Vec::new());
        }
        members[slot[r]].push(v as u32);
    }
    let mut tris: Vec<Vec<[u32; 3]>> = vec![Vec::new(); members.len()];
    for t in &mesh.triangles {
        tris[slot[uf.find(t[0] as usize)]].push(*t);
    }
    let mut out: Vec<(Vec<u32>, TriMesh)> = members
        .into_iter()
        .zip(tris)
        .map(|(vs, ts)| renumbered(mesh, vs, &ts))
        .collect();
    out.sort_by_cached_key(part_key);
    out
}

/// The order of parts: lowest vertex by exact coordinates, then size,
/// then (only for coincident, equal-sized parts) the numbering.
fn part_key((vertices, sub): &(Vec<u32>, TriMesh)) -> ([i64; 3], usize, usize, u32) {
    let lowest = sub
        .positions
        .iter()
        .map(|p| coord_key(*p))
        .min()
        .unwrap_or_default();
    let first = vertices.iter().min().copied().unwrap_or(0);
    (lowest, sub.positions.len(), sub.triangles.len(), first)
}

/// Coordinates as totally ordered integers (`f64::total_cmp`'s order).
fn coord_key(p: DVec3) -> [i64; 3] {
    let k = |x: f64| {
        let b = x.to_bits() as i64;
        b ^ ((((b >> 63) as u64) >> 1) as i64)
    };
    [k(p.x), k(p.y), k(p.z)]
}

/// The part of `mesh` on `vertices` with triangles `tris`, renumbered in
/// [`canonical_order`]; its triangles each start at their lowest vertex
/// (orientation kept) and are sorted.
fn renumbered(mesh: &TriMesh, vertices: Vec<u32>, tris: &[[u32; 3]]) -> (Vec<u32>, TriMesh) {
    renumbered_in(
        mesh,
        vertices,
        tris,
        Order::from_env().unwrap_or(Order::Morton),
    )
}

/// [`renumbered`] in the order `by`.
fn renumbered_in(
    mesh: &TriMesh,
    vertices: Vec<u32>,
    tris: &[[u32; 3]],
    by: Order,
) -> (Vec<u32>, TriMesh) {
    let order = match by {
        Order::Morton => canonical_order(&mesh.positions, &vertices),
        Order::Lexicographic => {
            let mut keyed: Vec<([i64; 3], u32)> = vertices
                .iter()
                .map(|&v| (coord_key(mesh.positions[v as usize]), v))
                .collect();
            keyed.sort_unstable();
            keyed.into_iter().map(|k| k.1).collect()
        }
        Order::Breadth => breadth_order(mesh, &vertices, tris),
    };
    let mut local = std::collections::HashMap::with_capacity(order.len());
    for (i, &v) in order.iter().enumerate() {
        local.insert(v, i as u32);
    }
    let mut triangles: Vec<[u32; 3]> = tris
        .iter()
        .map(|t| {
            let l = t.map(|v| local[&v]);
            let k = (0..3).min_by_key(|&k| l[k]).unwrap_or(0);
            [l[k], l[(k + 1) % 3], l[(k + 2) % 3]]
        })
        .collect();
    triangles.sort_unstable();
    let positions = order.iter().map(|&v| mesh.positions[v as usize]).collect();
    (
        order,
        TriMesh {
            positions,
            triangles,
        },
    )
}

/// Which position-keyed order the parts are renumbered in
/// (`SUBDFIT_FIELD_ORDER` = `morton`, `lex`, `bfs`). Parts of a
/// several-part mesh are always renumbered (Morton unless set); a
/// whole one-part M is renumbered only when the variable is set
/// ([`Order::from_env`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Order {
    /// [`canonical_order`].
    Morton,
    /// By exact coordinates, x then y then z.
    Lexicographic,
    /// [`breadth_order`].
    Breadth,
}

impl Order {
    /// The order `SUBDFIT_FIELD_ORDER` names, `None` when unset (or
    /// empty, or `input`).
    pub fn from_env() -> Option<Order> {
        match crate::switches::text("SUBDFIT_FIELD_ORDER").as_deref() {
            Some("lex") => Some(Order::Lexicographic),
            Some("bfs") => Some(Order::Breadth),
            Some("") | Some("input") | None => None,
            Some(_) => Some(Order::Morton),
        }
    }
}

/// Breadth-first over the triangles' edges from the vertex first in
/// [`canonical_order`], each vertex's neighbours taken in that order (a
/// front that sweeps the surface, as Cuthill–McKee's); the next unreached
/// vertex in that order starts the next front.
fn breadth_order(mesh: &TriMesh, vertices: &[u32], tris: &[[u32; 3]]) -> Vec<u32> {
    let by_key = canonical_order(&mesh.positions, vertices);
    let mut rank = std::collections::HashMap::with_capacity(by_key.len());
    for (i, &v) in by_key.iter().enumerate() {
        rank.insert(v, i as u32);
    }
    let n = by_key.len();
    let mut nbr: Vec<Vec<u32>> = vec![Vec::new(); n];
    for t in tris {
        let r = t.map(|v| rank[&v]);
        for k in 0..3 {
            nbr[r[k] as usize].push(r[(k + 1) % 3]);
            nbr[r[(k + 1) % 3] as usize].push(r[k]);
        }
    }
    for l in &mut nbr {
        l.sort_unstable();
        l.dedup();
    }
    let mut seen = vec![false; n];
    let mut out = Vec::with_capacity(n);
    let mut queue = std::collections::VecDeque::new();
    for s in 0..n {
        if seen[s] {
            continue;
        }
        seen[s] = true;
        queue.push_back(s as u32);
        while let Some(v) = queue.pop_front() {
            out.push(by_key[v as usize]);
            for &w in &nbr[v as usize] {
                if !seen[w as usize] {
                    seen[w as usize] = true;
                    queue.push_back(w);
                }
            }
        }
    }
    out
}

/// `vertices` sorted by position: the Morton code of each point in the
/// bounding cube of the set (21 bits per axis; neighbours on the surface
/// stay near in the order, as in a scanner's or modeller's numbering),
/// then the exact coordinates, then (coincident points only) the index.
pub(super) fn canonical_order(positions: &[DVec3], vertices: &[u32]) -> Vec<u32> {
    let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
    for &v in vertices {
        lo = lo.min(positions[v as usize]);
        hi = hi.max(positions[v as usize]);
    }
    let extent = (hi - lo).max_element();
    let scale = if extent > 0.0 && extent.is_finite() {
        ((1u64 << 21) - 1) as f64 / extent
    } else {
        0.0
    };
    let morton = |p: DVec3| -> u64 {
        let q = (p - lo) * scale;
        let axis = |x: f64| spread((x.max(0.0) as u64).min((1 << 21) - 1));
        axis(q.x) | (axis(q.y) << 1) | (axis(q.z) << 2)
    };
    let mut keyed: Vec<(u64, [i64; 3], u32)> = vertices
        .iter()
        .map(|&v| {
            let p = positions[v as usize];
            (morton(p), coord_key(p), v)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|k| k.2).collect()
}

/// `mesh` renumbered by position as a whole: its vertices in
/// [`canonical_order`], its triangles each starting at their lowest vertex
/// and sorted; with, per new vertex, the vertex of `mesh` it is. What is
/// computed on it (the Fitmap's seeds and per-vertex random streams, the
/// proxy's decimation order) is then the surface's, not the numbering's.
pub fn canonical_mesh(mesh: &TriMesh) -> (TriMesh, Vec<u32>) {
    canonical_mesh_in(mesh, Order::from_env().unwrap_or(Order::Morton))
}

/// [`canonical_mesh`] in the order `by`.
pub fn canonical_mesh_in(mesh: &TriMesh, by: Order) -> (TriMesh, Vec<u32>) {
    let all: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    let (order, canon) = renumbered_in(mesh, all, &mesh.triangles, by);
    (canon, order)
}

/// The 21 low bits of `x` spread to every third bit.
fn spread(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// A part's predicted count below which its sizes are lowered before the
/// lattice is laid ([`floor_count`]): a closed part needs at least a
/// cube's 6 quads, and a position-field lattice of a handful of cells
/// seldom closes up (the lattice's own count lands at 0.55–0.95 of the
/// prediction on coarse fields); 24 is a cube split once.
pub const MIN_PART_FACES: f64 = 24.0;

/// `h` scaled down on a part whose predicted count is below
/// [`MIN_PART_FACES`]; the factor (1 when it was not).
pub(super) fn floor_count(surf: &Surface, h: &mut [f64]) -> f64 {
    let n = super::sizing::predicted_faces(surf, h);
    if !(n.is_finite() && n < MIN_PART_FACES) || n <= 0.0 {
        return 1.0;
    }
    let f = (n / MIN_PART_FACES).sqrt();
    for x in h.iter_mut() {
        *x *= f;
    }
    f
}

/// The last resort of a part no lattice kept the topology of: its own
/// triangles, each split into three quads at its edge midpoints and
/// centroid (one Catmull–Clark split of the triangles: the same surface,
/// components, boundary loops and Euler characteristic, V − E + F being
/// unchanged by the split).
pub(super) fn split_triangles(mesh: &TriMesh) -> Result<ControlMesh> {
    let mut positions = mesh.positions.clone();
    let mut mids: std::collections::HashMap<(u32, u32), u32> = Default::default();
    let mut mid = |a: u32, b: u32, positions: &mut Vec<DVec3>| -> u32 {
        let k = (a.min(b), a.max(b));
        *mids.entry(k).or_insert_with(|| {
            positions.push(0.5 * (positions[a as usize] + positions[b as usize]));
            (positions.len() - 1) as u32
        })
    };
    let mut quads = Vec::with_capacity(3 * mesh.triangles.len());
    for &[a, b, c] in &mesh.triangles {
        let (ab, bc, ca) = (
            mid(a, b, &mut positions),
            mid(b, c, &mut positions),
            mid(c, a, &mut positions),
        );
        let pa = positions[a as usize];
        let pb = positions[b as usize];
        let pc = positions[c as usize];
        positions.push((pa + pb + pc) / 3.0);
        let m = (positions.len() - 1) as u32;
        quads.push([a, ab, m, ca]);
        quads.push([b, bc, m, ab]);
        quads.push([c, ca, m, bc]);
    }
    ControlMesh::from_polygons(positions, &quads)
}

/// The control meshes of several parts as one mesh (vertices and faces
/// in the parts' order).
pub(super) fn join(meshes: &[ControlMesh]) -> Result<ControlMesh> {
    let mut positions: Vec<DVec3> = Vec::new();
    let mut faces: Vec<Vec<u32>> = Vec::new();
    for k in meshes {
        let base = positions.len() as u32;
        positions.extend_from_slice(k.positions());
        faces.extend(
            k.to_polygons()
                .into_iter()
                .map(|f| f.into_iter().map(|v| v + base).collect()),
        );
    }
    ControlMesh::from_polygons(positions, &faces)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_puts_each_bit_every_third_place() {
        assert_eq!(spread(0b1), 0b1);
        assert_eq!(spread(0b11), 0b1001);
        assert_eq!(spread(0b101), 0b1_000_000 | 1);
        let all = spread((1 << 21) - 1);
        assert_eq!(all.count_ones(), 21);
        assert_eq!(all, 0x1249_2492_4924_9249);
    }

    #[test]
    fn split_finds_parts_and_their_order_ignores_the_numbering() {
        // Two triangles far apart, then the same with the vertices and
        // triangles listed in another order.
        let p = |x: f64, y: f64| DVec3::new(x, y, 0.0);
        let a = TriMesh {
            positions: vec![
                p(0., 0.),
                p(1., 0.),
                p(0., 1.),
                p(5., 0.),
                p(6., 0.),
                p(5., 1.),
            ],
            triangles: vec![[0, 1, 2], [3, 4, 5]],
        };
        let b = TriMesh {
            positions: vec![
                p(6., 0.),
                p(0., 1.),
                p(5., 1.),
                p(1., 0.),
                p(5., 0.),
                p(0., 0.),
            ],
            triangles: vec![[4, 0, 2], [1, 5, 3]],
        };
        let (sa, sb) = (split(&a), split(&b));
        assert_eq!(sa.len(), 2);
        assert_eq!(sb.len(), 2);
        for ((_, ma), (_, mb)) in sa.iter().zip(&sb) {
            assert_eq!(ma.positions, mb.positions);
            assert_eq!(ma.triangles, mb.triangles);
        }
        assert_eq!(sa[0].1.positions[0].x, 0.0, "the part at the origin first");
    }

    #[test]
    fn split_triangles_keeps_the_topology() {
        // A tetrahedron: closed, χ = 2, 4 triangles → 12 quads.
        let t = TriMesh {
            positions: vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z],
            triangles: vec![[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
        };
        let k = split_triangles(&t).unwrap();
        assert_eq!(k.num_faces(), 12);
        let s = super::super::control_topology(&k);
        assert_eq!((s.components, s.boundary_loops, s.euler), (1, 0, 2));
    }
}
