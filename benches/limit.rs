//! Limit evaluations per second on regular faces and on faces next to
//! extraordinary vertices, for both backends (OpenSubdiv at its default
//! isolation level 10; a call includes its per-call refinement of the
//! control points, so batches are what is measured).
//!
//! Mesh: the valence-6 polar sphere refined twice (~2300 quads; valence-6
//! poles and valence-3 corners, i.e. both kinds of faces).

use std::time::Duration;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use subdfit::fixtures;
use subdfit::mesh::{ControlMesh, FaceId};
use subdfit::subdiv::refine::refine_uniform;
use subdfit::subdiv::{make_evaluator, Backend, EvalOptions, SurfaceLocation};

const BACKENDS: &[Backend] = &[Backend::Rust, Backend::Osd];
const LOCATIONS: usize = 20_000;

/// Faces whose corners are all interior valence-4 vertices with all-quad
/// neighbours (regular), and faces with an extraordinary corner.
fn split_faces(m: &ControlMesh) -> (Vec<FaceId>, Vec<FaceId>) {
    let regular_vertex = |v| {
        !m.is_boundary_vertex(v)
            && m.valence(v) == 4
            && m.vertex_faces(v).all(|f| m.face_size(f) == 4)
    };
    m.faces().partition(|&f| {
        m.face_vertices(f)
            .all(|v| regular_vertex(v) && m.outgoing(v).all(|h| regular_vertex(m.head(h))))
    })
}

fn locations(faces: &[FaceId], seed: u64) -> Vec<SurfaceLocation> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..LOCATIONS)
        .map(|i| SurfaceLocation::quad(faces[i % faces.len()], rng.gen(), rng.gen()))
        .collect()
}

fn bench_limit(c: &mut Criterion) {
    let mesh = refine_uniform(&fixtures::polar_sphere(6, 1), 2).expect("refines");
    let (regular, irregular) = split_faces(&mesh);
    let cases = [
        ("regular", locations(&regular, 1)),
        ("extraordinary", locations(&irregular, 2)),
    ];
    let mut group = c.benchmark_group("limit_evaluate");
    group
        .measurement_time(Duration::from_secs(3))
        .warm_up_time(Duration::from_secs(1))
        .sample_size(10)
        .throughput(Throughput::Elements(LOCATIONS as u64));
    for &backend in BACKENDS {
        let ev = make_evaluator(backend, &mesh, &EvalOptions::default()).expect("evaluator");
        for (name, locs) in &cases {
            group.bench_with_input(
                BenchmarkId::new(format!("{backend:?}"), name),
                locs,
                |b, locs| b.iter(|| ev.evaluate(mesh.positions(), locs).expect("evaluates")),
            );
        }
        group.bench_with_input(
            BenchmarkId::new(format!("{backend:?}"), "stencils_extraordinary"),
            &cases[1].1,
            |b, locs| b.iter(|| ev.stencils(locs).expect("stencils")),
        );
    }
    group.finish();
}

criterion_group!(benches, bench_limit);
criterion_main!(benches);
