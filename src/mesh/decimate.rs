//! The layout proxy M′ of the Fitmaps paper's §4: a copy of M simplified by
//! a real decimator, on which the Fitmap, the quadrangulation and the
//! simplification run, while every fit, projection and measurement refers
//! to M itself.
//!
//! The decimator is meshoptimizer's quadric edge-collapse simplifier (the
//! `meshopt` crate). OpenMesh's `DecimaterT` with `ModQuadricT`, already
//! linked, was tried first and was about ten times slower on a scan
//! (docs/status.md, "Measurements behind the code"); [`decimate`] splits
//! the work over the cores.
//!
//! meshoptimizer does not check the link condition: on a dense scan it
//! leaves a few "pillows", two triangles on the same three vertices facing
//! each other (docs/status.md, "Measurements behind the code", counts
//! them on a scan). They enclose nothing and are removed. Whatever else changes M's topology is
//! caught by [`Topology`], which the pipeline compares before using M′.

use crate::error::{Error, Result};

use super::TriMesh;

/// What [`decimate`] did, for the report.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DecimateStats {
    /// Triangles removed as pillows (see the module doc).
    pub pillow_triangles: usize,
    /// Triangles removed as pinched-off pockets (see [`without_pockets`]).
    pub pocket_triangles: usize,
    /// Components kept verbatim (too small to decimate).
    pub small_components: usize,
    /// Parts decimated side by side before the final pass.
    pub parts: usize,
}

/// Components below this many triangles are kept as they are: decimating a
/// small closed part can only fold it flat, and they cost nothing later.
const SMALL_COMPONENT: usize = 256;

/// Below this many triangles one pass is quick (< 1 s); above, the mesh is
/// cut in two halves decimated side by side.
const SPLIT_ABOVE: usize = 200_000;

/// `mesh` decimated to about `target_triangles` triangles. M's boundary is
/// decimated like the rest: meshoptimizer (1.3) collapses a border vertex
/// only along its border and adds a plane through each border edge,
/// perpendicular to its triangle, to the quadrics, so the holes keep their
/// shape. Locking the border instead kept every boundary vertex of M in
/// M′, and the control mesh inherited them (on a scan with many holes, as
/// many boundary control vertices as patches; docs/status.md,
/// "Measurements behind the code").
/// The surviving vertices are M's own, bit for bit: an edge collapse keeps one
/// of its two vertices where it is, so M′ lies on M's vertices. Pillows are
/// removed; a non-manifold vertex the simplifier leaves is split
/// ([`super::split_non_manifold`]), as every later stage needs one fan per
/// vertex.
///
/// Both cores: above [`SPLIT_ABOVE`] triangles the mesh is cut at the
/// median of the triangle centroids along its longest box axis, each half
/// is decimated to its share of twice the target with its borders locked
/// (the cut is a border of each half and must stay where it is for the
/// halves to meet), and a final pass over the union, where the cut is
/// interior again and M's own border free, reaches the target. Deterministic: the cut is a
/// sort with the triangle index as tie-break, and meshoptimizer draws no
/// random numbers (each pass is sequential: one global priority queue).
pub fn decimate(mesh: &TriMesh, target_triangles: usize) -> Result<(TriMesh, DecimateStats)> {
    let mut stats = DecimateStats::default();
    let pos: Vec<f32> = mesh
        .positions
        .iter()
        .flat_map(|p| p.to_array().map(|x| x as f32))
        .collect();
    // Small components are kept; the rest is decimated.
    let comp = triangle_components(mesh);
    let mut size = vec![0usize; comp.1];
    for &c in &comp.0 {
        size[c as usize] += 1;
    }
    let (mut keep, mut big) = (Vec::new(), Vec::new());
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if size[comp.0[t] as usize] < SMALL_COMPONENT {
            keep.extend_from_slice(tri);
        } else {
            big.push(t as u32);
        }
    }
    stats.small_components = size.iter().filter(|&&n| n < SMALL_COMPONENT).count();
    let target = target_triangles.saturating_sub(keep.len() / 3).max(4);
    let mut kept = if big.len() > SPLIT_ABOVE && big.len() > 4 * target {
        stats.parts = 2;
        let (a, b) = halves(mesh, &big);
        let share = |n: usize| (2 * target * n / big.len()).max(4);
        let (ia, ib) = rayon::join(
            || simplify(&pos, &indices(mesh, &a), share(a.len()), true),
            || simplify(&pos, &indices(mesh, &b), share(b.len()), true),
        );
        let mut union = ia?;
        union.extend(ib?);
        simplify(&pos, &union, target, false)?
    } else {
        stats.parts = 1;
        simplify(&pos, &indices(mesh, &big), target, false)?
    };
    let decimated = kept.len() / 3;
    kept.extend(keep);
    // Keep M's vertex order among the survivors, so M′ is the same whatever
    // the order collapses happened in.
    let mut used = vec![u32::MAX; mesh.positions.len()];
    for &i in &kept {
        used[i as usize] = 0;
    }
    let mut positions = Vec::new();
    for (i, u) in used.iter_mut().enumerate() {
        if *u == 0 {
            *u = positions.len() as u32;
            positions.push(mesh.positions[i]);
        }
    }
    let triangles: Vec<[u32; 3]> = kept
        .chunks_exact(3)
        .map(|c| {
            [
                used[c[0] as usize],
                used[c[1] as usize],
                used[c[2] as usize],
            ]
        })
        .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
        .collect();
    // The degenerate-triangle filter keeps the order, so the decimated
    // triangles still come first.
    let decimated = decimated.min(triangles.len());
    let (triangles, pillows) = without_pillows(triangles);
    stats.pillow_triangles = pillows;
    let (m, _) = super::split_non_manifold(&TriMesh {
        positions,
        triangles,
    });
    let (m, pockets) = without_pockets(m, decimated - pillows.min(decimated));
    stats.pocket_triangles = pockets;
    Ok((m, stats))
}

