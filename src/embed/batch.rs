//! Batch conversion of an asset library: `subdfit batch` and the Python
//! package's Dask batch (`subdfit.distributed`) both run this, so an asset
//! converted either way gets the same folder, the same bytes and the same
//! summary line.
//!
//! - [`plan`] turns the inputs (mesh files, folders, glob patterns, manifest
//!   files) into assets, one output folder each under the output root;
//! - [`convert_asset`] converts one asset as `subdfit convert` would, unless
//!   its folder already holds the result of the same input bytes and
//!   options (the fingerprint in [`STAMP`]); it never panics nor returns an
//!   error: a failure is an outcome, so one bad asset never stops the rest;
//! - [`run`] converts many on `jobs` threads, [`summary_table`] and
//!   [`write_summary`] report them.

use std::collections::{BTreeMap, HashSet};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::{convert_file, error_message, Options, Progress};
use crate::error::{Error, Result};
use crate::io::Format;

/// The file in an asset's folder that records what its outputs were made
/// from (input content hash, options, subdfit version). It is written last,
/// after the output set is in place, so its presence means "complete".
pub const STAMP: &str = ".subdfit-batch.json";

/// The summary files written into the output root.
pub const SUMMARY_CSV: &str = "batch.csv";
pub const SUMMARY_JSON: &str = "batch.json";

/// One input mesh and the folder its outputs go to.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Asset {
    /// The folder's name under the output root (the file's stem, made
    /// unique).
    pub name: String,
    pub input: PathBuf,
    pub output: PathBuf,
}

/// What became of an asset.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Converted,
    /// Unchanged since the run that converted it (same fingerprint).
    Skipped,
    Failed,
}

impl Status {
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Converted => "converted",
            Status::Skipped => "skipped",
            Status::Failed => "failed",
        }
    }
}

/// One asset's line of the summary.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AssetOutcome {
    #[serde(flatten)]
    pub asset: Asset,
    pub status: Status,
    /// Wall time spent on the asset in this run (checking, converting,
    /// writing).
    pub seconds: f64,
    /// The pipeline that made the result (`organic` / `mechanical`).
    pub mode: Option<String>,
    /// The CLI's message, for a failed asset.
    pub error: Option<String>,
    /// Every number of the asset's `report.json`, keys as dotted paths.
    pub figures: BTreeMap<String, f64>,
}

// ---- planning -----------------------------------------------------------------

fn is_glob(spec: &str) -> bool {
    spec.contains(['*', '?', '['])
}

fn is_mesh_file(p: &Path) -> bool {
    p.is_file() && Format::from_path(p).is_ok()
}

/// The mesh files of a folder (not its sub-folders), in name order.
fn folder_meshes(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let p = entry.map_err(|e| Error::io(dir, e))?.path();
        if is_mesh_file(&p) {
            out.push(p);
        }
    }
    out.sort();
    if out.is_empty() {
        return Err(Error::option(
            "inputs",
            format!(
                "{}: no mesh file (OBJ, PLY, OFF, STL) in this folder",
                dir.display()
            ),
        ));
    }
    Ok(out)
}

/// A manifest: one mesh path per line, relative to the manifest's folder;
/// blank lines and lines starting with `#` are ignored. A listed file that
/// is missing stays an asset (it fails, and the summary says why).
fn manifest_meshes(path: &Path) -> Result<Vec<PathBuf>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let base = path.parent().unwrap_or(Path::new(""));
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let p = base.join(line);
        if p.is_dir() {
            return Err(Error::Parse {
                path: path.to_owned(),
                location: format!("line {}", i + 1),
                msg: format!("{line} is a folder; a manifest lists mesh files"),
            });
        }
        out.push(p);
    }
    Ok(out)
}

fn glob_meshes(pattern: &str) -> Result<Vec<PathBuf>> {
    let bad = |msg: String| Error::option("inputs", format!("pattern {pattern}: {msg}"));
    let mut out = Vec::new();
    for p in glob::glob(pattern).map_err(|e| bad(e.to_string()))? {
        let p = p.map_err(|e| bad(e.to_string()))?;
        if is_mesh_file(&p) {
            out.push(p);
        }
    }
    if out.is_empty() {
        return Err(bad("matches no mesh file (OBJ, PLY, OFF, STL)".into()));
    }
    Ok(out)
}

