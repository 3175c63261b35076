//! `subdfit._subdfit`, the native half of the Python package: a thin layer
//! over `subdfit::embed`, as `src/embed/bridge.rs` is for C++. It takes flat,
//! contiguous NumPy arrays (the pure-Python `subdfit/__init__.py` checks
//! shapes and dtypes and gives them that form) and hands back flat arrays;
//! every rule about meshes, options and outputs lives in the library.
//!
//! Long calls run on a thread of their own with the GIL released; the
//! calling thread wakes every [`POLL`] to let Python handle signals, so
//! Ctrl-C cancels the call (through `embed::Progress`) and raises
//! `KeyboardInterrupt` in the caller.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::Duration;

use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;
use pyo3::types::PyBytes;
use subdfit::embed::batch::{self, Asset, AssetOutcome};
use subdfit::embed::{self, ControlArrays, MeshArrays, Options, Progress};
use subdfit::mesh::FaceId;
use subdfit::subdiv::{Backend, LimitPoint, SurfaceLocation};

create_exception!(subdfit, Error, PyException, "Any error of subdfit.");
create_exception!(
    subdfit,
    InvalidInput,
    Error,
    "A mesh, an array or an option that cannot be used; the message names the file and the element."
);
create_exception!(
    subdfit,
    InvalidOption,
    InvalidInput,
    "An option out of its range (subdfit::ErrorKind::Option); the message names the option."
);
create_exception!(
    subdfit,
    FileError,
    Error,
    "A file that cannot be opened, read or written."
);
create_exception!(
    subdfit,
    NumericalError,
    Error,
    "A numerical stage failed on a valid input (subdfit::ErrorKind::Numerical)."
);
create_exception!(
    subdfit,
    BackendError,
    NumericalError,
    "A C++ backend (OpenSubdiv, Embree, Eigen) or a solver failed."
);
create_exception!(
    subdfit,
    InternalError,
    Error,
    "A bug in subdfit (subdfit::ErrorKind::Internal): please report it."
);
create_exception!(
    subdfit,
    Cancelled,
    Error,
    "The progress callback returned False."
);

/// How often the calling thread looks for signals while a call runs: the
/// share of the ~50 ms Ctrl-C budget that is spent before the pipeline is
/// told to stop (its own reports come at least every 20-50 ms).
const POLL: Duration = Duration::from_millis(5);

/// The CLI's message, in the exception class of the error's kind
/// ([`subdfit::ErrorKind`]; files and C++ backends get their own
/// subclasses).
fn to_py(e: &subdfit::Error) -> PyErr {
    use subdfit::{Error as E, ErrorKind as K};
    let mut inner = e;
    while let E::Role { source, .. } | E::Context { source, .. } = inner {
        inner = &**source;
    }
    let msg = embed::error_message(e);
    match (inner, e.kind()) {
        (E::Io { .. }, _) => FileError::new_err(msg),
        (E::Backend { .. } | E::RankDeficient { .. }, _) => BackendError::new_err(msg),
        (_, K::Cancelled) => Cancelled::new_err(msg),
        (_, K::Option) => InvalidOption::new_err(msg),
        (_, K::Numerical) => NumericalError::new_err(msg),
        (_, K::Internal) => InternalError::new_err(msg),
        _ => InvalidInput::new_err(msg),
    }
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    let msg = payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".to_owned());
    format!("internal error: subdfit panicked ({msg}); this is a bug, please report it")
}