/// Closed bits the decimation pinched off (a collapsed fold: a tetrahedron
/// of 4 triangles, a pillow of more) are split off as components of their
/// own by [`super::split_non_manifold`]; those of fewer than [`POCKET`]
/// triangles among the first `decimated` triangles (the decimated part, not
/// the small components kept verbatim) are removed. Returns the mesh with
/// its vertices compacted and the count removed.
fn without_pockets(m: TriMesh, decimated: usize) -> (TriMesh, usize) {
    let (comp, n) = triangle_components(&m);
    let mut size = vec![0usize; n];
    let mut from_decimated = vec![true; n];
    for (t, &c) in comp.iter().enumerate() {
        size[c as usize] += 1;
        if t >= decimated {
            from_decimated[c as usize] = false;
        }
    }
    let drop = |c: u32| size[c as usize] < POCKET && from_decimated[c as usize];
    let removed = comp.iter().filter(|&&c| drop(c)).count();
    if removed == 0 {
        return (m, 0);
    }
    let kept: Vec<[u32; 3]> = m
        .triangles
        .iter()
        .zip(&comp)
        .filter(|(_, &c)| !drop(c))
        .map(|(t, _)| *t)
        .collect();
    let mut used = vec![u32::MAX; m.positions.len()];
    let mut positions = Vec::new();
    for &v in kept.iter().flatten() {
        if used[v as usize] == u32::MAX {
            used[v as usize] = 0;
        }
    }
    for (i, u) in used.iter_mut().enumerate() {
        if *u == 0 {
            *u = positions.len() as u32;
            positions.push(m.positions[i]);
        }
    }
    let triangles = kept.iter().map(|t| t.map(|v| used[v as usize])).collect();
    (
        TriMesh {
            positions,
            triangles,
        },
        removed,
    )
}

/// See [`without_pockets`]: a pinched-off fold has a handful of triangles;
/// a real part of the input has more (and small ones are kept verbatim).
const POCKET: usize = 16;

/// One meshoptimizer pass over `indices` (into all of `pos`) to about
/// `target` triangles, borders locked.
fn simplify(pos: &[f32], indices: &[u32], target: usize, lock_border: bool) -> Result<Vec<u32>> {
    // f32 is meshoptimizer's only position type; it only steers the
    // collapse order (positions are taken back from M in f64), and the
    // pipeline runs at a unit diagonal, where f32 resolves 1e-7.
    let adapter = meshopt::VertexDataAdapter::new(bytemuck_f32(pos), 12, 0)
        .map_err(|e| Error::backend("meshoptimizer", e.to_string()))?;
    Ok(meshopt::simplify(
        indices,
        &adapter,
        3 * target,
        f32::MAX,
        if lock_border {
            meshopt::SimplifyOptions::LockBorder
        } else {
            meshopt::SimplifyOptions::None
        },
        None,
    ))
}

fn indices(mesh: &TriMesh, tris: &[u32]) -> Vec<u32> {
    tris.iter()
        .flat_map(|&t| mesh.triangles[t as usize])
        .collect()
}

