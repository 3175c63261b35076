//! Writes the procedural CAD parts of issue 38's regression set
//! (`subdfit::fixtures::cad::parts`) as PLY files, for `subdfit convert`
//! and `bench/mechanical.sh`.
//!
//! Usage: `cargo run --release --example cad_parts -- <dir>`

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    std::fs::create_dir_all(&dir)?;
    let mut parts = subdfit::fixtures::cad::parts();
    parts.extend(subdfit::fixtures::cad::heavy_parts());
    for (name, plate) in parts {
        let m = plate.mesh();
        let path = dir.join(format!("{name}.ply"));
        subdfit::io::write_ply(&path, &m.positions, &m.triangles, &[], None)?;
        println!("{} {} triangles", path.display(), m.triangles.len());
    }
    Ok(())
}
