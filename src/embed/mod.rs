//! The library API behind the C++ embedding (`include/subdfit/subdfit.hpp`).
//!
//! Everything a C++ host can call goes through this module: the cxx bridge in
//! `bridge` (`src/embed/bridge.rs`) only turns flat slices into the borrowed views below,
//! catches panics and formats errors. Keeping the logic here means the C++
//! API and the Rust API cannot drift apart, and everything is testable from
//! Rust.
//!
//! # Progress and cancellation (for the pipeline stages)
//!
//! [`convert`] and [`fit`] take a [`Progress`]. Every long stage must
//!
//! - call [`Progress::report`]`(stage, fraction)` when it starts (`0.0`), at
//!   least every ~50 ms of work while it runs (per patch, per solver
//!   iteration, per chunk of a parallel loop — it is cheap: the host callback
//!   is rate-limited to one call per [`Progress::MIN_INTERVAL`] except at
//!   `0.0`, `1.0` and stage changes) and when it ends (`1.0`);
//! - propagate its `Err(Error::Cancelled { .. })` with `?`, dropping whatever it
//!   built. Inner loops that cannot afford a call may poll the atomic
//!   [`Progress::check`] instead.
//!
//! A cancelled call therefore returns within one report interval, and since
//! no stage keeps anything outside its own stack (no global caches: thread
//! pools made for `Options::threads` are per call too), nothing survives it.
//!
//! `report` may be called from rayon workers: calls into the host callback
//! are serialised (a worker that finds the callback busy skips its report
//! instead of waiting), so the host sees one call at a time, though not
//! necessarily on its own thread.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::analysis::FitmapOptions;
use crate::convert::{
    convert_in_memory, fit_in_memory, write_converted, ConvertOptions, Converted, PipelineOptions,
};
use crate::displace::Atlas;
use crate::error::{Error, Result};
use crate::fit::FitOptions;
use crate::io::control_obj_with_uvs;
use crate::mesh::{validate_soup, ControlMesh, PolySoup, ValidatedMesh, VertexId};
use crate::report::{MetricsOptions, StageTimer};
use crate::subdiv::{make_evaluator, Backend, EvalOptions, LimitPoint, SurfaceLocation};
use crate::{DVec2, DVec3};

/// The cxx `extern "Rust"` bridge of `cpp/api/subdfit.cpp`: it lives here,
/// beside the API it exposes, so that `crate::ffi` (bridges *to* C++, used by
/// the lowest layers) never imports the top of the crate.
mod bridge;

pub mod batch;

// ---- options ------------------------------------------------------------------

/// The choices of a conversion, as every host spells them: one mode enum
/// and one objective enum for the CLI, this API, C++ and Python.
pub use crate::convert::{Mode, Proxy};
pub use crate::fit::Objective;

/// Options of [`convert`] and [`fit`]: `subdfit convert`'s options
/// ([`ConvertOptions`], the one options type every host maps to, so that
/// an option added there reaches every host) and how this call runs.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct Options {
    /// τ, `--faces`, `--mode`, `--fit`, `--displacement-res`,
    /// `--max-error`, `--no-mfitmap`, `--tessellation`, `--proxy`. τ is set
    /// (to the CLI's default, [`crate::analysis::fitmap::DEFAULT_TOLERANCE`])
    /// so that `report.json` states it as the CLI's does.
    pub convert: ConvertOptions,
    /// Worker threads; 0 uses rayon's global pool (all cores). A non-zero
    /// value runs the call on a pool of its own that ends with the call.
    pub threads: u32,
    /// Name used for the input in error messages (the CLI uses the path, so
    /// a host that passes the file name gets the CLI's messages verbatim).
    pub source_name: String,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            convert: ConvertOptions::default()
                .with_tolerance(Some(crate::analysis::fitmap::DEFAULT_TOLERANCE)),
            threads: 0,
            source_name: "input mesh".to_owned(),
        }
    }
}

impl Options {
    /// Rejects values no stage could use, before any work starts
    /// ([`ConvertOptions::check`]).
    pub fn check(&self) -> Result<()> {
        self.convert.check()
    }
}

// ---- progress -----------------------------------------------------------------

/// The host's progress callback: `(stage, fraction)`, returns `false` to
/// cancel.
pub type ProgressFn<'a> = dyn Fn(&str, f64) -> bool + Sync + 'a;

