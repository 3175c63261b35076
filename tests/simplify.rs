//! The simplification loop (Fitmaps §3.3–3.4) with synthetic Fitmaps on the
//! shared meshes (the real Fitmap takes minutes on a loaded machine; the
//! CLI numbers in the report use it): invariants after every step, no
//! inverted patch, adaptivity to F_S, determinism, cancellation.

mod common;

use subdfit::analysis::Fitmap;
use subdfit::mesh::TriMesh;
use subdfit::project::project_along_normals;
use subdfit::quad::{face_centre_limit, simplify, simplify_with_progress, SimplifyOptions};
use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::Error;

/// A Fitmap with the given per-vertex F_S and a uniform F_M.
fn synthetic(m: &TriMesh, s: impl Fn(subdfit::DVec3) -> f64, fm: f64) -> Fitmap {
    let n = m.positions.len();
    Fitmap {
        radii: vec![fm],
        s: m.positions.iter().map(|&p| s(p)).collect(),
        m: vec![fm; n],
        m_step: vec![0; n],
        tolerance: 0.05,
        stats: Default::default(),
    }
}

/// `simplify` with default options but the S-fitmap scale (0 turns the
/// S-fitmap test off).
fn simplify_at_scale(
    m: &TriMesh,
    fitmap: &Fitmap,
    caster: &dyn subdfit::raycast::RayCaster,
    scale: f64,
) -> subdfit::quad::Simplified {
    simplify(
        m,
        fitmap,
        caster,
        &SimplifyOptions::default().with_s_fitmap_scale(scale),
    )
    .unwrap()
}

/// Fraction of faces whose limit normal at the centre agrees (positive dot
/// product) with the normal of the M triangle φ reaches.
fn normal_agreement(m: &TriMesh, k: &subdfit::mesh::ControlMesh) -> (f64, usize) {
    let caster = make_raycaster(RayBackend::Embree, m).unwrap();
    let pts: Vec<_> = k.faces().map(|f| face_centre_limit(k, f)).collect();
    let (proj, st) =
        project_along_normals(caster.as_ref(), &pts, 0.25 * m.bbox_diagonal()).unwrap();
    let mut agree = 0;
    let mut n = 0;
    for (p, l) in proj.iter().zip(&pts) {
        if let Some(p) = p {
            let [a, b, c] = m.triangle(p.triangle as usize);
            let tn = (b - a).cross(c - a);
            n += 1;
            if tn.dot(l.normal()) > 0.0 {
                agree += 1;
            }
        }
    }
    (agree as f64 / n.max(1) as f64, st.unprojectable)
}

#[test]
fn heap_driven_sequence_keeps_invariants_every_step() {
    let (name, target) = ("spot.ply", 60);
    let Some(m) = common::load_data_mesh(name) else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let fitmap = synthetic(&m, |_| 1.0, 0.25 * m.bbox_diagonal());
    let opts = SimplifyOptions::default()
        .with_check_every_step(true)
        .with_target_faces(Some(target));
    let r = simplify(&m, &fitmap, caster.as_ref(), &opts).unwrap();
    let k = &r.mesh;
    k.validate().unwrap();
    assert!(k.is_all_quads());
    assert_eq!(k.num_components(), 1);
    assert_eq!(k.num_boundary_loops(), 0);
    // Closed genus 0: V − E + F = 2.
    assert_eq!(
        k.num_vertices() as i64 - k.num_edges() as i64 + k.num_faces() as i64,
        2
    );
    assert!(r.stats.faces <= target || r.stats.stop.is_some());
    let (agree, unproj) = normal_agreement(&m, k);
    eprintln!(
        "{name}: {} -> {} faces, {} collapses, {} rotations, {} doublets, {} irregular; \
         normals agree {:.1} %, {unproj} centres unprojectable",
        r.stats.initial_faces,
        r.stats.faces,
        r.stats.collapses,
        r.stats.rotations,
        r.stats.doublets,
        r.stats.irregular_vertices,
        100.0 * agree
    );
    // Inverted patches would show as disagreeing normals; allow 2 % for
    // centres whose φ lands across a thin feature.
    assert!(
        agree >= 0.98,
        "{name}: only {:.1} % normals agree",
        100.0 * agree
    );
}

