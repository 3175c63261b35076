//! Initial control polyhedron per region (Lavoué et al. §6).
//!
//! Each region's boundary control polygon is read off the curve network
//! (shared control points: the polygons of neighbouring regions are
//! synchronised by construction, §6.1). The region is a disc (see
//! [`super::segment`]), so its polygon can be laid on a circle in
//! boundary order: a convex polygon, in which *any* set of non-crossing
//! chords is a valid planar subdivision. The polygon is then cut
//! recursively (§6.3.2) along the chord of smallest coherency score SC
//! (eq. 3, Dijkstra paths on M between the chord ends' anchors, isotropic
//! vertices counting 45°, vertices on a boundary 90°), until the pieces
//! are quads or triangles; a region that is planar (all its vertices within
//! [`PLANAR_TOLERANCE`] of a plane) keeps one facet per part instead (its
//! limit patch is then exactly planar, bounded by its crease curves),
//! split at reflex vertices as Hertel–Mehlhorn do (§6.3.2) until each part
//! is convex or star-shaped from its vertex centroid. Convexity is more
//! than the limit needs: every point of Catmull-Clark's refinement of a
//! planar face is an affine combination of its vertices, so the patch stays
//! in the plane whatever the face's shape, and what must not happen is a
//! fold of the first step's quads (face point, edge midpoints, vertex),
//! which star-shapedness from the face point rules out. On fandisk the
//! initial faces fall from 83 to 72 (same error); joint.ply's output from
//! 205 to 182 faces.
//!
//! Chords never duplicate an edge that already exists (a curve segment or
//! another region's chord), so the assembled mesh stays manifold.

use std::collections::{BinaryHeap, HashSet};

use super::curvature::VertexCurvature;
use super::OrdF;
use crate::mesh::TriMesh;
use crate::DVec3;

/// A region is planar when its vertices lie within this fraction of M's
/// diagonal of their least-squares plane: 2e-4 (a tenth of the paper's
/// curve threshold: flat CAD faces are flat to the float resolution).
pub const PLANAR_TOLERANCE: f64 = 2e-4;

/// The normalised sum of the area-weighted normals of `tris`.
fn area_normal(mesh: &TriMesh, tris: &[u32]) -> DVec3 {
    let mut n = DVec3::ZERO;
    for &t in tris {
        let [a, b, c] = mesh.triangle(t as usize);
        n += (b - a).cross(c - a);
    }
    n.normalize_or_zero()
}

/// The plane (a point and unit normal) of a region whose vertices all lie
/// within [`PLANAR_TOLERANCE`] of it, or `None`. Least-squares plane:
/// the vertices' centroid and, for the normal, that of the area-weighted
/// triangle normals, which is the plane's whenever the region is planar.
pub fn region_plane(mesh: &TriMesh, tris: &[u32], diag: f64) -> Option<(DVec3, DVec3)> {
    let mut verts: Vec<u32> = tris
        .iter()
        .flat_map(|&t| mesh.triangles[t as usize])
        .collect();
    verts.sort_unstable();
    verts.dedup();
    let c = verts
        .iter()
        .map(|&v| mesh.positions[v as usize])
        .sum::<DVec3>()
        / verts.len().max(1) as f64;
    let n = area_normal(mesh, tris);
    (n != DVec3::ZERO
        && verts
            .iter()
            .all(|&v| (mesh.positions[v as usize] - c).dot(n).abs() <= PLANAR_TOLERANCE * diag))
    .then_some((c, n))
}

/// One boundary control point of a region polygon.
#[derive(Copy, Clone, Debug)]
pub struct PolyVertex {
    /// Control vertex id in the assembled mesh.
    pub id: u32,
    /// Nearest vertex of M along the boundary (for the Dijkstra paths).
    pub anchor: u32,
}

