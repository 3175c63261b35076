//! `subdfit simplify`: Fitmap-driven simplification of the quad control
//! mesh (Fitmaps §3.3–3.4).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use subdfit::analysis::{compute_fitmap, Fitmap, FitmapOptions};
use subdfit::quad::{simplify_with_progress, SimplifyOptions, SimplifyStats, StopReason};
use subdfit::raycast::{make_raycaster, RayBackend};

#[derive(Args)]
pub struct SimplifyArgs {
    /// Input triangle mesh (OBJ, PLY, OFF, STL).
    mesh: PathBuf,
    /// Output control mesh (OBJ, written atomically).
    #[arg(short, long)]
    output: PathBuf,
    /// Fitmap tolerance τ (a fraction: 0.01 = 1 %), the only parameter of the
    /// method (§3.1.3). Default: the Fitmap default, 0.05.
    #[arg(long)]
    tolerance: Option<f64>,
    /// Stop at this many faces (simplification may end above it).
    #[arg(long)]
    faces: Option<usize>,
    /// Lift the M-fitmap projectability test (the paper's Fig. 7 experiment).
    #[arg(long)]
    no_mfitmap: bool,
    /// Print a JSON summary instead of text (no progress bar).
    #[arg(long)]
    json: bool,
    /// Development aid: read the Fitmap from this file if it exists (it
    /// must match the mesh's vertex count and τ), else compute it and store
    /// it there. The Fitmap of bunny takes minutes; the simplification alone
    /// is what `bench/simplify.sh` times.
    #[arg(long, hide = true)]
    fitmap_cache: Option<PathBuf>,
    /// Development aid: the surface guard's "scale,floor,min_cos" (see
    /// `SimplifyOptions::guard_scale`).
    #[arg(long, hide = true, value_delimiter = ',')]
    guard: Option<Vec<f64>>,
    /// Development aid: the S-fitmap test's κ in units of the Fitmap's
    /// equal-count κ₀ (see `SimplifyOptions::s_fitmap_scale`; 0 = off).
    #[arg(long, hide = true)]
    s_fitmap: Option<f64>,
    /// Development aid: collapses evaluated together (see
    /// `SimplifyOptions::batch`; 1 = the sequential loop).
    #[arg(long, hide = true)]
    batch: Option<usize>,
}

/// Raw little-endian cache of the Fitmap fields the simplification reads:
/// magic, τ, counts, then radii, s, m (f64) and m_step (u8).
const CACHE_MAGIC: &[u8; 8] = b"SDFFMAP1";

fn save_fitmap(path: &std::path::Path, f: &Fitmap) -> Result<()> {
    let mut b = Vec::with_capacity(32 + 8 * (f.radii.len() + 2 * f.s.len()) + f.s.len());
    b.extend_from_slice(CACHE_MAGIC);
    b.extend_from_slice(&f.tolerance.to_le_bytes());
    b.extend_from_slice(&(f.radii.len() as u64).to_le_bytes());
    b.extend_from_slice(&(f.s.len() as u64).to_le_bytes());
    for x in f.radii.iter().chain(&f.s).chain(&f.m) {
        b.extend_from_slice(&x.to_le_bytes());
    }
    b.extend_from_slice(&f.m_step);
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, &b).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn load_fitmap(path: &std::path::Path, nv: usize, tolerance: f64) -> Result<Option<Fitmap>> {
    let Ok(b) = std::fs::read(path) else {
        return Ok(None);
    };
    let bad = || anyhow::anyhow!("{}: not a Fitmap cache of this mesh and τ", path.display());
    let f64_at = |i: usize| -> Result<f64> {
        let s = b.get(i..i + 8).ok_or_else(bad)?;
        Ok(f64::from_le_bytes(s.try_into().expect("8 bytes")))
    };
    if b.get(..8) != Some(CACHE_MAGIC.as_slice()) || f64_at(8)? != tolerance {
        return Err(bad());
    }
    let nr = f64_at(16)?.to_bits() as usize;
    let n = f64_at(24)?.to_bits() as usize;
    if n != nv || b.len() != 32 + 8 * (nr + 2 * n) + n {
        return Err(bad());
    }
    let mut at = 32;
    let mut take = |k: usize| -> Result<Vec<f64>> {
        let v = (0..k).map(|i| f64_at(at + 8 * i)).collect::<Result<_>>()?;
        at += 8 * k;
        Ok(v)
    };
    let radii = take(nr)?;
    let s = take(n)?;
    let m = take(n)?;
    let m_step = b[32 + 8 * (nr + 2 * n)..].to_vec();
    Ok(Some(Fitmap {
        radii,
        s,
        m,
        m_step,
        tolerance,
        stats: Default::default(),
    }))
}

#[derive(Serialize)]
struct Summary {
    input: String,
    output: String,
    tolerance: f64,
    target_faces: Option<usize>,
    m_fitmap: bool,
    faces: usize,
    vertices: usize,
    irregular_vertices: usize,
    collapses: usize,
    rotations: usize,
    doublets: usize,
    stopped_at: StopReason,
    message: Option<String>,
    seconds_read: f64,
    seconds_fitmap: f64,
    seconds_quadrangulate: f64,
    seconds_interpolate: f64,
    seconds_simplify: f64,
    collapses_per_second: f64,
    stats: SimplifyStats,
}

