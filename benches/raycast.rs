//! Ray-casting throughput of both [`RayCaster`] backends on the Stanford
//! bunny (69,451 triangles): fitting-like short rays along ±normal from
//! points near the surface, incoherent rays, line (two-sided) queries and
//! closest-point queries. Runs in a one-thread rayon pool so the numbers are
//! per core (the STACK-NOTES Embree figures are per core too).
//!
//! `cargo bench --bench raycast`; skips with a message if the data is absent.

#[path = "../tests/common/mod.rs"]
mod common;

use std::time::{Duration, Instant};

use common::*;
use criterion::{BenchmarkId, Criterion, Throughput};
use rand::Rng;
use subdfit::raycast::{make_raycaster, Ray, RayBackend, RayCaster};
use subdfit::DVec3;

const N: usize = 50_000;

fn main() {
    let Some(mesh) = load_data_mesh("bunny.ply") else {
        return;
    };
    let diag = mesh.bbox_diagonal();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();

    let mut casters: Vec<Box<dyn RayCaster>> = Vec::new();
    for backend in [RayBackend::Rust, RayBackend::Embree] {
        let t0 = Instant::now();
        let rc = pool.install(|| make_raycaster(backend, &mesh)).unwrap();
        eprintln!(
            "build {:?} (1 thread): {:.1} ms",
            backend,
            t0.elapsed().as_secs_f64() * 1e3
        );
        casters.push(rc);
    }

    let mut rng = seeded_rng(42);
    let mut near_rays = Vec::with_capacity(N);
    let mut origins = Vec::with_capacity(N);
    let mut dirs = Vec::with_capacity(N);
    let mut near_points = Vec::with_capacity(N);
    for _ in 0..N {
        let (p, n) = random_surface_point(&mut rng, &mesh);
        let o = p + rng.gen_range(-0.005..0.005) * diag * n;
        let d = if rng.gen::<bool>() { n } else { -n };
        near_rays.push(Ray {
            tmax: 0.02 * diag,
            ..Ray::new(o, d)
        });
        origins.push(o);
        dirs.push(n);
        near_points.push(o);
    }
    let incoherent: Vec<Ray> = (0..N)
        .map(|_| {
            Ray::new(
                random_point_in_bbox(&mut rng, &mesh, 0.2),
                random_dir(&mut rng),
            )
        })
        .collect();
    let far_points: Vec<DVec3> = (0..N)
        .map(|_| random_point_in_bbox(&mut rng, &mesh, 0.2))
        .collect();

    let mut c = Criterion::default()
        .warm_up_time(Duration::from_millis(300))
        .measurement_time(Duration::from_secs(2))
        .sample_size(10)
        .configure_from_args();

    let mut g = c.benchmark_group("bunny");
    g.throughput(Throughput::Elements(N as u64));
    for rc in &casters {
        let name = rc.name();
        g.bench_function(BenchmarkId::new("normal_rays", name), |b| {
            b.iter(|| pool.install(|| rc.first_hits(&near_rays).unwrap()))
        });
        g.bench_function(BenchmarkId::new("incoherent_rays", name), |b| {
            b.iter(|| pool.install(|| rc.first_hits(&incoherent).unwrap()))
        });
        g.bench_function(BenchmarkId::new("line_hits", name), |b| {
            b.iter(|| pool.install(|| rc.line_hits(&origins, &dirs, 0.02 * diag).unwrap()))
        });
        g.bench_function(BenchmarkId::new("closest_near", name), |b| {
            b.iter(|| pool.install(|| rc.closest_points(&near_points, f64::INFINITY).unwrap()))
        });
        g.bench_function(BenchmarkId::new("closest_far", name), |b| {
            b.iter(|| pool.install(|| rc.closest_points(&far_points, f64::INFINITY).unwrap()))
        });
    }
    g.finish();
    c.final_summary();

    // Wall-clock numbers above are unreliable on a shared, oversubscribed
    // machine; queries per *CPU* second of the tracing thread are not
    // (Linux: /proc/thread-self/schedstat, first field = ns on CPU).
    eprintln!("\nper CPU-second of the tracing thread (best of 3):");
    for rc in &casters {
        let name = rc.name();
        let row = |what: &str, f: &(dyn Fn() + Sync)| {
            let best = (0..3)
                .map(|_| {
                    pool.install(|| {
                        let t0 = thread_cpu_ns();
                        f();
                        thread_cpu_ns() - t0
                    })
                })
                .min()
                .unwrap();
            eprintln!(
                "  {name:>6} {what:<16} {:>7.3} M/s",
                N as f64 / (best as f64 * 1e-9) / 1e6
            );
        };
        row("normal_rays", &|| drop(rc.first_hits(&near_rays).unwrap()));
        row("incoherent_rays", &|| {
            drop(rc.first_hits(&incoherent).unwrap())
        });
        row("line_hits", &|| {
            drop(rc.line_hits(&origins, &dirs, 0.02 * diag).unwrap())
        });
        row("closest_near", &|| {
            drop(rc.closest_points(&near_points, f64::INFINITY).unwrap())
        });
        row("closest_far", &|| {
            drop(rc.closest_points(&far_points, f64::INFINITY).unwrap())
        });
    }
}

/// CPU time of the calling thread in ns (0 where unavailable).
fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(0)
}
