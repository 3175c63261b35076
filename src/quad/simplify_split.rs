//! The split greedy loop ([`SimplifyOptions::split`], issue 39): two halves
//! of the control mesh simplified side by side, then the whole.
//!
//! The greedy loop of Fitmaps §3.3 is sequential: each step's heap, mesh
//! and local refit (§3.4) read the previous step's. But a step only writes
//! within a few edges of its quad and reads within eight (see
//! `BATCH_RINGS`), so steps far apart commute. The split loop cuts the
//! start mesh in two by a rule that depends on the mesh alone (the median
//! face centroid along the bounding box's longest axis), freezes a band of
//! [`BAND`] rings on each side of the cut, and runs the ordinary loop on
//! each half on its own copy of the simplifier (one on the calling thread,
//! one on a scoped thread), with two restrictions:
//!
//! * only quads wholly inside the half, [`MARGIN`] rings clear of the band,
//!   enter the heap ([`Region::eligible`]);
//! * a step whose collapse, rotations or refit region W would change a
//!   face or move a vertex outside the half is undone
//!   ([`Simplifier::region_allows`]): the band's faces and positions stay
//!   those of the start in both copies.
//!
//! So every edge at a frozen vertex is an edge of the start, a path from
//! one half to the other crosses at least `2·BAND + 2 > 8` of them, and
//! what one half reads the other never writes: the halves' results do not
//! depend on which runs first or on the thread count. The other half's
//! steps are then put into the first copy ([`Simplifier::absorb`]: its
//! faces replaced, its positions copied; the vertex ids are the start's in
//! both copies, the operators create none), and the ordinary loop runs on
//! the whole mesh — the band, what the halves left, and the natural end or
//! `target_faces` by the global rule.
//!
//! The halves do not share one half-edge mesh: the mesh's free lists (face
//! and edge slots reused from the smallest id), the heap, the per-face
//! arrays and the undo logs are global, so each half gets a clone of the
//! simplifier's state (the control mesh and its per-vertex and per-face
//! arrays, linear in the mesh; the BVH over M is shared). Sharing one mesh
//! would need per-half free lists and id ranges in `ControlMesh`.
//!
//! Checkpoints (`--max-error`'s candidates) of the first phase are whole
//! meshes made of each half's state after it removed the same fraction of
//! its own faces (the halves' steps commute, so any such pair is a mesh
//! the loop could have passed through).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Instant;

use super::{
    all_limits, centroid, Blocked, Candidate, Checkpoint, Progress, Result, Simplifier,
    SimplifyStats, SplitStats, CHECKPOINT_RATIO,
};
use crate::error::Error;
use crate::mesh::{ControlMesh, FaceId, VertexId};
use crate::watch::thread_cpu_seconds;
use crate::DVec3;

/// Rings of frozen vertices on each side of the cut: `2·BAND + 2` edges of
/// the start separate the halves, more than the eight a step reads.
pub(super) const BAND: u32 = 4;

/// Rings between the band and the quads that enter a half's heap: steps
/// nearer than this mostly reach the band and are undone (wasted work).
const MARGIN: u32 = 2;

/// Below this many faces the loop is not split (the band would be most of
/// the mesh).
const MIN_FACES: usize = 4000;

/// Each half removes at most this share of its part of the faces
/// `target_faces` asks to remove, so the whole loop decides where to stop.
const TARGET_SHARE: f64 = 0.9;

/// A vertex's label: in the frozen band.
const FROZEN: u8 = 2;

/// Whether `SUBDFIT_SIMPLIFY_SPLIT=1` asks for the split loop.
pub(super) fn env_on() -> bool {
    crate::switches::on("SUBDFIT_SIMPLIFY_SPLIT")
}

/// The cut of the start mesh, shared by both halves.
pub(super) struct Partition {
    /// Per vertex id: 0 or 1 (its half), or [`FROZEN`].
    label: Vec<u8>,
    /// Per vertex id: edges from the cut in the start (`u32::MAX` for a
    /// component the cut does not reach).
    dist: Vec<u32>,
    /// Faces wholly in each half, and the others (a corner in the band).
    own_faces: [usize; 2],
    /// The faces with a corner in the band and the start's positions: the
    /// part of the mesh neither half changes (for the checkpoints).
    base_faces: Vec<[VertexId; 4]>,
    base_pos: Vec<DVec3>,
}