/// Progress reporting and cancellation for one call; see the module doc.
pub struct Progress<'a> {
    sink: Option<&'a ProgressFn<'a>>,
    cancelled: AtomicBool,
    /// Held while the host callback runs; also the time of the last call and
    /// the last stage, for rate limiting.
    state: Mutex<(Option<Instant>, String, f64)>,
}

impl<'a> Progress<'a> {
    /// Shortest interval between two host calls within a stage.
    pub const MIN_INTERVAL: Duration = Duration::from_millis(20);

    /// No callback: reports are dropped and nothing cancels.
    pub fn none() -> Self {
        Progress {
            sink: None,
            cancelled: AtomicBool::new(false),
            state: Mutex::new((None, String::new(), -1.0)),
        }
    }

    pub fn new(sink: &'a ProgressFn<'a>) -> Self {
        Progress {
            sink: Some(sink),
            ..Progress::none()
        }
    }

    /// Tells the host that `stage` is `fraction` (0..=1) done and asks
    /// whether to go on: `Err(Error::Cancelled { .. })` once the host said stop.
    pub fn report(&self, stage: &str, fraction: f64) -> Result<()> {
        self.check()?;
        let Some(sink) = self.sink else {
            return Ok(());
        };
        let fraction = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        // A worker that finds another one inside the callback skips its
        // report: the host gets serialised calls and workers never queue.
        let Ok(mut state) = self.state.try_lock() else {
            return Ok(());
        };
        let now = Instant::now();
        // A stage's start and end always pass; a repeat of the last report
        // (a watched stage asking whether to go on, `crate::watch`) is rate
        // limited like any other.
        let boundary =
            state.1 != stage || ((fraction == 0.0 || fraction == 1.0) && state.2 != fraction);
        if !boundary && state.0.is_some_and(|t| now - t < Self::MIN_INTERVAL) {
            return Ok(());
        }
        state.0 = Some(now);
        state.2 = fraction;
        if state.1 != stage {
            state.1 = stage.to_owned();
        }
        if !sink(stage, fraction) {
            self.cancelled.store(true, Ordering::Relaxed);
        }
        drop(state);
        self.check()
    }

    /// Cheap poll for inner loops (one atomic load).
    pub fn check(&self) -> Result<()> {
        if self.is_cancelled() {
            let stage = self
                .state
                .try_lock()
                .map(|s| s.1.clone())
                .unwrap_or_default();
            Err(Error::Cancelled { stage })
        } else {
            Ok(())
        }
    }

    pub fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::Relaxed)
    }
}

// ---- inputs -------------------------------------------------------------------

/// A polygon mesh as flat arrays borrowed from the host (no copy until it is
/// validated into the pipeline's own mesh).
#[derive(Copy, Clone, Debug)]
pub struct MeshArrays<'a> {
    /// xyz per vertex.
    pub positions: &'a [f64],
    /// Corner count per face.
    pub face_sizes: &'a [u32],
    /// Vertex indices of all faces, concatenated.
    pub face_indices: &'a [u32],
}

impl MeshArrays<'_> {
    fn check_shape(&self) -> Result<()> {
        if self.positions.len() % 3 != 0 {
            return Err(Error::InvalidArgument(format!(
                "positions hold {} doubles, not a multiple of 3 (x, y, z per vertex)",
                self.positions.len()
            )));
        }
        let total: u64 = self.face_sizes.iter().map(|&n| u64::from(n)).sum();
        if total != self.face_indices.len() as u64 {
            return Err(Error::InvalidArgument(format!(
                "face sizes add up to {total} but {} face indices were given",
                self.face_indices.len()
            )));
        }
        Ok(())
    }

    fn points(&self) -> Vec<DVec3> {
        self.positions
            .chunks_exact(3)
            .map(|p| DVec3::new(p[0], p[1], p[2]))
            .collect()
    }

    /// The polygons as a soup, indices unchecked (validation names the bad
    /// element with the same messages as the file readers).
    pub fn to_soup(&self) -> Result<PolySoup> {
        self.check_shape()?;
        let mut soup = PolySoup {
            positions: self.points(),
            face_offsets: Vec::with_capacity(self.face_sizes.len() + 1),
            face_indices: self.face_indices.to_vec(),
        };
        let mut end = 0u32;
        soup.face_offsets.push(0);
        for &n in self.face_sizes {
            end += n; // cannot overflow: the sum equals face_indices.len()
            soup.face_offsets.push(end);
        }
        Ok(soup)
    }

    /// The validated triangle mesh the pipeline starts from, as
    /// `subdfit::io::read_mesh` gives it for a file called `name`.
    pub fn to_validated(&self, name: &str) -> Result<ValidatedMesh> {
        validate_soup(self.to_soup()?, Path::new(name))
    }

    /// [`MeshArrays::to_validated`] as the CLI's `convert` / `fit` take their
    /// input: non-manifold pieces split, errors said of the "input mesh".
    pub fn to_input_mesh(&self, name: &str) -> Result<ValidatedMesh> {
        self.to_validated(name)
            .and_then(|m| m.into_manifold(Path::new(name)))
            .map_err(|e| e.in_role("input mesh"))
    }
}