#[test]
fn patch_size_follows_one_over_fs() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    // F_S 8 times larger on the x > 0 half: patches there should be smaller.
    let fs = |p: subdfit::DVec3| if p.x > 0.0 { 8.0 } else { 1.0 };
    let fitmap = synthetic(&m, fs, 0.25 * m.bbox_diagonal());
    let opts = SimplifyOptions::default().with_target_faces(Some(300));
    let r = simplify(&m, &fitmap, caster.as_ref(), &opts).unwrap();
    let k = &r.mesh;
    let (mut size, mut inv) = (Vec::new(), Vec::new());
    for f in k.faces() {
        let vs: Vec<_> = k.face_vertices(f).map(|v| k.position(v)).collect();
        let c = face_centre_limit(k, f).position;
        let rad = vs.iter().map(|p| (*p - c).length()).fold(0.0, f64::max);
        size.push(rad);
        inv.push(1.0 / fs(c));
    }
    let rho = subdfit::analysis::spearman(&size, &inv).unwrap();
    let mean = |big: bool| {
        let v: Vec<f64> = size
            .iter()
            .zip(&inv)
            .filter(|(_, &i)| (i == 1.0) == big)
            .map(|(s, _)| *s)
            .collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let ratio = mean(true) / mean(false);
    eprintln!(
        "spot: {} faces, Spearman(patch radius, 1/F_S) = {rho:.3}, mean radius where F_S = 1 \
         over where F_S = 8: {ratio:.2}",
        k.num_faces()
    );
    // F_S is two-valued, so ties cap the rank correlation well below 1;
    // the size ratio is the sharper check.
    assert!(rho > 0.25, "patch size does not follow 1/F_S: rho = {rho}");
    assert!(
        ratio > 1.5,
        "patches not larger where F_S is small: {ratio}"
    );
}

#[test]
fn deterministic_across_thread_counts() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let fitmap = synthetic(&m, |p| 1.0 + p.y.abs(), 0.05 * m.bbox_diagonal());
    let opts = SimplifyOptions::default();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| simplify(&m, &fitmap, caster.as_ref(), &opts).unwrap())
    };
    let (a, b) = (run(1), run(2));
    let dir = tempfile::tempdir().unwrap();
    let (pa, pb) = (dir.path().join("a.obj"), dir.path().join("b.obj"));
    subdfit::io::write_control_obj(&pa, &a.mesh).unwrap();
    subdfit::io::write_control_obj(&pb, &b.mesh).unwrap();
    assert_eq!(std::fs::read(&pa).unwrap(), std::fs::read(&pb).unwrap());
    eprintln!(
        "spot natural end with F_M = 5 % diag: {} faces, median radius / F_M {:.3}, \
         {} collapses refused by the M-fitmap test",
        a.stats.faces, a.stats.median_radius_over_fm, a.stats.refused_m_fitmap
    );
    // The M-fitmap test bounds the patches it lets grow: at the natural end
    // the typical patch is within F_M (doublet removals, which merge two
    // patches unchecked, and rotations are the only way past it) and, the
    // test being what ended the simplification, not far below it either
    // (a collapse at most doubles a neighbour's area, so its radius by ~√2).
    assert!(a.stats.refused_m_fitmap > 0);
    assert!(
        a.stats.median_radius_over_fm <= 1.0 && a.stats.median_radius_over_fm > 0.5,
        "median radius / F_M = {}",
        a.stats.median_radius_over_fm
    );
}