/// The input files of one command-line input: a mesh file, a folder (its
/// mesh files), a glob pattern or a manifest (any other existing file).
fn expand(spec: &str) -> Result<Vec<PathBuf>> {
    let path = Path::new(spec);
    if path.is_dir() {
        folder_meshes(path)
    } else if path.is_file() {
        if Format::from_path(path).is_ok() {
            Ok(vec![path.to_owned()])
        } else {
            manifest_meshes(path)
        }
    } else if is_glob(spec) {
        glob_meshes(spec)
    } else {
        // A missing mesh file: an asset that fails, like a broken one.
        Ok(vec![path.to_owned()])
    }
}

/// The assets of `inputs`, each with its folder under `out_root`, in input
/// order (a file given twice is one asset). Folder names are the files'
/// stems; a stem seen before gets the extension (`bunny.obj`), then a
/// number (`bunny-2`), so names depend only on the inputs' order.
pub fn plan(inputs: &[String], out_root: &Path) -> Result<Vec<Asset>> {
    if inputs.is_empty() {
        return Err(Error::option("inputs", "no input given"));
    }
    let mut seen_inputs = HashSet::new();
    let mut names = HashSet::new();
    let mut assets = Vec::new();
    for spec in inputs {
        for input in expand(spec)? {
            if !seen_inputs.insert(input.clone()) {
                continue;
            }
            let name_of = |p: &Path, ext: bool| {
                let n = if ext { p.file_name() } else { p.file_stem() };
                n.map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "mesh".into())
            };
            let base = name_of(&input, false);
            let mut name = base.clone();
            if names.contains(&name) {
                name = name_of(&input, true);
            }
            let mut k = 2;
            while names.contains(&name) {
                name = format!("{base}-{k}");
                k += 1;
            }
            names.insert(name.clone());
            assets.push(Asset {
                output: out_root.join(&name),
                name,
                input,
            });
        }
    }
    Ok(assets)
}

// ---- one asset ----------------------------------------------------------------

/// What an asset's outputs depend on besides the input bytes, as one line.
/// The options a batch had before the proxy and the tessellation reached
/// it keep their line (so finished assets stay finished); those two are
/// added only when they are not the defaults.
fn options_key(o: &Options, source_name: &str) -> String {
    let c = &o.convert;
    let mut later = String::new();
    if c.proxy != crate::convert::Proxy::Auto {
        later += &format!(" proxy={:?}", c.proxy);
    }
    if let Some(n) = c.tessellation {
        later += &format!(" tessellation={n}");
    }
    if let Some(n) = c.displacement_samples {
        later += &format!(" displacement_samples={n}");
    }
    if c.displacement_allocation != crate::displace::SampleAllocation::Adaptive {
        later += &format!(" displacement_allocation={:?}", c.displacement_allocation);
    }
    if c.layout != crate::convert::LayoutKind::Greedy {
        later += &format!(" layout={:?}", c.layout);
    }
    if c.exact_metrics {
        later += " exact_metrics=true";
    }
    format!(
        "tolerance={:?} faces={} mode={:?} fit={:?} displacement_res={} max_error={:?} \
         m_fitmap={}{later} name={source_name}",
        c.tolerance
            .unwrap_or(crate::analysis::fitmap::DEFAULT_TOLERANCE),
        c.target_faces.unwrap_or(0),
        c.mode,
        c.objective,
        c.displacement_res.unwrap_or(0),
        c.max_error,
        !c.no_m_fitmap
    )
}

/// SHA-256 of the subdfit version, the options and the input's bytes.
pub fn fingerprint(input: &Path, options: &Options) -> Result<String> {
    let bytes = std::fs::read(input).map_err(|e| Error::io(input, e).in_role("input mesh"))?;
    let mut h = Sha256::new();
    h.update(concat!("subdfit ", env!("CARGO_PKG_VERSION"), "\n"));
    h.update(options_key(options, &input.display().to_string()));
    h.update("\n");
    h.update(&bytes);
    Ok(h.finalize().iter().map(|b| format!("{b:02x}")).collect())
}

