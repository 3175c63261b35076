//! Pure-Rust [`RayCaster`]: a binned-SAH bounding volume hierarchy built in
//! parallel, flattened into a depth-first node array.
//!
//! Precision: node boxes are `f32` (rounded outwards, so they always enclose
//! the exact triangles) to keep a node in 32 bytes, two per cache line; the
//! slab test and the triangles are `f64`. The differential tolerance against
//! Embree is 1e-6 of the bounding-box diagonal, and downstream fitting
//! measures distances at that scale, so the triangle test must not round the
//! input to f32 (which alone moves vertices by ~3e-8 of their magnitude,
//! far from the origin much more than of the diagonal).
//!
//! References:
//! - SAH binning: Wald, "On fast construction of SAH-based bounding volume
//!   hierarchies", IEEE RT 2007 (§3: bins on centroid bounds, cost
//!   `C_trav + (A_L N_L + A_R N_R) / A`).
//! - Watertight ray/triangle test: Woop, Benthin, Wald, "Watertight
//!   ray/triangle intersection", JCGT 2(1), 2013 (§3, Algorithm 1).
//! - Robust slab test: Ize, "Robust BVH ray traversal", JCGT 2(2), 2013
//!   (scale the far distance by `1 + 2 gamma(3)`).
//! - Closest point: Ericson, *Real-Time Collision Detection*, §5.1.5, with
//!   best-first traversal (nodes ordered by distance to their box).

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::mem::MaybeUninit;

use rayon::prelude::*;

use crate::error::Result;
use crate::mesh::{prefetch, TriMesh};
use crate::raycast::{
    check_max_dist, closest_point_triangle, surface_triangles, ClosestPoint, Hit, Ray, RayCaster,
};
use crate::DVec3;

/// SAH bins per axis (Wald 2007 reports 16 to be nearly as good as a full
/// sweep; 32 costs little more at build time and helps dense scans).
const BINS: usize = 32;
/// Leaves of at most this many triangles may be made when SAH prefers it;
/// larger sets are always split.
const MAX_LEAF: usize = 8;
/// Relative cost of a traversal step vs a triangle test in the SAH.
const C_TRAV: f64 = 1.0;
/// Below this many triangles, build sequentially (rayon task overhead).
const PAR_THRESHOLD: usize = 4096;
/// SAH splits deeper than this become object-median splits, which bounds the
/// tree depth by `MAX_SAH_DEPTH + 32` and so the traversal stack.
const MAX_SAH_DEPTH: usize = 96;
const STACK: usize = MAX_SAH_DEPTH + 40;

/// A flattened node, 32 bytes. Interior (`count == 0`): the children are
/// the pair of nodes `offset` (left) and `offset + 1` (right). Leaf:
/// `tris[offset..offset + count]`.
#[derive(Copy, Clone, Debug)]
#[repr(C, align(32))]
struct Node {
    lo: [f32; 3],
    count: u32,
    hi: [f32; 3],
    offset: u32,
}

/// Two siblings in one 64-byte cache line. An interior node's traversal
/// tests both children's boxes; with the left child next to its parent
/// and the right one far away (the depth-first layout used before), that
/// was two lines per step, and the far one a miss (the load of the right
/// child's box was the hottest instruction of `line_hit` in a profile of
/// bunny's simplification, session 16). Stored together, one line serves
/// both tests. The tree, its boxes and the order
/// in which the traversals visit it are the same, so are the answers. Pair
/// 0 holds the root and an unused slot.
#[derive(Copy, Clone, Debug)]
#[repr(C, align(64))]
struct NodePair([Node; 2]);

pub struct BvhCaster {
    /// The nodes in sibling pairs: node `i` is `pairs[i / 2].0[i % 2]`.
    pairs: Vec<NodePair>,
    /// Triangle corners in leaf order.
    tris: Vec<[DVec3; 3]>,
    /// Mesh triangle id of `tris[i]`.
    tri_ids: Vec<u32>,
}

// ---------------------------------------------------------------------------
// Build

#[derive(Copy, Clone)]
struct Aabb {
    lo: DVec3,
    hi: DVec3,
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: DVec3::splat(f64::INFINITY),
        hi: DVec3::splat(f64::NEG_INFINITY),
    };
    fn grow(&mut self, b: &Aabb) {
        self.lo = self.lo.min(b.lo);
        self.hi = self.hi.max(b.hi);
    }
    fn grow_point(&mut self, p: DVec3) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }
    fn half_area(&self) -> f64 {
        let e = (self.hi - self.lo).max(DVec3::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }
}

enum BuildNode {
    Leaf {
        bounds: Aabb,
        start: usize,
        count: usize,
    },
    Inner {
        bounds: Aabb,
        children: Box<[BuildNode; 2]>,
    },
}

struct PrimInfo {
    bounds: Aabb,
    centroid: DVec3,
}

