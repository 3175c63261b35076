//! `SUBDFIT_FIELD_FIT_ITERS` (issue 40, session 24): the field layout's
//! fits run more iterations. Its own test binary, since it sets the
//! process's environment.

mod fit_support;

use fit_support::*;
use subdfit::convert::field::{fit_iterations, FIT_ITERS_ENV};
use subdfit::fit::{fit, FitOptions};
use subdfit::raycast::{make_raycaster, RayBackend};

#[test]
fn more_field_fit_iterations_continue_the_same_fit_and_bring_the_limit_nearer_m() {
    std::env::remove_var(FIT_ITERS_ENV);
    let base = FitOptions::default();
    // Unset: the options as they were, on either layout.
    assert_eq!(fit_iterations(base.clone(), true), base);
    assert_eq!(fit_iterations(base.clone(), false), base);
    std::env::set_var(FIT_ITERS_ENV, "16");
    let more = fit_iterations(base.clone(), true);
    assert_eq!(more.max_iterations, 16);
    assert_eq!(more.clone().with_max_iterations(base.max_iterations), base);
    // The greedy layout's fit is not the switch's.
    assert_eq!(fit_iterations(base.clone(), false), base);
    std::env::set_var(FIT_ITERS_ENV, "0");
    assert_eq!(fit_iterations(base.clone(), true).max_iterations, 1);
    std::env::remove_var(FIT_ITERS_ENV);

    // A start far from M (the initial control mesh shrunk to 80 % and
    // twisted), so that eight iterations do not converge: the fit still
    // gains more than `min_improvement` per round at its eighth.
    let mesh = bumpy_sphere(4);
    let mut control = initial_control(&mesh);
    let start: Vec<_> = control
        .positions()
        .iter()
        .map(|p| {
            let (s, c) = (0.4 * p.z).sin_cos();
            0.8 * subdfit::DVec3::new(c * p.x - s * p.y, s * p.x + c * p.y, p.z)
        })
        .collect();
    control.set_positions(start).unwrap();
    let caster = make_raycaster(RayBackend::Embree, &mesh).unwrap();
    let eight = fit(&mesh, control.clone(), caster.as_ref(), &base).unwrap();
    assert_eq!(
        eight.report.best_iteration, base.max_iterations,
        "the fixture converged within 8 rounds: {:?}",
        eight.report.iterations
    );
    let longer = fit(&mesh, control, caster.as_ref(), &more).unwrap();
    // The same rounds first (a round's update does not read the bound),
    // then more of them; the kept iterate is never worse and, as the
    // eight-round fit was still improving, strictly better.
    let n = eight.report.iterations.len();
    assert_eq!(longer.report.iterations[..n], eight.report.iterations[..]);
    assert!(longer.report.iterations.len() > n);
    assert!(
        longer.report.final_rms_permille < eight.report.final_rms_permille,
        "{} vs {}",
        longer.report.final_rms_permille,
        eight.report.final_rms_permille
    );
    // Geometrically: M's vertices lie nearer the longer fit's limit
    // surface, measured by the metrics on a fine tessellation.
    let opts = subdfit::report::MetricsOptions::default()
        .with_displacement_res(Some(4))
        .with_tessellation_res(Some(9));
    let m_to_limit = |c: &subdfit::mesh::ControlMesh| {
        let s =
            subdfit::report::evaluate_surfaces(&mesh, c, caster.as_ref(), &opts, &mut |_, _| true)
                .unwrap();
        s.metrics.limit.mesh_to_surface.rms_permille
    };
    let (l8, l16) = (m_to_limit(&eight.control), m_to_limit(&longer.control));
    assert!(
        l16 < l8,
        "M → limit RMS {l16} ‰ after 16 rounds, {l8} ‰ after 8"
    );
}
