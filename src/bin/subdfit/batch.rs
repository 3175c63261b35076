//! `subdfit batch INPUTS… -o OUTROOT`: many assets, one `convert` each
//! (`subdfit::embed::batch` does the work; this is its terminal face).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use subdfit::embed::batch::{self, Event, Status};
use subdfit::embed::{Options, Progress};

#[derive(Args)]
pub struct BatchArgs {
    /// Mesh files, folders (their OBJ/PLY/OFF/STL files), glob patterns
    /// (quoted: `'scans/*.ply'`) or manifest files (one mesh path per line,
    /// relative to the manifest; `#` comments).
    #[arg(required = true)]
    inputs: Vec<String>,
    /// Output root: one folder per asset (named after the file), as
    /// `subdfit convert` writes it, plus batch.csv and batch.json.
    #[arg(short, long)]
    output: PathBuf,
    /// Assets converted at once (each also uses all cores).
    #[arg(long, default_value_t = 1)]
    jobs: usize,
    /// Convert every asset, even those whose input and options are
    /// unchanged since they were converted.
    #[arg(long)]
    force: bool,
    /// The options of each conversion, as `subdfit convert`'s.
    #[command(flatten)]
    conversion: crate::convert::ConversionArgs,
    /// No progress bar and no table (the summary files are still written).
    #[arg(long)]
    quiet: bool,
}

fn options(a: &BatchArgs) -> Options {
    let mut o = Options::default();
    o.convert = a.conversion.options();
    o
}

/// Exit status 0 when every asset was converted or skipped, 2 when one
/// failed (the others are converted all the same).
pub fn run(a: BatchArgs) -> Result<ExitCode> {
    let opts = options(&a);
    // A bad option would fail every asset the same way: say it once.
    opts.check()?;
    let assets = batch::plan(&a.inputs, &a.output)?;
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(assets.len() as u64)
    };
    bar.set_style(
        ProgressStyle::with_template("{prefix:>8} [{bar:30}] {pos}/{len} {elapsed} {msg}")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.set_prefix("assets");
    let on_event = |e: Event<'_>| match e {
        Event::Started(asset) => bar.set_message(asset.name.clone()),
        Event::Finished(o) => {
            if o.status == Status::Failed {
                bar.println(format!(
                    "subdfit: error: {}: {}",
                    o.asset.name,
                    o.error.as_deref().unwrap_or("")
                ));
            }
            bar.inc(1);
        }
    };
    let outcomes = batch::run(
        &assets,
        &opts,
        a.force,
        a.jobs,
        &on_event,
        &Progress::none(),
    );
    bar.finish_and_clear();
    let written = batch::write_summary(&a.output, &outcomes)?;
    if !a.quiet {
        crate::emit(&batch::summary_table(&outcomes))?;
        let names: Vec<String> = written.iter().map(|p| p.display().to_string()).collect();
        crate::emit(&format!("summary: {}", names.join(", ")))?;
    }
    let failed = outcomes.iter().any(|o| o.status == Status::Failed);
    Ok(if failed {
        ExitCode::from(2)
    } else {
        ExitCode::SUCCESS
    })
}
