//! `subdfit convert MESH -o OUTDIR`: the whole organic pipeline (Fitmaps).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Args;
use subdfit::analysis::fitmap::DEFAULT_TOLERANCE;
use subdfit::convert::{
    convert_in_memory, write_converted, ConvertOptions, LayoutKind, Mode, Proxy,
};
use subdfit::displace::{Reconstruction, SampleAllocation};
use subdfit::fit::Objective;

use crate::fit::progress_bars;

#[derive(Args)]
pub struct ConvertArgs {
    /// The dense input mesh M (OBJ, PLY, OFF, STL): one closed or open
    /// manifold surface.
    mesh: PathBuf,
    /// Output folder: control.obj, control.usda, limit.ply, displaced.ply,
    /// displacement.exr and displacement_vector.exr (or UDIM tiles),
    /// fitmap.ply, report.json (and
    /// report.html) as one set: built beside the folder and swapped in
    /// whole, so the folder never mixes two runs; other files in it are
    /// kept, a sub-folder in it is an error.
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten)]
    conversion: ConversionArgs,
    #[command(flatten)]
    files: OutputArgs,
    /// No progress bars.
    #[arg(long)]
    quiet: bool,
    /// Print report.json to stdout.
    #[arg(long)]
    json: bool,
    /// Also write OUTDIR/report.html: pictures and Table 1 in one
    /// self-contained page.
    #[arg(long)]
    report: bool,
    /// Exit with status 1 when the result misses a target it was given
    /// (`--max-error`, `--faces`; report.json's `targets`). Without it a
    /// miss is a warning on stderr and `"targets_met": false`.
    #[arg(long)]
    strict: bool,
}