/// Builds the subtree over `items` (mesh triangle ids, reordered in place
/// into leaf order); `start` is the offset of `items` in the whole array.
///
/// Determinism: every decision depends only on the items of this node, each
/// node's items are partitioned by one task, and `rayon::join` only decides
/// *where* the two independent halves run, so the tree is the same whatever
/// the thread count.
fn build(items: &mut [u32], start: usize, info: &[PrimInfo], depth: usize) -> BuildNode {
    let mut bounds = Aabb::EMPTY;
    let mut cbounds = Aabb::EMPTY;
    for &t in items.iter() {
        let p = &info[t as usize];
        bounds.grow(&p.bounds);
        cbounds.grow_point(p.centroid);
    }
    let n = items.len();
    let leaf = BuildNode::Leaf {
        bounds,
        start,
        count: n,
    };
    if n <= 2 {
        return leaf;
    }
    let extent = cbounds.hi - cbounds.lo;
    let mid = if depth >= MAX_SAH_DEPTH || extent.max_element() <= 0.0 {
        // All centroids coincide (or too deep): SAH cannot separate them.
        if n <= MAX_LEAF && depth < MAX_SAH_DEPTH {
            return leaf;
        }
        n / 2
    } else {
        match sah_split(items, info, &bounds, &cbounds) {
            Some((axis, bin, cost)) => {
                if n <= MAX_LEAF && cost >= n as f64 {
                    return leaf;
                }
                let k = bin_of(axis, &cbounds);
                partition(items, |t| k(info[t as usize].centroid) < bin)
            }
            None if n <= MAX_LEAF => return leaf,
            None => n / 2,
        }
    };
    let mid = mid.clamp(1, n - 1);
    let (l, r) = items.split_at_mut(mid);
    let (a, b) = if n >= PAR_THRESHOLD {
        rayon::join(
            || build(l, start, info, depth + 1),
            || build(r, start + mid, info, depth + 1),
        )
    } else {
        (
            build(l, start, info, depth + 1),
            build(r, start + mid, info, depth + 1),
        )
    };
    BuildNode::Inner {
        bounds,
        children: Box::new([a, b]),
    }
}

/// Bin index along `axis` for a centroid (Wald 2007, eq. 1).
fn bin_of(axis: usize, cb: &Aabb) -> impl Fn(DVec3) -> usize {
    let lo = cb.lo[axis];
    let ext = cb.hi[axis] - lo;
    let scale = BINS as f64 * (1.0 - 1e-9) / ext;
    move |c: DVec3| (((c[axis] - lo) * scale) as usize).min(BINS - 1)
}

/// Best binned SAH split: `(axis, first bin of the right side, cost)` with
/// cost in units of triangle tests, or `None` if no axis has extent.
fn sah_split(
    items: &[u32],
    info: &[PrimInfo],
    bounds: &Aabb,
    cb: &Aabb,
) -> Option<(usize, usize, f64)> {
    let mut best: Option<(usize, usize, f64)> = None;
    let inv_area = 1.0 / bounds.half_area().max(f64::MIN_POSITIVE);
    for axis in 0..3 {
        if cb.hi[axis] - cb.lo[axis] <= 0.0 {
            continue;
        }
        let k = bin_of(axis, cb);
        let mut bb = [Aabb::EMPTY; BINS];
        let mut cnt = [0usize; BINS];
        for &t in items {
            let p = &info[t as usize];
            let b = k(p.centroid);
            bb[b].grow(&p.bounds);
            cnt[b] += 1;
        }
        // Sweep from the right for suffix areas, then from the left.
        let mut right_area = [0.0; BINS];
        let mut acc = Aabb::EMPTY;
        let mut right_cnt = [0usize; BINS];
        let mut c = 0;
        for b in (1..BINS).rev() {
            acc.grow(&bb[b]);
            c += cnt[b];
            right_area[b] = acc.half_area();
            right_cnt[b] = c;
        }
        let mut acc = Aabb::EMPTY;
        let mut c = 0;
        for b in 1..BINS {
            acc.grow(&bb[b - 1]);
            c += cnt[b - 1];
            if c == 0 || right_cnt[b] == 0 {
                continue;
            }
            let cost = C_TRAV
                + (acc.half_area() * c as f64 + right_area[b] * right_cnt[b] as f64) * inv_area;
            // Strict `<` keeps the first best (lowest axis, lowest bin): a
            // deterministic choice.
            if best.map_or(true, |(_, _, bc)| cost < bc) {
                best = Some((axis, b, cost));
            }
        }
    }
    best
}

/// In-place partition; returns the number of items for which `left` holds.
fn partition(items: &mut [u32], left: impl Fn(u32) -> bool) -> usize {
    let mut i = 0;
    let mut j = items.len();
    while i < j {
        if left(items[i]) {
            i += 1;
        } else {
            j -= 1;
            items.swap(i, j);
        }
    }
    i
}

