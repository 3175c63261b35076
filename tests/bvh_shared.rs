//! `BvhCaster::shared` (session 20): the field layout's extractions and
//! cleanups and the convert layer's patch errors share one BVH of M (or M′)
//! instead of building it again each time. Exact only if the shared tree
//! answers every query as a fresh build of the same mesh does, bit for bit,
//! and a mesh that differs (one vertex moved) never gets another mesh's
//! tree; both are asserted here on a folded surface, so that the queries
//! see many candidate triangles.

use subdfit::mesh::TriMesh;
use subdfit::raycast::bvh::BvhCaster;
use subdfit::raycast::{ClosestPoint, Hit, Ray, RayCaster};
use subdfit::DVec3;

/// A 30 × 30 grid folded by a sine in z (queries from above and below cross
/// it several times).
fn folded(lift: f64) -> TriMesh {
    subdfit::fixtures::tri_grid(
        30,
        |i, j| {
            let (x, y) = (i as f64 / 30.0, j as f64 / 30.0);
            DVec3::new(x, y, lift * (7.0 * x).sin() * (5.0 * y).cos())
        },
        |_, _| true,
    )
}

/// Query points and rays spread over and around the grid.
fn queries() -> (Vec<DVec3>, Vec<Ray>) {
    let points: Vec<DVec3> = (0..400)
        .map(|i| {
            let t = i as f64;
            DVec3::new(
                (t * 0.0137) % 1.2 - 0.1,
                (t * 0.0291) % 1.2 - 0.1,
                0.4 * (t * 0.11).sin(),
            )
        })
        .collect();
    let rays = points
        .iter()
        .enumerate()
        .map(|(i, &p)| Ray {
            origin: p + DVec3::new(0.0, 0.0, 1.0),
            dir: DVec3::new(0.05 * (i as f64).cos(), 0.05 * (i as f64).sin(), -1.0).normalize(),
            tmin: 0.0,
            tmax: f64::INFINITY,
        })
        .collect();
    (points, rays)
}

/// Every answer of `c` to [`queries`], as bits.
#[allow(clippy::type_complexity)]
fn answers(c: &dyn RayCaster) -> (Vec<Option<([u64; 3], u64, u32)>>, Vec<Option<(u64, u32)>>) {
    let (points, rays) = queries();
    let closest = c.closest_points(&points, f64::INFINITY).expect("closest");
    let hits = c.first_hits(&rays).expect("hits");
    let cp = |c: &Option<ClosestPoint>| {
        c.as_ref().map(|c| {
            (
                c.point.to_array().map(f64::to_bits),
                c.distance.to_bits(),
                c.triangle,
            )
        })
    };
    let hit = |h: &Option<Hit>| h.as_ref().map(|h| (h.t.to_bits(), h.triangle));
    (
        closest.iter().map(cp).collect(),
        hits.iter().map(hit).collect(),
    )
}

#[test]
fn the_shared_tree_answers_as_a_fresh_build_of_the_same_mesh() {
    let mesh = folded(0.2);
    let fresh = answers(&BvhCaster::new(&mesh).expect("build"));
    // Some queries hit and some miss, so the comparison can fail.
    assert!(fresh.1.iter().any(Option::is_some) && fresh.1.iter().any(Option::is_none));
    let first = BvhCaster::shared(&mesh).expect("shared");
    let again = BvhCaster::shared(&mesh.clone()).expect("shared again");
    assert_eq!(answers(&*first), fresh);
    assert_eq!(answers(&*again), fresh);

    // One vertex moved: the moved mesh's own tree, not the cached one.
    let mut moved = mesh.clone();
    moved.positions[15 * 31 + 15].z += 0.3;
    let moved_fresh = answers(&BvhCaster::new(&moved).expect("build moved"));
    assert_ne!(moved_fresh, fresh, "the moved vertex changes some answer");
    assert_eq!(
        answers(&*BvhCaster::shared(&moved).expect("shared moved")),
        moved_fresh
    );
    // A mesh of other positions everywhere, then the first again.
    let other = folded(0.25);
    assert_eq!(
        answers(&*BvhCaster::shared(&other).expect("shared other")),
        answers(&BvhCaster::new(&other).expect("build other"))
    );
    assert_eq!(
        answers(&*BvhCaster::shared(&mesh).expect("shared once more")),
        fresh
    );
}

/// Shared across threads (the draws are laid side by side): every thread
/// gets a tree answering as a fresh build does.
#[test]
fn the_shared_tree_is_the_same_from_every_thread() {
    let mesh = folded(0.15);
    let fresh = answers(&BvhCaster::new(&mesh).expect("build"));
    let got: Vec<_> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..4)
            .map(|_| s.spawn(|| answers(&*BvhCaster::shared(&mesh).expect("shared"))))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("thread"))
            .collect()
    });
    assert!(got.iter().all(|a| *a == fresh));
}
