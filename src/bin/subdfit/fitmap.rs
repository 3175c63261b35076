//! `subdfit fitmap`: the Fitmap of an input mesh (Fitmaps §3.1) written as a
//! coloured PLY with the per-vertex fields `fitmap_s` and `fitmap_m`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::Result;
use clap::{Args, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use subdfit::analysis::fitmap::DEFAULT_TOLERANCE;
use subdfit::analysis::{compute_fitmap_with_progress, Fitmap, FitmapOptions, FitmapStats};
use subdfit::raycast::{make_raycaster, RayBackend};

use crate::emit;

#[derive(Copy, Clone, Debug, PartialEq, Eq, ValueEnum, Serialize)]
pub enum ColourBy {
    /// F_S on a log scale (blue: flat, red: curved).
    S,
    /// F_M by radius step (red: r_0, blue: r_h).
    M,
}

#[derive(Args)]
#[command(
    long_about = "Computes the Fitmap of a triangle mesh (Fitmaps §3.1): per vertex, \
the S-fitmap F_S (how fast the RMS error of one cubic patch grows with its radius, \
E(r) ≈ F_S⁴ r⁴) and the M-fitmap F_M (the largest of 9 radii r_0..r_h, r_0 = mean edge, \
r_h = bbox diagonal / 4, at which a patch still projects onto the mesh along its normals). \
Writes the mesh as binary PLY with float vertex properties fitmap_s and fitmap_m and a colour \
ramp in the vertex colours (see --colour-by)."
)]
pub struct FitmapArgs {
    /// Input triangle mesh (OBJ, PLY, OFF, STL); polygons are triangulated,
    /// unreferenced vertices dropped.
    mesh: PathBuf,
    /// Output PLY.
    #[arg(short, long)]
    output: PathBuf,
    /// τ, the largest fraction of a neighbourhood's area that may be
    /// unreachable by normal projection ("flipped") for the patch of that
    /// radius to count as projectable (§3.1.3). The default 0.05 sits between
    /// the paper's 1 % and 10 %: at 1 % one unhit triangle in a hundred —
    /// scanner noise — already stops a patch; at 10 % visible folds pass.
    #[arg(long, default_value_t = DEFAULT_TOLERANCE)]
    tolerance: f64,
    /// Follow §3.1.2–3.1.3 literally (quadratic in the mesh size: minutes on
    /// 10k vertices, hours on 100k). The default fast mode computes the same
    /// quantities with bounded work per vertex.
    #[arg(long)]
    exact: bool,
    /// Which field the vertex colours show. F_S: log scale, from its 2nd to
    /// its 98th percentile over the vertices; F_M: radius step / 8.
    #[arg(long, value_enum, default_value_t = ColourBy::S)]
    colour_by: ColourBy,
    /// Seed of the random samples (results are identical for one seed,
    /// whatever the thread count).
    #[arg(long, default_value_t = FitmapOptions::default().seed)]
    seed: u64,
    /// Print summary statistics and timings as JSON on stdout.
    #[arg(long)]
    json: bool,
    /// No progress bar.
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Serialize)]
struct Summary {
    mesh: String,
    output: String,
    tolerance: f64,
    exact: bool,
    colour_by: ColourBy,
    threads: usize,
    radii: Vec<f64>,
    s_min: f64,
    s_median: f64,
    s_mean: f64,
    s_max: f64,
    /// Vertices per F_M radius step 0..=8.
    m_step_histogram: Vec<usize>,
    stats: FitmapStats,
    seconds_read: f64,
    seconds_raycaster: f64,
    seconds_fitmap: f64,
    seconds_write: f64,
    seconds_total: f64,
    /// Peak resident memory of the process (VmHWM), bytes; null where
    /// /proc is unavailable.
    peak_rss_bytes: Option<u64>,
}

/// Peak resident set size of this process, from `/proc/self/status`.
pub fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// The colour ramp of the output: five stops blue → cyan → green → yellow →
/// red (a perceptually ordered "jet" without its dark ends, so that shading
/// in a viewer stays visible), linear between stops; `x` in [0, 1].
pub fn ramp(x: f64) -> [u8; 3] {
    const STOPS: [[f64; 3]; 5] = [
        [0.0, 0.0, 1.0],
        [0.0, 1.0, 1.0],
        [0.0, 1.0, 0.0],
        [1.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
    ];
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) } * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    let c = |k: usize| STOPS[i][k] + f * (STOPS[i + 1][k] - STOPS[i][k]);
    [0, 1, 2].map(|k| (c(k) * 255.0).round() as u8)
}

