//! Writes the procedural control meshes of `subdfit::fixtures` as OBJ files
//! (creases and corners as OpenSubdiv shape-file tags) into a folder, for
//! `subdfit diff-limit` / `subdfit limit` or any other tool.
//!
//! `cargo run --example export_fixtures -- OUTDIR`

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args()
        .nth(1)
        .ok_or("usage: export_fixtures OUTDIR")?;
    std::fs::create_dir_all(&dir)?;
    for (name, mesh) in subdfit::fixtures::collection() {
        let path = std::path::Path::new(&dir).join(format!("{name}.obj"));
        subdfit::io::write_control_obj(&path, &mesh)?;
        println!("{}", path.display());
    }
    Ok(())
}