#[derive(Serialize, Deserialize)]
struct Stamp {
    fingerprint: String,
    input: String,
    options: String,
    version: String,
}

/// The figures of a finished asset, when its stamp matches `print`.
fn finished(asset: &Asset, print: &str) -> Option<crate::report::WrittenReport> {
    let stamp = std::fs::read_to_string(asset.output.join(STAMP)).ok()?;
    let stamp: Stamp = serde_json::from_str(&stamp).ok()?;
    if stamp.fingerprint != print {
        return None;
    }
    crate::report::WrittenReport::read(&asset.output.join("report.json")).ok()
}

fn write_stamp(asset: &Asset, options: &Options, print: String) -> Result<()> {
    let stamp = Stamp {
        fingerprint: print,
        input: asset.input.display().to_string(),
        options: options_key(options, &asset.input.display().to_string()),
        version: env!("CARGO_PKG_VERSION").into(),
    };
    let text = serde_json::to_string_pretty(&stamp)
        .map_err(|e| Error::internal(format!("{STAMP}: {e}")))?;
    // Written aside and renamed, so a stamp is never half there.
    let tmp = asset.output.join(format!("{STAMP}.tmp"));
    let path = asset.output.join(STAMP);
    std::fs::write(&tmp, text + "\n").map_err(|e| Error::io(&tmp, e))?;
    std::fs::rename(&tmp, &path).map_err(|e| Error::io(&path, e))
}

/// Converts one asset as `subdfit convert INPUT -o OUTPUT` would (the
/// input named by its path, as given), or skips it when its folder holds
/// the result of the same input and options (`force` converts anyway).
/// Never fails: errors and panics become a `Failed` outcome.
pub fn convert_asset(
    asset: &Asset,
    options: &Options,
    force: bool,
    progress: &Progress,
) -> AssetOutcome {
    let t0 = Instant::now();
    let mut outcome = AssetOutcome {
        asset: asset.clone(),
        status: Status::Failed,
        seconds: 0.0,
        mode: None,
        error: None,
        figures: BTreeMap::new(),
    };
    // (status, pipeline, figures): a skipped asset's from its written
    // report.json, a converted one's from the typed result.
    type Done = (Status, Option<String>, Vec<(String, f64)>);
    let run = || -> Result<Done> {
        let options = Options {
            source_name: asset.input.display().to_string(),
            ..options.clone()
        };
        let print = fingerprint(&asset.input, &options)?;
        if !force {
            if let Some(report) = finished(asset, &print) {
                let mode = report.mode().map(str::to_owned);
                return Ok((Status::Skipped, mode, report.figures));
            }
        }
        let c = convert_file(&asset.input, &options, progress)?;
        c.write(&asset.output, progress)?;
        write_stamp(asset, &options, print)?;
        let mode = c.mode().map(str::to_owned);
        Ok((Status::Converted, mode, c.metrics))
    };
    match catch_unwind(AssertUnwindSafe(run)) {
        Ok(Ok((status, mode, figures))) => {
            outcome.status = status;
            outcome.mode = mode;
            outcome.figures = figures.into_iter().collect();
        }
        Ok(Err(e)) => outcome.error = Some(error_message(&e)),
        Err(payload) => {
            let msg = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".to_owned());
            outcome.error = Some(format!(
                "{}: internal error: subdfit panicked ({msg}); this is a bug, please report it",
                asset.input.display()
            ));
        }
    }
    outcome.seconds = t0.elapsed().as_secs_f64();
    outcome
}

// ---- many assets --------------------------------------------------------------