/// `tris` cut in two at the median centroid along the longest axis of
/// their bounding box (ties by triangle index).
fn halves(mesh: &TriMesh, tris: &[u32]) -> (Vec<u32>, Vec<u32>) {
    let centroid = |t: u32| {
        let [a, b, c] = mesh.triangle(t as usize);
        (a + b + c) / 3.0
    };
    let (mut lo, mut hi) = (
        crate::DVec3::splat(f64::INFINITY),
        crate::DVec3::splat(f64::NEG_INFINITY),
    );
    for &t in tris {
        let c = centroid(t);
        lo = lo.min(c);
        hi = hi.max(c);
    }
    let ext = hi - lo;
    let axis = if ext.x >= ext.y && ext.x >= ext.z {
        0
    } else if ext.y >= ext.z {
        1
    } else {
        2
    };
    let mut keyed: Vec<(f64, u32)> = tris.iter().map(|&t| (centroid(t)[axis], t)).collect();
    let mid = keyed.len() / 2;
    keyed.select_nth_unstable_by(mid, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut a: Vec<u32> = keyed[..mid].iter().map(|k| k.1).collect();
    let mut b: Vec<u32> = keyed[mid..].iter().map(|k| k.1).collect();
    a.sort_unstable();
    b.sort_unstable();
    (a, b)
}

/// Removes every triangle whose vertex set another triangle repeats (the
/// pillows of the module doc); returns the rest, in order, and the count
/// removed.
fn without_pillows(triangles: Vec<[u32; 3]>) -> (Vec<[u32; 3]>, usize) {
    let mut keys: Vec<([u32; 3], u32)> = triangles
        .iter()
        .enumerate()
        .map(|(i, t)| {
            let mut k = *t;
            k.sort_unstable();
            (k, i as u32)
        })
        .collect();
    keys.sort_unstable();
    let mut drop = vec![false; triangles.len()];
    for w in keys.windows(2) {
        if w[0].0 == w[1].0 {
            drop[w[0].1 as usize] = true;
            drop[w[1].1 as usize] = true;
        }
    }
    let removed = drop.iter().filter(|&&d| d).count();
    let kept = triangles
        .into_iter()
        .zip(drop)
        .filter(|(_, d)| !d)
        .map(|(t, _)| t)
        .collect();
    (kept, removed)
}

/// The component of each triangle (triangles sharing a vertex are
/// connected) and the number of components, numbered in order of first
/// triangle.
fn triangle_components(mesh: &TriMesh) -> (Vec<u32>, usize) {
    let mut parent: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    fn find(p: &mut [u32], mut x: u32) -> u32 {
        while p[x as usize] != x {
            p[x as usize] = p[p[x as usize] as usize];
            x = p[x as usize];
        }
        x
    }
    for t in &mesh.triangles {
        let a = find(&mut parent, t[0]);
        for &v in &t[1..] {
            let b = find(&mut parent, v);
            if a != b {
                parent[b as usize] = a;
            }
        }
    }
    let mut id = vec![u32::MAX; mesh.positions.len()];
    let mut n = 0u32;
    let comp = mesh
        .triangles
        .iter()
        .map(|t| {
            let r = find(&mut parent, t[0]) as usize;
            if id[r] == u32::MAX {
                id[r] = n;
                n += 1;
            }
            id[r]
        })
        .collect();
    (comp, n as usize)
}

/// The topology a layout proxy must share with M: components (triangles
/// sharing a vertex), boundary loops (components of the boundary edges)
/// and the Euler characteristic V − E + F over referenced vertices.
/// Equal figures on two manifold meshes mean the same genus per
/// component, in sum: what the control mesh inherits.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Topology {
    pub components: usize,
    pub boundary_loops: usize,
    pub euler: i64,
}

impl Topology {
    pub fn of(mesh: &TriMesh) -> Topology {
        let edges = mesh.edge_counts();
        let e = edges.len();
        let boundary: Vec<u64> = edges.iter().filter(|c| c.1 == 1).map(|c| c.0).collect();
        let mut referenced = vec![false; mesh.positions.len()];
        for &v in mesh.triangles.iter().flatten() {
            referenced[v as usize] = true;
        }
        let v = referenced.iter().filter(|&&r| r).count();
        // Boundary loops: connected components of the boundary edge graph.
        let mut parent: std::collections::HashMap<u32, u32> = Default::default();
        fn find(p: &mut std::collections::HashMap<u32, u32>, x: u32) -> u32 {
            let mut r = x;
            while let Some(&q) = p.get(&r) {
                if q == r {
                    break;
                }
                r = q;
            }
            p.insert(x, r);
            r
        }
        for &k in &boundary {
            let (a, b) = ((k >> 32) as u32, k as u32);
            parent.entry(a).or_insert(a);
            parent.entry(b).or_insert(b);
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            if ra != rb {
                parent.insert(rb, ra);
            }
        }
        let roots: Vec<u32> = parent.keys().copied().collect();
        let mut loops = std::collections::HashSet::new();
        for x in roots {
            loops.insert(find(&mut parent, x));
        }
        Topology {
            components: triangle_components(mesh).1,
            boundary_loops: loops.len(),
            euler: v as i64 - e as i64 + mesh.triangles.len() as i64,
        }
    }
}