/// Largest f32 not above `x` / smallest not below: boxes rounded outwards.
fn f32_down(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) > x {
        next_toward_neg_inf(f)
    } else {
        f
    }
}
fn f32_up(x: f64) -> f32 {
    let f = x as f32;
    if (f as f64) < x {
        -next_toward_neg_inf(-f)
    } else {
        f
    }
}
fn next_toward_neg_inf(f: f32) -> f32 {
    if f.is_nan() || f == f32::NEG_INFINITY {
        f
    } else if f == 0.0 {
        -f32::from_bits(1)
    } else if f > 0.0 {
        f32::from_bits(f.to_bits() - 1)
    } else {
        f32::from_bits(f.to_bits() + 1)
    }
}

/// Writes `node` at index `me` of `out` and its subtree after it: each
/// interior node's children as a new pair at the end (an even index), then
/// the left child's subtree, then the right one's (depth-first by pairs).
fn flatten(node: &BuildNode, me: usize, out: &mut Vec<Node>) {
    let (b, count, offset) = match node {
        BuildNode::Leaf {
            bounds,
            start,
            count,
        } => (bounds, *count as u32, *start as u32),
        BuildNode::Inner { bounds, .. } => (bounds, 0, 0),
    };
    out[me] = Node {
        lo: b.lo.to_array().map(f32_down),
        count,
        hi: b.hi.to_array().map(f32_up),
        offset,
    };
    if let BuildNode::Inner { children, .. } = node {
        let first = out.len();
        out.extend([EMPTY_NODE; 2]);
        out[me].offset = first as u32;
        flatten(&children[0], first, out);
        flatten(&children[1], first + 1, out);
    }
}

/// A slot before [`flatten`] writes it (and the unused half of pair 0).
const EMPTY_NODE: Node = Node {
    lo: [0.0; 3],
    count: 0,
    hi: [0.0; 3],
    offset: 0,
};

/// The BVHs [`BvhCaster::shared`] hands out, with a copy of the mesh each
/// was built on, most recently used last.
static SHARED: std::sync::Mutex<Vec<(TriMesh, std::sync::Arc<BvhCaster>)>> =
    std::sync::Mutex::new(Vec::new());

/// How many meshes [`BvhCaster::shared`] keeps a BVH of: M and M′ of a
/// run, with room for a test run beside it.
pub const SHARED_MESHES: usize = 4;

/// `a` and `b` bit for bit (`-0.0 ≠ 0.0`, a NaN equal to itself).
fn same_mesh(a: &TriMesh, b: &TriMesh) -> bool {
    let bits = |p: &DVec3| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()];
    a.triangles == b.triangles
        && a.positions.len() == b.positions.len()
        && a.positions
            .iter()
            .zip(&b.positions)
            .all(|(p, q)| bits(p) == bits(q))
}

impl BvhCaster {
    /// [`BvhCaster::new`] of `mesh`, shared with every other caller asking
    /// for the same mesh bit for bit (issue 40, session 20): the field
    /// layout's extractions, its cleanups and the convert layer's patch
    /// errors each built the BVH of M (or M′) again, ~120 times a run on
    /// homer at 272 patches under `SUBDFIT_FIELD_BEST` (5 % of its CPU).
    /// The build is a function of the mesh alone, whatever the thread count
    /// (`tree_is_independent_of_thread_count`), so the shared tree is the
    /// one a fresh build would give, and so is every answer. At most
    /// [`SHARED_MESHES`] meshes are kept (the least recently used goes).
    /// The lock is not held while building: a build runs rayon tasks,
    /// and a task stolen by the waiting thread could ask for the lock.
    pub fn shared(mesh: &TriMesh) -> Result<std::sync::Arc<Self>> {
        let lock = || SHARED.lock().unwrap_or_else(|e| e.into_inner());
        {
            let mut cache = lock();
            if let Some(i) = cache.iter().position(|(m, _)| same_mesh(m, mesh)) {
                let hit = cache.remove(i);
                let bvh = hit.1.clone();
                cache.push(hit);
                return Ok(bvh);
            }
        }
        let bvh = std::sync::Arc::new(BvhCaster::new(mesh)?);
        let mut cache = lock();
        if !cache.iter().any(|(m, _)| same_mesh(m, mesh)) {
            if cache.len() >= SHARED_MESHES {
                cache.remove(0);
            }
            cache.push((mesh.clone(), bvh.clone()));
        }
        Ok(bvh)
    }

    /// Forgets every tree [`BvhCaster::shared`] keeps (holders keep theirs):
    /// a conversion calls it when it ends, so a batch or a host process
    /// does not keep the last run's meshes and trees alive.
    pub fn clear_shared() {
        SHARED.lock().unwrap_or_else(|e| e.into_inner()).clear();
    }

