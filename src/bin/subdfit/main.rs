//! The `subdfit` command line. Exit status: 0 success, 1 a check failed
//! (e.g. `diff-limit` above tolerance), 2 bad input or a bad option (a file
//! that cannot be read or used, I/O, an option out of range), 3 a numerical
//! failure on a valid input (a solver, a C++ backend), 70 an internal error
//! (a bug in subdfit; sysexits' `EX_SOFTWARE`): see [`exit_code`].

mod batch;
mod convert;
mod fit;
mod fitmap;
mod limit;
mod metrics;
mod quadrangulate;
mod render;
mod simplify;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "subdfit",
    version,
    about = "Dense triangle mesh to adaptive Catmull-Clark subdivision surface",
    long_about = "Dense triangle mesh to adaptive Catmull-Clark subdivision surface.\n\n\
                  Exit status: 0 on success, 1 when a check fails (diff-limit above tolerance), \
                  2 on an error (unreadable or invalid input, I/O failure)."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Read a mesh (OBJ, PLY, OFF, STL), validate it and print a report.
    Info {
        mesh: PathBuf,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Evaluate the Catmull-Clark limit surface of a control mesh to CSV.
    Limit(limit::LimitArgs),
    /// Compare the OpenSubdiv and pure-Rust limit evaluators on a control mesh.
    DiffLimit(limit::DiffArgs),
    /// Turn a triangle mesh into a pure quad mesh on the same vertices.
    Quadrangulate(quadrangulate::QuadrangulateArgs),
    /// Simplify a triangle mesh into an adaptive quad control mesh (Fitmaps).
    Simplify(simplify::SimplifyArgs),
    /// Compute the Fitmap (S- and M-fitmap, Fitmaps §3.1) of a mesh.
    Fitmap(fitmap::FitmapArgs),
    /// Print the versions of subdfit and the linked C++ libraries.
    Version,
    /// Convert a dense mesh into a fitted Catmull-Clark surface with displacement (Fitmaps).
    Convert(convert::ConvertArgs),
    /// Convert many meshes (files, folders, globs, manifests), one output folder each;
    /// resumable, with a summary table, CSV and JSON.
    Batch(batch::BatchArgs),
    /// Fit a given control mesh to a mesh and write the surface, displacement and report.
    Fit(fit::FitArgs),
    /// Accuracy and projectability of a control mesh against a mesh (Table 1 figures).
    Metrics(metrics::MetricsArgs),
    /// Render a picture (PNG) of a mesh or a convert output folder: input, fitmap,
    /// patches, limit, displaced or error map.
    Render(render::RenderArgs),
}

fn run(cli: Cli) -> Result<ExitCode> {
    match cli.command {
        Command::Info { mesh, json } => {
            let m = read_input(&mesh)?;
            if json {
                emit(&serde_json::to_string_pretty(&m.report)?)?;
            } else {
                emit(&m.report.to_string())?;
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Limit(a) => limit::limit(a),
        Command::DiffLimit(a) => limit::diff_limit(a),
        Command::Quadrangulate(a) => quadrangulate::run(a),
        Command::Simplify(a) => simplify::run(a),
        Command::Convert(a) => convert::convert(a),
        Command::Batch(a) => batch::run(a),
        Command::Fit(a) => fit::fit(a),
        Command::Metrics(a) => metrics::metrics(a),
        Command::Fitmap(a) => fitmap::fitmap(a),
        Command::Render(a) => render::run(a),
        Command::Version => {
            let mut text = format!("subdfit {}", env!("CARGO_PKG_VERSION"));
            for (name, v) in subdfit::linked_library_versions() {
                text += &format!("\n{name} {v}");
            }
            emit(&text)?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// Reads the dense input mesh M. Its errors start with "input mesh" (then
/// the file and the element), so that a command reading two meshes says
/// which one is bad; [`read_layout`] does the same for the control mesh.
pub(crate) fn read_input(path: &Path) -> Result<subdfit::mesh::ValidatedMesh> {
    subdfit::io::read_mesh(path).context("input mesh")
}

/// Reads a layout another tool may have written (`fit`, `metrics`), its
/// errors starting with "control mesh"; repaired the least that makes it a manifold
/// control mesh (issue 17, "fit any layout"), each repair a note on stderr
/// unless `quiet`.
pub(crate) fn read_layout(
    path: &Path,
    quiet: bool,
) -> Result<(subdfit::mesh::ControlMesh, subdfit::mesh::ForeignRepairs)> {
    let (control, repairs) =
        subdfit::io::read_control_mesh_as_found(path).context("control mesh")?;
    if !quiet {
        for n in repairs.notes() {
            eprintln!("subdfit: note: control mesh {}: {n}", path.display());
        }
    }
    Ok((control, repairs))
}

/// Prints `text` and a newline to stdout. A closed pipe (`subdfit info … |
/// head`) ends the output quietly instead of panicking like `println!`.
pub(crate) fn emit(text: &str) -> Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{}", text.trim_end_matches('\n')).and_then(|_| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}

/// The error and its causes, `: `-separated, skipping a cause whose text the
/// message before it already contains (our typed errors print their source).
/// The exit status of an error, by the kind of the library error in its
/// chain ([`subdfit::ErrorKind`]); 2 for the command line's own errors.
fn exit_code(e: &anyhow::Error) -> ExitCode {
    use subdfit::ErrorKind;
    let kind = e
        .chain()
        .find_map(|c| c.downcast_ref::<subdfit::Error>())
        .map(subdfit::Error::kind);
    ExitCode::from(match kind {
        Some(ErrorKind::Numerical) => 3,
        Some(ErrorKind::Internal) => 70,
        // Cancelled: the staging is gone and nothing was written; only a
        // signal cancels the CLI, which exits 128 + signal before this.
        _ => 2,
    })
}

fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if !out.contains(&text) {
            if !out.is_empty() {
                out += ": ";
            }
            out += &text;
        }
    }
    out
}

/// SIGINT and SIGTERM: the staging folders of a write in progress are
/// removed (see `subdfit::report::remove_staging_folders`), then the process
/// exits with 128 + the signal (130, 143), as a shell reports it.
fn handle_signals() {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let Ok(mut signals) = signal_hook::iterator::Signals::new([SIGINT, SIGTERM]) else {
        return; // Default handling then: no cleanup, but no crash either.
    };
    std::thread::spawn(move || {
        if let Some(sig) = signals.forever().next() {
            subdfit::report::remove_staging_folders();
            std::process::exit(128 + sig);
        }
    });
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    // Only the commands that write an output set have staging to clean up;
    // the others keep the default handling (and no extra thread).
    if matches!(
        cli.command,
        Command::Convert(_) | Command::Fit(_) | Command::Batch(_)
    ) {
        handle_signals();
    }
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("subdfit: error: {}", error_chain(&e));
            exit_code(&e)
        }
    }
}