/// Runs `f` on a thread of its own with the GIL released, giving it a
/// `Progress` that calls `callback(stage, fraction)` (with the GIL; `False`
/// cancels, an exception cancels and is re-raised) and that stops once the
/// calling thread saw a signal (Ctrl-C: `KeyboardInterrupt`). Panics come
/// back as `subdfit.Error`, never an abort.
fn run_cancellable<T: Send>(
    py: Python<'_>,
    callback: Option<Py<PyAny>>,
    f: impl FnOnce(&Progress) -> subdfit::Result<T> + Send,
) -> PyResult<T> {
    let stop = AtomicBool::new(false);
    let raised: Mutex<Option<PyErr>> = Mutex::new(None);
    let sink = |stage: &str, fraction: f64| -> bool {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        let Some(cb) = &callback else {
            return true;
        };
        Python::attach(|py| match cb.call1(py, (stage, fraction)) {
            Ok(r) => !r.bind(py).is(pyo3::types::PyBool::new(py, false)),
            Err(e) => {
                raised
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .get_or_insert(e);
                false
            }
        })
    };
    let done = AtomicBool::new(false);
    let caller = std::thread::current();
    let (result, interrupt) = std::thread::scope(|s| {
        let worker = s.spawn(|| {
            let progress = Progress::new(&sink);
            let r = catch_unwind(AssertUnwindSafe(|| f(&progress)));
            done.store(true, Ordering::Release);
            caller.unpark();
            r
        });
        let mut interrupt = None;
        loop {
            // Parked until the worker is done or POLL has passed (a stray
            // unpark only makes one poll early).
            py.detach(|| std::thread::park_timeout(POLL));
            if done.load(Ordering::Acquire) {
                break;
            }
            // Only the main thread runs Python's signal handlers; elsewhere
            // (a Dask worker thread) this is a no-op.
            if interrupt.is_none() {
                if let Err(e) = py.check_signals() {
                    stop.store(true, Ordering::Relaxed);
                    interrupt = Some(e);
                }
            }
        }
        let joined = py.detach(|| worker.join());
        (joined, interrupt)
    });
    if let Some(e) = interrupt {
        return Err(e);
    }
    if let Some(e) = raised.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(e);
    }
    match result {
        Ok(Ok(Ok(v))) => Ok(v),
        Ok(Ok(Err(e))) => Err(to_py(&e)),
        Ok(Err(payload)) | Err(payload) => Err(Error::new_err(panic_message(&*payload))),
    }
}

// ---- options ------------------------------------------------------------------

/// Options of `convert` and `fit`: the CLI's flags (see `subdfit convert
/// --help`).
#[pyclass(name = "Options", module = "subdfit._subdfit", frozen)]
#[derive(Clone)]
struct PyOptions(Options);

#[pymethods]
impl PyOptions {
    #[new]
    #[pyo3(signature = (*, tolerance=None, mode="auto", max_error=None, faces_target=0,
        fit="point", displacement_res=0, m_fitmap=true, tessellation=0, proxy="auto",
        layout="greedy", displacement_samples=0, threads=0, name=None, exact_metrics=false,
        displacement_allocation="adaptive", displacement_reconstruction="bilinear"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        tolerance: Option<f64>,
        mode: &str,
        max_error: Option<f64>,
        faces_target: u32,
        fit: &str,
        displacement_res: u32,
        m_fitmap: bool,
        tessellation: u32,
        proxy: &str,
        layout: &str,
        displacement_samples: u32,
        threads: u32,
        name: Option<String>,
        exact_metrics: bool,
        displacement_allocation: &str,
        displacement_reconstruction: &str,
    ) -> PyResult<Self> {
        // The library's own types and words (`subdfit::convert::Mode`,
        // `subdfit::fit::Objective`, `Proxy`): one definition for every host.
        let mut o = Options::default();
        let positive = |n: u32| (n > 0).then_some(n as usize);
        let c = o.convert.clone();
        let c = match tolerance {
            Some(t) => c.with_tolerance(Some(t)),
            None => c,
        };
        o.convert = c
            .with_mode(mode.parse().map_err(|_| {
                InvalidOption::new_err(format!(
                    "unknown mode {mode:?}: auto, organic or mechanical"
                ))
            })?)
            .with_objective(fit.parse().map_err(|_| {
                InvalidOption::new_err(format!("unknown fit {fit:?}: point or sdm"))
            })?)
            .with_max_error(max_error)
            .with_target_faces(positive(faces_target))
            .with_displacement_res(positive(displacement_res))
            .with_displacement_samples(positive(displacement_samples))
            .with_displacement_allocation(displacement_allocation.parse().map_err(|_| {
                InvalidOption::new_err(format!(
                    "unknown displacement_allocation {displacement_allocation:?}: adaptive or uniform"
                ))
            })?)
            .with_displacement_reconstruction(displacement_reconstruction.parse().map_err(
                |_| {
                    InvalidOption::new_err(format!(
                        "unknown displacement_reconstruction {displacement_reconstruction:?}: \
                         bilinear or bspline"
                    ))
                },
            )?)
            .with_m_fitmap(m_fitmap)
            .with_exact_metrics(exact_metrics)
            .with_tessellation(positive(tessellation))
            .with_proxy(
                proxy
                    .parse()
                    .map_err(|e: String| InvalidOption::new_err(format!("proxy: {e}")))?,
            )
            .with_layout(layout.parse().map_err(|_| {
                InvalidOption::new_err(format!("unknown layout {layout:?}: greedy or field"))
            })?);
        o.threads = threads;
        if let Some(n) = name {
            o.source_name = n;
        }
        o.check().map_err(|e| to_py(&e))?;
        Ok(PyOptions(o))
    }

    #[getter]
    fn tolerance(&self) -> f64 {
        self.0
            .convert
            .tolerance
            .unwrap_or(subdfit::analysis::fitmap::DEFAULT_TOLERANCE)
    }

    #[getter]
    fn name(&self) -> String {
        self.0.source_name.clone()
    }
}

