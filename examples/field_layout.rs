//! The field-aligned layout (`subdfit::quad::field`, issue 40) on a mesh.
//!
//! `cargo run --release --example field_layout -- MESH OUT [TAU] [FACES...]`
//!
//! Reads MESH, computes the Fitmap at τ (default 0.01) in the working frame
//! the pipeline uses (centred, unit diagonal), runs [`field_layout`] at
//! the Fitmap's own sizes (α = 1) and once per FACES target, and writes
//! each control mesh, mapped back to MESH's coordinates, to
//! `OUT_natural.obj` / `OUT_<FACES>.obj`, so that
//! `subdfit fit MESH OUT_natural.obj -o DIR` fits it. Prints one JSON line
//! per run: the layout's stats and M's topology against the result's.
//! `FIELD_UNIFORM=N` lays out one uniform size for N quads instead.
//! `FIELD_SPLIT` solves at 2h and splits every face; `FIELD_ALIGN`,
//! `FIELD_SWEEPS`, `FIELD_OSWEEPS` and `FIELD_GRADATION` override
//! [`FieldOptions::alignment_weight`], [`FieldOptions::position_sweeps`],
//! [`FieldOptions::orientation_sweeps`] and [`FieldOptions::gradation`]
//! (for measuring them).

use std::time::Instant;

use subdfit::analysis::{compute_fitmap, FitmapOptions};
use subdfit::mesh::Frame;
use subdfit::quad::field::{control_topology, field_layout, FieldOptions, Surface};
use subdfit::raycast::{make_raycaster, RayBackend};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        args.len() >= 3,
        "usage: field_layout MESH OUT [TAU] [FACES...]"
    );
    let tau: f64 = args.get(3).map_or(Ok(0.01), |s| s.parse())?;
    let mut targets: Vec<Option<usize>> = vec![None];
    for a in args.iter().skip(4) {
        targets.push(Some(a.parse()?));
    }
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
    let m_topology = Surface::new(&mesh)?.topology;

    for target in targets {
        let t1 = Instant::now();
        let weight: f64 = std::env::var("FIELD_ALIGN").map_or(Ok(1.0), |v| v.parse())?;
        let mut opts = FieldOptions::default()
            .with_target_faces(target)
            .with_alignment_weight(weight);
        if let Ok(v) = std::env::var("FIELD_SWEEPS") {
            opts.position_sweeps = v.parse()?;
        }
        if let Ok(v) = std::env::var("FIELD_OSWEEPS") {
            opts.orientation_sweeps = v.parse()?;
        }
        if let Ok(v) = std::env::var("FIELD_GRADATION") {
            opts = opts.with_gradation(v.parse()?);
        }
        if std::env::var("FIELD_SPLIT").is_ok() {
            opts.lattice_at_size = false;
        }
        // FIELD_UNIFORM=N: one uniform size for N quads (h = √(area / N)),
        // no Fitmap (for comparing the lattice with a peer's at its count).
        if let Ok(v) = std::env::var("FIELD_UNIFORM") {
            let n: f64 = v.parse()?;
            let area: f64 = subdfit::analysis::normals::triangle_areas(&mesh)
                .iter()
                .sum();
            opts = opts.with_uniform_size(Some((area / n).sqrt()));
        }
        let result = field_layout(&mesh, &fitmap, &opts);
        let layout_seconds = t1.elapsed().as_secs_f64();
        let name = target.map_or("natural".to_string(), |n| n.to_string());
        let out = match result {
            Ok(out) => out,
            Err(e) => {
                println!(
                    "{}",
                    serde_json::json!({
                        "mesh": args[1], "tau": tau, "target": target, "error": e.to_string(),
                        "layout_seconds": layout_seconds,
                    })
                );
                continue;
            }
        };
        let topology = control_topology(&out.control);
        let mut control = out.control;
        frame.points_from_unit(control.positions_mut());
        let path = format!("{}_{name}.obj", args[2]);
        subdfit::io::write_control_obj(path.as_ref(), &control)?;
        println!(
            "{}",
            serde_json::json!({
                "mesh": args[1],
                "tau": tau,
                "target": target,
                "output": path,
                "stats": out.stats,
                "topology": topology,
                "m_topology": m_topology,
                "fitmap_seconds": fitmap_seconds,
                "layout_seconds": layout_seconds,
            })
        );
    }
    Ok(())
}