/// The sequential loop with its φ batches split in two over a pool of two
/// threads (`SimplifyOptions::step_fork`, issue 39) against the loop that
/// splits none, at one and at two threads: the same control mesh bit for
/// bit (every vertex's position bits, the faces), the same counters of φ
/// lines, misses and steps. At a 2-line threshold nearly every batch of a
/// step splits, so the split path is what ran (`step_forks` > 0), and with
/// a synthetic F_S varying over spot the loop runs its whole course
/// (thousands of steps, guard undos, the final sweep).
#[test]
fn split_phi_batches_give_the_sequential_loops_mesh() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let fitmap = synthetic(&m, |p| 1.0 + 4.0 * p.y.abs(), 0.05 * m.bbox_diagonal());
    let run = |fork: usize, threads: usize| {
        let opts = SimplifyOptions::default().with_step_fork(Some(fork));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| simplify(&m, &fitmap, caster.as_ref(), &opts).unwrap())
    };
    let seq1 = run(0, 1);
    let seq2 = run(0, 2);
    let split = run(2, 2);
    assert_eq!(seq1.stats.step_forks, 0);
    assert_eq!(seq2.stats.step_forks, 0);
    assert!(
        split.stats.step_forks > split.stats.collapses,
        "only {} of the {} steps split a φ batch",
        split.stats.step_forks,
        split.stats.collapses
    );
    let bits = |r: &subdfit::quad::Simplified| {
        let k = &r.mesh;
        let pos: Vec<[u64; 3]> = k
            .positions()
            .iter()
            .map(|p| [p.x.to_bits(), p.y.to_bits(), p.z.to_bits()])
            .collect();
        let faces: Vec<Vec<u32>> = k
            .live_faces()
            .map(|f| k.face_vertices(f).map(|v| v.0).collect())
            .collect();
        let s = &r.stats;
        let counts = (s.faces, s.collapses, s.rotations, s.doublets, s.projections);
        (pos, faces, counts, s.unprojectable, s.refused_m_fitmap)
    };
    let want = bits(&seq1);
    assert!(want.2 .1 > 1000, "only {} collapses", want.2 .1);
    assert!(bits(&seq2) == want, "two threads without splits differ");
    assert!(bits(&split) == want, "the split φ batches changed the mesh");
}

/// The batched loop (the default) against the sequential one (a batch of
/// one) on spot with a varying F_S: batches of several candidates do form,
/// and the two orders reach the same kind of natural end: face counts and
/// irregular vertices within 10 % (the greedy outcome moves by ±5 % with
/// small changes of the order, docs/status.md "Measurements behind the
/// code"), and no inverted patch; the batched result is the same at 1 and
/// 2 threads, and every step keeps the invariants.
#[test]
fn batched_loop_ends_where_the_sequential_one_does() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let fitmap = synthetic(&m, |p| 1.0 + 4.0 * p.y.abs(), 0.05 * m.bbox_diagonal());
    let run = |batch: usize, threads: usize| {
        // Every step's invariants (manifold, pure quads, no doublet, the
        // same components, boundary loops and Euler characteristic) are
        // checked on the batched loop too.
        let opts = SimplifyOptions::default()
            .with_batch(batch)
            .with_check_every_step(true);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| simplify(&m, &fitmap, caster.as_ref(), &opts).unwrap())
    };
    let (seq, bat, bat1) = (run(1, 2), run(16, 2), run(16, 1));
    let dir = tempfile::tempdir().unwrap();
    let (pa, pb) = (dir.path().join("a.obj"), dir.path().join("b.obj"));
    subdfit::io::write_control_obj(&pa, &bat.mesh).unwrap();
    subdfit::io::write_control_obj(&pb, &bat1.mesh).unwrap();
    assert_eq!(std::fs::read(&pa).unwrap(), std::fs::read(&pb).unwrap());
    let mean = |r: &subdfit::quad::Simplified| {
        r.stats.batched_candidates as f64 / r.stats.batches.max(1) as f64
    };
    eprintln!(
        "spot: sequential {} faces / {} irregular ({} batches), batched {} / {} ({} batches, \
         {:.2} candidates each)",
        seq.stats.faces,
        seq.stats.irregular_vertices,
        seq.stats.batches,
        bat.stats.faces,
        bat.stats.irregular_vertices,
        bat.stats.batches,
        mean(&bat)
    );
    assert_eq!(mean(&seq), 1.0);
    // Fewer batches than the sequential loop's steps: some held several
    // candidates (spot is small, so most regions meet and few do).
    assert!(
        bat.stats.batches < seq.stats.batches,
        "no batch of several candidates formed"
    );
    let near = |a: usize, b: usize| (a as f64 - b as f64).abs() <= 0.1 * a as f64;
    assert!(near(seq.stats.faces, bat.stats.faces));
    assert!(near(
        seq.stats.irregular_vertices,
        bat.stats.irregular_vertices
    ));
    let (agree, _) = normal_agreement(&m, &bat.mesh);
    assert!(agree >= 0.98, "only {:.1} % normals agree", 100.0 * agree);
}