/// A control mesh as flat arrays borrowed from the host.
#[derive(Copy, Clone, Debug)]
pub struct ControlArrays<'a> {
    pub mesh: MeshArrays<'a>,
    /// Pairs of vertex indices, one pair per crease edge.
    pub crease_vertices: &'a [u32],
    pub crease_weights: &'a [f64],
    pub corner_vertices: &'a [u32],
    pub corner_weights: &'a [f64],
}

impl ControlArrays<'_> {
    /// Builds (and checks) the half-edge control mesh.
    pub fn to_control_mesh(&self) -> Result<ControlMesh> {
        self.mesh.check_shape()?;
        if self.crease_vertices.len() != 2 * self.crease_weights.len() {
            return Err(Error::InvalidArgument(format!(
                "{} crease vertex indices for {} crease weights (two per crease expected)",
                self.crease_vertices.len(),
                self.crease_weights.len()
            )));
        }
        if self.corner_vertices.len() != self.corner_weights.len() {
            return Err(Error::InvalidArgument(format!(
                "{} corner vertices for {} corner weights",
                self.corner_vertices.len(),
                self.corner_weights.len()
            )));
        }
        let mut faces = Vec::with_capacity(self.mesh.face_sizes.len());
        let mut start = 0usize;
        for &n in self.mesh.face_sizes {
            faces.push(&self.mesh.face_indices[start..start + n as usize]);
            start += n as usize;
        }
        let mut mesh = ControlMesh::from_polygons(self.mesh.points(), &faces)?;
        for (ab, &s) in self
            .crease_vertices
            .chunks_exact(2)
            .zip(self.crease_weights)
        {
            mesh.set_crease(VertexId(ab[0]), VertexId(ab[1]), s)?;
        }
        for (&v, &s) in self.corner_vertices.iter().zip(self.corner_weights) {
            mesh.set_corner(VertexId(v), s)?;
        }
        Ok(mesh)
    }
}

// ---- outputs ------------------------------------------------------------------

/// One patch's displacement samples: `resolution × resolution` scalar
/// offsets along the limit normal, row-major in the patch's `(u, v)`
/// (`v` rows, `u` columns), as baked into the atlas.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DisplacementTile {
    pub face: u32,
    pub resolution: u32,
    pub values: Vec<f32>,
}

/// What [`convert`] and [`fit`] produce.
#[derive(Clone, Debug)]
pub struct Conversion {
    pub control: ControlMesh,
    /// Per-corner UVs into the displacement atlas: `uv_indices` runs
    /// parallel to the control mesh's face indices and points into `uvs`.
    pub uvs: Vec<DVec2>,
    pub uv_indices: Vec<u32>,
    pub tiles: Vec<DisplacementTile>,
    /// The numeric leaves of `report.json`, keys as dotted paths
    /// (`"accuracy.limit.rms_permille"`), in key order
    /// ([`crate::report::Report::figures`]).
    pub metrics: Vec<(String, f64)>,
    /// `report.json`, byte for byte what the CLI writes (timings differ
    /// from run to run).
    pub report_json: String,
    /// `control.obj`, byte for byte what the CLI writes.
    pub control_obj: Vec<u8>,
    /// What [`Conversion::write`] writes from: the validated input and the
    /// pipeline's own result (shared, so a clone stays cheap).
    outputs: Arc<Outputs>,
}

/// The input and the pipeline result behind a [`Conversion`], kept so that
/// the host can write the CLI's output set without a second run.
struct Outputs {
    input: ValidatedMesh,
    converted: Converted,
}

impl std::fmt::Debug for Outputs {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Outputs { .. }")
    }
}