/// The options of one conversion, shared by `convert` and `batch`: one
/// flag per field of [`ConvertOptions`] (the library's one options type,
/// which `embed`, C++ and Python map to as well).
#[derive(Args)]
pub struct ConversionArgs {
    /// τ, the only parameter of the method (Fitmaps §3.1.3): the share of a
    /// neighbourhood allowed to be unreachable by normal projection, as a
    /// fraction (0.01 = the paper's 1 %, 0.1 = its 10 %); larger τ, fewer
    /// patches. The default, 5 %, sits between the paper's two settings
    /// (see `subdfit fitmap --help`).
    #[arg(long, default_value_t = DEFAULT_TOLERANCE)]
    tolerance: f64,
    /// Stop simplifying at this many faces, ±2 % (the paper's "*" rows).
    /// Below the natural end the halting tests (M-fitmap radius, S-fitmap
    /// bound, surface guard) are relaxed by ×1.25 steps until it is
    /// reached; report.json's `targets` says how far and what it cost in
    /// unprojectable area. With --faces, organic mode has no default
    /// --max-error.
    #[arg(long)]
    faces: Option<usize>,
    /// Global fit objective.
    #[arg(long, value_enum, default_value_t = Objective::Point)]
    fit: Objective,
    /// Displacement samples per patch side, the same on every patch
    /// (implies --displacement-allocation uniform).
    #[arg(long)]
    displacement_res: Option<usize>,
    /// Displacement samples in all, each shared sample counted once
    /// (default: M's vertex count).
    #[arg(long)]
    displacement_samples: Option<usize>,
    /// `adaptive`: per-patch resolution (2^k + 1 per side, where the
    /// detail is) under --displacement-samples; `uniform`: the same R × R
    /// grid on every patch, R from the budget (the behaviour before
    /// issue 37).
    #[arg(long, value_enum, default_value_t = SampleAllocation::Adaptive)]
    displacement_allocation: SampleAllocation,
    /// How hosts read the maps between texels: `bilinear` (every host;
    /// the maps hold samples) or `bspline` (the maps hold bicubic
    /// B-spline coefficients with a linear-extrapolation gutter, for
    /// Blender/Cycles' "Cubic" image interpolation; a bilinear-only host,
    /// USD's UsdUVTexture among them, must not read them). docs/handoff.md.
    #[arg(long, value_enum, default_value_t = Reconstruction::Bilinear)]
    displacement_reconstruction: Reconstruction,
    /// Lift the projectability (M-fitmap) test (the paper's Fig. 7).
    #[arg(long)]
    no_mfitmap: bool,
    /// Pipeline: `organic` (Fitmaps), `mechanical` (Lavoué et al. 2007:
    /// sharp features as creases, compact quad/triangle control mesh), or
    /// `auto`: mechanical when at least 0.5 % of the edges are sharp
    /// (dihedral > 30°) and at least 30 % flat (< 1°); report.json says which and why. Mechanical mode
    /// enriches in at most 8 rounds (5 geometry iterations each), then runs
    /// at most 10 more geometry iterations while they still lower the
    /// error, and stops at 20 000 faces, so it always terminates.
    #[arg(long, value_enum, default_value_t = Mode::Auto)]
    mode: Mode,
    /// An RMS distance bound, as a fraction of the bounding-box diagonal.
    /// Mechanical mode: E_limit per control face (default 3e-3, Lavoué et
    /// al.'s). Organic mode: RMS L of the whole limit surface, met with the
    /// fewest patches the simplification passed through (checkpoints 1.06×
    /// apart, each fitted and measured as the result is). Default 5e-3:
    /// the natural end of the simplification is set by projectability and
    /// the Fitmap's predicted error, which leaves small smooth inputs
    /// coarser than a user expects (spot: 79 patches, RMS L 6.7‰ → 94
    /// patches, 4.6‰); `inf` keeps the natural end.
    #[arg(long, value_parser = parse_max_error)]
    max_error: Option<f64>,
    /// Organic mode's layout proxy M' (Fitmaps §4): the Fitmap,
    /// quadrangulation and simplification run on a quadric decimation of
    /// the input to this many triangles, while the fit, displacement and
    /// every figure use the input itself. `auto`: 50 000 triangles for
    /// inputs above 100 000 (below, the full-resolution layout takes under
    /// ~20 s and stays the reference); `none`: the layout runs on the input
    /// (minutes on big scans, for comparison); `adaptive`: sized by the
    /// output, ~58 triangles per patch predicted by the Fitmap of a
    /// 4 000-triangle probe, the input itself when that is more than half
    /// of it; or a triangle count (used when the input has more). The proxy is used only if it keeps the
    /// input's topology (components, boundary loops, Euler characteristic);
    /// report.json's `layout_proxy` says what was tried.
    #[arg(long, default_value = "auto", value_parser = clap::value_parser!(Proxy))]
    proxy: Proxy,
    /// Cells per patch side of limit.ply and displaced.ply (1-1024).
    /// Default: the smallest power of two from 16 to 64 whose RMS chord
    /// error (against the exact limit surface) is below a tenth of the
    /// fit's RMS distance and whose largest is below that distance;
    /// report.json's `tessellation` gives the figures.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1024))]
    tessellation: Option<u64>,
    /// Organic mode's layout: `greedy` (Fitmaps §3.2-3.3: the input's
    /// triangle pairs simplified by collapses, rotations and doublet
    /// removals under the Fitmap's tests) or `field` (a curvature-aligned
    /// cross field and a position field sized by the Fitmap, extracted into
    /// a pure-quad mesh with the input's topology; experimental: see
    /// docs/status.md). report.json's `options.convert.layout` says which ran.
    #[arg(long, value_enum, default_value_t = LayoutKind::Greedy)]
    layout: LayoutKind,
    /// Measure the metrics on every point. By default the displaced
    /// surface's two directions are measured on a stratified draw of
    /// 100 000 points when they have more (its S → M has ~12 points per
    /// input triangle), and L's directions and the projectability, which
    /// steer the output, on 300 000 when they have more; report.json gives
    /// each figure's sample count, population and 95 % confidence interval
    /// (`rms_ci95_permille`, `mean_ci95_permille`,
    /// `unprojectable_ci95_percent`); a drawn max is a lower bound.
    #[arg(long)]
    exact_metrics: bool,
}

impl ConversionArgs {
    pub fn options(&self) -> ConvertOptions {
        ConvertOptions::default()
            .with_tolerance(Some(self.tolerance))
            .with_target_faces(self.faces)
            .with_m_fitmap(!self.no_mfitmap)
            .with_objective(self.fit)
            .with_displacement_res(self.displacement_res)
            .with_displacement_samples(self.displacement_samples)
            .with_displacement_allocation(self.displacement_allocation)
            .with_displacement_reconstruction(self.displacement_reconstruction)
            .with_mode(self.mode)
            .with_max_error(self.max_error)
            .with_tessellation(self.tessellation.map(|n| n as usize))
            .with_proxy(self.proxy)
            .with_layout(self.layout)
            .with_exact_metrics(self.exact_metrics)
    }
}

/// `--atlas`.
#[derive(Copy, Clone, Debug, clap::ValueEnum)]
pub enum AtlasArg {
    Single,
    Udim,
}