#[test]
fn progress_can_cancel() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let fitmap = synthetic(&m, |_| 1.0, m.bbox_diagonal());
    let mut calls = 0;
    let r = simplify_with_progress(
        &m,
        &fitmap,
        caster.as_ref(),
        &SimplifyOptions::default(),
        &mut |p| {
            calls += 1;
            assert!(p.faces <= p.initial_faces);
            false
        },
    );
    assert!(matches!(r, Err(Error::Cancelled { .. })), "{r:?}");
    assert_eq!(calls, 1);
}

/// The surface guard (§3.4's refit must keep the limit on M): with a tight
/// bound it undoes collapses; every undo restores a valid mesh (invariants
/// checked after every step, undo included), the undo built from the
/// step's log of changed faces equals the one built from a snapshot of its
/// region (`check_every_step` compares them and fails the run otherwise),
/// and at the end no patch centre is further from M than the bound the
/// guard enforced.
#[test]
fn guard_undoes_collapses_and_keeps_the_surface_on_m() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let diag = m.bbox_diagonal();
    let fitmap = synthetic(&m, |_| 1.0, 0.25 * diag);
    // Floor 0.0047 · τ^¼ (τ = 0.05) ≈ 2.2‰ of the diagonal; the S-fitmap term
    // is negligible with F_S = 1 on a unit-size mesh.
    let opts = SimplifyOptions::default()
        .with_check_every_step(true)
        .with_guard(1e-6, 0.0047, 0.3);
    let r = simplify(&m, &fitmap, caster.as_ref(), &opts).unwrap();
    let s = &r.stats;
    eprintln!(
        "spot with a tight guard: {} faces, {} collapses, {} undone (distance), {} (normal)",
        s.faces, s.collapses, s.refused_guard_distance, s.refused_guard_normal
    );
    assert!(s.refused_guard_distance + s.refused_guard_normal > 0);
    let k = &r.mesh;
    k.validate().unwrap();
    let bound = 0.0047 * 0.05f64.powf(0.25) * diag;
    let pts: Vec<_> = k.faces().map(|f| face_centre_limit(k, f)).collect();
    let (proj, _) = project_along_normals(caster.as_ref(), &pts, 0.25 * diag).unwrap();
    let mut worst = 0.0f64;
    for p in proj.iter().flatten() {
        worst = worst.max(p.offset.abs());
    }
    // The guard checks the centres after each step's refit; later steps
    // elsewhere perturb a patch only through its 2-ring (§3.4), and the
    // next refit nearby re-checks it, so allow twice the bound.
    assert!(
        worst <= 2.0 * bound,
        "a patch centre is {:.2}‰ from M, bound {:.2}‰",
        1e3 * worst / diag,
        1e3 * bound / diag
    );
}