/// Vertex colours for the chosen field. F_S spans orders of magnitude (flat
/// regions have F_S → 0), so it is shown on a log scale between its 2nd and
/// 98th percentiles over the vertices with F_S > 0 (outliers clamp to the
/// ends, F_S = 0 shows as the low end); F_M is discrete, step / h, reversed
/// so that red marks the smallest patches ("hard to fit" is red in both).
pub fn colours(f: &Fitmap, by: ColourBy) -> Vec<[u8; 3]> {
    let h = (f.radii.len() - 1).max(1) as f64;
    match by {
        ColourBy::M => f.m_step.iter().map(|&s| ramp(1.0 - s as f64 / h)).collect(),
        ColourBy::S => {
            let mut logs: Vec<f64> = f.s.iter().filter(|&&s| s > 0.0).map(|s| s.ln()).collect();
            logs.sort_by(f64::total_cmp);
            let (lo, hi) = if logs.is_empty() {
                (0.0, 1.0)
            } else {
                let q = |p: f64| logs[((logs.len() - 1) as f64 * p).round() as usize];
                (q(0.02), q(0.98))
            };
            let span = if hi > lo { hi - lo } else { 1.0 };
            f.s.iter()
                .map(|&s| {
                    if s > 0.0 {
                        ramp((s.ln() - lo) / span)
                    } else {
                        ramp(0.0)
                    }
                })
                .collect()
        }
    }
}

pub fn fitmap(a: FitmapArgs) -> Result<ExitCode> {
    let t0 = Instant::now();
    let vm = crate::read_input(&a.mesh)?;
    let mesh = vm.mesh;
    let seconds_read = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let caster = make_raycaster(RayBackend::Embree, &mesh)?;
    let seconds_raycaster = t1.elapsed().as_secs_f64();
    let opts = FitmapOptions::default()
        .with_tolerance(a.tolerance)
        .with_exact(a.exact)
        .with_seed(a.seed);
    let bar = if a.quiet {
        ProgressBar::hidden()
    } else {
        // indicatif draws on stderr and hides itself when that is not a terminal.
        let b = ProgressBar::new(mesh.positions.len() as u64);
        b.set_style(
            ProgressStyle::with_template("fitmap {bar:40} {pos}/{len} vertices, eta {eta}")
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b
    };
    let t2 = Instant::now();
    let f = compute_fitmap_with_progress(&mesh, caster.as_ref(), &opts, &|k| bar.inc(k as u64))?;
    bar.finish_and_clear();
    let seconds_fitmap = t2.elapsed().as_secs_f64();
    let t3 = Instant::now();
    let s32: Vec<f32> = f.s.iter().map(|&x| x as f32).collect();
    let m32: Vec<f32> = f.m.iter().map(|&x| x as f32).collect();
    subdfit::io::write_ply(
        &a.output,
        &mesh.positions,
        &mesh.triangles,
        &[("fitmap_s", &s32), ("fitmap_m", &m32)],
        Some(&colours(&f, a.colour_by)),
    )?;
    let seconds_write = t3.elapsed().as_secs_f64();
    let mut sorted = f.s.clone();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len().max(1);
    let mut hist = vec![0usize; f.radii.len()];
    for &s in &f.m_step {
        hist[s as usize] += 1;
    }
    let summary = Summary {
        mesh: a.mesh.display().to_string(),
        output: a.output.display().to_string(),
        tolerance: a.tolerance,
        exact: a.exact,
        colour_by: a.colour_by,
        threads: rayon::current_num_threads(),
        radii: f.radii.clone(),
        s_min: sorted.first().copied().unwrap_or(0.0),
        s_median: sorted.get(sorted.len() / 2).copied().unwrap_or(0.0),
        s_mean: sorted.iter().sum::<f64>() / n as f64,
        s_max: sorted.last().copied().unwrap_or(0.0),
        m_step_histogram: hist,
        stats: f.stats.clone(),
        seconds_read,
        seconds_raycaster,
        seconds_fitmap,
        seconds_write,
        seconds_total: t0.elapsed().as_secs_f64(),
        peak_rss_bytes: peak_rss_bytes(),
    };
    if a.json {
        emit(&serde_json::to_string_pretty(&summary)?)?;
    } else {
        emit(&format!(
            "{}: {} vertices, F_S median {:.4e} (max {:.4e}), F_M steps {:?}, {:.2} s (fitmap {:.2} s), wrote {}",
            summary.mesh,
            f.s.len(),
            summary.s_median,
            summary.s_max,
            summary.m_step_histogram,
            summary.seconds_total,
            seconds_fitmap,
            summary.output
        ))?;
    }
    Ok(ExitCode::SUCCESS)
}
