//! `subdfit quadrangulate`: triangles to quads on the same vertex set
//! (Fitmaps §3.2).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;
use serde::Serialize;
use subdfit::quad::{quadrangulate, QuadrangulateOptions};

#[derive(Args)]
pub struct QuadrangulateArgs {
    /// Input triangle mesh (OBJ, PLY, OFF, STL).
    mesh: PathBuf,
    /// Output quad mesh (OBJ, written atomically).
    #[arg(short, long)]
    output: PathBuf,
    /// Print a JSON summary instead of text.
    #[arg(long)]
    json: bool,
}

#[derive(Serialize)]
struct Summary<'a> {
    input: String,
    output: String,
    quads: usize,
    vertices: usize,
    seconds: f64,
    triangles: usize,
    leftover_triangles: usize,
    parity_fixes: usize,
    non_convex_quads: usize,
    angle_deviation_deg: &'a subdfit::quad::QualityStats,
    dihedral_deg: &'a subdfit::quad::QualityStats,
}

pub fn run(a: QuadrangulateArgs) -> Result<ExitCode> {
    let t = std::time::Instant::now();
    let m = crate::read_input(&a.mesh)?;
    let q = quadrangulate(&m.mesh, &QuadrangulateOptions::default())
        .with_context(|| format!("{}: quadrangulation failed", a.mesh.display()))?;
    subdfit::io::write_control_obj(&a.output, &q.mesh)?;
    let s = Summary {
        input: a.mesh.display().to_string(),
        output: a.output.display().to_string(),
        quads: q.mesh.num_faces(),
        vertices: q.mesh.num_vertices(),
        seconds: t.elapsed().as_secs_f64(),
        triangles: q.report.num_triangles,
        leftover_triangles: q.report.leftover_triangles,
        parity_fixes: q.report.parity_fixes.len(),
        non_convex_quads: q.report.non_convex_quads,
        angle_deviation_deg: &q.report.angle_deviation,
        dihedral_deg: &q.report.dihedral,
    };
    if a.json {
        crate::emit(&serde_json::to_string_pretty(&s)?)?;
    } else {
        let r = &q.report;
        crate::emit(&format!(
            "{}: {} triangles -> {} quads, {} leftover triangles, {} parity fixes, {} non-convex quads\n\
             angle deviation (deg): {}\ndihedral (deg): {}\nwrote {} in {:.2} s",
            s.input,
            r.num_triangles,
            s.quads,
            r.leftover_triangles,
            r.parity_fixes.len(),
            r.non_convex_quads,
            r.angle_deviation,
            r.dihedral,
            s.output,
            s.seconds
        ))?;
    }
    Ok(ExitCode::SUCCESS)
}
