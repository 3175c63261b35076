//! Differential tests of the two `LimitEvaluator`s (OpenSubdiv and pure
//! Rust) on the procedural fixture collection: valences 3 to 8, open
//! boundaries, creases and corners, triangles and n-gons, several
//! components. Tolerances are relative to the bounding-box diagonal:
//! - control vertices: 1e-9 (both evaluate closed-form limit masks; the
//!   margin covers round-off of refinement at semi-sharp features); normals
//!   1e-5 rad: where a semi-sharp feature is still sharp at level 1,
//!   OpenSubdiv evaluates the vertex on its patches, and where the vertex is
//!   extraordinary once the feature runs out that is a Gregory end cap whose
//!   tangent plane is ~2e-6 rad off at isolation level 10;
//! - ≥ 10,000 random locations per mesh, OpenSubdiv at isolation level 10:
//!   1e-8 and 1e-6 rad wherever the location is ≥ 0.01 (in u or v) from an
//!   irregular corner — both are exact there (bicubic patches);
//! - nearer, OpenSubdiv's end caps approximate the limit: reported apart, and
//!   shown to shrink as the isolation level grows.
//!
//! Known deliberate differences (interior valence-2 vertices, darts,
//! OpenSubdiv's boundary tangent masks) are excluded and checked to be
//! reported.

use subdfit::fixtures;
use subdfit::subdiv::diff::{compare, near_irregular_locations, random_locations, DiffReport};
use subdfit::subdiv::{make_evaluator, Backend, EvalOptions};

fn run(name: &str, mesh: &subdfit::mesh::ControlMesh, level: u8, samples: usize) -> DiffReport {
    let opts = EvalOptions::default().with_isolation_level(level);
    let osd =
        make_evaluator(Backend::Osd, mesh, &opts).unwrap_or_else(|e| panic!("{name}: osd: {e}"));
    let rust =
        make_evaluator(Backend::Rust, mesh, &opts).unwrap_or_else(|e| panic!("{name}: rust: {e}"));
    let mut locs = random_locations(mesh, samples, 7);
    locs.extend(near_irregular_locations(mesh, 8, 0.01, 11));
    compare(mesh, osd.as_ref(), rust.as_ref(), &locs, 0.01)
        .unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn dump_on_failure(name: &str, mesh: &subdfit::mesh::ControlMesh, report: &DiffReport) {
    // Failing inputs go to target/ for replay with `subdfit diff-limit`.
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("limit_differential");
    let _ = std::fs::create_dir_all(&dir);
    let path = dir.join(format!("{name}.obj"));
    let _ = subdfit::io::write_control_obj(&path, mesh);
    eprintln!("{name}: {report}\n(mesh dumped to {})", path.display());
}

#[test]
fn evaluators_agree_on_fixture_collection() {
    let mut failures = Vec::new();
    for (name, mesh) in fixtures::collection() {
        mesh.validate().unwrap();
        let r = run(name, &mesh, 10, 10_000);
        println!("{name}: {r}");
        let ok = r.vertices.position <= 1e-9
            && r.vertices.normal <= 1e-5
            && r.regular.position <= 1e-8
            && r.regular.normal <= 1e-6
            && r.regular.count >= 5_000;
        if !ok {
            dump_on_failure(name, &mesh, &r);
            failures.push(name);
        }
    }
    assert!(failures.is_empty(), "evaluators disagree on {failures:?}");
}

#[test]
fn end_cap_error_shrinks_with_isolation_level() {
    for (name, mesh) in fixtures::collection() {
        let near: Vec<f64> = [2u8, 6, 10]
            .iter()
            .map(|&l| run(name, &mesh, l, 4_000).near_irregular.position)
            .collect();
        println!("{name}: near-irregular worst deviation at isolation 2/6/10: {near:?}");
        if near[0] > 1e-9 {
            assert!(
                near[2] < near[1] && near[1] < near[0],
                "{name}: {near:?} does not shrink with the isolation level"
            );
        }
        // Gregory end caps also parametrise the corner region differently,
        // so (u, v)-matched points differ more than the surfaces do; the
        // bound is loose on purpose, the trend is the point.
        assert!(
            near[2] < 1e-3,
            "{name}: end-cap deviation {} at level 10",
            near[2]
        );
    }
}

#[test]
fn known_differences_are_named() {
    let mut seen = [false; 2];
    for (name, mesh) in fixtures::collection() {
        let known = subdfit::subdiv::known_differences(&mesh);
        if known.is_empty() {
            continue;
        }
        let r = run(name, &mesh, 10, 1_000);
        assert_eq!(r.known_differences, known);
        if known.iter().any(|k| !k.normal_only) {
            // OpenSubdiv's mask moves the vertex elsewhere than the exact
            // limit: a real difference, not round-off (STACK-NOTES: 2e-3).
            assert!(r.known.position > 1e-6, "{name}: {r}");
            seen[0] = true;
        } else {
            assert!(r.known.normal > 1e-6, "{name}: {r}");
            assert!(r.vertices.position <= 1e-9, "{name}: {r}");
            seen[1] = true;
        }
    }
    assert_eq!(
        seen,
        [true, true],
        "the collection covers both kinds of known difference"
    );
}