/// Region data needed by the cutting.
pub struct RegionGeom<'a> {
    pub mesh: &'a TriMesh,
    pub curv: &'a [VertexCurvature],
    /// Vertices of M in the region (sorted).
    pub verts: Vec<u32>,
    /// Adjacency within the region (per entry of `verts`).
    pub adj: Vec<Vec<(usize, f64)>>,
    pub on_boundary: &'a [bool],
    pub planar: Option<(DVec3, DVec3)>,
    /// The region's triangles seen along its mean normal, when it is
    /// nearly flat (see [`FlatShadow`]).
    flat: Option<FlatShadow>,
}

impl<'a> RegionGeom<'a> {
    pub fn new(
        mesh: &'a TriMesh,
        curv: &'a [VertexCurvature],
        tris: &[u32],
        on_boundary: &'a [bool],
        diag: f64,
    ) -> Self {
        let mut verts: Vec<u32> = tris
            .iter()
            .flat_map(|&t| mesh.triangles[t as usize])
            .collect();
        verts.sort_unstable();
        verts.dedup();
        let idx = |v: u32| verts.binary_search(&v).unwrap_or(0);
        let mut adj: Vec<Vec<(usize, f64)>> = vec![Vec::new(); verts.len()];
        for &t in tris {
            let tri = mesh.triangles[t as usize];
            for k in 0..3 {
                let (a, b) = (idx(tri[k]), idx(tri[(k + 1) % 3]));
                let w = (mesh.positions[tri[k] as usize]
                    - mesh.positions[tri[(k + 1) % 3] as usize])
                    .length();
                if !adj[a].iter().any(|x| x.0 == b) {
                    adj[a].push((b, w));
                    adj[b].push((a, w));
                }
            }
        }
        let planar = region_plane(mesh, tris, diag);
        let n = area_normal(mesh, tris);
        let flat = FlatShadow::new(mesh, tris, n);
        RegionGeom {
            mesh,
            curv,
            verts,
            adj,
            on_boundary,
            planar,
            flat,
        }
    }

    fn local(&self, v: u32) -> Option<usize> {
        self.verts.binary_search(&v).ok()
    }

    /// Shortest path (local indices) from `a` to every vertex: predecessor.
    fn dijkstra(&self, a: usize) -> Vec<usize> {
        let n = self.verts.len();
        let mut dist = vec![f64::INFINITY; n];
        let mut pred = vec![usize::MAX; n];
        let mut heap = BinaryHeap::new();
        dist[a] = 0.0;
        heap.push((std::cmp::Reverse(OrdF(0.0)), a));
        while let Some((std::cmp::Reverse(OrdF(d)), u)) = heap.pop() {
            if d > dist[u] {
                continue;
            }
            for &(w, l) in &self.adj[u] {
                let nd = d + l;
                if nd < dist[w] {
                    dist[w] = nd;
                    pred[w] = u;
                    heap.push((std::cmp::Reverse(OrdF(nd)), w));
                }
            }
        }
        pred
    }
}

/// Coherency scores SC (eq. 3) of every pair of polygon vertices.
fn scores(g: &RegionGeom<'_>, poly: &[PolyVertex]) -> Vec<Vec<f64>> {
    let k = poly.len();
    let mut sc = vec![vec![90.0; k]; k];
    let locals: Vec<Option<usize>> = poly.iter().map(|p| g.local(p.anchor)).collect();
    for i in 0..k {
        let Some(a) = locals[i] else { continue };
        let pred = g.dijkstra(a);
        for j in 0..k {
            if i == j {
                continue;
            }
            let Some(b) = locals[j] else { continue };
            let pa = g.mesh.positions[poly[i].anchor as usize];
            let pb = g.mesh.positions[poly[j].anchor as usize];
            let seg = pb - pa;
            let (mut smin, mut smax, mut n) = (0.0, 0.0, 0usize);
            let mut sag = 0.0f64;
            let mut u = pred[b];
            let mut guard = 0;
            while u != usize::MAX && u != a && guard < g.verts.len() {
                let v = g.verts[u] as usize;
                let c = &g.curv[v];
                sag = sag.max(normal_sag(g.mesh.positions[v], c.normal, pa, pb));
                let (tmin, tmax) = if g.on_boundary[v] {
                    (90.0, 90.0)
                } else if c.isotropic {
                    (45.0, 45.0)
                } else {
                    let d = (seg - seg.dot(c.normal) * c.normal).normalize_or_zero();
                    let ang = |e: DVec3| d.dot(e).abs().clamp(0.0, 1.0).acos().to_degrees();
                    (ang(c.d_min), ang(c.d_max))
                };
                smin += tmin;
                smax += tmax;
                n += 1;
                u = pred[u];
                guard += 1;
            }
            sc[i][j] = if pred[b] == usize::MAX && a != b {
                90.0
            } else if n == 0 {
                45.0
            } else {
                f64::min(smin, smax) / n as f64
            } + bend_penalty(sag, seg.length())
                + g.flat.as_ref().map_or(0.0, |f| f.leave_penalty(pa, pb));
        }
    }
    sc
}