impl Partition {
    /// The cut of `k` (all quads), or `None` when the loop should not be
    /// split (too small, creases, or a half with too few faces).
    fn of(k: &ControlMesh) -> Option<Self> {
        if k.has_sharpness() || !k.is_all_quads() || k.num_live_faces() < MIN_FACES {
            return None;
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for v in k.live_vertices() {
            lo = lo.min(k.position(v));
            hi = hi.max(k.position(v));
        }
        let ext = hi - lo;
        let axis = if ext.x >= ext.y && ext.x >= ext.z {
            0
        } else if ext.y >= ext.z {
            1
        } else {
            2
        };
        // The median of the face centroids along the axis, ties by face id:
        // a rule of the mesh alone, never of the thread count.
        let mut key: Vec<(f64, u32)> = k
            .live_faces()
            .map(|f| (centroid(k, f)[axis], f.0))
            .collect();
        key.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut side = vec![u8::MAX; k.num_faces()];
        let half = key.len() / 2;
        for (i, &(_, f)) in key.iter().enumerate() {
            side[f as usize] = (i >= half) as u8;
        }
        let nv = k.num_vertices();
        let mut label = vec![FROZEN; nv];
        let mut dist = vec![u32::MAX; nv];
        let mut ring = Vec::new();
        for v in k.live_vertices() {
            let mut sides = k.vertex_faces(v).map(|f| side[f.idx()]);
            let first = sides.next().unwrap_or(FROZEN);
            if sides.all(|s| s == first) {
                label[v.idx()] = first;
            } else {
                dist[v.idx()] = 0;
                ring.push(v);
            }
        }
        // Rings out from the cut, by levels.
        let mut d = 0;
        while !ring.is_empty() {
            d += 1;
            let mut next = Vec::new();
            for &v in &ring {
                for h in k.outgoing(v) {
                    let u = k.head(h);
                    if dist[u.idx()] == u32::MAX {
                        dist[u.idx()] = d;
                        next.push(u);
                    }
                }
            }
            ring = next;
        }
        for (l, &d) in label.iter_mut().zip(&dist) {
            if d <= BAND {
                *l = FROZEN;
            }
        }
        let mut own_faces = [0; 2];
        let mut base_faces = Vec::new();
        for f in k.live_faces() {
            let q = super::super::ops::quad(k, f);
            let s = label[q[0].idx()];
            if s != FROZEN && q.iter().all(|v| label[v.idx()] == s) {
                own_faces[s as usize] += 1;
            } else {
                base_faces.push(q);
            }
        }
        if own_faces.iter().any(|&n| n < MIN_FACES / 4) {
            return None;
        }
        Some(Partition {
            label,
            dist,
            own_faces,
            base_faces,
            base_pos: k.positions().to_vec(),
        })
    }
}

/// One half's state in its copy of the simplifier.
#[derive(Clone)]
pub(super) struct Region {
    part: Arc<Partition>,
    side: u8,
    /// Faces of the copy when the half began.
    copy_initial: usize,
    /// Checkpoints of the half's own part, the index `j` of the fraction
    /// `1 − CHECKPOINT_RATIO^−j` of its faces removed by then.
    snaps: VecDeque<(usize, RegionSnap)>,
    next_snap: usize,
    refused: usize,
}

/// A half's own part at a checkpoint: its faces and its vertices'
/// positions (the rest of the mesh is the start's).
#[derive(Clone)]
struct RegionSnap {
    faces: Vec<[VertexId; 4]>,
    positions: Vec<(VertexId, DVec3)>,
}

impl Region {
    #[inline]
    fn own(&self, v: VertexId) -> bool {
        self.part.label.get(v.idx()) == Some(&self.side)
    }

    /// Whether the half keeps `f`'s centre and Fitmap values current: a
    /// face it may read (a corner in the half or the band).
    pub(super) fn reads(&self, k: &ControlMesh, f: FaceId) -> bool {
        let other = 1 - self.side;
        k.face_vertices(f)
            .any(|v| self.part.label.get(v.idx()) != Some(&other))
    }

    /// Whether `f`'s diagonals enter the half's heap: every corner in the
    /// half, [`MARGIN`] rings clear of the band (in the start).
    pub(super) fn eligible(&self, k: &ControlMesh, f: FaceId) -> bool {
        k.face_vertices(f).all(|v| {
            self.own(v)
                && self
                    .part
                    .dist
                    .get(v.idx())
                    .is_some_and(|&d| d > BAND + MARGIN)
        })
    }