    /// Builds the BVH over the non-zero-area triangles of `mesh`. Errors: see
    /// [`crate::raycast::surface_triangles`].
    pub fn new(mesh: &TriMesh) -> Result<Self> {
        let mut items = surface_triangles(mesh)?;
        let info: Vec<PrimInfo> = (0..mesh.triangles.len())
            .into_par_iter()
            .map(|t| {
                let [a, b, c] = mesh.triangle(t);
                PrimInfo {
                    bounds: Aabb {
                        lo: a.min(b).min(c),
                        hi: a.max(b).max(c),
                    },
                    centroid: (a + b + c) / 3.0,
                }
            })
            .collect();
        let mut nodes = Vec::new();
        if !items.is_empty() {
            let root = build(&mut items, 0, &info, 0);
            nodes.reserve(2 * items.len() + 2);
            nodes.extend([EMPTY_NODE; 2]);
            flatten(&root, 0, &mut nodes);
        }
        // Pairs start at even indices (pair 0: the root and the unused slot).
        let pairs = nodes
            .chunks_exact(2)
            .map(|c| NodePair([c[0], c[1]]))
            .collect();
        let tris = items
            .par_iter()
            .map(|&t| mesh.triangle(t as usize))
            .collect();
        Ok(BvhCaster {
            pairs,
            tris,
            tri_ids: items,
        })
    }

    /// Number of nodes (for tests and statistics).
    pub fn num_nodes(&self) -> usize {
        (2 * self.pairs.len()).saturating_sub(1)
    }

    /// Node `i` (see [`NodePair`]).
    #[inline(always)]
    fn node(&self, i: usize) -> &Node {
        &self.pairs[i >> 1].0[i & 1]
    }

    /// Asks for the memory the traversal reads when it comes back to node
    /// `i` from the stack: its children's pair, or its leaf's first
    /// triangles. A pushed node is taken again only after the near
    /// subtree, so the miss (the hottest load of `line_hit`, session 17's
    /// profile of bunny's simplification) overlaps that work instead of
    /// stalling the pop. A hint only: what is read, and so every answer,
    /// is unchanged.
    #[inline(always)]
    fn prefetch_below(&self, i: usize) {
        let n = self.node(i);
        let at = n.offset as usize;
        if n.count == 0 {
            prefetch(self.pairs.as_ptr().wrapping_add(at >> 1));
        } else {
            // A triangle is 72 bytes: its first two lines hold the first
            // one and most of the second.
            let t = self.tris.as_ptr().wrapping_add(at);
            prefetch(t);
            prefetch((t as *const u8).wrapping_add(64));
        }
    }

