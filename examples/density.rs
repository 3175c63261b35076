//! RMS D against the displacement density, for `bench/density.sh`.
//!
//! `cargo run --release --example density -- MESH CONTROL.obj [MULT...]`
//!
//! For each multiple `m` of the default sample count (total samples ≈ M's
//! vertices, `subdfit::displace::auto_resolution`; default multiples 1 2 4
//! 9 16), the per-patch resolution `R = round((R₀ − 1)·√m) + 1`, and for
//! both offset modes (φ's hits, least squares), prints one JSON line: the
//! samples, D in both directions (‰ of M's diagonal) and the seconds of the
//! displacement + metrics evaluation.

use std::time::Instant;

use subdfit::displace::{auto_resolution, OffsetMode};
use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::report::{metrics, MetricsOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        args.len() >= 3,
        "usage: density MESH CONTROL.obj [MULTIPLE...]"
    );
    let input = subdfit::io::read_mesh(args[1].as_ref())?;
    let control = subdfit::io::read_control_mesh(args[2].as_ref())?;
    let mults: Vec<f64> = if args.len() > 3 {
        args[3..]
            .iter()
            .map(|s| s.parse())
            .collect::<Result<_, _>>()?
    } else {
        vec![1.0, 2.0, 4.0, 9.0, 16.0]
    };
    let caster = make_raycaster(RayBackend::Embree, &input.mesh)?;
    let r0 = auto_resolution(input.mesh.positions.len(), control.num_faces());
    for m in mults {
        let r = ((r0 - 1) as f64 * m.sqrt()).round() as usize + 1;
        for (name, mode) in [("hit", OffsetMode::Hit), ("lsq", OffsetMode::LeastSquares)] {
            let t0 = Instant::now();
            let opts = MetricsOptions::default()
                .with_displacement_res(Some(r))
                .with_offsets(mode);
            let met = metrics(&input.mesh, &control, caster.as_ref(), &opts)?;
            let d = &met.displaced;
            println!(
                "{}",
                serde_json::json!({
                    "multiple": m,
                    "res": r,
                    "offsets": name,
                    "samples": met.displacement.samples,
                    "mesh_vertices": input.mesh.positions.len(),
                    "d_rms": d.rms_permille,
                    "d_s2m": d.surface_to_mesh.rms_permille,
                    "d_m2s": d.mesh_to_surface.rms_permille,
                    "seconds": t0.elapsed().as_secs_f64(),
                })
            );
        }
    }
    Ok(())
}