    /// The checkpoint index `j` the half's own part has reached with the
    /// copy at `live` faces.
    fn reached(&self, live: usize) -> usize {
        let own = self.part.own_faces[self.side as usize] as f64;
        let left = own - self.copy_initial.saturating_sub(live) as f64;
        if left <= 0.0 {
            return usize::MAX;
        }
        ((own / left).ln() / CHECKPOINT_RATIO.ln()).floor() as usize
    }
}

impl<'a> Simplifier<'a> {
    /// The split loop: both halves, then the whole (module documentation).
    /// Runs the ordinary loop when the mesh is not split.
    pub(super) fn run_split(
        &mut self,
        stats: &mut SimplifyStats,
        progress: &mut dyn FnMut(Progress) -> bool,
    ) -> Result<()> {
        let initial = self.k.num_live_faces();
        let target = self.opts.target_faces;
        let part = match Partition::of(&self.k) {
            Some(p) if target.map_or(true, |n| n < initial) => Arc::new(p),
            _ => return self.run_loop(stats, progress),
        };
        let t = Instant::now();
        let own = part.own_faces;
        let removable = target.map(|n| (initial - n) as f64);
        let mut a = self.fork(&part, 0, removable);
        let mut b = self.fork(&part, 1, removable);
        let (mut sa, mut sb) = (SimplifyStats::default(), SimplifyStats::default());
        let cancel = AtomicBool::new(false);
        let (ra, rb) = std::thread::scope(|s| {
            let (b, sb, cancel) = (&mut b, &mut sb, &cancel);
            let other = s.spawn(move || {
                let c = thread_cpu_seconds();
                let r = b.run_loop(sb, &mut |_| !cancel.load(Ordering::Relaxed));
                (r, thread_cpu_seconds() - c)
            });
            let c = thread_cpu_seconds();
            let ra = a.run_loop(&mut sa, &mut |p| {
                let go = progress(p);
                if !go {
                    cancel.store(true, Ordering::Relaxed);
                }
                go
            });
            let ca = thread_cpu_seconds() - c;
            if ra.is_err() {
                cancel.store(true, Ordering::Relaxed);
            }
            let (rb, cb) = other
                .join()
                .unwrap_or_else(|e| std::panic::resume_unwind(e));
            (ra.map(|_| ca), rb.map(|_| cb))
        });
        let thread_cpu = [ra?, rb?];
        let refused = [
            a.region.as_ref().map_or(0, |r| r.refused),
            b.region.as_ref().map_or(0, |r| r.refused),
        ];
        let base_projections = (self.projections, self.unprojectable);
        a.projections += b.projections - base_projections.0;
        a.unprojectable += b.unprojectable - base_projections.1;
        let checkpoints = if self.opts.checkpoints > 0 {
            joined_checkpoints(&part, &a, &b)
        } else {
            Vec::new()
        };
        a.absorb(&b, &part)?;
        for s in [&sa, &sb] {
            add_counts(stats, s);
        }
        a.opts = self.opts.clone();
        a.region = None;
        a.relax = self.relax;
        let live = a.k.num_live_faces();
        for c in checkpoints {
            if a.checkpoints.len() == a.opts.checkpoints {
                a.checkpoints.pop_front();
            }
            a.checkpoints.push_back(c);
        }
        a.next_checkpoint = (live as f64 / CHECKPOINT_RATIO).floor() as usize;
        *self = a;
        let split = SplitStats {
            faces: own,
            band_faces: part.base_faces.len(),
            collapses: [sa.collapses, sb.collapses],
            refused_band: refused,
            faces_joined: live,
            seconds: t.elapsed().as_secs_f64(),
            thread_cpu,
            thread_cpu_joined: 0.0,
        };
        let c = thread_cpu_seconds();
        self.run_loop(stats, progress)?;
        let split = SplitStats {
            thread_cpu_joined: thread_cpu_seconds() - c,
            ..split
        };
        stats.initial_faces = initial;
        stats.split = Some(split);
        Ok(())
    }