/// A nearly flat region's triangles projected onto the plane of its mean
/// normal, bucketed on a grid, to tell whether a straight chord stays over
/// the region.
///
/// SC (eq. 3) rates a chord by the Dijkstra path between its ends, and
/// [`MAX_CHORD_BEND`] by how far that path leaves the chord along the
/// normal; neither sees a path that bends *within* the surface, around a
/// hole or a boss in the region. On a casting's top face (a nearly flat
/// region wrapped around a rib's end: a few fillet triangles kept it from
/// [`PLANAR_TOLERANCE`]) a chord from the rib's lower side to a point
/// above the rib ran straight across the rib's foot; the facet covered
/// ground that is not the region, 13‰ off M, and no enrichment inside the
/// region's fixed boundary could take it back (8 faces of 1007 over the
/// limit at the end). A chord whose shadow leaves the region's shadow is
/// scored as a boundary (90°), as an over-bent one is.
struct FlatShadow {
    e1: DVec3,
    e2: DVec3,
    /// Projected triangles, and per grid cell the triangles touching it.
    tris: Vec<[(f64, f64); 3]>,
    lo: (f64, f64),
    cell: f64,
    nx: usize,
    ny: usize,
    cells: Vec<Vec<u32>>,
}

/// A region is nearly flat (see [`FlatShadow`]) when at least
/// [`FLAT_SHARE`] of its area has normals within 30° of the mean normal
/// (a flat face with strips of fillet or chamfer the segmentation left
/// on it). Every triangle casts its shadow; a steep one casts a thin one,
/// which can only make the test stricter next to it, and the penalty is
/// a score (a chord off the shadow is still cut when nothing else can be).
const FLAT_COS: f64 = 0.866_025_403_784_438_6;

/// See [`FLAT_COS`]: half the area.
const FLAT_SHARE: f64 = 0.5;

/// Interior points of a chord tested by [`FlatShadow::leave_penalty`]: 15,
/// ends excluded.
const CHORD_SAMPLES: usize = 16;

