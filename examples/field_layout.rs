//! The field-aligned layout (`subdfit::quad::field`, issue 40) on a mesh.
//!
//! `cargo run --release --example field_layout -- MESH OUT.obj [TAU] [FACES]`
//!
//! Reads MESH, computes the Fitmap at τ (default 0.01) in the working frame
//! the pipeline uses (centred, unit diagonal), runs [`field_layout`]
//! (with a face target when FACES is given) and writes the control mesh,
//! mapped back to MESH's coordinates, to OUT.obj so that
//! `subdfit fit MESH OUT.obj -o DIR` fits it. Prints one JSON line: the
//! layout's stats and whether M's topology was kept.

use std::time::Instant;

use subdfit::analysis::{compute_fitmap, FitmapOptions};
use subdfit::mesh::Frame;
use subdfit::quad::field::{control_topology, field_layout, FieldOptions};
use subdfit::raycast::{make_raycaster, RayBackend};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        args.len() >= 3,
        "usage: field_layout MESH OUT.obj [TAU] [FACES]"
    );
    let tau: f64 = args.get(3).map_or(Ok(0.01), |s| s.parse())?;
    let faces: Option<usize> = args.get(4).map(|s| s.parse()).transpose()?;
    let input = subdfit::io::read_mesh(args[1].as_ref())?;
    let (lo, hi) = input.mesh.bbox();
    let frame = Frame::of_bbox(lo, hi);
    let mut mesh = input.mesh.clone();
    frame.points_to_unit(&mut mesh.positions);

    let t0 = Instant::now();
    let caster = make_raycaster(RayBackend::Embree, &mesh)?;
    let fitmap = compute_fitmap(
        &mesh,
        caster.as_ref(),
        &FitmapOptions::default().with_tolerance(tau),
    )?;
    let fitmap_seconds = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let opts = FieldOptions::default().with_target_faces(faces);
    let result = field_layout(&mesh, &fitmap, &opts);
    let layout_seconds = t1.elapsed().as_secs_f64();
    let out = match result {
        Ok(out) => out,
        Err(e) => {
            println!(
                "{}",
                serde_json::json!({
                    "mesh": args[1], "tau": tau, "error": e.to_string(),
                    "layout_seconds": layout_seconds,
                })
            );
            std::process::exit(1);
        }
    };
    let topology = control_topology(&out.control);
    let mut control = out.control;
    frame.points_from_unit(control.positions_mut());
    subdfit::io::write_control_obj(args[2].as_ref(), &control)?;
    println!(
        "{}",
        serde_json::json!({
            "mesh": args[1],
            "tau": tau,
            "stats": out.stats,
            "topology": topology,
            "fitmap_seconds": fitmap_seconds,
            "layout_seconds": layout_seconds,
        })
    );
    Ok(())
}