/// Adaptivity on the paper's bunny with its real Fitmap (τ = 1 %), the
/// acceptance figure of issue 4. §3.3.1: "systematically executing the
/// least expensive collapse causes survivors to have a size proportional
/// to the inverse of the S-fitmap". That holds while the cost order decides
/// which patches grow, i.e. before the M-fitmap test halts most regions, so
/// the rank correlation between patch radius and 1/F_S at the patch centre
/// is measured on a run stopped at 2000 patches (the paper's "*" rows).
/// At the natural end the halting rule, F_M, sets the sizes instead: the
/// second run checks that patch radius follows F_M there and that the five
/// boundary loops survive while the boundary coarsens.
///
/// Threshold 0.3: F_S spans only a factor ≈ 1.5 between its 5th and 95th
/// percentiles on bunny while one collapse changes a patch's radius by
/// ≈ √2, so the signal is of the order of the discreteness noise and a
/// correlation near 1 is not to be expected; on ~2000 patches the standard
/// error of a null rank correlation is 1/√(n − 1) ≈ 0.022, so 0.3 is far
/// beyond chance (measured: 0.47; 0.03 at the natural end, where F_M rules).
/// Issue 4's acceptance: at the natural end on bunny (τ = 1 %), patches are
/// visibly smaller where F_S is large, within Table 1's count. Measured by
/// the test itself (patch radius against the Fitmap at M's point closest
/// to the limit centre), independently of the loop's statistics.
#[test]
fn bunny_patch_size_follows_one_over_fs_and_fm() {
    let Some(m) = common::load_data_mesh("bunny.ply") else {
        eprintln!("skipped: bunny.ply not found (set the shared data dir)");
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let fitmap = subdfit::analysis::compute_fitmap(
        &m,
        caster.as_ref(),
        &subdfit::analysis::FitmapOptions::default().with_tolerance(0.01),
    )
    .unwrap();
    // Per patch: radius (largest distance from the limit centre to a
    // control corner), F_S and F_M at M's point closest to the limit centre.
    // Returns Spearman(radius, 1/F_S), Spearman(radius, F_M) and the mean
    // radius of the top F_S quartile over the bottom one.
    let measure = |k: &subdfit::mesh::ControlMesh| {
        let ctr: Vec<_> = k
            .faces()
            .map(|f| face_centre_limit(k, f).position)
            .collect();
        let near = caster.closest_points(&ctr, f64::INFINITY).unwrap();
        let (mut r, mut inv_fs, mut fm, mut fs_r) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (f, (c, p)) in k.faces().zip(ctr.iter().zip(near)) {
            let p = p.expect("a closest point on M");
            let rad = k
                .face_vertices(f)
                .map(|v| (k.position(v) - *c).length())
                .fold(0.0, f64::max);
            let s = fitmap.s_at(&m, p.triangle, p.u, p.v);
            r.push(rad);
            inv_fs.push(1.0 / s);
            fm.push(fitmap.m_at(&m, p.triangle, p.u, p.v));
            fs_r.push((s, rad));
        }
        fs_r.sort_by(|a, b| a.0.total_cmp(&b.0));
        let q = fs_r.len() / 4;
        let mean = |x: &[(f64, f64)]| x.iter().map(|p| p.1).sum::<f64>() / x.len() as f64;
        (
            subdfit::analysis::spearman(&r, &inv_fs).unwrap(),
            subdfit::analysis::spearman(&r, &fm).unwrap(),
            mean(&fs_r[fs_r.len() - q..]) / mean(&fs_r[..q]),
        )
    };
    let mid = simplify(
        &m,
        &fitmap,
        caster.as_ref(),
        &SimplifyOptions::default().with_target_faces(Some(2000)),
    )
    .unwrap();
    let (rho_s, ..) = measure(&mid.mesh);
    let end = simplify(&m, &fitmap, caster.as_ref(), &SimplifyOptions::default()).unwrap();
    let (rho_s_end, rho_m_end, quart) = measure(&end.mesh);
    let nb =
        |k: &subdfit::mesh::ControlMesh| k.vertices().filter(|&v| k.is_boundary_vertex(v)).count();
    eprintln!(
        "bunny τ 1 %: at {} patches Spearman(radius, 1/F_S) = {rho_s:.3}; natural end {} \
         patches (κ = {:.4}): Spearman(radius, 1/F_S) = {rho_s_end:.3}, Spearman(radius, F_M) \
         = {rho_m_end:.3}, mean radius top / bottom F_S quartile = {quart:.3} (loop's own: \
         {:.3}, {:.3}); final blockers {:?}; boundary vertices {} -> {}",
        mid.stats.faces,
        end.stats.faces,
        end.stats.s_fitmap_kappa,
        end.stats.adaptivity_spearman.unwrap_or(f64::NAN),
        end.stats.radius_ratio_fs_quartiles,
        end.stats.final_blockers,
        nb(&mid.mesh),
        nb(&end.mesh)
    );
    assert!(rho_s > 0.3, "patch size does not follow 1/F_S: {rho_s}");
    // The acceptance figures ("patches visibly smaller where F_S is
    // large"): a rank correlation of at least 0.4 (the null's standard
    // error is 1/√(n−1) ≈ 0.05 at ~400 patches) and patches in the top F_S
    // quartile at most 0.7× as large as in the bottom one. Measured with
    // the log-space F_S (`analysis::fitmap`) and the default S-fitmap test:
    // ≈ 0.7 and ≈ 0.25; with the former linear F_S fit (F_S ≈ E(r_h)/r_h⁴,
    // a near-global quantity) −0.09 and 0.90, which fail both.
    assert!(rho_s_end >= 0.4, "Spearman(radius, 1/F_S) = {rho_s_end}");
    assert!(quart <= 0.7, "top / bottom F_S quartile radius = {quart}");
    // Within Table 1's count (506) at τ = 1 %.
    assert!(end.stats.faces <= 506, "{} patches", end.stats.faces);
    // Both §3.1.1 prescriptions stop patches: the M-fitmap test most, the
    // S-fitmap test (on by default) a sizeable share (measured 316 and 111
    // of 415).
    let blocked = |what: &str| end.stats.final_blockers.get(what).copied().unwrap_or(0);
    assert!(
        2 * blocked("m_fitmap") >= end.stats.faces && 10 * blocked("s_fitmap") >= end.stats.faces,
        "{:?} of {} patches",
        end.stats.final_blockers,
        end.stats.faces
    );
    // F_M, the projectability bound, still shapes the sizes.
    assert!(
        rho_m_end > 0.3,
        "patch size does not follow F_M: {rho_m_end}"
    );
    // The S-fitmap test only adds patches where r·F_S is large: without it
    // there are fewer patches, and the correlation with 1/F_S is weaker.
    let off = simplify_at_scale(&m, &fitmap, caster.as_ref(), 0.0);
    let (rho_s_off, ..) = measure(&off.mesh);
    eprintln!(
        "bunny τ 1 % without the S-fitmap test: {} patches, Spearman(radius, 1/F_S) = \
         {rho_s_off:.3}",
        off.stats.faces
    );
    assert!(off.stats.faces < end.stats.faces);
    assert!(rho_s_off < rho_s_end, "{rho_s_off} vs {rho_s_end}");
    // Holes kept, boundary coarsened (the input's 5 loops; issue 4).
    assert_eq!(end.mesh.num_boundary_loops(), 5);
    end.mesh.validate().unwrap();
    assert!(nb(&end.mesh) < nb(&mid.mesh));
}

/// Mean patch radius (largest limit-centre-to-control-corner distance) on
/// either side of the plane x = 0, for the two-valued synthetic F_S below.
fn mean_radius_by_side(k: &subdfit::mesh::ControlMesh) -> (f64, f64, usize, usize) {
    let (mut lo, mut hi, mut nlo, mut nhi) = (0.0, 0.0, 0, 0);
    for f in k.faces() {
        let c = face_centre_limit(k, f).position;
        let rad = k
            .face_vertices(f)
            .map(|v| (k.position(v) - c).length())
            .fold(0.0, f64::max);
        if c.x > 0.0 {
            hi += rad;
            nhi += 1;
        } else {
            lo += rad;
            nlo += 1;
        }
    }
    (lo / nlo.max(1) as f64, hi / nhi.max(1) as f64, nlo, nhi)
}

/// The S-fitmap test (§3.1.1's "radius inversely proportional to F_S" made
/// a bound, `radius · F_S ≤ κ`) makes the *natural end* adaptive. F_S is 4
/// on the x > 0 half of spot and 1 on the other, F_M uniform (10 % of the
/// diagonal). Without the test every patch grows until the M-fitmap test
/// (or the guard) stops it, so at the natural end both halves have patches
/// of about the same size whatever F_S (the heap order only decides which
/// grow first); with it the x > 0 half stops at a 4 times smaller radius.
/// κ = 0.3 κ₀ with κ₀ = F_M·√(mean F_S²) ∈ (F_M, 4 F_M): the bound on the
/// x ≤ 0 half, ≈ 0.3·2.9 F_M = 0.087 diag, is below F_M, and on the x > 0
/// half, ≈ 0.022 diag, it is above the input's resolution (mean edge 1.8 %
/// of the diagonal), so both halves are stopped by the S-fitmap test and
/// the ideal ratio of mean radii is 4. A collapse changes a radius in steps
/// of up to ≈ √2 and patches straddling x = 0 mix the halves, so the test
/// asks for 2.5 (measured 3.8; without the test 0.8, asked below 1.5).
#[test]
fn s_fitmap_test_makes_the_natural_end_follow_one_over_fs() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let diag = m.bbox_diagonal();
    let fs = |p: subdfit::DVec3| if p.x > 0.0 { 4.0 } else { 1.0 };
    let fm = 0.1 * diag;
    let fitmap = synthetic(&m, fs, fm);
    let kappa0 = subdfit::quad::s_fitmap_kappa(&m, &fitmap);
    assert!(
        kappa0 > fm && kappa0 < 4.0 * fm,
        "κ₀ = {kappa0}, F_M = {fm}"
    );
    let off = simplify_at_scale(&m, &fitmap, caster.as_ref(), 0.0);
    let on = simplify_at_scale(&m, &fitmap, caster.as_ref(), 0.3);
    let (lo_off, hi_off, ..) = mean_radius_by_side(&off.mesh);
    let (lo_on, hi_on, nlo, nhi) = mean_radius_by_side(&on.mesh);
    let rho = on.stats.adaptivity_spearman.unwrap_or(f64::NAN);
    eprintln!(
        "spot natural end: S-fitmap test off {} faces, mean radius where F_S = 1 over F_S = 4: \
         {:.2}; on (κ = {:.4}) {} faces ({nlo} / {nhi} per half), ratio {:.2}, \
         Spearman(radius, 1/F_S) {rho:.3}; final blockers {:?}",
        off.stats.faces,
        lo_off / hi_off,
        on.stats.s_fitmap_kappa,
        on.stats.faces,
        lo_on / hi_on,
        on.stats.final_blockers
    );
    assert_eq!(on.stats.stop, Some(subdfit::quad::StopReason::NaturalEnd));
    assert!(on.stats.refused_s_fitmap > 0);
    assert!((on.stats.s_fitmap_kappa - 0.3 * kappa0).abs() <= 1e-12 * kappa0);
    // The S-fitmap test is what stops most final patches.
    let by_s = on
        .stats
        .final_blockers
        .get("s_fitmap")
        .copied()
        .unwrap_or(0);
    assert!(2 * by_s > on.stats.faces, "{:?}", on.stats.final_blockers);
    assert!(
        lo_off / hi_off < 1.5,
        "without the S-fitmap test the sizes should follow F_M: {}",
        lo_off / hi_off
    );
    assert!(
        lo_on / hi_on > 2.5,
        "with the S-fitmap test patches should be smaller where F_S is large: {}",
        lo_on / hi_on
    );
    // F_S is two-valued (ties), and the straddling patches blur it; 0.499
    // measured, far above the null's standard error 1/√(n−1) ≈ 0.03.
    assert!(rho > 0.3, "Spearman(radius, 1/F_S) = {rho}");
    on.mesh.validate().unwrap();
    assert!(on.mesh.is_all_quads());
}