pub fn run(a: SimplifyArgs) -> Result<ExitCode> {
    let t = Instant::now();
    let m = crate::read_input(&a.mesh)?;
    let seconds_read = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let caster = make_raycaster(RayBackend::Embree, &m.mesh)
        .with_context(|| format!("{}: building the ray caster", a.mesh.display()))?;
    let mut fo = FitmapOptions::default();
    if let Some(tau) = a.tolerance {
        fo = fo.with_tolerance(tau);
    }
    let tolerance = fo.tolerance;
    let cached = match &a.fitmap_cache {
        Some(p) => load_fitmap(p, m.mesh.positions.len(), tolerance)?,
        None => None,
    };
    let fitmap = match cached {
        Some(f) => f,
        None => {
            let f = compute_fitmap(&m.mesh, caster.as_ref(), &fo)
                .with_context(|| format!("{}: Fitmap", a.mesh.display()))?;
            if let Some(p) = &a.fitmap_cache {
                save_fitmap(p, &f)?;
            }
            f
        }
    };
    let seconds_fitmap = t.elapsed().as_secs_f64();
    let mut opts = SimplifyOptions::default()
        .with_target_faces(a.faces)
        .with_m_fitmap(!a.no_mfitmap);
    if let Some(n) = a.batch {
        opts = opts.with_batch(n);
    }
    if let Some(g) = &a.guard {
        anyhow::ensure!(g.len() == 3, "--guard takes scale,floor,min_cos");
        opts = opts.with_guard(g[0], g[1], g[2]);
    }
    if let Some(x) = a.s_fitmap {
        anyhow::ensure!(x >= 0.0, "--s-fitmap takes a scale >= 0");
        opts = opts.with_s_fitmap_scale(x);
    }
    let bar = if a.json {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(0);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} simplifying [{elapsed_precise}] {wide_bar} {msg}",
            )
            .expect("static template"),
        );
        b
    };
    let mut cb = |p: subdfit::quad::Progress| {
        let goal = p.initial_faces.saturating_sub(a.faces.unwrap_or(0)) as u64;
        bar.set_length(goal.max(1));
        bar.set_position((p.initial_faces - p.faces) as u64);
        bar.set_message(format!(
            "{} faces left, {:.0} collapses/s",
            p.faces,
            p.collapses as f64 / p.seconds.max(1e-9)
        ));
        true
    };
    let s = simplify_with_progress(&m.mesh, &fitmap, caster.as_ref(), &opts, &mut cb)
        .with_context(|| format!("{}: simplification", a.mesh.display()))?;
    bar.finish_and_clear();
    subdfit::io::write_control_obj(&a.output, &s.mesh)?;
    let st = s.stats;
    let stopped_at = st.stop.unwrap_or(StopReason::NaturalEnd);
    let message = match a.faces {
        Some(n) if st.faces > n => Some(format!(
            "simplification ended above {n} faces: no allowed collapse remains at {} faces",
            st.faces
        )),
        _ => None,
    };
    let sum = Summary {
        input: a.mesh.display().to_string(),
        output: a.output.display().to_string(),
        tolerance,
        target_faces: a.faces,
        m_fitmap: !a.no_mfitmap,
        faces: st.faces,
        vertices: st.vertices,
        irregular_vertices: st.irregular_vertices,
        collapses: st.collapses,
        rotations: st.rotations,
        doublets: st.doublets,
        stopped_at,
        message: message.clone(),
        seconds_read,
        seconds_fitmap,
        seconds_quadrangulate: st.seconds_quadrangulate,
        seconds_interpolate: st.seconds_interpolate,
        seconds_simplify: st.seconds_simplify,
        collapses_per_second: st.collapses as f64 / st.seconds_simplify.max(1e-9),
        stats: st,
    };
    if a.json {
        crate::emit(&serde_json::to_string_pretty(&sum)?)?;
    } else {
        let mut text = format!(
            "{}: {} triangles -> {} faces, {} vertices ({} irregular)\n\
             {} collapses, {} rotations, {} doublets removed; stopped: {:?}\n\
             time: read {:.2} s, fitmap {:.2} s, quadrangulate {:.2} s, interpolate {:.2} s, \
             simplify {:.2} s ({:.0} collapses/s)\nwrote {}",
            sum.input,
            sum.stats.input_triangles,
            sum.faces,
            sum.vertices,
            sum.irregular_vertices,
            sum.collapses,
            sum.rotations,
            sum.doublets,
            sum.stopped_at,
            seconds_read,
            seconds_fitmap,
            sum.seconds_quadrangulate,
            sum.seconds_interpolate,
            sum.seconds_simplify,
            sum.collapses_per_second,
            sum.output
        );
        if let Some(msg) = message {
            text += &format!("\n{msg}");
        }
        crate::emit(&text)?;
    }
    Ok(ExitCode::SUCCESS)
}