    /// First hit of one ray (see [`RayCaster::first_hits`]).
    pub fn first_hit(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() || self.pairs.is_empty() {
            return None;
        }
        let tr = WatertightRay::new(ray);
        let inv = ray.dir.recip();
        let slab = |n: &Node, tfar: f64| -> Option<f64> {
            let lo = DVec3::new(n.lo[0] as f64, n.lo[1] as f64, n.lo[2] as f64);
            let hi = DVec3::new(n.hi[0] as f64, n.hi[1] as f64, n.hi[2] as f64);
            let t0 = (lo - ray.origin) * inv;
            let t1 = (hi - ray.origin) * inv;
            // min/max ignore the NaN of 0 * inf (origin on a slab plane of a
            // zero direction component): that axis then does not cull.
            let tn = t0.min(t1).max_element().max(ray.tmin);
            // Ize 2013: widen the far distance to absorb rounding.
            let tf = t0.max(t1).min_element() * (1.0 + 4.0 * f64::EPSILON);
            (tn <= tf.min(tfar)).then_some(tn)
        };
        let mut best: Option<Hit> = None;
        let mut tfar = ray.tmax;
        slab(self.node(0), tfar)?;
        // Uninitialised: zeroing 2 KiB per ray costs ~10% on short rays.
        let mut stack = [const { MaybeUninit::<(u32, f64)>::uninit() }; STACK];
        let mut sp = 0usize;
        let mut node = 0usize;
        loop {
            let n = self.node(node);
            if n.count > 0 {
                let s = n.offset as usize;
                for i in s..s + n.count as usize {
                    if let Some((t, u, v)) = tr.intersect(&self.tris[i]) {
                        // `<=` for the first (tmax inclusive), then strictly
                        // nearer: the first found of equal hits is kept.
                        if t >= ray.tmin && t <= tfar && (best.is_none() || t < tfar) {
                            tfar = t;
                            best = Some(Hit {
                                t,
                                triangle: self.tri_ids[i],
                                u,
                                v,
                            });
                        }
                    }
                }
            } else {
                let (l, r) = (n.offset as usize, n.offset as usize + 1);
                match (slab(self.node(l), tfar), slab(self.node(r), tfar)) {
                    (Some(tl), Some(tr_)) => {
                        let (near, far, tfar_entry) =
                            if tl <= tr_ { (l, r, tr_) } else { (r, l, tl) };
                        stack[sp].write((far as u32, tfar_entry));
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = r;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            // Pop the next node whose box is still in front of the best hit.
            loop {
                if sp == 0 {
                    return best;
                }
                sp -= 1;
                // SAFETY: entries below `sp` were written by the push above.
                let (k, t_entry) = unsafe { stack[sp].assume_init() };
                if t_entry <= tfar {
                    node = k as usize;
                    break;
                }
            }
        }
    }

    /// The hit of the line `origin + t·dir`, `|t| ≤ max_t`, nearest to
    /// `origin`, with `t` signed: what [`super::nearer_on_line`] makes of a
    /// `first_hit` along `+dir` over `[0, max_t]` and one along `-dir` up to
    /// the forward hit (the pair behind [`RayCaster::line_hits`]), in one
    /// traversal instead of two (the second descended the same upper
    /// levels again).
    ///
    /// Same values bit for bit: the watertight test of the `-dir` ray is the
    /// `+dir` one with kx/ky swapped and every edge function negated (exact
    /// in IEEE arithmetic), so it yields exactly `-t` and the same `(u, v)`;
    /// a node's slab interval along `-dir` is exactly the negated one, widened
    /// at each end as the single-ray test widens its far end (Ize 2013). The
    /// `+dir` hit wins ties on `|t|`, and a `t` of ±0 counts on both sides,
    /// as before. Only the order in which exactly equal `t` on different
    /// triangles (a line through a shared edge) are met can differ, and with
    /// it which of them is kept.
    pub fn line_hit(&self, origin: DVec3, dir: DVec3, max_t: f64) -> Option<Hit> {
        let ray = Ray {
            origin,
            dir,
            tmin: 0.0,
            tmax: max_t,
        };
        if !ray.is_valid() || self.pairs.is_empty() {
            return None;
        }
        let tr = WatertightRay::new(&ray);
        let inv = dir.recip();
        // The distance from the origin to the node's interval on the line
        // (0 when the interval holds the origin), or None if the line
        // misses the box within `bound`.
        let key = |n: &Node, bound: f64| -> Option<f64> {
            let lo = DVec3::new(n.lo[0] as f64, n.lo[1] as f64, n.lo[2] as f64);
            let hi = DVec3::new(n.hi[0] as f64, n.hi[1] as f64, n.hi[2] as f64);
            let t0 = (lo - origin) * inv;
            let t1 = (hi - origin) * inv;
            let widen = 1.0 + 4.0 * f64::EPSILON;
            let tn = t0.min(t1).max_element();
            let tf = t0.max(t1).min_element();
            // Each end widened away from the origin, as the single ray
            // widens its far end (the near end of the `-dir` ray is `-tf`).
            let (tn, tf) = (
                if tn < 0.0 { tn * widen } else { tn },
                if tf > 0.0 { tf * widen } else { tf },
            );
            let d = if tn > 0.0 {
                tn
            } else if tf < 0.0 {
                -tf
            } else {
                0.0
            };
            (tn <= tf && d <= bound).then_some(d)
        };
        // Best hit per side, by |t|; `bound` the nearer of the two.
        let (mut fwd, mut bwd): (Option<Hit>, Option<Hit>) = (None, None);
        let mut bound = max_t;
        key(self.node(0), bound)?;
        let mut stack = [const { MaybeUninit::<(u32, f64)>::uninit() }; STACK];
        let mut sp = 0usize;
        let mut node = 0usize;
        loop {
            let n = self.node(node);
            if n.count > 0 {
                let s = n.offset as usize;
                for i in s..s + n.count as usize {
                    let Some((t, u, v)) = tr.intersect(&self.tris[i]) else {
                        continue;
                    };
                    let hit = Hit {
                        t,
                        triangle: self.tri_ids[i],
                        u,
                        v,
                    };
                    // `<=` for the first (max_t inclusive), then strictly
                    // nearer: the first found of equal hits is kept.
                    if t >= 0.0 && t <= max_t && fwd.map_or(true, |f| t < f.t) {
                        fwd = Some(hit);
                        bound = bound.min(t);
                    }
                    if t <= 0.0 && -t <= max_t && bwd.map_or(true, |b| -t < -b.t) {
                        bwd = Some(hit);
                        bound = bound.min(-t);
                    }
                }
            } else {
                let (l, r) = (n.offset as usize, n.offset as usize + 1);
                match (key(self.node(l), bound), key(self.node(r), bound)) {
                    (Some(kl), Some(kr)) => {
                        let (near, far, k_far) = if kl <= kr { (l, r, kr) } else { (r, l, kl) };
                        self.prefetch_below(far);
                        stack[sp].write((far as u32, k_far));
                        sp += 1;
                        node = near;
                        continue;
                    }
                    (Some(_), None) => {
                        node = l;
                        continue;
                    }
                    (None, Some(_)) => {
                        node = r;
                        continue;
                    }
                    (None, None) => {}
                }
            }
            loop {
                if sp == 0 {
                    // `-dir`'s hit wins only when strictly nearer.
                    return match (fwd, bwd) {
                        (Some(f), Some(b)) if -b.t < f.t => Some(b),
                        (Some(f), _) => Some(f),
                        (None, b) => b,
                    };
                }
                sp -= 1;
                // SAFETY: entries below `sp` were written by the push above.
                let (k, k_entry) = unsafe { stack[sp].assume_init() };
                if k_entry <= bound {
                    node = k as usize;
                    break;
                }
            }
        }
    }

    /// Closest point to one point (see [`RayCaster::closest_points`]);
    /// `heap` is scratch space reused across queries.
    fn closest_point(
        &self,
        p: DVec3,
        max_dist: f64,
        heap: &mut BinaryHeap<Pending>,
    ) -> Option<ClosestPoint> {
        if !p.is_finite() || self.pairs.is_empty() {
            return None;
        }
        let box_d2 = |n: &Node| -> f64 {
            let lo = DVec3::new(n.lo[0] as f64, n.lo[1] as f64, n.lo[2] as f64);
            let hi = DVec3::new(n.hi[0] as f64, n.hi[1] as f64, n.hi[2] as f64);
            let d = (lo - p).max(p - hi).max(DVec3::ZERO);
            d.length_squared()
        };
        let mut best_d2 = max_dist * max_dist;
        let mut best: Option<(u32, DVec3, f64, f64)> = None;
        heap.clear();
        heap.push(Pending {
            d2: box_d2(self.node(0)),
            node: 0,
        });
        // Best-first: pop boxes by increasing distance; once the nearest
        // pending box is farther than the best triangle, nothing can improve.
        // Boxes at exactly the best distance are still visited so that ties
        // go to the smallest triangle id, as in the Embree callback.
        while let Some(Pending { d2, node }) = heap.pop() {
            if d2 > best_d2 {
                break;
            }
            let n = self.node(node as usize);
            if n.count > 0 {
                let s = n.offset as usize;
                for i in s..s + n.count as usize {
                    let [a, b, c] = self.tris[i];
                    let (q, u, v) = closest_point_triangle(p, a, b, c);
                    let dq = (p - q).length_squared();
                    let id = self.tri_ids[i];
                    let better = match best {
                        None => dq <= best_d2,
                        Some((bid, ..)) => dq < best_d2 || (dq == best_d2 && id < bid),
                    };
                    if better {
                        best_d2 = dq;
                        best = Some((id, q, u, v));
                    }
                }
            } else {
                for k in [n.offset as usize, n.offset as usize + 1] {
                    let d2 = box_d2(self.node(k));
                    if d2 <= best_d2 {
                        heap.push(Pending { d2, node: k as u32 });
                    }
                }
            }
        }
        best.map(|(triangle, point, u, v)| ClosestPoint {
            point,
            distance: (p - point).length(),
            triangle,
            u,
            v,
        })
    }
}

/// A node waiting in the best-first queue; `BinaryHeap` is a max-heap, so
/// the order is reversed (ties by node index, for determinism).
#[derive(Copy, Clone, Debug)]
struct Pending {
    d2: f64,
    node: u32,
}
impl PartialEq for Pending {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Pending {}
impl PartialOrd for Pending {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Pending {
    fn cmp(&self, o: &Self) -> Ordering {
        o.d2.total_cmp(&self.d2).then(o.node.cmp(&self.node))
    }
}

/// Per-ray constants of the watertight test (Woop et al. 2013, §3): the axis
/// `kz` of the largest direction component and the shear that maps the ray
/// onto +z, so edge functions are evaluated in 2D with consistent rounding
/// along shared edges.
struct WatertightRay {
    org: [f64; 3],
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f64,
    sy: f64,
    sz: f64,
}

impl WatertightRay {
    fn new(ray: &Ray) -> Self {
        let d = ray.dir.to_array();
        let a = ray.dir.abs();
        let kz = if a.x >= a.y && a.x >= a.z {
            0
        } else if a.y >= a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        // Keep the winding so that the sign of U, V, W means the same side
        // (only needed for backface culling, but cheap and as in the paper).
        if d[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        WatertightRay {
            org: ray.origin.to_array(),
            kx,
            ky,
            kz,
            sx: d[kx] / d[kz],
            sy: d[ky] / d[kz],
            sz: 1.0 / d[kz],
        }
    }

    /// `(t, u, v)` with Embree's barycentric convention, or `None`. Both
    /// faces are hit; a zero-area (det = 0) triangle never is.
    #[inline]
    fn intersect(&self, tri: &[DVec3; 3]) -> Option<(f64, f64, f64)> {
        let rel = |p: DVec3| {
            let p = p.to_array();
            [p[0] - self.org[0], p[1] - self.org[1], p[2] - self.org[2]]
        };
        let (a, b, c) = (rel(tri[0]), rel(tri[1]), rel(tri[2]));
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        let ax = a[kx] - self.sx * a[kz];
        let ay = a[ky] - self.sy * a[kz];
        let bx = b[kx] - self.sx * b[kz];
        let by = b[ky] - self.sy * b[kz];
        let cx = c[kx] - self.sx * c[kz];
        let cy = c[ky] - self.sy * c[kz];
        // Scaled barycentrics (edge functions), weights of a, b, c.
        let u = cx * by - cy * bx;
        let v = ax * cy - ay * cx;
        let w = bx * ay - by * ax;
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let t_scaled = u * (self.sz * a[kz]) + v * (self.sz * b[kz]) + w * (self.sz * c[kz]);
        let inv = 1.0 / det;
        Some((t_scaled * inv, v * inv, w * inv))
    }
}

impl RayCaster for BvhCaster {
    fn name(&self) -> &'static str {
        "rust"
    }

    fn first_hits(&self, rays: &[Ray]) -> Result<Vec<Option<Hit>>> {
        Ok(rays
            .par_iter()
            .with_min_len(256)
            .map(|r| self.first_hit(r))
            .collect())
    }

    fn closest_points(&self, points: &[DVec3], max_dist: f64) -> Result<Vec<Option<ClosestPoint>>> {
        check_max_dist(max_dist)?;
        Ok(points
            .par_iter()
            .with_min_len(64)
            .map_init(BinaryHeap::new, |heap, &p| {
                self.closest_point(p, max_dist, heap)
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outward_rounding_encloses() {
        for x in [0.1f64, -0.1, 1e-30, -1e-30, 0.0, 3.0, 1.0 / 3.0, -7.7e5] {
            assert!(f32_down(x) as f64 <= x, "{x}");
            assert!(f32_up(x) as f64 >= x, "{x}");
        }
    }

    /// `line_hit` against the pair of rays it replaces, bit for bit, on a
    /// folded surface (lines that cross it several times on both sides),
    /// with origins on it (t = 0), reaches too short to hit (misses) and
    /// lines along the axes (zero direction components).
    #[test]
    fn line_hit_equals_the_forward_and_backward_rays() {
        let mesh = crate::fixtures::tri_grid(
            40,
            |i, j| {
                let (x, y) = (i as f64 * 0.25, j as f64 * 0.25);
                DVec3::new(x, y, 1.5 * (1.3 * x).sin() * (0.9 * y).cos())
            },
            |_, _| true,
        );
        let bvh = BvhCaster::new(&mesh).unwrap();
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut both, mut back, mut miss) = (0, 0, 0);
        for i in 0..20_000 {
            let mut o = DVec3::new(10.0 * rnd(), 10.0 * rnd(), 4.0 * rnd() - 2.0);
            if i % 10 == 0 {
                // On the surface: a hit at t = 0 (or close to it).
                o = mesh.positions[(i / 10) % mesh.positions.len()];
            }
            let mut n = DVec3::new(rnd() - 0.5, rnd() - 0.5, rnd() - 0.5).normalize();
            if i % 7 == 0 {
                n = [DVec3::X, DVec3::NEG_Y, DVec3::Z][i % 3];
            }
            let max_t = if i % 5 == 0 { 0.05 } else { 8.0 * rnd() };
            let ray = |dir: DVec3, tmax: f64| Ray {
                origin: o,
                dir,
                tmin: 0.0,
                tmax,
            };
            let fwd = bvh.first_hit(&ray(n, max_t));
            let bwd = bvh.first_hit(&ray(-n, fwd.map_or(max_t, |h| h.t)));
            let want = crate::raycast::nearer_on_line(fwd, bwd);
            let got = bvh.line_hit(o, n, max_t);
            let bits = |h: Option<Hit>| {
                h.map(|h| (h.t.to_bits(), h.triangle, h.u.to_bits(), h.v.to_bits()))
            };
            assert_eq!(bits(got), bits(want), "line {i}: {o} {n} {max_t}");
            match (fwd, bwd) {
                (Some(_), Some(_)) => both += 1,
                (None, Some(_)) => back += 1,
                (None, None) => miss += 1,
                _ => {}
            }
        }
        // The cases the equality covers all occur.
        assert!(
            both > 100 && back > 100 && miss > 100,
            "{both} {back} {miss}"
        );
    }

    /// `line_hit` against every triangle tested in turn, on a rolled sheet
    /// (several layers of M along most lines, so the traversal pushes far
    /// children, and pops and prefetches them, `BvhCaster::prefetch_below`):
    /// the nearest `|t|` within `max_t` on either side, `+dir` winning ties,
    /// bit for bit; the triangle is one hit at exactly that `t` (the first
    /// met of equal hits depends on the visit order, not the scan's).
    #[test]
    fn line_hit_is_the_nearest_of_all_triangles() {
        let mesh = crate::fixtures::tri_grid(
            48,
            |i, j| {
                let a = 5.0 * std::f64::consts::PI * i as f64 / 48.0;
                let rad = 1.0 + 0.08 * a;
                DVec3::new(rad * a.cos(), j as f64 / 16.0, rad * a.sin())
            },
            |_, _| true,
        );
        let bvh = BvhCaster::new(&mesh).unwrap();
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut hits, mut layered) = (0, 0);
        for i in 0..4000 {
            let o = DVec3::new(4.0 * rnd() - 2.0, 3.0 * rnd(), 4.0 * rnd() - 2.0);
            let n = DVec3::new(rnd() - 0.5, 0.2 * (rnd() - 0.5), rnd() - 0.5).normalize();
            let max_t = if i % 3 == 0 { 0.3 } else { 5.0 };
            let tr = WatertightRay::new(&Ray {
                origin: o,
                dir: n,
                tmin: 0.0,
                tmax: max_t,
            });
            let all: Vec<(f64, u32)> = (0..mesh.triangles.len())
                .filter_map(|t| tr.intersect(&mesh.triangle(t)).map(|h| (h.0, t as u32)))
                .filter(|h| h.0.abs() <= max_t)
                .collect();
            let fwd = all
                .iter()
                .filter(|h| h.0 >= 0.0)
                .map(|h| h.0)
                .reduce(f64::min);
            let bwd = all
                .iter()
                .filter(|h| h.0 <= 0.0)
                .map(|h| h.0)
                .reduce(f64::max);
            let want = match (fwd, bwd) {
                (Some(f), Some(b)) if -b < f => Some(b),
                (Some(f), _) => Some(f),
                (None, b) => b,
            };
            let got = bvh.line_hit(o, n, max_t);
            assert_eq!(
                got.map(|h| h.t.to_bits()),
                want.map(f64::to_bits),
                "line {i}: {o} {n} {max_t}"
            );
            if let Some(h) = got {
                assert!(all.contains(&(h.t, h.triangle)), "line {i}");
                hits += 1;
                layered += (all.len() >= 3) as usize;
            }
        }
        // Most lines meet M, and many meet it several times.
        assert!(hits > 1000 && layered > 300, "{hits} {layered}");
    }

    /// The sibling-pair layout is a tree: from the root, every interior
    /// node's pair lies after it and inside its box, every node is reached
    /// once, and the leaves' ranges cover each triangle exactly once.
    #[test]
    fn pairs_form_a_tree_covering_every_triangle_once() {
        let mesh = crate::raycast::tests_support::noisy_grid(60);
        let bvh = BvhCaster::new(&mesh).unwrap();
        let mut covered = vec![0u32; bvh.tris.len()];
        let mut reached = vec![0u32; 2 * bvh.pairs.len()];
        let mut stack = vec![0usize];
        while let Some(i) = stack.pop() {
            reached[i] += 1;
            let n = bvh.node(i);
            if n.count > 0 {
                let s = n.offset as usize;
                covered[s..s + n.count as usize]
                    .iter_mut()
                    .for_each(|c| *c += 1);
                continue;
            }
            let first = n.offset as usize;
            assert!(first > i && first % 2 == 0, "node {i}: pair at {first}");
            for k in [first, first + 1] {
                let c = bvh.node(k);
                for a in 0..3 {
                    assert!(
                        c.lo[a] >= n.lo[a] && c.hi[a] <= n.hi[a],
                        "node {k} outside {i}"
                    );
                }
                stack.push(k);
            }
        }
        assert!(covered.iter().all(|&c| c == 1));
        // Every slot but the unused half of pair 0 is a node of the tree.
        assert_eq!(reached[1], 0);
        assert!(reached.iter().enumerate().all(|(i, &r)| i == 1 || r == 1));
        assert_eq!(bvh.num_nodes(), reached.len() - 1);
    }

    #[test]
    fn tree_is_independent_of_thread_count() {
        let mesh = crate::raycast::tests_support::noisy_grid(200);
        let build_with = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| BvhCaster::new(&mesh).unwrap())
        };
        let (a, b) = (build_with(1), build_with(4));
        assert_eq!(a.tri_ids, b.tri_ids);
        assert_eq!(a.pairs.len(), b.pairs.len());
        for (x, y) in a
            .pairs
            .iter()
            .flat_map(|p| &p.0)
            .zip(b.pairs.iter().flat_map(|p| &p.0))
        {
            assert_eq!(
                (x.lo, x.hi, x.count, x.offset),
                (y.lo, y.hi, y.count, y.offset)
            );
        }
    }
}
