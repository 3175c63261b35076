//! Fitmap benchmarks for `bench/fitmap_compare.sh` and
//! `bench/fitmap_speed.sh` (issue 3):
//!
//! - `fitmap_bench compare MESH...`: fast vs exact on each mesh, printing
//!   Spearman ρ of F_S, the fraction of vertices with F_M on the same radius
//!   step, the largest step difference, and both times; exits 1 when a mesh
//!   fails the criterion (ρ >= 0.95, >= 90 % same step, never more
//!   than one step apart).
//! - `fitmap_bench diag MESH...`: the vertices where fast and exact F_M
//!   are more than one step apart, with the exact mode's flipped fraction
//!   at every radius (which radii sit near τ) and the neighbours' steps.
//! - `fitmap_bench speed MESH [SPLITS]`: the fast mode on MESH after
//!   `SPLITS` 1→4 midpoint subdivisions (the geometry is unchanged, the
//!   sampling four times denser each time), printing wall time, CPU time
//!   and the process's peak resident memory (VmHWM) as one JSON line.
//!
//! `FITMAP_CERTIFY=1` runs the fast mode with `FitmapOptions::certify`.
//! All use the Embree caster and all threads of rayon's pool
//! (`RAYON_NUM_THREADS` to pin it).

use std::collections::HashMap;
use std::path::Path;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use subdfit::analysis::fitmap::exact_flip_fractions;
use subdfit::analysis::{compare_fitmaps, compute_fitmap, FitmapOptions};
use subdfit::mesh::TriMesh;
use subdfit::raycast::{make_raycaster, RayBackend};

/// One 1→4 midpoint split: every triangle into four, shared edge midpoints.
fn split(m: &TriMesh) -> TriMesh {
    let mut positions = m.positions.clone();
    let mut mid: HashMap<(u32, u32), u32> = HashMap::with_capacity(m.triangles.len() * 3 / 2);
    let mut triangles = Vec::with_capacity(m.triangles.len() * 4);
    for t in &m.triangles {
        let mut e = [0u32; 3];
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            e[k] = *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                positions.push((positions[a as usize] + positions[b as usize]) * 0.5);
                (positions.len() - 1) as u32
            });
        }
        triangles.push([t[0], e[0], e[2]]);
        triangles.push([t[1], e[1], e[0]]);
        triangles.push([t[2], e[2], e[1]]);
        triangles.push(e);
    }
    TriMesh {
        positions,
        triangles,
    }
}

fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    Some(line.split_whitespace().nth(1)?.parse::<u64>().ok()? * 1024)
}

/// CPU seconds (user + system) of this process, from `/proc/self/stat`.
fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0) // USER_HZ is 100 on Linux
}

fn load(path: &str) -> Result<TriMesh> {
    Ok(subdfit::io::read_mesh(Path::new(path))
        .with_context(|| format!("reading {path}"))?
        .mesh)
}

/// The exact Fitmap, cached under `$FITMAP_EXACT_CACHE` (a directory)
/// when that is set: the exact mode takes minutes, and comparing variants
/// of the fast mode against it needs it once per mesh and seed.
fn exact_cached(
    path: &str,
    m: &TriMesh,
    caster: &dyn subdfit::raycast::RayCaster,
    opts: &FitmapOptions,
) -> Result<subdfit::analysis::Fitmap> {
    let exact = || compute_fitmap(m, caster, &opts.clone().with_exact(true));
    let Some(dir) = std::env::var_os("FITMAP_EXACT_CACHE") else {
        return Ok(exact()?);
    };
    let name = Path::new(path)
        .file_name()
        .map_or("mesh".into(), |n| n.to_string_lossy().into_owned());
    let file = Path::new(&dir).join(format!("{name}.{}.{}.fm", opts.seed, opts.tolerance));
    if let Ok(bytes) = std::fs::read(&file) {
        // A template with the right radii and stats; fields overwritten.
        let mut f = compute_fitmap(m, caster, opts)?;
        let n = m.positions.len();
        if bytes.len() == n * 9 {
            for v in 0..n {
                let mut b = [0u8; 8];
                b.copy_from_slice(&bytes[8 * v..8 * v + 8]);
                f.s[v] = f64::from_le_bytes(b);
                f.m_step[v] = bytes[8 * n + v];
                f.m[v] = f.radii[f.m_step[v] as usize];
            }
            return Ok(f);
        }
    }
    let f = exact()?;
    let mut bytes: Vec<u8> = f.s.iter().flat_map(|x| x.to_le_bytes()).collect();
    bytes.extend_from_slice(&f.m_step);
    std::fs::write(&file, bytes)?;
    Ok(f)
}