impl Conversion {
    /// Everything a host gets from a pipeline result, taken from the same
    /// values the CLI writes (so files made from it match the CLI's).
    fn from_converted(input: ValidatedMesh, c: Converted) -> Result<Conversion> {
        // Mechanical mode: the atlas is laid out on the once-refined quad
        // mesh (same limit surface), which the host gets, so that UVs and
        // tiles apply to the mesh it holds (the CLI's control.obj).
        let control = c.quad_control.as_ref().unwrap_or(&c.control).clone();
        let d = &c.surfaces.displacement;
        let patches = d.grid.num_patches();
        let atlas = Atlas::for_grid(&d.grid, c.outputs.atlas)?;
        let quads: Vec<[DVec2; 4]> = (0..patches).map(|f| atlas.corner_uvs(f)).collect();
        let control_obj = control_obj_with_uvs(&control, &quads)?;
        // One `vt` per face corner, as in control.obj.
        let uvs: Vec<DVec2> = quads.iter().flatten().copied().collect();
        let uv_indices = (0..uvs.len() as u32).collect();
        let tiles = (0..patches)
            .map(|f| {
                let res = d.grid.patch_res(f);
                let mut values = Vec::with_capacity(res * res);
                for j in 0..res {
                    for i in 0..res {
                        values.push(d.offsets[d.grid.sample(f, i, j) as usize] as f32);
                    }
                }
                DisplacementTile {
                    face: f as u32,
                    resolution: res as u32,
                    values,
                }
            })
            .collect();
        let mut report_json = serde_json::to_string_pretty(&c.report)
            .map_err(|e| Error::internal(format!("report.json: {e}")))?;
        report_json.push('\n');
        Ok(Conversion {
            metrics: c.report.figures()?,
            control,
            uvs,
            uv_indices,
            tiles,
            report_json,
            control_obj,
            outputs: Arc::new(Outputs {
                input,
                converted: c,
            }),
        })
    }

    /// The pipeline whose result this is (`"organic"`, `"mechanical"`;
    /// `None` for `fit`), from the typed run record
    /// ([`crate::convert::RunOptions::mode`]).
    pub fn mode(&self) -> Option<&'static str> {
        self.outputs.converted.report.options.mode()
    }

    /// Writes the CLI's output set (`control.obj`, `control.usda`,
    /// `limit.ply`, `displaced.ply`, `displacement.exr`, `fitmap.ply`,
    /// `report.json`, …) into `dir` as `subdfit convert` / `subdfit fit`
    /// does: the same bytes (but for the timings in `report.json`), built
    /// beside `dir` and swapped in whole. Returns the files written.
    pub fn write(&self, dir: &Path, progress: &Progress) -> Result<Vec<PathBuf>> {
        let o = &self.outputs;
        write_converted(&o.input, &o.converted, dir, None, &mut sink(progress)).map_err(|e| match e
        {
            Error::Cancelled { .. } => e,
            e => e.context(dir.display()),
        })
    }
}

/// An error as the CLI prints it after `subdfit: error: `: the message
/// and its causes, `: `-separated, skipping a cause whose text is already
/// there (our errors print their source too).
pub fn error_message(e: &Error) -> String {
    let mut out = e.to_string();
    let mut cause = std::error::Error::source(e);
    while let Some(c) = cause {
        let text = c.to_string();
        if !out.contains(&text) {
            out += ": ";
            out += &text;
        }
        cause = c.source();
    }
    out
}

/// Reads a mesh file as `subdfit convert` / `subdfit fit` read their input:
/// validated, non-manifold pieces split, errors said of the "input mesh".
pub fn read_input(path: &Path) -> Result<ValidatedMesh> {
    crate::io::read_mesh(path)
        .and_then(|m| m.into_manifold(path))
        .map_err(|e| e.in_role("input mesh"))
}

// ---- entry points -------------------------------------------------------------

/// Limit position, derivatives (tangent masks) at every control vertex, in
/// order — what `subdfit limit CONTROL` writes.
pub fn limit_points(control: &ControlArrays, backend: Backend) -> Result<Vec<LimitPoint>> {
    let mesh = control.to_control_mesh()?;
    let eval = make_evaluator(backend, &mesh, &EvalOptions::default())?;
    eval.vertex_limits(mesh.positions())
}

/// Limit position and derivatives at each location.
pub fn evaluate(
    control: &ControlArrays,
    locations: &[SurfaceLocation],
    backend: Backend,
) -> Result<Vec<LimitPoint>> {
    let mesh = control.to_control_mesh()?;
    let eval = make_evaluator(backend, &mesh, &EvalOptions::default())?;
    eval.evaluate(mesh.positions(), locations)
}