impl FlatShadow {
    fn new(mesh: &TriMesh, tris: &[u32], n: DVec3) -> Option<Self> {
        if n == DVec3::ZERO || tris.is_empty() {
            return None;
        }
        let mut proj = Vec::with_capacity(tris.len());
        let e1 = n.any_orthonormal_vector();
        let e2 = n.cross(e1);
        let (mut lo, mut hi) = ((f64::MAX, f64::MAX), (f64::MIN, f64::MIN));
        let (mut flat_area, mut area) = (0.0, 0.0);
        for &t in tris {
            let [a, b, c] = mesh.triangle(t as usize);
            let tn = (b - a).cross(c - a);
            area += tn.length();
            if tn.normalize_or_zero().dot(n) >= FLAT_COS {
                flat_area += tn.length();
            }
            let p = [a, b, c].map(|p| (p.dot(e1), p.dot(e2)));
            for q in p {
                lo = (lo.0.min(q.0), lo.1.min(q.1));
                hi = (hi.0.max(q.0), hi.1.max(q.1));
            }
            proj.push(p);
        }
        if flat_area < FLAT_SHARE * area {
            return None;
        }
        // About one triangle per cell along each axis of a square grid.
        let side = (tris.len() as f64).sqrt().ceil().max(1.0);
        let cell = ((hi.0 - lo.0).max(hi.1 - lo.1) / side).max(1e-12);
        let nx = ((hi.0 - lo.0) / cell) as usize + 1;
        let ny = ((hi.1 - lo.1) / cell) as usize + 1;
        let mut cells = vec![Vec::new(); nx * ny];
        for (i, p) in proj.iter().enumerate() {
            let (x0, x1) = (
                p.iter().map(|q| q.0).fold(f64::MAX, f64::min),
                p.iter().map(|q| q.0).fold(f64::MIN, f64::max),
            );
            let (y0, y1) = (
                p.iter().map(|q| q.1).fold(f64::MAX, f64::min),
                p.iter().map(|q| q.1).fold(f64::MIN, f64::max),
            );
            let cx = |x: f64| (((x - lo.0) / cell) as usize).min(nx - 1);
            let cy = |y: f64| (((y - lo.1) / cell) as usize).min(ny - 1);
            for y in cy(y0)..=cy(y1) {
                for x in cx(x0)..=cx(x1) {
                    cells[y * nx + x].push(i as u32);
                }
            }
        }
        Some(FlatShadow {
            e1,
            e2,
            tris: proj,
            lo,
            cell,
            nx,
            ny,
            cells,
        })
    }

    /// Whether the shadow of `p` falls on a triangle's shadow (a margin of
    /// 5 % of the triangle in barycentric terms, for points on an edge).
    fn covers(&self, p: DVec3) -> bool {
        let q = (p.dot(self.e1), p.dot(self.e2));
        let x = (q.0 - self.lo.0) / self.cell;
        let y = (q.1 - self.lo.1) / self.cell;
        if x < 0.0 || y < 0.0 || x >= self.nx as f64 || y >= self.ny as f64 {
            return false;
        }
        self.cells[y as usize * self.nx + x as usize]
            .iter()
            .any(|&t| {
                let [a, b, c] = self.tris[t as usize];
                let d = (b.0 - a.0) * (c.1 - a.1) - (b.1 - a.1) * (c.0 - a.0);
                if d.abs() < 1e-300 {
                    return false;
                }
                let l1 = ((b.0 - q.0) * (c.1 - q.1) - (b.1 - q.1) * (c.0 - q.0)) / d;
                let l2 = ((c.0 - q.0) * (a.1 - q.1) - (c.1 - q.1) * (a.0 - q.0)) / d;
                let l3 = 1.0 - l1 - l2;
                l1 >= -0.05 && l2 >= -0.05 && l3 >= -0.05
            })
    }

    /// 90° when a point of the chord `a b` (ends excluded) falls off the
    /// region's shadow, else 0.
    fn leave_penalty(&self, a: DVec3, b: DVec3) -> f64 {
        let off = (1..CHORD_SAMPLES).any(|t| {
            let s = t as f64 / CHORD_SAMPLES as f64;
            !self.covers(a + s * (b - a))
        });
        if off {
            90.0
        } else {
            0.0
        }
    }
}