/// κ₀ is the equal-count constant: for constant fields it is F_S·F_M, and
/// scaling the fields as a scaling of the mesh by c does (F_S by c^-¾, F_M
/// by c, areas by c²) scales it by c^¼, as F_S·r.
#[test]
fn s_fitmap_kappa_is_the_equal_count_constant() {
    let Some(m) = common::load_data_mesh("spot.ply") else {
        return;
    };
    let f = synthetic(&m, |_| 3.0, 0.02);
    let k = subdfit::quad::s_fitmap_kappa(&m, &f);
    assert!((k - 3.0 * 0.02).abs() < 1e-12, "{k}");
    let f = synthetic(&m, |p| 1.0 + p.y.abs(), 0.05);
    let k1 = subdfit::quad::s_fitmap_kappa(&m, &f);
    let c: f64 = 3.0;
    let mut big = m.clone();
    for p in &mut big.positions {
        *p *= c;
    }
    let mut g = f.clone();
    g.s.iter_mut().for_each(|s| *s *= c.powf(-0.75));
    g.m.iter_mut().for_each(|x| *x *= c);
    let k2 = subdfit::quad::s_fitmap_kappa(&big, &g);
    assert!((k2 / k1 - c.powf(0.25)).abs() < 1e-9, "{k1} {k2}");
    // No value anywhere: off.
    let mut z = f.clone();
    z.s.iter_mut().for_each(|s| *s = 0.0);
    assert_eq!(subdfit::quad::s_fitmap_kappa(&m, &z), 0.0);
}