/// Runs `f` on a pool of `threads` workers made for this call (0: rayon's
/// global pool). The pool is dropped, its threads joined, before returning.
fn with_threads<T: Send>(threads: u32, f: impl FnOnce() -> Result<T> + Send) -> Result<T> {
    if threads == 0 {
        return f();
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads as usize)
        .thread_name(|i| format!("subdfit-{i}"))
        .build()
        .map_err(|e| Error::option("threads", format!("cannot start {threads} threads: {e}")))?;
    pool.install(f)
}

/// The pipeline's progress callback over a host [`Progress`]: a `false`
/// from the host (or an earlier one) stops the pipeline at its next report.
fn sink<'p>(progress: &'p Progress<'p>) -> impl FnMut(&str, f64) -> bool + 'p {
    move |stage, fraction| progress.report(stage, fraction).is_ok()
}

/// The `"run"` part of `report.json`, as the CLI writes it for a file
/// called `source_name`.
fn run_info(command: &str, options: &Options) -> crate::convert::HostRecord {
    use crate::convert::HostRecord;
    match command {
        "fit" => HostRecord::fit(&options.source_name, None),
        _ => HostRecord::convert(&options.source_name),
    }
}

/// Dense mesh → control mesh + displacement + metrics: `subdfit convert`.
pub fn convert(input: &MeshArrays, options: &Options, progress: &Progress) -> Result<Conversion> {
    options.check()?;
    with_threads(options.threads, || {
        progress.report("read", 0.0)?;
        let mesh = input.to_input_mesh(&options.source_name)?;
        progress.report("read", 1.0)?;
        convert_validated(mesh, options, progress)
    })
}

/// [`convert`] of a mesh file: `subdfit convert PATH` (errors and
/// `report.json` name the file as `options.source_name` says).
pub fn convert_file(path: &Path, options: &Options, progress: &Progress) -> Result<Conversion> {
    options.check()?;
    with_threads(options.threads, || {
        progress.report("read", 0.0)?;
        let mesh = read_input(path)?;
        progress.report("read", 1.0)?;
        convert_validated(mesh, options, progress)
    })
}

/// The pipeline of [`convert`] on an input already read and validated.
fn convert_validated(
    mesh: ValidatedMesh,
    options: &Options,
    progress: &Progress,
) -> Result<Conversion> {
    let c = convert_in_memory(
        &mesh,
        &options.convert,
        run_info("convert", options),
        &mut sink(progress),
    )
    .map_err(|e| with_source(e, options))?;
    Conversion::from_converted(mesh, c)
}

/// The CLI prefixes pipeline errors with the input's name; so does the API,
/// so a host passing the file name gets the CLI's message verbatim.
fn with_source(e: Error, options: &Options) -> Error {
    match e {
        Error::Cancelled { .. } => e,
        e => e.context(&options.source_name),
    }
}

/// Fits a given control mesh to a dense mesh: `subdfit fit`.
pub fn fit(
    input: &MeshArrays,
    control: &ControlArrays,
    options: &Options,
    progress: &Progress,
) -> Result<Conversion> {
    options.check()?;
    with_threads(options.threads, || {
        progress.report("read", 0.0)?;
        let mesh = input.to_input_mesh(&options.source_name)?;
        let control = control.to_control_mesh()?;
        progress.report("read", 1.0)?;
        let timer = StageTimer::default();
        let o = &options.convert;
        let po = PipelineOptions::default()
            .with_fit(FitOptions::default().with_objective(o.objective))
            .with_metrics(
                MetricsOptions::default()
                    .with_displacement_res(o.displacement_res)
                    .with_displacement_samples(o.displacement_samples)
                    .with_displacement_allocation(o.displacement_allocation)
                    .with_output_tessellation(o.tessellation),
            )
            .with_fitmap(Some(o.tolerance.map_or_else(FitmapOptions::default, |t| {
                FitmapOptions::default().with_tolerance(t)
            })));
        let c = fit_in_memory(
            &mesh,
            control,
            &po,
            timer,
            run_info("fit", options),
            &mut sink(progress),
        )?;
        Conversion::from_converted(mesh, c)
    })
}