/// Cuts a region polygon into facets (see the module docs). `edges` holds
/// the undirected control edges that exist already; chords are added to it.
pub fn cut_region(
    g: &RegionGeom<'_>,
    poly: &[PolyVertex],
    positions: &[DVec3],
    edges: &mut HashSet<(u32, u32)>,
) -> Vec<Vec<u32>> {
    let key = |a: u32, b: u32| (a.min(b), a.max(b));
    let mut out = Vec::new();
    // A slit (a feature fading out inside the region, see
    // `SegmentOptions::slits`) visits its points twice; every facet must
    // hold a point once, so such a polygon is cut until none repeats
    // (the planar decomposition below assumes a simple polygon).
    let repeats = |p: &[usize]| {
        let mut ids: Vec<u32> = p.iter().map(|&i| poly[i].id).collect();
        ids.sort_unstable();
        ids.windows(2).any(|w| w[0] == w[1])
    };
    let all: Vec<usize> = (0..poly.len()).collect();
    let slit = repeats(&all);
    if let (Some((_, n)), false) = (g.planar, slit) {
        let ids: Vec<u32> = poly.iter().map(|p| p.id).collect();
        convex_parts(&ids, positions, n, edges, &mut out);
        return out;
    }
    let sc = scores(g, poly);
    // Work on index lists into `poly`.
    let mut stack: Vec<Vec<usize>> = vec![all];
    while let Some(p) = stack.pop() {
        let k = p.len();
        if k <= 4 && !repeats(&p) {
            out.push(p.iter().map(|&i| poly[i].id).collect());
            continue;
        }
        // A slit's tip (both neighbours the same point) is cut first, to a
        // point off that slit: the two sides of the slit then lie in two
        // different parts, each visiting the slit's points once, and no
        // facet joins the slit's sides (which would fold it over the
        // feature). `slit_run`: the tip's slit, as offsets either side.
        let id_at = |j: usize| poly[p[j % k]].id;
        let tip = (0..k).find(|&t| k > 3 && id_at(t + k - 1) == id_at(t + 1));
        let slit_run = tip.map_or(0, |t| {
            (1..k / 2)
                .take_while(|&j| id_at(t + k - j) == id_at(t + j))
                .count()
        });
        let on_tip_slit = |b: usize| {
            tip.is_some_and(|t| {
                let d = (b + k - t) % k;
                d <= slit_run || k - d <= slit_run
            })
        };
        let mut best: Option<(f64, usize, usize)> = None;
        for a in 0..k {
            for b in a + 2..k {
                if a == 0 && b == k - 1 {
                    continue;
                }
                if let Some(t) = tip {
                    let other = if a == t {
                        b
                    } else if b == t {
                        a
                    } else {
                        continue;
                    };
                    if on_tip_slit(other) {
                        continue;
                    }
                }
                let (ia, ib) = (p[a], p[b]);
                if poly[ia].id == poly[ib].id || edges.contains(&key(poly[ia].id, poly[ib].id)) {
                    continue;
                }
                let s1 = b - a + 1;
                let s2 = k - (b - a) + 1;
                // Prefer quads: a triangle piece costs 10°, and a balanced cut
                // is preferred among equal scores.
                let tri_pen = if s1 == 3 || s2 == 3 { 10.0 } else { 0.0 };
                let bal = 5.0 * (1.0 - s1.min(s2) as f64 / s1.max(s2) as f64);
                // From a tip, the straightest continuation of the feature
                // (as step 3b of `segment` continues it): the turn from the
                // slit's last chord, in degrees, is added.
                let turn = tip.map_or(0.0, |t| {
                    let other = if a == t { ib } else { ia };
                    let pt = g.mesh.positions[poly[p[t]].anchor as usize];
                    let prev = g.mesh.positions[poly[p[(t + 1) % k]].anchor as usize];
                    let dir = (pt - prev).normalize_or_zero();
                    let to =
                        (g.mesh.positions[poly[other].anchor as usize] - pt).normalize_or_zero();
                    dir.dot(to).clamp(-1.0, 1.0).acos().to_degrees()
                });
                let score = 0.5 * (sc[ia][ib] + sc[ib][ia]) + tri_pen + bal + turn;
                if best.map_or(true, |x| score < x.0) {
                    best = Some((score, a, b));
                }
            }
        }
        match best {
            Some((_, a, b)) => {
                edges.insert(key(poly[p[a]].id, poly[p[b]].id));
                stack.push(p[a..=b].to_vec());
                let mut rest: Vec<usize> = p[b..].to_vec();
                rest.extend_from_slice(&p[..=a]);
                stack.push(rest);
            }
            None => out.push(p.iter().map(|&i| poly[i].id).collect()),
        }
    }
    out
}