/// What [`run`] tells its caller as it goes (a progress bar).
pub enum Event<'a> {
    Started(&'a Asset),
    Finished(&'a AssetOutcome),
}

/// Converts `assets` on `jobs` threads (each conversion uses the rayon pool
/// as well). Outcomes come back in `assets`' order whatever the timing; a
/// cancelled `progress` stops starting new assets (those not started are
/// not in the result).
pub fn run(
    assets: &[Asset],
    options: &Options,
    force: bool,
    jobs: usize,
    on_event: &(dyn Fn(Event<'_>) + Sync),
    progress: &Progress,
) -> Vec<AssetOutcome> {
    let next = AtomicUsize::new(0);
    let done: Mutex<Vec<Option<AssetOutcome>>> = Mutex::new(vec![None; assets.len()]);
    std::thread::scope(|s| {
        for _ in 0..jobs.clamp(1, assets.len().max(1)) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                if i >= assets.len() || progress.is_cancelled() {
                    break;
                }
                on_event(Event::Started(&assets[i]));
                let o = convert_asset(&assets[i], options, force, progress);
                on_event(Event::Finished(&o));
                done.lock().unwrap_or_else(|p| p.into_inner())[i] = Some(o);
            });
        }
    });
    done.into_inner()
        .unwrap_or_else(|p| p.into_inner())
        .into_iter()
        .flatten()
        .collect()
}

// ---- summary ------------------------------------------------------------------

/// The figures the table and the CSV's first columns show: (header, key).
const KEY_FIGURES: [(&str, &str); 6] = [
    ("input F", "input.faces"),
    ("control F", "control.faces"),
    ("control V", "control.vertices"),
    ("limit RMS‰", "accuracy.limit.rms_permille"),
    ("displaced RMS‰", "accuracy.displaced.rms_permille"),
    ("limit max‰", "accuracy.limit.mesh_to_surface.max_permille"),
];

fn figure(o: &AssetOutcome, key: &str) -> String {
    match o.figures.get(key) {
        Some(v) if v.fract() == 0.0 && v.abs() < 1e15 => format!("{v:.0}"),
        Some(v) => format!("{v:.3}"),
        None => "-".into(),
    }
}