fn compare(paths: &[String]) -> Result<bool> {
    let mut all = true;
    println!(
        "{:<18} {:>7} {:>9} {:>9} {:>10} {:>9} {:>9} {:>8}",
        "mesh", "verts", "exact s", "fast s", "rho(F_S)", "same F_M", "max diff", "passes"
    );
    for p in paths {
        let m = load(p)?;
        let caster = make_raycaster(RayBackend::Embree, &m)?;
        let opts = fast_options();
        let t = Instant::now();
        let exact = exact_cached(p, &m, caster.as_ref(), &opts)?;
        let te = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let fast = compute_fitmap(&m, caster.as_ref(), &opts)?;
        let tf = t.elapsed().as_secs_f64();
        let a = compare_fitmaps(&exact, &fast);
        let name = Path::new(p)
            .file_name()
            .map_or(p.clone(), |n| n.to_string_lossy().into());
        println!(
            "{:<18} {:>7} {:>9.2} {:>9.2} {:>10.4} {:>8.2}% {:>9} {:>8}",
            name,
            m.positions.len(),
            te,
            tf,
            a.s_spearman.unwrap_or(f64::NAN),
            100.0 * a.m_same_step,
            a.m_max_step_diff,
            a.passes()
        );
        all &= a.passes();
    }
    Ok(all)
}

/// The fast mode's options: the default, or with
/// [`FitmapOptions::certify`] when `FITMAP_CERTIFY=1`.
fn fast_options() -> FitmapOptions {
    let certify = std::env::var("FITMAP_CERTIFY").is_ok_and(|v| v == "1");
    FitmapOptions::default().with_certify(certify)
}

/// Where fast and exact F_M differ by more than one step: the histogram of
/// step differences, then per such vertex both steps, the exact mode's
/// literal flipped fraction at every radius (F_M is the largest radius
/// below τ, so this shows which radii sit near τ) and its neighbours'
/// `exact/fast` steps (whether they agree with it).
fn diag(paths: &[String]) -> Result<()> {
    for p in paths {
        let m = load(p)?;
        let caster = make_raycaster(RayBackend::Embree, &m)?;
        let opts = fast_options();
        let exact = exact_cached(p, &m, caster.as_ref(), &opts)?;
        let fast = compute_fitmap(&m, caster.as_ref(), &opts)?;
        let adj = subdfit::analysis::neighbourhood::Adjacency::new(&m);
        let mut hist = [0usize; 9];
        for v in 0..m.positions.len() {
            let d = exact.m_step[v].abs_diff(fast.m_step[v]) as usize;
            hist[d.min(8)] += 1;
            if d <= 1 {
                continue;
            }
            let fr = exact_flip_fractions(&m, caster.as_ref(), &opts, v as u32)?;
            let fr: Vec<String> = fr
                .iter()
                .map(|f| f.map_or("-".into(), |f| format!("{:.3}", f.max(0.0))))
                .collect();
            let nb: Vec<String> = adj
                .vv
                .row(v)
                .iter()
                .map(|&w| {
                    format!(
                        "{w}:{}/{}",
                        exact.m_step[w as usize], fast.m_step[w as usize]
                    )
                })
                .collect();
            println!(
                "v{v} exact {} fast {} fractions [{}] neighbours {}",
                exact.m_step[v],
                fast.m_step[v],
                fr.join(" "),
                nb.join(" ")
            );
        }
        println!("{p}: vertices by |step difference| 0..8: {hist:?}");
    }
    Ok(())
}

fn speed(path: &str, splits: u32) -> Result<()> {
    let mut m = load(path)?;
    for _ in 0..splits {
        m = split(&m);
    }
    let c0 = cpu_seconds().unwrap_or(0.0);
    let t = Instant::now();
    let caster = make_raycaster(RayBackend::Embree, &m)?;
    let f = compute_fitmap(&m, caster.as_ref(), &fast_options())?;
    let wall = t.elapsed().as_secs_f64();
    let cpu = cpu_seconds().unwrap_or(0.0) - c0;
    let name = Path::new(path)
        .file_name()
        .map_or(path.into(), |n| n.to_string_lossy().into_owned());
    println!(
        "{}",
        serde_json::json!({
            "mesh": name,
            "splits": splits,
            "vertices": m.positions.len(),
            "triangles": m.triangles.len(),
            "threads": rayon::current_num_threads(),
            "wall_seconds": wall,
            "cpu_seconds": cpu,
            "analysed_vertices": f.stats.analysed_vertices,
            "rays": f.stats.rays,
            "peak_rss_bytes": peak_rss_bytes(),
        })
    );
    Ok(())
}

fn main() -> Result<ExitCode> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("compare") if args.len() > 1 => Ok(if compare(&args[1..])? {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(1)
        }),
        Some("diag") => {
            diag(&args[1..])?;
            Ok(ExitCode::SUCCESS)
        }
        Some("speed") if args.len() == 2 || args.len() == 3 => {
            let splits = args.get(2).map_or(Ok(0), |s| s.parse()).context("SPLITS")?;
            speed(&args[1], splits)?;
            Ok(ExitCode::SUCCESS)
        }
        _ => bail!(
            "usage: fitmap_bench compare MESH... | fitmap_bench diag MESH... | \
             fitmap_bench speed MESH [SPLITS]"
        ),
    }
}
