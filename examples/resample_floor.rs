//! The idealised floor of RMS D for a mesh: a resampling of M at its own
//! density with every vertex on M (`subdfit::report::resampling_floor`),
//! measured like the displaced surface. Used by `bench/density.sh`.
//!
//! `cargo run --release --example resample_floor -- MESH [REACH] [SEED]`
//! prints one JSON object (‰ of M's bounding-box diagonal).

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(
        (2..=4).contains(&args.len()),
        "usage: resample_floor MESH [REACH in 0..=0.5] [SEED]"
    );
    let m = subdfit::io::read_mesh(args[1].as_ref())?;
    let reach: f64 = args.get(2).map_or(Ok(0.5), |s| s.parse())?;
    let seed: u64 = args.get(3).map_or(Ok(1), |s| s.parse())?;
    let acc = subdfit::report::resampling_floor(&m.mesh, reach, seed)?;
    println!(
        "{}",
        serde_json::json!({
            "mesh": args[1],
            "vertices": m.mesh.positions.len(),
            "reach": reach,
            "seed": seed,
            "floor": acc,
        })
    );
    Ok(())
}