// ---- arrays -------------------------------------------------------------------

fn slice<'a, T: numpy::Element>(a: &'a PyReadonlyArray1<'_, T>, what: &str) -> PyResult<&'a [T]> {
    a.as_slice()
        .map_err(|_| InvalidInput::new_err(format!("{what}: the array is not contiguous")))
}

/// A control mesh's arrays, owned (copied out of NumPy before the GIL is
/// released).
struct ControlData {
    positions: Vec<f64>,
    face_sizes: Vec<u32>,
    face_indices: Vec<u32>,
    crease_vertices: Vec<u32>,
    crease_weights: Vec<f64>,
    corner_vertices: Vec<u32>,
    corner_weights: Vec<f64>,
}

impl ControlData {
    fn arrays(&self) -> ControlArrays<'_> {
        ControlArrays {
            mesh: MeshArrays {
                positions: &self.positions,
                face_sizes: &self.face_sizes,
                face_indices: &self.face_indices,
            },
            crease_vertices: &self.crease_vertices,
            crease_weights: &self.crease_weights,
            corner_vertices: &self.corner_vertices,
            corner_weights: &self.corner_weights,
        }
    }

    fn from_mesh(m: &subdfit::mesh::ControlMesh) -> Self {
        let creases = m.creases();
        let corners = m.corners();
        ControlData {
            positions: m.positions().iter().flat_map(|p| p.to_array()).collect(),
            face_sizes: m.face_sizes(),
            face_indices: m.face_indices_flat(),
            crease_vertices: creases.iter().flat_map(|&(a, b, _)| [a.0, b.0]).collect(),
            crease_weights: creases.iter().map(|&(_, _, s)| s).collect(),
            corner_vertices: corners.iter().map(|&(v, _)| v.0).collect(),
            corner_weights: corners.iter().map(|&(_, s)| s).collect(),
        }
    }

    /// `(positions, face_sizes, face_indices, crease_vertices,
    /// crease_weights, corner_vertices, corner_weights)`, flat.
    #[allow(clippy::type_complexity)]
    fn into_py(
        self,
        py: Python<'_>,
    ) -> (
        Bound<'_, PyArray1<f64>>,
        Bound<'_, PyArray1<u32>>,
        Bound<'_, PyArray1<u32>>,
        Bound<'_, PyArray1<u32>>,
        Bound<'_, PyArray1<f64>>,
        Bound<'_, PyArray1<u32>>,
        Bound<'_, PyArray1<f64>>,
    ) {
        (
            PyArray1::from_vec(py, self.positions),
            PyArray1::from_vec(py, self.face_sizes),
            PyArray1::from_vec(py, self.face_indices),
            PyArray1::from_vec(py, self.crease_vertices),
            PyArray1::from_vec(py, self.crease_weights),
            PyArray1::from_vec(py, self.corner_vertices),
            PyArray1::from_vec(py, self.corner_weights),
        )
    }
}

type MeshIn<'py> = (
    PyReadonlyArray1<'py, f64>,
    PyReadonlyArray1<'py, u32>,
    PyReadonlyArray1<'py, u32>,
);

