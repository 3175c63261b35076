//! `FieldOptions::with_natural_adaptivity` (`SUBDFIT_FIELD_ADAPT=1` on
//! `convert` at the natural size, issue 40's adaptivity): on a sphere
//! whose S-fitmap rises along one axis, with per-vertex noise as a scan's
//! Fitmap has, the same lattice's patches get smaller where F_S is higher.

mod common;

use subdfit::analysis::{spearman, Fitmap};
use subdfit::mesh::{ControlMesh, TriMesh};
use subdfit::quad::field::{
    control_topology, field_layout, field_layout_counted_following, field_layout_refined_following,
    lay_near_count, sizing, FieldOptions, Follow, Prepared, Surface, COUNT_WINDOW,
};
use subdfit::DVec3;

/// The S-fitmap's trend: F_S = e^{K x} on the unit sphere (e = 2.7× from
/// pole to pole, about twice the p90/p10 spread of 1/F_S the bunny and
/// the gargoyle have at τ 1 %).
const K: f64 = 0.5;

/// F_S = e^{K x} times a fixed per-vertex hash factor in [0.8, 1.2] (a
/// scan's F_S is noisy from vertex to vertex: the minimum grading turns
/// each low value into a cone); F_M = 0.1 everywhere, so that the
/// S-fitmap sizes (√2 κ / F_S, κ from [`subdfit::quad::s_fitmap_kappa`])
/// are 0.1–0.3 (300-odd patches) and F_M (β √2 F_M = 0.31) bounds only
/// the largest few.
fn rising_fitmap(m: &TriMesh) -> Fitmap {
    let s = m
        .positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let h = (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40;
            let noise = 0.8 + 0.4 * h as f64 / (1u64 << 24) as f64;
            (K * p.x).exp() * noise
        })
        .collect();
    let n = m.positions.len();
    Fitmap {
        radii: vec![0.01, 1.0],
        s,
        m: vec![0.1; n],
        m_step: vec![1; n],
        tolerance: 0.01,
        stats: Default::default(),
    }
}

/// The rounds' setting on the sphere: its rising S-fitmap, natural
/// adaptivity, and the first layout's graded sizing to follow.
struct Graded {
    m: TriMesh,
    fitmap: Fitmap,
    opts: FieldOptions,
    surf: Surface,
    prep: Prepared,
    follow: Follow,
}

fn graded_sphere() -> Graded {
    let m = common::icosphere(5, DVec3::ZERO, 1.0);
    let fitmap = rising_fitmap(&m);
    let opts = FieldOptions::default().with_natural_adaptivity();
    let surf = Surface::new(&m).unwrap();
    let prep = Prepared::new(&m, &opts).unwrap();
    let (base, alpha, ..) = sizing::sizing_for(&surf, &m, &fitmap, &opts).unwrap();
    let follow = Follow { base, alpha };
    Graded {
        m,
        fitmap,
        opts,
        surf,
        prep,
        follow,
    }
}

/// Spearman's ρ between each patch's radius (centre to farthest corner)
/// and the trend's size e^{−K x} at its centre.
fn rho_trend(k: &ControlMesh) -> f64 {
    let (mut r, mut size) = (Vec::new(), Vec::new());
    for f in k.faces() {
        let q: Vec<DVec3> = k.face_vertices(f).map(|v| k.position(v)).collect();
        let c = q.iter().copied().sum::<DVec3>() / q.len() as f64;
        r.push(q.iter().map(|p| (*p - c).length()).fold(0.0, f64::max));
        size.push((-K * c.x).exp());
    }
    spearman(&r, &size).unwrap()
}

#[test]
fn natural_adaptivity_makes_patches_follow_the_s_fitmap() {
    let m = common::icosphere(5, DVec3::ZERO, 1.0);
    let fitmap = rising_fitmap(&m);
    let topology = Surface::new(&m).unwrap().topology;
    let rho = |opts: &FieldOptions| {
        let laid = field_layout(&m, &fitmap, opts).unwrap();
        assert_eq!(control_topology(&laid.control), topology);
        let rho = sizing::adaptivity_spearman(&m, &fitmap, &laid.control)
            .unwrap()
            .unwrap();
        (rho, rho_trend(&laid.control), laid.control.num_faces())
    };
    let (before, trend0, n0) = rho(&FieldOptions::default());
    let (after, trend1, n1) = rho(&FieldOptions::default().with_natural_adaptivity());
    eprintln!(
        "Spearman(radius, 1/F_S) {before:.3} → {after:.3}, (radius, e^-Kx) {trend0:.3} → {trend1:.3}, patches {n0} → {n1}"
    );
    // The sphere is closed: the same minimum grading, the same lattice
    // (count and topology), only its points moved by the relaxation.
    assert_eq!(n0, n1);
    // The radii fall where F_S rises, and follow it more closely than the
    // lattice laid at the graded sizes does (measured: ρ 0.535 → 0.606,
    // against the trend 0.529 → 0.607; the bounds ask for about half the
    // gain, so the relaxation must still do its work, and for ρ against
    // the trend well above the default's).
    assert!(after > before + 0.03, "ρ {before:.3} → {after:.3}");
    assert!(trend1 > trend0 + 0.03, "trend {trend0:.3} → {trend1:.3}");
    assert!(trend1 > 0.56, "trend {trend1:.3}");
}

