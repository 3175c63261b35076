//! A fit stopped once its side of a bound is plain (`fit::fit_deciding`,
//! what the `--max-error` search runs) and resumed gives the fit an
//! uninterrupted run gives, bit for bit: on a closed mesh (one start) and
//! on an open one whose border loops move (two starts side by side).

mod fit_support;

use fit_support::*;
use subdfit::fit::{
    fit, fit_deciding, fit_deciding_with, Decide, FitOptions, Fitted, MeshFacts, Objective,
};
use subdfit::mesh::{ControlMesh, TriMesh};
use subdfit::raycast::{make_raycaster, RayBackend};

fn same_fit(a: &Fitted, b: &Fitted, what: &str) {
    assert_eq!(a.control.positions(), b.control.positions(), "{what}");
    assert_eq!(a.report.iterations, b.report.iterations, "{what}");
    assert_eq!(a.report.best_iteration, b.report.best_iteration, "{what}");
}

/// Pauses the fit of `control` at a bound between its first and last RMS
/// (an early pass) and at half its final RMS (an early miss, from round
/// 1), checks that each paused fit says so and stopped before the whole
/// fit's last round, then resumes each to the end.
fn pause_and_resume(mesh: &TriMesh, control: &ControlMesh) {
    let caster = make_raycaster(RayBackend::Embree, mesh).unwrap();
    let opts = FitOptions::default();
    let whole = fit(mesh, control.clone(), caster.as_ref(), &opts).unwrap();
    let (first, last) = (
        whole.report.initial_rms_permille,
        whole.report.final_rms_permille,
    );
    assert!(whole.report.iterations.len() > 2, "{:?}", whole.report);
    assert!(
        last < 0.9 * first,
        "the rounds lower the RMS: {first} → {last}"
    );
    for (bound, pass) in [(0.5 * (first + last), true), (0.5 * last, false)] {
        let decide = Some(Decide {
            bound_permille: bound,
        });
        let quiet = &mut |_: &str, _: f64| true;
        let (early, state) = fit_deciding(
            mesh,
            control.clone(),
            caster.as_ref(),
            &opts,
            quiet,
            (decide, None),
        )
        .unwrap();
        let state = state.expect("paused before the last round");
        assert!(
            early.report.iterations.len() < whole.report.iterations.len(),
            "bound {bound}: {} rounds of {}",
            early.report.iterations.len(),
            whole.report.iterations.len()
        );
        assert_eq!(
            early.report.final_rms_permille <= bound,
            pass,
            "bound {bound}: stopped at {}",
            early.report.final_rms_permille
        );
        // A pass is not a guess about the end: the whole fit passes too.
        assert_eq!(last <= bound, pass);
        let (resumed, rest) = fit_deciding(
            mesh,
            control.clone(),
            caster.as_ref(),
            &opts,
            quiet,
            (None, Some(state)),
        )
        .unwrap();
        assert!(rest.is_none());
        same_fit(&resumed, &whole, &format!("resumed from bound {bound}"));
    }
}

#[test]
fn closed_mesh_fit_resumes_to_the_uninterrupted_fit() {
    let mesh = bumpy_sphere(5);
    let control = initial_control(&bumpy_sphere(2));
    pause_and_resume(&mesh, &control);
}

#[test]
fn open_mesh_fit_with_two_starts_resumes_to_the_uninterrupted_fit() {
    // A square [0, 4]² and a control grid overhanging it: its border loops
    // move onto M's rim, so both starts run.
    let mesh = subdfit::fixtures::tri_grid(
        16,
        |i, j| {
            let (x, y) = (0.25 * i as f64, 0.25 * j as f64);
            subdfit::DVec3::new(x, y, 0.1 * (x * 1.3).sin() * (y * 0.9).cos())
        },
        |_, _| true,
    );
    let mut control = subdfit::fixtures::flat_grid(4, 4);
    for p in control.positions_mut() {
        *p = subdfit::DVec3::new(1.25 * p.x - 0.5, 1.25 * p.y - 0.5, 0.05);
    }
    pause_and_resume(&mesh, &control);
}

/// The `--max-error` search makes M's facts (rim, normals, curvatures)
/// once and fits every candidate with them (`fit_deciding_with`): each
/// candidate's fit must be the one a fit of its own gives, bit for bit,
/// whichever candidate came first and whether or not it made the SDM's
/// curvatures. Two control meshes of different topology on an open M (two
/// starts sharing one system), the point objective first (its last rounds
/// make the curvatures) then the SDM, and a paused fit resumed on them.
#[test]
fn fits_sharing_mesh_facts_are_the_fits_of_their_own() {
    let mesh = subdfit::fixtures::tri_grid(
        16,
        |i, j| {
            let (x, y) = (0.25 * i as f64, 0.25 * j as f64);
            subdfit::DVec3::new(x, y, 0.1 * (x * 1.3).sin() * (y * 0.9).cos())
        },
        |_, _| true,
    );
    let grid = |n: u32| {
        let mut c = subdfit::fixtures::flat_grid(n, n);
        let s = 5.0 / n as f64;
        for p in c.positions_mut() {
            *p = subdfit::DVec3::new(s * p.x - 0.5, s * p.y - 0.5, 0.05);
        }
        c
    };
    let caster = make_raycaster(RayBackend::Embree, &mesh).unwrap();
    let facts = MeshFacts::of(&mesh);
    let quiet = &mut |_: &str, _: f64| true;
    for objective in [Objective::Point, Objective::Sdm] {
        let opts = FitOptions::default().with_objective(objective);
        for n in [4, 3] {
            let control = grid(n);
            let own = fit(&mesh, control.clone(), caster.as_ref(), &opts).unwrap();
            let (shared, rest) = fit_deciding_with(
                &mesh,
                &facts,
                control.clone(),
                caster.as_ref(),
                &opts,
                quiet,
                (None, None),
            )
            .unwrap();
            assert!(rest.is_none());
            same_fit(&shared, &own, &format!("{objective:?}, {n}×{n} grid"));
            // Paused at a bound it passes after its first round, resumed.
            let bound = own.report.iterations[0].rms_permille * 1.01;
            let (_, state) = fit_deciding_with(
                &mesh,
                &facts,
                control.clone(),
                caster.as_ref(),
                &opts,
                quiet,
                (
                    Some(Decide {
                        bound_permille: bound,
                    }),
                    None,
                ),
            )
            .unwrap();
            let state = state.expect("paused after its first round");
            let (resumed, _) = fit_deciding_with(
                &mesh,
                &facts,
                control,
                caster.as_ref(),
                &opts,
                quiet,
                (None, Some(state)),
            )
            .unwrap();
            same_fit(&resumed, &own, &format!("{objective:?}, {n}×{n}, resumed"));
        }
    }
}