    /// A copy of the simplifier for one half: the mesh and its per-vertex
    /// and per-face arrays cloned, an empty heap, the loop sequential; with
    /// `target_faces`, a share of the faces to remove (`removable`) as the
    /// half's own target.
    fn fork(&self, part: &Arc<Partition>, side: u8, removable: Option<f64>) -> Simplifier<'a> {
        let live = self.k.num_live_faces();
        let mut opts = self.opts.clone();
        opts.batch = 1;
        opts.target_faces = removable.map(|r| {
            let share = part.own_faces[side as usize] as f64
                / (part.own_faces[0] + part.own_faces[1]) as f64;
            live - (TARGET_SHARE * share * r).floor() as usize
        });
        Simplifier {
            m: self.m,
            fitmap: self.fitmap,
            caster: self.caster,
            bvh: self.bvh.clone(),
            opts,
            max_dist: self.max_dist,
            k: self.k.clone(),
            valence_targets: self.valence_targets.clone(),
            version: self.version.clone(),
            fs: self.fs.clone(),
            fm: self.fm.clone(),
            lim: self.lim.clone(),
            heap: Default::default(),
            projections: self.projections,
            unprojectable: self.unprojectable,
            invariants: self.invariants,
            m_normals: self.m_normals.clone(),
            diag: self.diag,
            refused: Default::default(),
            stamp: Vec::new(),
            stamp_now: 0,
            face_stamp: Vec::new(),
            memo: Default::default(),
            claimed: Vec::new(),
            batch_now: 0,
            ring_scratch: Vec::new(),
            face_scratch: Default::default(),
            pos_log: Vec::new(),
            lim_log: Vec::new(),
            blocked: Default::default(),
            kappa: self.kappa,
            checkpoints: Default::default(),
            checkpoint_map: Vec::new(),
            next_checkpoint: usize::MAX,
            relax: self.relax,
            region: Some(Region {
                part: part.clone(),
                side,
                copy_initial: live,
                snaps: VecDeque::new(),
                next_snap: 1,
                refused: 0,
            }),
            // The halves already keep both cores busy.
            step_fork: usize::MAX,
            step_forks: 0,
        }
    }

    /// Whether the step just made (collapse and rotations of `c`) stays in
    /// the half: the faces it removed and added, the vertices it deleted
    /// and its refit region W (the touched vertices and their 1-ring) are
    /// all the half's own. Always true outside a split half.
    pub(super) fn region_allows(&self, c: &Candidate) -> bool {
        let Some(r) = &self.region else {
            return true;
        };
        let k = &self.k;
        let own = |v: VertexId| r.own(v);
        for &v in &c.touched {
            if k.is_vertex_deleted(v) {
                continue;
            }
            if !own(v) || k.outgoing(v).any(|h| !own(k.head(h))) {
                return false;
            }
        }
        let Some(log) = &c.log else {
            return false;
        };
        log.removed.iter().all(|(_, q)| q.iter().all(|&v| own(v)))
            && log
                .added
                .iter()
                .all(|&f| k.is_face_deleted(f) || k.face_vertices(f).all(own))
            && log.deleted.iter().all(|&v| own(v))
    }

    /// Undoes a step that left its half (from its log), and does not try
    /// it again in this sweep.
    pub(super) fn undo_outside(&mut self, c: Candidate, stats: &mut SimplifyStats) -> Result<()> {
        let Some(log) = &c.log else {
            return Err(Error::topology(
                c.face().to_string(),
                "a split half's step has no log to undo it",
            ));
        };
        stats.collapses -= 1;
        stats.doublets -= c.doublets;
        stats.rotations -= c.rotations;
        let lists = self.log_lists(log);
        let face = c.face();
        self.pos_log = c.pos_log;
        self.lim_log = c.lim_log;
        self.restore(lists)?;
        self.block(face.0, Blocked::TOPOLOGY);
        self.refused.insert(c.pair, Blocked::TOPOLOGY);
        if let Some(r) = &mut self.region {
            r.refused += 1;
        }
        self.check_step("undo of a step out of its half")
    }

    /// A half's checkpoint: its own faces and positions each time it has
    /// removed another fraction of its faces (see [`Region::reached`]).
    pub(super) fn region_checkpoint(&mut self) {
        if self.opts.checkpoints == 0 {
            return;
        }
        let live = self.k.num_live_faces();
        let (k, cap) = (&self.k, self.opts.checkpoints);
        let Some(r) = &mut self.region else {
            return;
        };
        let j = r.reached(live);
        if j < r.next_snap || j == usize::MAX {
            return;
        }
        r.next_snap = j + 1;
        let faces = k
            .live_faces()
            .map(|f| super::super::ops::quad(k, f))
            .filter(|q| q.iter().all(|&v| r.own(v)))
            .collect();
        let positions = k
            .live_vertices()
            .filter(|&v| r.own(v))
            .map(|v| (v, k.position(v)))
            .collect();
        if r.snaps.len() == cap {
            r.snaps.pop_front();
        }
        r.snaps.push_back((j, RegionSnap { faces, positions }));
    }