/// Through `--max-error`'s rounds (`SUBDFIT_FIELD_ADAPT=1`, issue 40's
/// adaptivity at the default `--max-error`): a round's sizing is the first
/// layout's times local factors (a refined region); its lattice must keep
/// following the S-fitmap, which it does only when the sized relaxation
/// follows the round's sizing ([`Follow`]).
#[test]
fn rounds_keep_the_grading_when_the_relaxation_follows_their_sizing() {
    let Graded {
        m,
        fitmap,
        opts,
        surf,
        prep,
        follow,
    } = graded_sphere();
    let base = &follow.base;
    let rho = |c: &subdfit::mesh::ControlMesh| {
        assert_eq!(control_topology(c), surf.topology);
        sizing::adaptivity_spearman(&m, &fitmap, c)
            .unwrap()
            .unwrap()
    };
    let first = field_layout(&m, &fitmap, &opts).unwrap();
    // A refinement round: h × 0.7 (`UNPROJECTABLE_REFINE`) on a cap across
    // the trend (y > 0.5, as the patches of a projectability miss), graded
    // again at the options' γ.
    let mut h: Vec<f64> = base
        .iter()
        .zip(&m.positions)
        .map(|(h, p)| if p.y > 0.5 { 0.7 * h } else { *h })
        .collect();
    sizing::grade(&surf, &mut h, opts.gradation);
    let plain = field_layout_refined_following(&prep, &m, &fitmap, &h, &opts, None).unwrap();
    let kept =
        field_layout_refined_following(&prep, &m, &fitmap, &h, &opts, Some(&follow)).unwrap();
    let r = [&first, &plain, &kept].map(|l| rho(&l.control));
    let f = [&first, &plain, &kept].map(|l| l.control.num_faces());
    eprintln!("ρ first / round / round following: {r:.3?}, patches {f:?}");
    // Same lattice (the relaxation moves points only).
    assert_eq!(f[1], f[2]);
    // Measured: ρ 0.606 on the first layout, 0.433 on the refined round
    // without the following relaxation (its lattice follows the graded,
    // refined sizing only), 0.506 with it. The round must keep ρ within
    // 0.12 of the first layout's (0.17 lost without) and gain over the
    // plain round by more than the run-to-run noise of a lattice.
    assert!(r[2] > r[1] + 0.03, "ρ {r:.3?}");
    assert!(r[2] > r[0] - 0.12, "ρ {r:.3?}");
}

/// The `--max-error` bracket's layout under the switch (a kept round's
/// sizing scaled towards fewer patches, no `--faces` trim) lands within
/// twice [`COUNT_WINDOW`] of the count it aims at: [`lay_near_count`] from the
/// first layout's sizing on the sphere, aimed at 70 % and 85 % of its
/// patches (the bracket's counts lie 6–40 % under the kept round's). The
/// one-shot √(kept / n) scale it replaces landed 1.5× off its aim on the
/// bunny (docs/status.md, session 17).
#[test]
fn the_bracket_lands_near_the_count_it_aims_at() {
    let Graded {
        m,
        fitmap,
        opts,
        surf,
        prep,
        follow,
    } = graded_sphere();
    let base = &follow.base;
    let mut laid = 0;
    let mut lay = |s: f64| {
        laid += 1;
        let h: Vec<f64> = base.iter().map(|x| x * s).collect();
        field_layout_counted_following(&prep, &m, &fitmap, h, &opts, &follow)
    };
    let kept = lay(1.0).unwrap().control.num_faces();
    for share in [0.70, 0.85] {
        let n = (share * kept as f64).round() as usize;
        let (l, s) = lay_near_count(&mut lay, (1.0, kept), n, 4)
            .unwrap()
            .expect("passes > 0");
        let got = l.control.num_faces();
        eprintln!("kept {kept}, aimed {n}, landed {got} at s {s:.3}");
        assert_eq!(control_topology(&l.control), surf.topology);
        // Fewer patches at a larger scale, within the window.
        assert!(s > 1.0, "s {s}");
        // The search stops inside COUNT_WINDOW or after its 4 lays at the
        // nearest count laid; a lattice's count moves in steps with the
        // scale, so the last lay can sit just outside the window
        // (measured: aimed 223, landed 210, 5.8 %). Twice the window still
        // fails the one-shot scale's 1.5× misses.
        let off = (got as f64 - n as f64).abs() / n as f64;
        assert!(off <= 2.0 * COUNT_WINDOW, "aimed {n}, landed {got}");
    }
    assert!(laid <= 9, "{laid} layouts");
}
