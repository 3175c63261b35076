//! The field layout's adaptivity on a real scan (issue 40's acceptance):
//! at τ = 1 % and the default sizing, Spearman's ρ between each patch's
//! radius and 1/F_S at its centre is at least 0.6 on the bunny, as the
//! greedy layout's own adaptivity figure is. Needs `../shared/data`
//! (skipped with a message when it is absent); ~40 s in release on a
//! loaded machine (the Fitmap dominates), so it is ignored by default and
//! run by `bench/adaptivity.sh`. Not met yet at the default sizing (see
//! the ignore reason). Measured on the bunny (2026-12-05): the patches
//! follow the sizing field (Spearman(radius, h at the centre) 0.87–0.92),
//! but the sizing itself follows F_S only at ρ 0.51 at the patch centres:
//! the grading at γ = 0.25 lowers 99 % of the vertices below their own
//! limits; γ = 1 keeps F_S (ρ 0.67) but tears the lattice at the bunny's
//! holes (four global refinements, 1251 patches).

use std::path::Path;

use subdfit::analysis::{compute_fitmap, FitmapOptions};
use subdfit::mesh::Frame;
use subdfit::quad::field::{control_topology, field_layout, sizing, FieldOptions, Surface};
use subdfit::raycast::{make_raycaster, RayBackend};

/// The field layout of `name` from ../shared/data at τ = 1 % in the
/// pipeline's working frame: ρ, patches, and whether M's topology was kept.
fn spearman_of(name: &str) -> Option<(f64, usize, bool)> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data")
        .join(format!("{name}.ply"));
    if !path.exists() {
        eprintln!("skipped: {} not found", path.display());
        return None;
    }
    let input = subdfit::io::read_mesh(&path).unwrap();
    let (lo, hi) = input.mesh.bbox();
    let mut mesh = input.mesh.clone();
    Frame::of_bbox(lo, hi).points_to_unit(&mut mesh.positions);
    let caster = make_raycaster(RayBackend::Embree, &mesh).unwrap();
    let fitmap = compute_fitmap(
        &mesh,
        caster.as_ref(),
        &FitmapOptions::default().with_tolerance(0.01),
    )
    .unwrap();
    let laid = field_layout(&mesh, &fitmap, &FieldOptions::default()).unwrap();
    let rho = sizing::adaptivity_spearman(&mesh, &fitmap, &laid.control)
        .unwrap()
        .expect("patches with an F_S");
    let kept = control_topology(&laid.control) == Surface::new(&mesh).unwrap().topology;
    Some((rho, laid.control.num_faces(), kept))
}

/// 0.6 is issue 40's bar: the patch sizes follow the S-fitmap's radii
/// (the sizing h ∝ 1/F_S where F_M does not cap it), with the grading and
/// the lattice's rounding to whole cells as the only noise.
#[test]
#[ignore = "slow (~40 s release, the bunny's Fitmap; bench/adaptivity.sh runs it) and not met yet: measured ρ = 0.52 at 511 patches (γ = 0.5: 0.55, γ = 1: 0.64 at 1251, β = 3: 0.37); docs/status.md, Field-aligned layout"]
fn bunny_patch_radius_follows_the_s_fitmap() {
    let Some((rho, faces, kept)) = spearman_of("bunny") else {
        return;
    };
    eprintln!("bunny: {faces} patches, Spearman(radius, 1/F_S) = {rho:.3}");
    assert!(kept, "the bunny's topology was not kept");
    assert!(rho >= 0.6, "Spearman(radius, 1/F_S) = {rho:.3} < 0.6");
}