/// How the output files are written (shared by `convert`).
#[derive(Args)]
pub struct OutputArgs {
    /// The length of one unit of the input's coordinates, for
    /// control.usda's metersPerUnit: m, dm, cm, mm, in, ft, or metres as a
    /// number (0.01 = cm). Default m: the input is taken to be in metres
    /// (scans and the Stanford models are; CAD exports are often mm).
    #[arg(long, default_value = "m", value_parser = parse_units)]
    units: f64,
    /// Displacement atlas: `single` (displacement.exr) or `udim` (tiles
    /// displacement.1001.exr, … of 8 × 8 patches each, UVs in UDIM space).
    /// Gutters and tile alignment serve mip levels 0-3 without bleeding.
    #[arg(long, value_enum, default_value_t = AtlasArg::Single)]
    atlas: AtlasArg,
    /// Write the EXR texels as 16-bit half floats (default 32-bit float).
    #[arg(long)]
    half: bool,
}

/// `--max-error`: a positive fraction (or `inf`).
pub(crate) fn parse_max_error(s: &str) -> std::result::Result<f64, String> {
    match s.parse::<f64>() {
        Ok(e) if e > 0.0 => Ok(e),
        _ => Err(format!(
            "{s:?}: give a positive fraction of the diagonal (e.g. 0.005), or inf"
        )),
    }
}

/// `--units`: a unit name or metres per unit.
fn parse_units(s: &str) -> std::result::Result<f64, String> {
    let m = match s {
        "m" => 1.0,
        "dm" => 0.1,
        "cm" => 0.01,
        "mm" => 0.001,
        "in" => 0.0254,
        "ft" => 0.3048,
        _ => s
            .parse::<f64>()
            .map_err(|_| format!("{s:?}: give m, dm, cm, mm, in, ft or metres per unit"))?,
    };
    if m.is_finite() && m > 0.0 {
        Ok(m)
    } else {
        Err(format!("{s:?}: metres per unit must be finite and > 0"))
    }
}

impl OutputArgs {
    fn options(&self) -> subdfit::report::OutputOptions {
        use subdfit::displace::{AtlasLayout, TexelType};
        subdfit::report::OutputOptions {
            meters_per_unit: self.units,
            atlas: match self.atlas {
                AtlasArg::Single => AtlasLayout::Single,
                AtlasArg::Udim => AtlasLayout::Udim,
            },
            texels: if self.half {
                TexelType::Half
            } else {
                TexelType::Float
            },
        }
    }
}

pub fn convert(a: ConvertArgs) -> Result<ExitCode> {
    // Non-manifold vertices and edges are split into manifold pieces (and
    // said so in report.json), as every later stage needs one fan per vertex.
    let input = crate::read_input(&a.mesh)?
        .into_manifold(&a.mesh)
        .context("input mesh")?;
    let opts = a.conversion.options();
    let extra = subdfit::convert::HostRecord::convert(a.mesh.display().to_string());
    let mut progress = progress_bars(a.quiet || a.json);
    let mut converted = convert_in_memory(&input, &opts, extra, &mut progress)
        .with_context(|| a.mesh.display().to_string())?;
    converted.outputs = a.files.options();
    // report.html is drawn from the staged files, so it belongs to the set.
    let mut html = |staging: &std::path::Path| -> subdfit::Result<Vec<String>> {
        if !a.report {
            return Ok(Vec::new());
        }
        subdfit::render::report_html::write_report_html(
            staging,
            Some(&a.mesh),
            &Default::default(),
            &mut |f| progress("report", f),
        )?;
        Ok(vec!["report.html".to_string()])
    };
    let written = write_converted(
        &input,
        &converted,
        &a.output,
        Some(&mut html),
        &mut |_, _| true,
    )
    .with_context(|| a.output.display().to_string())?;
    let report = &converted.report;
    if a.json {
        crate::emit(&serde_json::to_string_pretty(report)?)?;
    } else if !a.quiet {
        crate::fit::print_summary(report, &written)?;
        if let Some(n) = a.conversion.faces {
            if report.control.faces > n {
                crate::emit(&format!(
                    "note: simplification ended at {} faces, above --faces {n}",
                    report.control.faces
                ))?;
            }
        }
    }
    for t in report.targets.iter().filter(|t| !t.met) {
        eprintln!(
            "subdfit: warning: {}: target missed: {}: {}",
            a.mesh.display(),
            t.target,
            t.outcome
        );
    }
    if let Some(second) = converted.second_opinion.as_ref().filter(|_| !a.quiet) {
        eprintln!(
            "subdfit: note: {}: {}; organic RMS {:.3}‰ in {} faces, mechanical {:.3}‰ in {}: kept {}",
            a.mesh.display(),
            second.why,
            second.organic.rms_limit_permille,
            second.organic.faces,
            second.mechanical.rms_limit_permille,
            second.mechanical.faces,
            second.kept
        );
    }
    Ok(if a.strict && !report.targets_met {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}