/// Test hooks for the C++ package test (not part of the API): `"panic"`
/// panics on the calling thread, `"panic-in-worker"` inside a rayon worker,
/// `"error"` returns an error (of kind `Input`; `"error-option"`,
/// `"error-numerical"` and `"error-internal"` one of each other kind),
/// `"progress"` runs a fake ten-second stage on
/// all workers that reports every millisecond, so a host can time its
/// cancellation.
#[doc(hidden)]
pub fn self_test(what: &str, progress: &Progress) -> Result<()> {
    use rayon::prelude::*;
    match what {
        "panic" => panic!("self-test panic requested by the host"),
        "panic-in-worker" => {
            (0..64u32).into_par_iter().for_each(|i| {
                if i == 37 {
                    panic!("self-test panic in a worker thread");
                }
            });
            Ok(())
        }
        "error" => Err(Error::InvalidArgument("self-test error".into())),
        // One error of each other kind, for a host to check its mapping
        // (exit code, exception class, `subdfit::Error::kind()`).
        "error-option" => Err(Error::option("self-test", "self-test option error")),
        "error-numerical" => Err(Error::numerical("self-test", "self-test numerical error")),
        "error-internal" => Err(Error::internal("self-test internal error")),
        "progress" => {
            const STEPS: u32 = 10_000;
            let done = std::sync::atomic::AtomicU32::new(0);
            progress.report("self-test", 0.0)?;
            (0..STEPS).into_par_iter().try_for_each(|_| {
                std::thread::sleep(Duration::from_millis(1));
                let n = done.fetch_add(1, Ordering::Relaxed) + 1;
                progress.report("self-test", f64::from(n) / f64::from(STEPS))
            })?;
            progress.report("self-test", 1.0)
        }
        _ => Err(Error::InvalidArgument(format!(
            "unknown self-test `{what}`"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU32;

    /// `fixtures::cube` as the flat arrays a host passes.
    fn cube() -> (Vec<f64>, Vec<u32>, Vec<u32>) {
        let c = crate::fixtures::cube();
        let p = c.positions().iter().flat_map(|p| p.to_array()).collect();
        (p, c.face_sizes(), c.face_indices_flat())
    }

    #[test]
    fn limit_points_of_cube_corners_are_at_half() {
        // STACK-NOTES: the valence-3 limit mask puts the cube's corners at
        // ±1/2 exactly; both backends must agree to rounding.
        let (p, s, i) = cube();
        let c = ControlArrays {
            mesh: MeshArrays {
                positions: &p,
                face_sizes: &s,
                face_indices: &i,
            },
            crease_vertices: &[],
            crease_weights: &[],
            corner_vertices: &[],
            corner_weights: &[],
        };
        for b in [Backend::Osd, Backend::Rust] {
            let l = limit_points(&c, b).unwrap();
            assert_eq!(l.len(), 8);
            for (k, q) in l.iter().enumerate() {
                let want = DVec3::new(p[3 * k], p[3 * k + 1], p[3 * k + 2]) * 0.5;
                assert!((q.position - want).length() < 1e-12, "{b:?} {k}: {q:?}");
            }
        }
    }

    #[test]
    fn malformed_arrays_are_errors_not_panics() {
        let m = MeshArrays {
            positions: &[0.0; 7],
            face_sizes: &[3],
            face_indices: &[0, 1, 2],
        };
        assert!(m
            .to_soup()
            .unwrap_err()
            .to_string()
            .contains("multiple of 3"));
        let m = MeshArrays {
            positions: &[0.0; 9],
            face_sizes: &[3, 3],
            face_indices: &[0, 1, 2],
        };
        assert!(m.to_soup().unwrap_err().to_string().contains("add up to 6"));
        let m = MeshArrays {
            positions: &[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            face_sizes: &[3],
            face_indices: &[0, 1, 9],
        };
        let e = convert(&m, &Options::default(), &Progress::none()).unwrap_err();
        assert!(e.to_string().contains("input mesh"), "{e}");
    }

    #[test]
    fn cancellation_stops_the_self_test_promptly() {
        let calls = AtomicU32::new(0);
        let cb = |_: &str, f: f64| {
            calls.fetch_add(1, Ordering::Relaxed);
            f < 0.05
        };
        let p = Progress::new(&cb);
        let t = Instant::now();
        let e = self_test("progress", &p).unwrap_err();
        assert!(matches!(e, Error::Cancelled { .. }), "{e}");
        // 5% of a 10 s stage is 0.5 s of work; one report interval plus the
        // in-flight 1 ms steps after the stop must fit well inside 3 s.
        assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
        assert!(calls.load(Ordering::Relaxed) >= 2);
    }
}