/// The split loop (`SimplifyOptions::split`, issue 39): homer's start is
/// cut in two halves simplified side by side with a frozen band between
/// them, then the whole. The halves' steps never depend on the thread
/// count (the cut is the mesh's median plane, each half on its own copy),
/// so the result is the same at 1 and 2 threads; the joined mesh and the
/// result keep the invariants (manifold, pure quads, no doublet, the same
/// components, boundary loops and Euler characteristic as the start: M's
/// topology); and the natural end is the
/// same kind as the sequential loop's (faces within 15 %: the greedy
/// outcome moves by ±5–10 % with the order, docs/status.md), with no
/// inverted patch.
#[test]
fn split_loop_is_deterministic_and_keeps_the_topology() {
    let Some(m) = common::load_data_mesh("homer.ply") else {
        return;
    };
    let caster = make_raycaster(RayBackend::Embree, &m).unwrap();
    let fitmap = synthetic(&m, |p| 1.0 + 4.0 * p.y.abs(), 0.05 * m.bbox_diagonal());
    // Every step's invariants (`with_check_every_step`) cost O(mesh) each,
    // minutes on homer on a loaded machine: the join of the halves checks
    // them once on every run (`Simplifier::check_invariants`), and the
    // result is compared with the sequential loop's below.
    let run = |split: bool, threads: usize| {
        let opts = SimplifyOptions::default().with_split(split);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| simplify(&m, &fitmap, caster.as_ref(), &opts).unwrap())
    };
    let (seq, two, one) = (run(false, 2), run(true, 2), run(true, 1));
    let dir = tempfile::tempdir().unwrap();
    let (pa, pb) = (dir.path().join("a.obj"), dir.path().join("b.obj"));
    subdfit::io::write_control_obj(&pa, &two.mesh).unwrap();
    subdfit::io::write_control_obj(&pb, &one.mesh).unwrap();
    assert_eq!(std::fs::read(&pa).unwrap(), std::fs::read(&pb).unwrap());
    let split = two
        .stats
        .split
        .clone()
        .expect("homer's start was not split");
    eprintln!(
        "homer: sequential {} faces / {} irregular, split {} / {} ({split:?})",
        seq.stats.faces,
        seq.stats.irregular_vertices,
        two.stats.faces,
        two.stats.irregular_vertices,
    );
    assert!(seq.stats.split.is_none());
    // Both halves did most of their part of the work before the join.
    for h in 0..2 {
        assert!(
            split.collapses[h] > split.faces[h] / 2,
            "half {h}: {} collapses of {} faces",
            split.collapses[h],
            split.faces[h]
        );
    }
    assert!(split.faces_joined < two.stats.initial_faces / 2);
    let topo = |k: &subdfit::mesh::ControlMesh| {
        let euler =
            k.num_live_vertices() as i64 - k.num_live_edges() as i64 + k.num_live_faces() as i64;
        (k.num_components(), k.num_boundary_loops(), euler)
    };
    assert_eq!(topo(&two.mesh), topo(&seq.mesh));
    let near = |a: usize, b: usize| (a as f64 - b as f64).abs() <= 0.15 * a as f64;
    assert!(near(seq.stats.faces, two.stats.faces));
    let (agree, _) = normal_agreement(&m, &two.mesh);
    assert!(agree >= 0.98, "only {:.1} % normals agree", 100.0 * agree);
}