type ControlIn<'py> = (
    PyReadonlyArray1<'py, f64>,
    PyReadonlyArray1<'py, u32>,
    PyReadonlyArray1<'py, u32>,
    PyReadonlyArray1<'py, u32>,
    PyReadonlyArray1<'py, f64>,
    PyReadonlyArray1<'py, u32>,
    PyReadonlyArray1<'py, f64>,
);

fn mesh_data(m: &MeshIn<'_>) -> PyResult<(Vec<f64>, Vec<u32>, Vec<u32>)> {
    Ok((
        slice(&m.0, "vertices")?.to_vec(),
        slice(&m.1, "face sizes")?.to_vec(),
        slice(&m.2, "face indices")?.to_vec(),
    ))
}

fn control_data(c: &ControlIn<'_>) -> PyResult<ControlData> {
    Ok(ControlData {
        positions: slice(&c.0, "control positions")?.to_vec(),
        face_sizes: slice(&c.1, "control face sizes")?.to_vec(),
        face_indices: slice(&c.2, "control face indices")?.to_vec(),
        crease_vertices: slice(&c.3, "crease vertices")?.to_vec(),
        crease_weights: slice(&c.4, "crease weights")?.to_vec(),
        corner_vertices: slice(&c.5, "corner vertices")?.to_vec(),
        corner_weights: slice(&c.6, "corner weights")?.to_vec(),
    })
}

// ---- results ------------------------------------------------------------------

/// What `convert` and `fit` return (wrapped by `subdfit.Conversion`).
#[pyclass(name = "NativeConversion", module = "subdfit._subdfit", frozen)]
struct PyConversion(embed::Conversion);

#[pymethods]
impl PyConversion {
    /// The control mesh's flat arrays, as `read_control` gives them.
    #[allow(clippy::type_complexity)]
    fn control<'py>(
        &self,
        py: Python<'py>,
    ) -> (
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<f64>>,
    ) {
        ControlData::from_mesh(&self.0.control).into_py(py)
    }

    /// `(uvs, uv_indices)`: uv pairs, flat, and one index per face corner.
    fn uvs<'py>(&self, py: Python<'py>) -> (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<u32>>) {
        let uvs = self.0.uvs.iter().flat_map(|p| [p.x, p.y]).collect();
        (
            PyArray1::from_vec(py, uvs),
            PyArray1::from_slice(py, &self.0.uv_indices),
        )
    }

    /// `(faces, resolution, values)`: all tiles have the same resolution;
    /// `values` holds them one after the other, each row-major (v rows).
    /// Each tile's patch, its resolution (samples per side: adaptive
    /// tiles differ patch to patch, issue 37) and every tile's values, one
    /// after the other.
    #[allow(clippy::type_complexity)]
    fn tiles<'py>(
        &self,
        py: Python<'py>,
    ) -> (
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<u32>>,
        Bound<'py, PyArray1<f32>>,
    ) {
        let t = &self.0.tiles;
        let faces: Vec<u32> = t.iter().map(|t| t.face).collect();
        let res: Vec<u32> = t.iter().map(|t| t.resolution).collect();
        let values: Vec<f32> = t.iter().flat_map(|t| t.values.iter().copied()).collect();
        (
            PyArray1::from_vec(py, faces),
            PyArray1::from_vec(py, res),
            PyArray1::from_vec(py, values),
        )
    }

    fn metrics(&self) -> Vec<(String, f64)> {
        self.0.metrics.clone()
    }

    fn report_json(&self) -> String {
        self.0.report_json.clone()
    }

    fn control_obj<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        PyBytes::new(py, &self.0.control_obj)
    }

    #[pyo3(signature = (dir, progress=None))]
    fn write(
        &self,
        py: Python<'_>,
        dir: PathBuf,
        progress: Option<Py<PyAny>>,
    ) -> PyResult<Vec<PathBuf>> {
        run_cancellable(py, progress, |p| self.0.write(&dir, p))
    }
}

// ---- functions ----------------------------------------------------------------

