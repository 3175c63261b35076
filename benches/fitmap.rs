//! The layout's two heaviest stages on the Stanford bunny (69,451
//! triangles), per core: the default (fast) Fitmap (Fitmaps §3.1) and the
//! greedy simplification loop (§3.3–3.4) at its default options, each in a
//! one-thread rayon pool, so the figures are CPU seconds of one core and do
//! not depend on what else the machine runs (the end-to-end wall times in
//! docs/status.md, "Scale", do); the loop also in batches of 16
//! (`SimplifyOptions::batch`), on one thread and on two; the loop alone
//! (its start prepared outside the timing) on bunny and gargoyle; and one
//! cubic fit of 600 points.
//!
//! `cargo bench --bench fitmap`; skips with a message if the data is absent.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::Duration;

use common::*;
use criterion::{BatchSize, Criterion};
use subdfit::analysis::{compute_fitmap, FitmapOptions};
use subdfit::quad::simplify::{prepare, simplify, simplify_prepared, SimplifyOptions};
use subdfit::raycast::{make_raycaster, RayBackend};

fn main() {
    let Some(mesh) = load_data_mesh("bunny.ply") else {
        return;
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let caster = pool
        .install(|| make_raycaster(RayBackend::Embree, &mesh))
        .unwrap();
    let opts = FitmapOptions::default();
    let fitmap = pool
        .install(|| compute_fitmap(&mesh, caster.as_ref(), &opts))
        .unwrap();

    let mut c = Criterion::default()
        .warm_up_time(Duration::from_millis(100))
        .measurement_time(Duration::from_secs(20))
        .sample_size(10)
        .configure_from_args();
    let mut g = c.benchmark_group("bunny");
    g.bench_function("fitmap_fast_1thread", |b| {
        b.iter(|| pool.install(|| compute_fitmap(&mesh, caster.as_ref(), &opts).unwrap()))
    });
    // One cubic fit (§3.1.2) of the size of the largest level-0 ball
    // (`FAST_LEVEL0_MAX_VERTICES`, 600 points): the Fitmap runs tens of
    // thousands of them, and their normal equations were ~7 % of it.
    let pts: Vec<subdfit::DVec3> = (0..600)
        .map(|k| {
            let t = k as f64;
            let (u, v) = ((1.3 * t).sin(), (0.7 * t).cos());
            subdfit::DVec3::new(u, v, 0.3 * u * u - 0.2 * u * v * v + 0.01 * (5.1 * t).sin())
        })
        .collect();
    g.bench_function("fit_cubic_600", |b| {
        b.iter(|| subdfit::analysis::cubic::fit_cubic(std::hint::black_box(&pts), None, 1.0))
    });
    // The loop sequential (the default) and in batches of 16, on
    // one thread (its CPU cost) and on two (what the batches buy in wall
    // time; that figure depends on what else the machine runs).
    let pool2 = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    for (name, so, pool) in [
        (
            "simplify_sequential_1thread",
            SimplifyOptions::default().with_batch(1),
            &pool,
        ),
        (
            "simplify_batched_1thread",
            SimplifyOptions::default().with_batch(16),
            &pool,
        ),
        (
            "simplify_batched_2threads",
            SimplifyOptions::default().with_batch(16),
            &pool2,
        ),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| pool.install(|| simplify(&mesh, &fitmap, caster.as_ref(), &so).unwrap()))
        });
    }
    // The loop alone, from a start prepared once per sample outside the
    // timing (quadrangulation and interpolation read M only: they run
    // beside the Fitmap in `convert`, so the loop is the stage's own
    // time), on bunny and on gargoyle, one thread.
    let gargoyle = load_data_mesh("gargoyle.ply").map(|m| {
        let caster = pool
            .install(|| make_raycaster(RayBackend::Embree, &m))
            .unwrap();
        let fitmap = pool
            .install(|| compute_fitmap(&m, caster.as_ref(), &opts))
            .unwrap();
        (m, caster, fitmap)
    });
    let so = SimplifyOptions::default();
    g.bench_function("simplify_loop_1thread", |b| {
        b.iter_batched(
            || prepare(&mesh).unwrap(),
            |start| {
                pool.install(|| {
                    simplify_prepared(&mesh, &fitmap, caster.as_ref(), &so, start, &mut |_| true)
                        .unwrap()
                })
            },
            BatchSize::PerIteration,
        )
    });
    g.finish();
    if let Some((m, caster, fitmap)) = &gargoyle {
        let mut g = c.benchmark_group("gargoyle");
        g.bench_function("simplify_loop_1thread", |b| {
            b.iter_batched(
                || prepare(m).unwrap(),
                |start| {
                    pool.install(|| {
                        simplify_prepared(m, fitmap, caster.as_ref(), &so, start, &mut |_| true)
                            .unwrap()
                    })
                },
                BatchSize::PerIteration,
            )
        });
        g.finish();
    }
    c.final_summary();
}
