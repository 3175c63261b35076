//! `subdfit fit MESH CONTROL -o OUTDIR` and `subdfit metrics MESH CONTROL`:
//! the fitting and measuring half of a conversion, from any given control
//! mesh (Fitmaps §3.5, §4).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use subdfit::convert::{fit_in_memory, measure, write_converted, PipelineOptions};
use subdfit::fit::{FitOptions, Objective};
use subdfit::report::{MetricsOptions, StageTimer};

#[derive(Args)]
pub struct FitArgs {
    /// The dense input mesh M (OBJ, PLY, OFF, STL).
    mesh: PathBuf,
    /// The control mesh to fit (OBJ with `t crease` / `t corner` tags, or
    /// any mesh format); pure quads for the displacement outputs.
    control: PathBuf,
    /// Output folder (created; existing files of the same names replaced).
    #[arg(short, long)]
    output: PathBuf,
    #[arg(long, value_enum, default_value_t = Objective::Point)]
    fit: Objective,
    /// Displacement samples per patch side (default: total ≈ M's vertices).
    #[arg(long)]
    displacement_res: Option<usize>,
    /// Parameter-correction rounds at most.
    #[arg(long, default_value_t = 8)]
    max_iterations: usize,
    /// Skip `fitmap.ply` (the Fitmap analysis of M).
    #[arg(long)]
    no_fitmap: bool,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
    /// Print report.json to stdout.
    #[arg(long)]
    json: bool,
}

#[derive(Args)]
pub struct MetricsArgs {
    /// The dense input mesh M.
    mesh: PathBuf,
    /// The control mesh (pure quads).
    control: PathBuf,
    /// Displacement samples per patch side (default: total ≈ M's vertices).
    #[arg(long)]
    displacement_res: Option<usize>,
    /// Print JSON.
    #[arg(long)]
    json: bool,
}

/// A progress callback drawing one bar per stage on stderr (none when
/// `quiet`).
pub fn progress_bars(quiet: bool) -> impl FnMut(&str, f64) -> bool {
    let mut current: Option<(String, ProgressBar)> = None;
    move |stage: &str, fraction: f64| {
        if quiet {
            return true;
        }
        let same = matches!(&current, Some((s, _)) if s == stage);
        if !same {
            if let Some((_, bar)) = current.take() {
                bar.finish();
            }
            let bar = ProgressBar::new(1000);
            bar.set_style(
                ProgressStyle::with_template(
                    "{prefix:>14} [{bar:30}] {percent:>3}% {elapsed} (eta {eta})",
                )
                .expect("static template")
                .progress_chars("=> "),
            );
            bar.set_prefix(stage.to_string());
            current = Some((stage.to_string(), bar));
        }
        if let Some((_, bar)) = &current {
            bar.set_position((fraction * 1000.0) as u64);
            if fraction >= 1.0 {
                bar.finish();
            }
        }
        true
    }
}

pub fn fit(a: FitArgs) -> Result<ExitCode> {
    let mut timer = StageTimer::default();
    let input = timer
        .run("read", || {
            subdfit::io::read_mesh(&a.mesh).and_then(|m| m.into_manifold(&a.mesh))
        })
        .context("input mesh")?;
    let (control, repairs) = crate::read_layout(&a.control, a.quiet)?;
    let notes = repairs.notes();
    let objective = a.fit;
    let opts = PipelineOptions::default()
        .with_fit(
            FitOptions::default()
                .with_objective(objective)
                .with_max_iterations(a.max_iterations),
        )
        .with_metrics(MetricsOptions::default().with_displacement_res(a.displacement_res))
        .with_fitmap((!a.no_fitmap).then(subdfit::analysis::FitmapOptions::default));
    let extra = subdfit::convert::HostRecord::fit(
        a.mesh.display().to_string(),
        Some(subdfit::convert::FitInputs {
            control: a.control.display().to_string(),
            control_repairs: repairs,
            control_notes: notes,
        }),
    );
    let mut progress = progress_bars(a.quiet || a.json);
    let c = fit_in_memory(&input, control, &opts, timer, extra, &mut progress)?;
    let written = write_converted(&input, &c, &a.output, None, &mut progress)?;
    let report = c.report;
    if a.json {
        crate::emit(&serde_json::to_string_pretty(&report)?)?;
    } else if !a.quiet {
        print_summary(&report, &written)?;
    }
    Ok(ExitCode::SUCCESS)
}

/// The one-paragraph summary `fit` and `convert` print.
pub fn print_summary(report: &subdfit::convert::Report, written: &[PathBuf]) -> Result<()> {
    let m = &report.accuracy;
    crate::emit(&format!(
        "{} patches, {} irregular vertices; RMS L {:.3}‰, RMS D {:.3}‰ of the diagonal; \
         unprojectable {:.2}% of M's area\nwrote {}",
        report.control.faces,
        report.control.irregular_vertices,
        m.limit.rms_permille,
        m.displaced.rms_permille,
        report.projectability.unprojectable_area_percent,
        written
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    ))
}

pub fn metrics_cmd(a: MetricsArgs) -> Result<ExitCode> {
    let input = crate::read_input(&a.mesh)?;
    let (control, repairs) = crate::read_layout(&a.control, a.json)?;
    let stats = subdfit::report::control_stats(&control);
    let m = measure(
        &input,
        control,
        &MetricsOptions::default().with_displacement_res(a.displacement_res),
    )?;
    if a.json {
        let v = serde_json::json!({
            "control": stats,
            "control_notes": repairs.notes(),
            "metrics": m,
        });
        crate::emit(&serde_json::to_string_pretty(&v)?)?;
    } else {
        let l = &m.limit;
        let d = &m.displaced;
        crate::emit(&format!(
            "patches {}  irregular {}  unprojectable {:.2}% (area)\n\
             limit L      RMS {:.3}‰  (L→M rms {:.3} mean {:.3} max {:.3}; M→L rms {:.3} mean {:.3} max {:.3})\n\
             displaced D  RMS {:.3}‰  (D→M rms {:.3} mean {:.3} max {:.3}; M→D rms {:.3} mean {:.3} max {:.3})\n\
             displacement {}×{} per patch, {} samples, {} unprojectable",
            stats.faces,
            stats.irregular_vertices,
            m.unprojectable_area_percent,
            l.rms_permille,
            l.surface_to_mesh.rms_permille,
            l.surface_to_mesh.mean_permille,
            l.surface_to_mesh.max_permille,
            l.mesh_to_surface.rms_permille,
            l.mesh_to_surface.mean_permille,
            l.mesh_to_surface.max_permille,
            d.rms_permille,
            d.surface_to_mesh.rms_permille,
            d.surface_to_mesh.mean_permille,
            d.surface_to_mesh.max_permille,
            d.mesh_to_surface.rms_permille,
            d.mesh_to_surface.mean_permille,
            d.mesh_to_surface.max_permille,
            m.displacement.resolution,
            m.displacement.resolution,
            m.displacement.samples,
            m.displacement.unprojectable,
        ))?;
    }
    Ok(ExitCode::SUCCESS)
}