/// `(positions, face_sizes, face_indices)` of a mesh file, flat, as read
/// (validation happens in `convert`, as in the CLI).
#[pyfunction]
#[allow(clippy::type_complexity)]
fn read<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<u32>>,
)> {
    let soup = py
        .detach(|| subdfit::io::read_soup(&path))
        .map_err(|e| to_py(&e.in_role("input mesh")))?;
    let sizes: Vec<u32> = soup.face_offsets.windows(2).map(|w| w[1] - w[0]).collect();
    let positions = soup.positions.iter().flat_map(|p| p.to_array()).collect();
    Ok((
        PyArray1::from_vec(py, positions),
        PyArray1::from_vec(py, sizes),
        PyArray1::from_vec(py, soup.face_indices),
    ))
}

/// A control mesh file (OBJ with crease / corner tags), as flat arrays.
#[pyfunction]
#[allow(clippy::type_complexity)]
fn read_control<'py>(
    py: Python<'py>,
    path: PathBuf,
) -> PyResult<(
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<u32>>,
    Bound<'py, PyArray1<f64>>,
)> {
    let mesh = py
        .detach(|| subdfit::io::read_control_mesh(&path))
        .map_err(|e| to_py(&e.in_role("control mesh")))?;
    Ok(ControlData::from_mesh(&mesh).into_py(py))
}