    /// Puts half `b`'s steps into this copy (half 0's): `b`'s own faces
    /// replace the start's, its deleted vertices go, its positions are
    /// copied; then every limit point is taken afresh and the per-sweep
    /// state cleared for the loop on the whole.
    fn absorb(&mut self, b: &Simplifier<'a>, part: &Partition) -> Result<()> {
        if b.k.num_vertices() != self.k.num_vertices() {
            return Err(Error::topology(
                "mesh",
                "the split halves have different vertex ids",
            ));
        }
        let own = |v: VertexId| part.label[v.idx()] == 1;
        let k = &self.k;
        let remove: Vec<FaceId> = k
            .live_faces()
            .filter(|&f| k.face_vertices(f).all(own))
            .collect();
        let add: Vec<[VertexId; 4]> =
            b.k.live_faces()
                .filter(|&f| b.k.face_vertices(f).all(own))
                .map(|f| super::super::ops::quad(&b.k, f))
                .collect();
        let delete: Vec<VertexId> = k
            .live_vertices()
            .filter(|&v| own(v) && b.k.is_vertex_deleted(v))
            .collect();
        let add_refs: Vec<&[VertexId]> = add.iter().map(|q| q.as_slice()).collect();
        self.k.replace_faces(&remove, &add_refs, &delete)?;
        let moved: Vec<(VertexId, DVec3)> =
            b.k.live_vertices()
                .filter(|&v| own(v))
                .map(|v| (v, b.k.position(v)))
                .collect();
        let pos = self.k.positions_mut();
        for (v, p) in moved {
            pos[v.idx()] = p;
        }
        self.lim = all_limits(&self.k)?;
        self.heap.clear();
        self.refused.clear();
        self.blocked.clear();
        self.pos_log.clear();
        self.lim_log.clear();
        // Once per run, O(mesh): the join is the one edit no operator's
        // own checks cover.
        self.check_invariants("joining the split halves")
    }
}

/// The first phase's checkpoints, most faces first: for each index `j`
/// both halves reached, the start's band with each half's part at `j`.
fn joined_checkpoints(part: &Partition, a: &Simplifier, b: &Simplifier) -> Vec<Checkpoint> {
    let (Some(ra), Some(rb)) = (&a.region, &b.region) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for (j, sa) in &ra.snaps {
        let Some((_, sb)) = rb.snaps.iter().find(|(i, _)| i == j) else {
            continue;
        };
        let mut pos = part.base_pos.clone();
        for &(v, p) in sa.positions.iter().chain(&sb.positions) {
            pos[v.idx()] = p;
        }
        let faces = || part.base_faces.iter().chain(&sa.faces).chain(&sb.faces);
        let mut map = vec![u32::MAX; pos.len()];
        for q in faces() {
            for v in q {
                map[v.idx()] = 0;
            }
        }
        let mut positions = Vec::new();
        for (i, m) in map.iter_mut().enumerate() {
            if *m == 0 {
                *m = positions.len() as u32;
                positions.push(pos[i]);
            }
        }
        let mut corners = Vec::new();
        let mut start = vec![0];
        for q in faces() {
            corners.extend(q.iter().map(|v| map[v.idx()]));
            start.push(corners.len() as u32);
        }
        out.push(Checkpoint {
            vertex_sharpness: vec![0.0; positions.len()],
            positions,
            corners,
            start,
            creases: Vec::new(),
        });
    }
    out
}

/// Adds a half's counters to the run's.
fn add_counts(stats: &mut SimplifyStats, s: &SimplifyStats) {
    stats.collapses += s.collapses;
    stats.rotations += s.rotations;
    stats.doublets += s.doublets;
    stats.refused_topology += s.refused_topology;
    for (why, n) in &s.refused_topology_by_reason {
        *stats
            .refused_topology_by_reason
            .entry(why.clone())
            .or_default() += n;
    }
    stats.refused_m_fitmap += s.refused_m_fitmap;
    stats.refused_s_fitmap += s.refused_s_fitmap;
    stats.refused_guard_distance += s.refused_guard_distance;
    stats.refused_guard_normal += s.refused_guard_normal;
    stats.refused_undershoot += s.refused_undershoot;
    stats.sweeps += s.sweeps;
    stats.batches += s.batches;
    stats.batched_candidates += s.batched_candidates;
}
