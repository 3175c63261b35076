//! Quad/triangle refinement cost: topology + subdivision matrices to level
//! 3, stencils over the control vertices, and applying the matrices to
//! positions (what a fitting loop pays per iteration).

use criterion::{criterion_group, criterion_main, Criterion};
use subdfit::fixtures;
use subdfit::subdiv::QuadTriRefiner;

fn bench(c: &mut Criterion) {
    // An all-quad closed sphere with valence-3 and valence-8 vertices.
    let m = fixtures::polar_sphere(8, 1);
    let mut g = c.benchmark_group("quadtri");
    g.sample_size(10);
    g.bench_function("prepare_level3", |b| {
        b.iter(|| QuadTriRefiner::new(&m, 3).unwrap())
    });
    let r = QuadTriRefiner::new(&m, 3).unwrap();
    g.bench_function("stencils_level3", |b| b.iter(|| r.stencils(3)));
    g.bench_function("refine_positions_level3", |b| {
        b.iter(|| r.refine_positions(m.positions()).unwrap())
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
