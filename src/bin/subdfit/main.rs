//! The `subdfit` command line.

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "subdfit",
    version,
    about = "Dense triangle mesh to adaptive Catmull-Clark subdivision surface"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the versions of the linked C++ libraries.
    Version,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Version => {
            println!("subdfit {}", env!("CARGO_PKG_VERSION"));
            for (name, v) in subdfit::linked_library_versions() {
                println!("{name} {v}");
            }
        }
    }
    Ok(())
}