/// A plain-text table, one line per asset, then the counts.
pub fn summary_table(outcomes: &[AssetOutcome]) -> String {
    let mut head = vec!["asset", "status", "mode"];
    head.extend(KEY_FIGURES.iter().map(|f| f.0));
    head.push("seconds");
    let mut rows = vec![head.iter().map(|s| s.to_string()).collect::<Vec<_>>()];
    for o in outcomes {
        let mut r = vec![
            o.asset.name.clone(),
            o.status.as_str().into(),
            o.mode.clone().unwrap_or_else(|| "-".into()),
        ];
        r.extend(KEY_FIGURES.iter().map(|f| figure(o, f.1)));
        r.push(format!("{:.1}", o.seconds));
        rows.push(r);
    }
    let widths: Vec<usize> = (0..rows[0].len())
        .map(|c| rows.iter().map(|r| r[c].chars().count()).max().unwrap_or(0))
        .collect();
    let mut out = String::new();
    for r in &rows {
        let cells: Vec<String> = r
            .iter()
            .zip(&widths)
            .map(|(s, &w)| format!("{s}{}", " ".repeat(w - s.chars().count())))
            .collect();
        out += cells.join("  ").trim_end();
        out.push('\n');
    }
    for o in outcomes.iter().filter(|o| o.status == Status::Failed) {
        out += &format!(
            "failed: {}: {}\n",
            o.asset.name,
            o.error.as_deref().unwrap_or("")
        );
    }
    let count = |s: Status| outcomes.iter().filter(|o| o.status == s).count();
    out += &format!(
        "{} assets: {} converted, {} skipped (unchanged), {} failed\n",
        outcomes.len(),
        count(Status::Converted),
        count(Status::Skipped),
        count(Status::Failed)
    );
    out
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// `batch.csv`: one row per asset (name, status, mode, input, output,
/// seconds, error), then one column per figure, every figure any asset has
/// (the key figures first, the rest in key order; empty where an asset
/// lacks it).
pub fn summary_csv(outcomes: &[AssetOutcome]) -> String {
    let mut keys: Vec<&str> = KEY_FIGURES.iter().map(|f| f.1).collect();
    let mut rest: Vec<&str> = outcomes
        .iter()
        .flat_map(|o| o.figures.keys().map(String::as_str))
        .filter(|k| !keys.contains(k))
        .collect();
    rest.sort_unstable();
    rest.dedup();
    keys.extend(rest);
    let mut out = String::from("asset,status,mode,input,output,seconds,error");
    for k in &keys {
        out.push(',');
        out += &csv_field(k);
    }
    out.push('\n');
    for o in outcomes {
        let mut cells = vec![
            csv_field(&o.asset.name),
            o.status.as_str().into(),
            o.mode.clone().unwrap_or_default(),
            csv_field(&o.asset.input.display().to_string()),
            csv_field(&o.asset.output.display().to_string()),
            format!("{:.3}", o.seconds),
            csv_field(o.error.as_deref().unwrap_or("")),
        ];
        cells.extend(
            keys.iter()
                .map(|k| o.figures.get(*k).map(|v| v.to_string()).unwrap_or_default()),
        );
        out += &cells.join(",");
        out.push('\n');
    }
    out
}

/// Writes [`SUMMARY_CSV`] and [`SUMMARY_JSON`] (the outcomes as a JSON
/// array) into `out_root`; returns their paths.
pub fn write_summary(out_root: &Path, outcomes: &[AssetOutcome]) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_root).map_err(|e| Error::io(out_root, e))?;
    let json = serde_json::to_string_pretty(outcomes)
        .map_err(|e| Error::internal(format!("{SUMMARY_JSON}: {e}")))?;
    let mut written = Vec::new();
    for (name, text) in [
        (SUMMARY_CSV, summary_csv(outcomes)),
        (SUMMARY_JSON, json + "\n"),
    ] {
        let path = out_root.join(name);
        std::fs::write(&path, text).map_err(|e| Error::io(&path, e))?;
        written.push(path);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_names_are_unique_and_follow_input_order() {
        let tmp = tempfile::tempdir().unwrap();
        let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
        std::fs::create_dir_all(&a).unwrap();
        std::fs::create_dir_all(&b).unwrap();
        for p in [
            a.join("x.ply"),
            a.join("x.obj"),
            b.join("x.ply"),
            a.join("y.off"),
        ] {
            std::fs::write(p, "").unwrap();
        }
        std::fs::write(a.join("notes.txt"), "").unwrap();
        let manifest = tmp.path().join("list.txt");
        std::fs::write(&manifest, "# assets\n\nb/x.ply\na/y.off\nmissing.stl\n").unwrap();
        let specs = [
            a.display().to_string(),
            manifest.display().to_string(),
            format!("{}/*.ply", b.display()),
        ];
        let assets = plan(&specs, Path::new("out")).unwrap();
        let names: Vec<&str> = assets.iter().map(|a| a.name.as_str()).collect();
        // Folder in name order (x.obj < x.ply), then the manifest's new
        // files; the glob's only match is already in.
        assert_eq!(names, ["x", "x.ply", "y", "x-2", "missing"]);
        assert_eq!(assets[3].input, b.join("x.ply"));
        assert_eq!(assets[3].output, Path::new("out/x-2"));
        let e = plan(&[format!("{}/*.stl", a.display())], Path::new("out")).unwrap_err();
        assert!(e.to_string().contains("matches no mesh file"), "{e}");
    }

    #[test]
    fn a_broken_asset_is_an_outcome_with_the_cli_message() {
        let tmp = tempfile::tempdir().unwrap();
        let input = tmp.path().join("bad.off");
        std::fs::write(&input, "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n").unwrap();
        let asset = Asset {
            name: "bad".into(),
            input: input.clone(),
            output: tmp.path().join("out/bad"),
        };
        let o = convert_asset(&asset, &Options::default(), false, &Progress::none());
        assert_eq!(o.status, Status::Failed);
        let e = o.error.unwrap();
        assert!(e.starts_with("input mesh: "), "{e}");
        assert!(e.contains(&input.display().to_string()), "{e}");
        assert!(!asset.output.exists(), "a failed asset leaves no folder");
        let csv = summary_csv(std::slice::from_ref(&AssetOutcome {
            error: Some("a, \"quoted\" message".into()),
            ..convert_asset(&asset, &Options::default(), false, &Progress::none())
        }));
        assert!(csv
            .lines()
            .nth(1)
            .unwrap()
            .contains(",\"a, \"\"quoted\"\" message\","));
    }
}