#[pyfunction]
#[pyo3(signature = (mesh, options, progress=None))]
fn convert(
    py: Python<'_>,
    mesh: MeshIn<'_>,
    options: &PyOptions,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyConversion> {
    let (p, s, i) = mesh_data(&mesh)?;
    drop(mesh);
    let o = options.0.clone();
    let c = run_cancellable(py, progress, move |pr| {
        let m = MeshArrays {
            positions: &p,
            face_sizes: &s,
            face_indices: &i,
        };
        embed::convert(&m, &o, pr)
    })?;
    Ok(PyConversion(c))
}

/// `convert` of a mesh file, read as the CLI reads it.
#[pyfunction]
#[pyo3(signature = (path, options, progress=None))]
fn convert_file(
    py: Python<'_>,
    path: PathBuf,
    options: &PyOptions,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyConversion> {
    let o = options.0.clone();
    let c = run_cancellable(py, progress, move |pr| embed::convert_file(&path, &o, pr))?;
    Ok(PyConversion(c))
}

#[pyfunction]
#[pyo3(signature = (mesh, control, options, progress=None))]
fn fit(
    py: Python<'_>,
    mesh: MeshIn<'_>,
    control: ControlIn<'_>,
    options: &PyOptions,
    progress: Option<Py<PyAny>>,
) -> PyResult<PyConversion> {
    let (p, s, i) = mesh_data(&mesh)?;
    let c = control_data(&control)?;
    drop((mesh, control));
    let o = options.0.clone();
    let r = run_cancellable(py, progress, move |pr| {
        let m = MeshArrays {
            positions: &p,
            face_sizes: &s,
            face_indices: &i,
        };
        embed::fit(&m, &c.arrays(), &o, pr)
    })?;
    Ok(PyConversion(r))
}

/// 12 doubles per point (position, du, dv, unit normal): at every control
/// vertex when `faces` is None, else at each `(faces[k], u[k], v[k])`.
#[pyfunction]
#[pyo3(signature = (control, faces, u, v, backend))]
fn limit<'py>(
    py: Python<'py>,
    control: ControlIn<'py>,
    faces: Option<PyReadonlyArray1<'py, u32>>,
    u: Option<PyReadonlyArray1<'py, f64>>,
    v: Option<PyReadonlyArray1<'py, f64>>,
    backend: &str,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let backend = match backend {
        "osd" | "opensubdiv" => Backend::Osd,
        "rust" => Backend::Rust,
        b => {
            return Err(InvalidInput::new_err(format!(
                "unknown backend {b:?}: osd or rust"
            )))
        }
    };
    let c = control_data(&control)?;
    let locations = match (&faces, &u, &v) {
        (Some(f), Some(u), Some(v)) => {
            let (f, u, v) = (slice(f, "faces")?, slice(u, "u")?, slice(v, "v")?);
            if u.len() != f.len() || v.len() != f.len() {
                return Err(InvalidInput::new_err(format!(
                    "location arrays differ in length (face {}, u {}, v {})",
                    f.len(),
                    u.len(),
                    v.len()
                )));
            }
            let loc = (0..f.len()).map(|k| SurfaceLocation {
                face: FaceId(f[k]),
                sub: 0,
                u: u[k],
                v: v[k],
            });
            Some(loc.collect::<Vec<_>>())
        }
        _ => None,
    };
    drop((control, faces, u, v));
    let points: Vec<LimitPoint> = run_cancellable(py, None, move |_| match &locations {
        Some(l) => embed::evaluate(&c.arrays(), l, backend),
        None => embed::limit_points(&c.arrays(), backend),
    })?;
    let mut out = Vec::with_capacity(12 * points.len());
    for p in &points {
        for q in [p.position, p.du, p.dv, p.normal()] {
            out.extend_from_slice(&q.to_array());
        }
    }
    Ok(PyArray1::from_vec(py, out))
}

// ---- batch --------------------------------------------------------------------

fn json_err(e: serde_json::Error) -> PyErr {
    InvalidInput::new_err(format!("batch record: {e}"))
}

/// The assets of `inputs` (files, folders, globs, manifests) under
/// `out_root`, as JSON records (what `convert_asset` takes).
#[pyfunction]
fn batch_plan(inputs: Vec<String>, out_root: PathBuf) -> PyResult<Vec<String>> {
    let assets = batch::plan(&inputs, &out_root).map_err(|e| to_py(&e))?;
    assets
        .iter()
        .map(|a| serde_json::to_string(a).map_err(json_err))
        .collect()
}

/// Converts (or skips) one asset of `batch_plan`; returns its outcome as
/// JSON. Never raises for a bad asset: the outcome says it failed.
#[pyfunction]
#[pyo3(signature = (asset, options, force=false, progress=None))]
fn convert_asset(
    py: Python<'_>,
    asset: &str,
    options: &PyOptions,
    force: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    let asset: Asset = serde_json::from_str(asset).map_err(json_err)?;
    let o = options.0.clone();
    let outcome = run_cancellable(py, progress, move |p| {
        let out = batch::convert_asset(&asset, &o, force, p);
        // A Ctrl-C is the caller's, not the asset's: raise it.
        p.check()?;
        Ok(out)
    })?;
    serde_json::to_string(&outcome).map_err(json_err)
}

fn outcomes(records: &[String]) -> PyResult<Vec<AssetOutcome>> {
    records
        .iter()
        .map(|r| serde_json::from_str(r).map_err(json_err))
        .collect()
}

/// Writes `batch.csv` and `batch.json` into `out_root`; returns their paths.
#[pyfunction]
fn write_summary(out_root: PathBuf, records: Vec<String>) -> PyResult<Vec<PathBuf>> {
    batch::write_summary(Path::new(&out_root), &outcomes(&records)?).map_err(|e| to_py(&e))
}

/// The table `subdfit batch` prints.
#[pyfunction]
fn summary_table(records: Vec<String>) -> PyResult<String> {
    Ok(batch::summary_table(&outcomes(&records)?))
}

#[pyfunction]
fn version() -> String {
    env!("CARGO_PKG_VERSION").to_owned()
}

#[pymodule]
fn _subdfit(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("Error", py.get_type::<Error>())?;
    m.add("InvalidInput", py.get_type::<InvalidInput>())?;
    m.add("InvalidOption", py.get_type::<InvalidOption>())?;
    m.add("FileError", py.get_type::<FileError>())?;
    m.add("NumericalError", py.get_type::<NumericalError>())?;
    m.add("BackendError", py.get_type::<BackendError>())?;
    m.add("InternalError", py.get_type::<InternalError>())?;
    m.add("Cancelled", py.get_type::<Cancelled>())?;
    m.add_class::<PyOptions>()?;
    m.add_class::<PyConversion>()?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(read_control, m)?)?;
    m.add_function(wrap_pyfunction!(convert, m)?)?;
    m.add_function(wrap_pyfunction!(convert_file, m)?)?;
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_function(wrap_pyfunction!(limit, m)?)?;
    m.add_function(wrap_pyfunction!(batch_plan, m)?)?;
    m.add_function(wrap_pyfunction!(convert_asset, m)?)?;
    m.add_function(wrap_pyfunction!(write_summary, m)?)?;
    m.add_function(wrap_pyfunction!(summary_table, m)?)?;
    m.add_function(wrap_pyfunction!(version, m)?)?;
    Ok(())
}
