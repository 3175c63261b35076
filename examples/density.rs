//! RMS D against the displacement samples, uniform and adaptive, for
//! `bench/density.sh`.
//!
//! `cargo run --release --example density -- MESH CONTROL.obj [MULT...]`
//! `cargo run --release --example density -- MESH displaced.ply` (only
//! the RMS distance from M to the file, ‰ of M's diagonal)
//!
//! For each multiple `m` of the default sample count (total samples ≈ M's
//! vertices, `subdfit::displace::auto_resolution`; default multiples 1 2
//! 4), evaluates the control mesh's displacement (least-squares offsets,
//! the default) twice: on the uniform grid `R = round((R₀ − 1)·√m) + 1`,
//! and per patch under a budget of `m` × M's vertices
//! (`--displacement-samples`, `subdfit::displace::allocate_resolutions`).
//! Prints one JSON line each: the samples, report.json's D (both
//! directions on the sample grid, ‰ of M's diagonal), and the RMS
//! distance from M to `displaced.ply` (the tessellation a host's bilinear
//! lookup of the written maps reproduces) measured from M's quadrature
//! points, as an independent harness does.

use std::time::Instant;

use subdfit::displace::auto_resolution;
use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::report::{distance_stats, evaluate_surfaces, quadrature_points, MetricsOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        args.len() >= 3,
        "usage: density MESH CONTROL.obj [MULTIPLE...]"
    );
    let input = subdfit::io::read_mesh(args[1].as_ref())?;
    if args[2].ends_with(".ply") {
        let s = subdfit::io::read_mesh(args[2].as_ref())?;
        let (mp, mw) = quadrature_points(&input.mesh);
        let dc = make_raycaster(RayBackend::Embree, &s.mesh)?;
        let st = distance_stats(&mp, &mw, dc.as_ref(), input.mesh.bbox_diagonal())?;
        println!(
            "{}",
            serde_json::json!({ "m_to_file": st.rms_permille, "max": st.max_permille })
        );
        return Ok(());
    }
    let control = subdfit::io::read_control_mesh(args[2].as_ref())?;
    let mults: Vec<f64> = if args.len() > 3 {
        args[3..]
            .iter()
            .map(|s| s.parse())
            .collect::<Result<_, _>>()?
    } else {
        vec![1.0, 2.0, 4.0]
    };
    let mesh = &input.mesh;
    let diag = mesh.bbox_diagonal();
    let caster = make_raycaster(RayBackend::Embree, mesh)?;
    let (mp, mw) = quadrature_points(mesh);
    let nv = mesh.positions.len();
    let r0 = auto_resolution(nv, control.num_faces());
    // `RECONS` (default "bilinear"): the reconstructions to measure, each
    // at every multiple and allocation (`--displacement-reconstruction`).
    let recons: Vec<subdfit::displace::Reconstruction> = std::env::var("RECONS")
        .unwrap_or_else(|_| "bilinear".into())
        .split_whitespace()
        .map(|s| s.parse().map_err(anyhow::Error::msg))
        .collect::<anyhow::Result<_>>()?;
    for m in mults {
        let r = ((r0 - 1) as f64 * m.sqrt()).round() as usize + 1;
        let budget = (m * nv as f64).round() as usize;
        for (recon, (name, opts)) in recons.iter().flat_map(|&rc| {
            [
                (
                    "uniform",
                    MetricsOptions::default().with_displacement_res(Some(r)),
                ),
                (
                    "adaptive",
                    MetricsOptions::default()
                        .with_displacement_samples(Some(budget))
                        .with_offsets(if std::env::var("SD_HIT").is_ok() {
                            subdfit::displace::OffsetMode::Hit
                        } else {
                            subdfit::displace::OffsetMode::LeastSquares
                        }),
                ),
            ]
            .map(|(n, o)| (rc, (n, o.with_reconstruction(rc))))
        }) {
            let t0 = Instant::now();
            let s = evaluate_surfaces(mesh, &control, caster.as_ref(), &opts, &mut |_, _| true)?;
            let seconds = t0.elapsed().as_secs_f64();
            let dc = make_raycaster(RayBackend::Embree, &s.displaced)?;
            let harness = distance_stats(&mp, &mw, dc.as_ref(), diag)?;
            let d = &s.metrics.displaced;
            println!(
                "{}",
                serde_json::json!({
                    "multiple": m,
                    "allocation": name,
                    "reconstruction": recon,
                    "res": s.displacement.grid.res(),
                    "samples": s.metrics.displacement.samples,
                    "mesh_vertices": nv,
                    "d_rms": d.rms_permille,
                    "d_s2m": d.surface_to_mesh.rms_permille,
                    "d_m2s": d.mesh_to_surface.rms_permille,
                    "m_to_displaced_ply": harness.rms_permille,
                    "displaced_ply_vertices": s.displaced.positions.len(),
                    "histogram": s.metrics.displacement.adaptive.as_ref().map(|a| &a.resolution_histogram),
                    "lsq": s.metrics.displacement.least_squares,
                    "breakdown": s.metrics.displaced_breakdown,
                    "worst_res": s.metrics.displaced_breakdown.worst_patches.iter()
                        .map(|p| s.displacement.grid.patch_res(p.patch)).collect::<Vec<_>>(),
                    "seconds": seconds,
                })
            );
        }
    }
    Ok(())
}
