//! The field layout's adaptivity on real scans (issue 40's acceptance):
//! at τ = 1 % and the default sizing, Spearman's ρ between each patch's
//! radius and 1/F_S at its centre is at least 0.6 on the bunny and the
//! gargoyle, as the greedy layout's own adaptivity figure is. Needs
//! `../shared/data` (skipped with a message when it is absent); ~40 s per
//! mesh in release on a loaded machine (the Fitmap dominates), so both are
//! ignored by default and run by `bench/adaptivity.sh`. Not met (see the
//! ignore reasons). Measured 2026-12-05 with the repaired lattice (one
//! local round on the bunny): bunny ρ 0.33 at 465 patches, gargoyle 0.22
//! at 898 (the 0.52 of session 5 was the fallback lattice's). Why, from
//! in-process diagnostics (docs/status.md, "Field-aligned layout",
//! 2026-12-05 adaptivity): 1/F_S spans only 1.46× from its 10th to its
//! 90th percentile at the patch centres, so the lattice's own spread of
//! radii at a given size decides the ranks. On the gargoyle a sizing that
//! follows F_S at ρ 0.90–0.97 (grading at γ = 0.5, 1 or none, the count
//! kept) is realised at ρ(radius, h) 0.14–0.26, and F_S smoothed towards
//! the patch scale keeps only ρ(h, 1/F_S) 0.65–0.76. On the bunny the
//! holes' caps, spread at γ, set 99 % of the sizes (ρ(h, 1/F_S) 0.61 over
//! the vertices, 0.86 with the caps spread at 2γ); spread at 2γ
//! (`FieldOptions::loop_cap_slope`, off) ρ is 0.44 at 433 patches but
//! RMS L 2.29 → 3.92‰ and 1.3 % unprojectable.
//! 2026-12-06: the extraction's relaxation weighted by the lattice
//! spacing (`FIELD_RELAX=sized:3:12`, off by default) makes the gargoyle's
//! radii follow h at ρ 0.75 (uniform 0.42) and ρ 0.55 (0.58 with γ = 1,
//! count kept), capped by h following 1/F_S at only 0.64–0.66 at the
//! centres; the bunny stays at 0.33 (h follows its holes' caps), and its
//! RMS L rises 17 %, so the default and these tests' figures are unchanged.
//! 2026-12-06 (session 13): relaxed after the extraction towards the
//! Fitmap's sizes without the holes' caps (`FIELD_SIZED_RELAX=6:12:inf:g`,
//! off by default): gargoyle ρ 0.60, bunny 0.54, but the bunny's RMS L
//! +27 % and homer 272's ×2.5, so again unchanged.
//! 2026-12-06 (session 16): `FieldOptions::with_natural_adaptivity`
//! (`SUBDFIT_FIELD_ADAPT=1` on `convert`, natural size only, so no
//! `--faces` case changes) meets the bar on both: bunny 0.644 at 445
//! patches, gargoyle 0.617 at 906 (last test below); the default and
//! the two tests above are unchanged.

use std::path::Path;

use subdfit::analysis::{compute_fitmap, FitmapOptions};
use subdfit::mesh::Frame;
use subdfit::quad::field::{control_topology, field_layout, sizing, FieldOptions, Surface};
use subdfit::raycast::{make_raycaster, RayBackend};

/// The field layout of `name` from ../shared/data at τ = 1 % in the
/// pipeline's working frame: ρ, patches, and whether M's topology was kept.
fn spearman_of(name: &str) -> Option<(f64, usize, bool)> {
    spearman_with(name, &FieldOptions::default())
}

/// [`spearman_of`] with `opts`.
fn spearman_with(name: &str, opts: &FieldOptions) -> Option<(f64, usize, bool)> {
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
    let laid = field_layout(&mesh, &fitmap, opts).unwrap();
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
#[ignore = "slow (~40 s release, the bunny's Fitmap; bench/adaptivity.sh runs it) and not met: measured ρ = 0.33 at 465 patches (holes' caps at 2γ: 0.44 at 433, RMS L +71 %); docs/status.md, Field-aligned layout"]
fn bunny_patch_radius_follows_the_s_fitmap() {
    let Some((rho, faces, kept)) = spearman_of("bunny") else {
        return;
    };
    eprintln!("bunny: {faces} patches, Spearman(radius, 1/F_S) = {rho:.3}");
    assert!(kept, "the bunny's topology was not kept");
    assert!(rho >= 0.6, "Spearman(radius, 1/F_S) = {rho:.3} < 0.6");
}

/// The same bar on the gargoyle (closed, no holes: its sizes are F_S's and
/// F_M's, graded at γ).
#[test]
#[ignore = "slow (~40 s release, the gargoyle's Fitmap; bench/adaptivity.sh runs it) and not met: measured ρ = 0.22 at 898 patches (γ = 1, count kept: 0.24; sizing ungraded: 0.21); docs/status.md, Field-aligned layout"]
fn gargoyle_patch_radius_follows_the_s_fitmap() {
    let Some((rho, faces, kept)) = spearman_of("gargoyle") else {
        return;
    };
    eprintln!("gargoyle: {faces} patches, Spearman(radius, 1/F_S) = {rho:.3}");
    assert!(kept, "the gargoyle's topology was not kept");
    assert!(rho >= 0.6, "Spearman(radius, 1/F_S) = {rho:.3} < 0.6");
}

/// The same bar with `FieldOptions::with_natural_adaptivity`
/// (`SUBDFIT_FIELD_ADAPT=1` on `convert` at the natural size; session 16,
/// measured ρ 0.644 on the bunny at 445 patches, 0.617 on the gargoyle at
/// 906).
#[test]
#[ignore = "slow (two Fitmaps, ~80 s release; bench/adaptivity.sh runs it)"]
fn natural_adaptivity_meets_the_bar_on_bunny_and_gargoyle() {
    for name in ["bunny", "gargoyle"] {
        let opts = FieldOptions::default().with_natural_adaptivity();
        let Some((rho, faces, kept)) = spearman_with(name, &opts) else {
            return;
        };
        eprintln!(
            "{name} (natural adaptivity): {faces} patches, Spearman(radius, 1/F_S) = {rho:.3}"
        );
        assert!(kept, "the {name}'s topology was not kept");
        assert!(
            rho >= 0.6,
            "{name}: Spearman(radius, 1/F_S) = {rho:.3} < 0.6"
        );
    }
}
