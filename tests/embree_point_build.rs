//! A scene asked only for closest points may be built at a cheaper Embree
//! build quality (`EmbreeCaster::for_points`, used for D, L's tessellation
//! and the fit's sample grids): the bridge keeps the least (distance,
//! triangle id) over every triangle within a radius that only shrinks to a
//! conservative bound of the best distance so far, so the answer is the
//! same whatever tree Embree builds. These tests pin that, bit for bit, on
//! meshes full of ties (duplicate triangles, points at shared vertices and
//! on shared edges, two sheets a hair apart) and on random points.

mod common;

use common::*;
use subdfit::mesh::TriMesh;
use subdfit::raycast::embree::{BuildQuality, EmbreeCaster};
use subdfit::raycast::{ClosestPoint, RayCaster};
use subdfit::DVec3;

/// A torus, two close copies of a bumpy sheet (one shifted by 1e-4 of
/// its size, so most points have two near candidates) and every triangle
/// of a flat grid twice (exact ties of distance between two ids).
fn tie_mesh() -> TriMesh {
    let mut mesh = perturbed_torus(40, 24, 1.0, 0.3, 0.01);
    let mut add = |m: &TriMesh, shift: DVec3| {
        let base = mesh.positions.len() as u32;
        mesh.positions
            .extend(m.positions.iter().map(|&p| p + shift));
        mesh.triangles
            .extend(m.triangles.iter().map(|t| t.map(|i| i + base)));
    };
    let mut grid = flat_grid(30);
    for p in &mut grid.positions {
        *p *= 0.1;
    }
    let mut bumpy = grid.clone();
    for p in &mut bumpy.positions {
        p.z = 0.05 * (7.0 * p.x).sin() * (5.0 * p.y).cos();
    }
    add(&bumpy, DVec3::new(0.0, 0.0, 1.5));
    add(&bumpy, DVec3::new(0.0, 0.0, 1.5 + 1e-4));
    let twice = TriMesh {
        positions: grid.positions.clone(),
        triangles: grid.triangles.iter().flat_map(|&t| [t, t]).collect(),
    };
    add(&twice, DVec3::new(0.0, 0.0, -1.5));
    mesh
}

/// Random points around the mesh, every vertex (distance 0 to all its
/// triangles) and every triangle's edge midpoints.
fn query_points(mesh: &TriMesh) -> Vec<DVec3> {
    let mut rng = seeded_rng(23);
    let mut pts: Vec<DVec3> = (0..4000)
        .map(|_| random_point_in_bbox(&mut rng, mesh, 0.2))
        .collect();
    pts.extend(mesh.positions.iter().copied());
    for t in mesh.triangles.iter().step_by(3) {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        pts.extend([0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)]);
    }
    pts
}

fn bits(c: &Option<ClosestPoint>) -> Option<(u32, [u64; 3], u64, u64, u64)> {
    c.map(|c| {
        (
            c.triangle,
            c.point.to_array().map(f64::to_bits),
            c.distance.to_bits(),
            c.u.to_bits(),
            c.v.to_bits(),
        )
    })
}

#[test]
fn every_build_quality_gives_the_same_closest_points_bit_for_bit() {
    let mesh = tie_mesh();
    let pts = query_points(&mesh);
    let high = EmbreeCaster::with_quality(&mesh, BuildQuality::High).unwrap();
    let want = high.closest_points(&pts, f64::INFINITY).unwrap();
    // The answers are the nearest triangles (a brute-force scan agrees on
    // the distance), so the comparison below is between right answers.
    for (p, c) in pts.iter().zip(&want).step_by(97) {
        let c = c.expect("an infinite radius always finds a triangle");
        let brute = mesh
            .triangles
            .iter()
            .enumerate()
            .map(|(t, _)| {
                let [a, b, cc] = mesh.triangle(t);
                common::point_triangle_distance(*p, a, b, cc)
            })
            .fold(f64::INFINITY, f64::min);
        assert!(
            (c.distance - brute).abs() <= 1e-12 * (1.0 + brute),
            "{p:?}: {} vs brute force {brute}",
            c.distance
        );
    }
    // Exact ties exist: of two copies of a triangle the first (smaller
    // id) is the answer.
    let twice_from = (mesh.triangles.len() - 2 * 2 * 30 * 30) as u32;
    let on_twice: Vec<u32> = want
        .iter()
        .flatten()
        .filter(|c| c.triangle >= twice_from)
        .map(|c| c.triangle - twice_from)
        .collect();
    assert!(
        on_twice.len() > 100,
        "only {} answers on the doubled grid",
        on_twice.len()
    );
    assert!(
        on_twice.iter().all(|t| t % 2 == 0),
        "a second copy won a tie"
    );
    let bounded: Vec<f64> = (0..pts.len()).map(|i| 0.02 * (i % 7) as f64).collect();
    let want_within = high.closest_points_within(&pts, &bounded).unwrap();
    for q in [BuildQuality::Low, BuildQuality::Medium] {
        let other = EmbreeCaster::with_quality(&mesh, q).unwrap();
        let got = other.closest_points(&pts, f64::INFINITY).unwrap();
        let differ = want
            .iter()
            .zip(&got)
            .filter(|(a, b)| bits(a) != bits(b))
            .count();
        assert_eq!(differ, 0, "{q:?}: {differ} of {} answers differ", pts.len());
        let got = other.closest_points_within(&pts, &bounded).unwrap();
        assert!(
            want_within
                .iter()
                .zip(&got)
                .all(|(a, b)| bits(a) == bits(b)),
            "{q:?}: bounded answers differ"
        );
    }
    // The point-query constructor is one of these qualities.
    let points = EmbreeCaster::for_points(&mesh).unwrap();
    let got = points.closest_points(&pts, f64::INFINITY).unwrap();
    assert!(want.iter().zip(&got).all(|(a, b)| bits(a) == bits(b)));
}