/// Whether a planar polygon (2D points, orientation `sign`, |area|
/// `scale`) is star-shaped from its vertex centroid, which is the face
/// point of Catmull-Clark's first step: every triangle (centroid, edge)
/// keeps the polygon's orientation with a margin (a twentieth of the mean
/// fan triangle's area), so the first step's quads do not fold.
fn star_shaped(pts: &[(f64, f64)], sign: f64, scale: f64) -> bool {
    let k = pts.len();
    let c = pts.iter().fold((0.0, 0.0), |a, p| {
        (a.0 + p.0 / k as f64, a.1 + p.1 / k as f64)
    });
    let margin = STAR_MARGIN * scale / k as f64;
    (0..k).all(|i| {
        let (a, b) = (pts[i], pts[(i + 1) % k]);
        sign * ((a.0 - c.0) * (b.1 - c.1) - (a.1 - c.1) * (b.0 - c.0)) > margin
    })
}

const STAR_MARGIN: f64 = 0.05;

/// Convex decomposition of a planar polygon (normal `n`) by diagonals from
/// reflex vertices (Hertel–Mehlhorn style); a polygon with no usable
/// diagonal is kept whole.
fn convex_parts(
    ids: &[u32],
    positions: &[DVec3],
    n: DVec3,
    edges: &mut HashSet<(u32, u32)>,
    out: &mut Vec<Vec<u32>>,
) {
    let e1 = n.any_orthonormal_vector();
    let e2 = n.cross(e1);
    let p2 = |i: u32| {
        let p = positions[i as usize];
        (p.dot(e1), p.dot(e2))
    };
    let cross = |o: (f64, f64), a: (f64, f64), b: (f64, f64)| {
        (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
    };
    let mut stack = vec![ids.to_vec()];
    while let Some(p) = stack.pop() {
        let k = p.len();
        let pts: Vec<(f64, f64)> = p.iter().map(|&i| p2(i)).collect();
        let area: f64 = (0..k)
            .map(|i| cross((0.0, 0.0), pts[i], pts[(i + 1) % k]))
            .sum::<f64>();
        let sign = area.signum();
        let scale = area.abs().max(1e-300);
        let reflex: Vec<usize> = (0..k)
            .filter(|&i| {
                sign * cross(pts[(i + k - 1) % k], pts[i], pts[(i + 1) % k]) < -1e-9 * scale
            })
            .collect();
        if reflex.is_empty() || k <= 3 || star_shaped(&pts, sign, scale) {
            out.push(p);
            continue;
        }
        let r = reflex[0];
        // Best diagonal from r: inside the polygon, crossing no edge,
        // closest to bisecting the reflex angle.
        let mut best: Option<(f64, usize)> = None;
        for j in 0..k {
            if j == r || j == (r + 1) % k || j == (r + k - 1) % k || p[j] == p[r] {
                continue;
            }
            if edges.contains(&(p[r].min(p[j]), p[r].max(p[j]))) {
                continue;
            }
            let (a, b) = (pts[r], pts[j]);
            let crosses = (0..k).any(|i| {
                let (c, d) = (pts[i], pts[(i + 1) % k]);
                if i == r || (i + 1) % k == r || i == j || (i + 1) % k == j {
                    return false;
                }
                let d1 = cross(a, b, c);
                let d2 = cross(a, b, d);
                let d3 = cross(c, d, a);
                let d4 = cross(c, d, b);
                d1 * d2 < 0.0 && d3 * d4 < 0.0
            });
            if crosses {
                continue;
            }
            // Inside: the diagonal leaves r into the polygon's interior
            // (between the incoming and outgoing edges, the reflex side).
            let prev = pts[(r + k - 1) % k];
            let next = pts[(r + 1) % k];
            let inside = !(sign * cross(prev, a, b) < 0.0 && sign * cross(a, next, b) < 0.0);
            if !inside {
                continue;
            }
            // Both parts must keep positive orientation.
            let part = |from: usize, to: usize| -> f64 {
                let mut s = 0.0;
                let mut i = from;
                loop {
                    let nx = if i == to { from } else { (i + 1) % k };
                    s += cross((0.0, 0.0), pts[i], pts[nx]);
                    if i == to {
                        break;
                    }
                    i = nx;
                }
                s * sign
            };
            if part(r, j) <= 0.0 || part(j, r) <= 0.0 {
                continue;
            }
            let bis = {
                let u = ((prev.0 - a.0), (prev.1 - a.1));
                let v = ((next.0 - a.0), (next.1 - a.1));
                let nu = (u.0 * u.0 + u.1 * u.1).sqrt().max(1e-300);
                let nv = (v.0 * v.0 + v.1 * v.1).sqrt().max(1e-300);
                (-(u.0 / nu + v.0 / nv), -(u.1 / nu + v.1 / nv))
            };
            let d = (b.0 - a.0, b.1 - a.1);
            let nd = (d.0 * d.0 + d.1 * d.1).sqrt().max(1e-300);
            let nb = (bis.0 * bis.0 + bis.1 * bis.1).sqrt().max(1e-300);
            let score = -(d.0 * bis.0 + d.1 * bis.1) / (nd * nb);
            if best.map_or(true, |x| score < x.0) {
                best = Some((score, j));
            }
        }
        match best {
            Some((_, j)) => {
                edges.insert((p[r].min(p[j]), p[r].max(p[j])));
                let (a, b) = (r.min(j), r.max(j));
                stack.push(p[a..=b].to_vec());
                let mut rest: Vec<u32> = p[b..].to_vec();
                rest.extend_from_slice(&p[..=a]);
                stack.push(rest);
            }
            None => out.push(p),
        }
    }
}

// ---- Chord bend (a chord may not span more than a quarter turn) ----------
//
// Diagnosed on block.ply (issue 6): a half-pipe region (normals turning
// 180° from −x through −y to +x, bounded by two feature arcs and two smooth
// sides) was cut into fans from the middle control points of its smooth
// sides. The coherency score SC only compares the *straight* chord's
// direction with the curvature lines along the Dijkstra path, and a chord
// straight across the pipe follows a line of curvature (the circle)
// perfectly, so SC rated it 0°. But one control edge cannot carry half a
// circle: the initial facets cut through the air inside the pipe (region
// RMS 47‰ before, 11.9‰ after the geometry step), and the enrichment never
// recovered (block ended at RMS 3.6‰ with three such regions, joint at
// 3.5‰ with one, which is why both used to fall back to a second build).

/// Largest bend of a chord, as the ratio of its path's deviation from the
/// straight chord (along the surface normal) to the chord's length:
/// `tan(22.5°)/2 ≈ 0.207`, the ratio of a circular arc of a quarter turn.
/// A Catmull-Clark control edge spans about one B-spline span, and a circle
/// takes at least four of them; a chord over a longer arc is scored as a
/// boundary (90°), so it is cut only when nothing else can be.
pub const MAX_CHORD_BEND: f64 = 0.207_106_781_186_547_5;

/// Distance of `p` (normal `n`) from the segment `a b`, along `n`: how far
/// the surface at `p` lies off the straight chord, in the direction the
/// chord would leave the surface. A path that curves *within* the surface
/// (around a concave part of a flat region's outline) has no normal
/// deviation and is not penalised.
fn normal_sag(p: DVec3, n: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let t = ((p - a).dot(ab) / ab.length_squared().max(1e-300)).clamp(0.0, 1.0);
    (p - (a + t * ab)).dot(n).abs()
}

/// SC's penalty (degrees) for a chord of length `len` whose path deviates
/// by `sag` (see [`MAX_CHORD_BEND`]).
fn bend_penalty(sag: f64, len: f64) -> f64 {
    if sag > MAX_CHORD_BEND * len {
        90.0
    } else {
        0.0
    }
}
