//! Writes the initial control mesh of Fitmaps §3.2 for a mesh: its
//! quadrangulation with vertices placed so that the limit surface
//! interpolates the mesh's vertices. A stand-in for `subdfit convert`'s
//! simplification when benchmarking `subdfit fit`.
//!
//! `cargo run --release --example quad_control -- MESH OUT.obj`

use subdfit::quad::{interpolate_limit, quadrangulate, InterpolationOptions, QuadrangulateOptions};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() == 3, "usage: quad_control MESH OUT.obj");
    let m = subdfit::io::read_mesh(args[1].as_ref())?;
    let q = quadrangulate(&m.mesh, &QuadrangulateOptions::default())?;
    let mut control = q.mesh;
    let targets = control.positions().to_vec();
    interpolate_limit(&mut control, &targets, &InterpolationOptions::default())?;
    subdfit::io::write_control_obj(args[2].as_ref(), &control)?;
    eprintln!(
        "{} quads, {} vertices",
        control.num_faces(),
        control.num_vertices()
    );
    Ok(())
}