/// The bytes of an f32 slice (meshoptimizer's adapter takes raw vertex
/// data with a stride).
fn bytemuck_f32(v: &[f32]) -> &[u8] {
    // SAFETY: f32 has no padding and any byte pattern is a valid u8; the
    // length is the slice's size in bytes and the lifetime is v's.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast::<u8>(), std::mem::size_of_val(v)) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn uv_sphere(n: usize, k: usize) -> TriMesh {
        use std::f64::consts::PI;
        let mut positions = vec![DVec3::Z];
        for i in 1..n {
            let th = PI * i as f64 / n as f64;
            for j in 0..k {
                let ph = 2.0 * PI * j as f64 / k as f64;
                positions.push(DVec3::new(
                    th.sin() * ph.cos(),
                    th.sin() * ph.sin(),
                    th.cos(),
                ));
            }
        }
        positions.push(-DVec3::Z);
        let s = (positions.len() - 1) as u32;
        let idx = |i: usize, j: usize| (1 + (i - 1) * k + j % k) as u32;
        let mut triangles = Vec::new();
        for j in 0..k {
            triangles.push([0, idx(1, j), idx(1, j + 1)]);
            triangles.push([s, idx(n - 1, j + 1), idx(n - 1, j)]);
        }
        for i in 1..n - 1 {
            for j in 0..k {
                let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
                triangles.push([a, b, c]);
                triangles.push([a, c, d]);
            }
        }
        TriMesh {
            positions,
            triangles,
        }
    }

    /// A closed UV sphere of `n` rings: decimation keeps it closed, reaches
    /// the target within the locked/illegal-collapse slack, and keeps every
    /// vertex on the input (a subset of its vertices, bit for bit).
    #[test]
    fn sphere_decimates_to_target_with_input_vertices() {
        let m = uv_sphere(60, 120);
        let (d, _) = decimate(&m, 2000).unwrap();
        let n = d.triangles.len();
        assert!((1900..=2000).contains(&n), "{n} triangles");
        let set: std::collections::HashSet<[u64; 3]> = m
            .positions
            .iter()
            .map(|p| p.to_array().map(f64::to_bits))
            .collect();
        assert!(d
            .positions
            .iter()
            .all(|p| set.contains(&p.to_array().map(f64::to_bits))));
        // Closed 2-manifold of genus 0: V - E + F = 2 with E = 3F/2.
        let (v, f) = (d.positions.len() as i64, d.triangles.len() as i64);
        assert_eq!(v - 3 * f / 2 + f, 2);
    }

    #[test]
    fn topology_of_a_sphere_a_disc_and_two_parts() {
        let s = uv_sphere(8, 12);
        let t = Topology::of(&s);
        assert_eq!((t.components, t.boundary_loops, t.euler), (1, 0, 2));
        // Drop the triangles around the north pole: one hole, a disc's χ.
        let mut open = s.clone();
        open.triangles.retain(|t| !t.contains(&0));
        let t = Topology::of(&open);
        assert_eq!((t.components, t.boundary_loops, t.euler), (1, 1, 1));
        // Two copies side by side: everything adds.
        let mut two = s.clone();
        let n = s.positions.len() as u32;
        two.positions
            .extend(s.positions.iter().map(|p| *p + DVec3::X * 3.0));
        two.triangles
            .extend(s.triangles.iter().map(|t| t.map(|v| v + n)));
        let t = Topology::of(&two);
        assert_eq!((t.components, t.boundary_loops, t.euler), (2, 0, 4));
    }

    #[test]
    fn pillows_go_and_nothing_else_does() {
        let tris = vec![[0, 1, 2], [3, 4, 5], [0, 2, 1], [2, 3, 4], [5, 4, 3]];
        let (kept, removed) = without_pillows(tris);
        assert_eq!(kept, vec![[2, 3, 4]]);
        assert_eq!(removed, 4);
    }

    /// Above `SPLIT_ABOVE` the two halves and the final pass give a mesh of
    /// the input's topology at the target, as one pass does.
    #[test]
    fn split_decimation_keeps_a_large_sphere_closed() {
        let m = uv_sphere(320, 640);
        assert!(m.triangles.len() > SPLIT_ABOVE);
        let (d, st) = decimate(&m, 20_000).unwrap();
        assert_eq!(st.parts, 2);
        assert!(
            (19_000..=20_000).contains(&d.triangles.len()),
            "{}",
            d.triangles.len()
        );
        assert_eq!(Topology::of(&d), Topology::of(&m));
    }
}
