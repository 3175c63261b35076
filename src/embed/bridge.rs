//! Bridge for C++ hosts: the `extern "Rust"` side of
//! `include/subdfit/subdfit.hpp`, implemented in `cpp/api/subdfit.cpp`.
//!
//! Arrays cross flat (xyz triples, concatenated faces); results come back as
//! shared structs of `rust::Vec`s that the C++ side moves into plain `std`
//! types. Every function here returns `Result`: cxx turns an `Err` into a
//! `rust::Error` exception carrying its message, which `subdfit.cpp` rethrows
//! as `subdfit::Error`, with the error's [`crate::ErrorKind`] (sent ahead of
//! the message as [`KIND_TAG`]`N:`, which `subdfit.cpp` strips). Panics are caught here ([`guard`]) so that unwinding
//! never reaches a C++ frame, which would abort the host.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Mutex;

use crate::displace::{Reconstruction, SampleAllocation};
use crate::embed::{self, ControlArrays, MeshArrays, Progress};
use crate::mesh::FaceId;
use crate::subdiv::{Backend, LimitPoint, SurfaceLocation};

#[cxx::bridge(namespace = "subdfit::ffi")]
pub(crate) mod api {
    /// `Options` of the public header, field for field.
    struct FfiOptions {
        tolerance: f64,
        target_faces: u32,
        /// 0 organic, 1 mechanical.
        mode: u8,
        /// 0 point, 1 sdm.
        fit_method: u8,
        displacement_resolution: u32,
        /// 0: the input's vertex count.
        displacement_samples: u32,
        /// 0 adaptive, 1 uniform.
        displacement_allocation: u8,
        /// 0 bilinear, 1 bspline.
        displacement_reconstruction: u8,
        /// 0 greedy, 1 field.
        layout: u8,
        /// 0: the mode's default; infinity: organic mode's natural end.
        max_error: f64,
        m_fitmap: bool,
        /// 0: automatic.
        tessellation: u32,
        /// -1 auto, 0 none, N: about N triangles.
        proxy: i64,
        exact_metrics: bool,
        threads: u32,
        source_name: String,
    }

    struct FfiControlMesh {
        face_sizes: Vec<u32>,
        face_indices: Vec<u32>,
        positions: Vec<f64>,
        crease_vertices: Vec<u32>,
        crease_weights: Vec<f64>,
        corner_vertices: Vec<u32>,
        corner_weights: Vec<f64>,
        uvs: Vec<f64>,
        uv_indices: Vec<u32>,
    }

    struct FfiTile {
        face: u32,
        resolution: u32,
        values: Vec<f32>,
    }

    struct FfiMetric {
        name: String,
        value: f64,
    }

    struct FfiConversion {
        control: FfiControlMesh,
        tiles: Vec<FfiTile>,
        metrics: Vec<FfiMetric>,
        report_json: String,
        control_obj: Vec<u8>,
    }

    extern "Rust" {
        /// 12 doubles per control vertex: position, du, dv, unit normal.
        /// `backend`: 0 OpenSubdiv, 1 Rust.
        #[allow(clippy::too_many_arguments)]
        fn embed_limit_points(
            positions: &[f64],
            face_sizes: &[u32],
            face_indices: &[u32],
            crease_vertices: &[u32],
            crease_weights: &[f64],
            corner_vertices: &[u32],
            corner_weights: &[f64],
            backend: u8,
        ) -> Result<Vec<f64>>;

        /// 12 doubles per location, as `embed_limit_points`.
        #[allow(clippy::too_many_arguments)]
        fn embed_evaluate(
            positions: &[f64],
            face_sizes: &[u32],
            face_indices: &[u32],
            crease_vertices: &[u32],
            crease_weights: &[f64],
            corner_vertices: &[u32],
            corner_weights: &[f64],
            faces: &[u32],
            subs: &[u16],
            u: &[f64],
            v: &[f64],
            backend: u8,
        ) -> Result<Vec<f64>>;

        fn embed_convert(
            positions: &[f64],
            face_sizes: &[u32],
            face_indices: &[u32],
            options: &FfiOptions,
            progress: &ProgressSink,
        ) -> Result<FfiConversion>;

        #[allow(clippy::too_many_arguments)]
        fn embed_fit(
            positions: &[f64],
            face_sizes: &[u32],
            face_indices: &[u32],
            control_positions: &[f64],
            control_face_sizes: &[u32],
            control_face_indices: &[u32],
            crease_vertices: &[u32],
            crease_weights: &[f64],
            corner_vertices: &[u32],
            corner_weights: &[f64],
            options: &FfiOptions,
            progress: &ProgressSink,
        ) -> Result<FfiConversion>;

        /// See `crate::embed::self_test`.
        fn embed_self_test(what: &str, progress: &ProgressSink) -> Result<()>;
    }

    unsafe extern "C++" {
        include!("subdfit/cpp/api/progress_sink.h");

        /// Wraps the host's `subdfit::Progress` (a `std::function`).
        type ProgressSink;

        /// Calls the host's callback; `false` asks to cancel. A C++
        /// exception thrown by the callback becomes an `Err`.
        fn report(self: &ProgressSink, stage: &str, fraction: f64) -> Result<bool>;
    }
}

use api::{FfiControlMesh, FfiConversion, FfiMetric, FfiOptions, FfiTile, ProgressSink};

// SAFETY: `ProgressSink` only holds a pointer to the host's `std::function`,
// which outlives the call that lent it. `embed::Progress` serialises every
// call into it (a mutex around the callback), so sharing the sink with rayon
// workers never runs the host callback on two threads at once; the header
// documents that it may run on a worker thread.
unsafe impl Sync for ProgressSink {}

/// What precedes an error's message across the bridge: the tag, the
/// [`crate::ErrorKind::code`], a colon (`subdfit.cpp`'s `call` reads it
/// into `subdfit::Error::kind()`; a cxx exception carries only a string).
pub(crate) const KIND_TAG: &str = "subdfit-error-kind:";

/// `msg` with its kind ahead, as `subdfit.cpp` reads it.
fn tagged(kind: crate::ErrorKind, msg: impl std::fmt::Display) -> String {
    format!("{KIND_TAG}{}:{msg}", kind.code())
}

/// Runs `f`, turning a panic into an `Err` so that unwinding stops here, and
/// formats errors like the CLI does (`anyhow`'s `{:#}`: the whole chain),
/// tagged with their kind.
fn guard<T>(f: impl FnOnce() -> crate::Result<T>) -> Result<T, String> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(tagged(
            e.kind(),
            format_args!("{:#}", anyhow::Error::from(e)),
        )),
        Err(payload) => {
            let msg = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".to_owned());
            Err(tagged(
                crate::ErrorKind::Internal,
                format_args!(
                    "internal error: subdfit panicked ({msg}); this is a bug, please report it"
                ),
            ))
        }
    }
}

/// Adapts the C++ sink to `embed::Progress`, remembering the first exception
/// thrown by the host callback (which cancels the call).
struct SinkAdapter<'a> {
    sink: &'a ProgressSink,
    thrown: Mutex<Option<String>>,
}

impl<'a> SinkAdapter<'a> {
    fn new(sink: &'a ProgressSink) -> Self {
        SinkAdapter {
            sink,
            thrown: Mutex::new(None),
        }
    }

    fn call(&self, stage: &str, fraction: f64) -> bool {
        match self.sink.report(stage, fraction) {
            Ok(go_on) => go_on,
            Err(e) => {
                let mut t = self.thrown.lock().unwrap_or_else(|p| p.into_inner());
                t.get_or_insert_with(|| e.what().to_owned());
                false
            }
        }
    }

    /// Runs `f` with a `Progress` over this sink; a callback exception wins
    /// over the `Cancelled` it caused.
    fn run<T>(&self, f: impl FnOnce(&Progress) -> crate::Result<T>) -> crate::Result<T> {
        let cb = |stage: &str, fraction: f64| self.call(stage, fraction);
        let r = f(&Progress::new(&cb));
        let thrown = self.thrown.lock().unwrap_or_else(|p| p.into_inner()).take();
        match (r, thrown) {
            (Err(crate::Error::Cancelled { .. }), Some(msg)) => Err(crate::Error::InvalidArgument(
                format!("the progress callback threw an exception: {msg}"),
            )),
            (r, _) => r,
        }
    }
}

fn backend(b: u8) -> crate::Result<Backend> {
    match b {
        0 => Ok(Backend::Osd),
        1 => Ok(Backend::Rust),
        _ => Err(crate::Error::option(
            "backend",
            format!("unknown backend {b}"),
        )),
    }
}

fn options(o: &FfiOptions) -> crate::Result<embed::Options> {
    use crate::convert::{LayoutKind, Mode, Proxy};
    use crate::fit::Objective;
    let bad = |what: &str, v: i64| crate::Error::option(what, format!("unknown {what} {v}"));
    let defaults = embed::Options::default();
    let positive = |n: u32| (n > 0).then_some(n as usize);
    let convert = defaults
        .convert
        .clone()
        .with_tolerance(Some(o.tolerance))
        .with_target_faces(positive(o.target_faces))
        .with_mode(match o.mode {
            0 => Mode::Organic,
            1 => Mode::Mechanical,
            2 => Mode::Auto,
            m => return Err(bad("mode", m.into())),
        })
        .with_objective(match o.fit_method {
            0 => Objective::Point,
            1 => Objective::Sdm,
            m => return Err(bad("fit method", m.into())),
        })
        .with_displacement_res(positive(o.displacement_resolution))
        .with_displacement_samples(positive(o.displacement_samples))
        .with_displacement_allocation(match o.displacement_allocation {
            0 => SampleAllocation::Adaptive,
            1 => SampleAllocation::Uniform,
            m => return Err(bad("displacement allocation", m.into())),
        })
        .with_displacement_reconstruction(match o.displacement_reconstruction {
            0 => Reconstruction::Bilinear,
            1 => Reconstruction::Bspline,
            m => return Err(bad("displacement reconstruction", m.into())),
        })
        .with_layout(match o.layout {
            0 => LayoutKind::Greedy,
            1 => LayoutKind::Field,
            m => return Err(bad("layout", m.into())),
        })
        .with_max_error((o.max_error != 0.0).then_some(o.max_error))
        .with_m_fitmap(o.m_fitmap)
        .with_tessellation(positive(o.tessellation))
        .with_proxy(match o.proxy {
            -2 => Proxy::Adaptive,
            -1 => Proxy::Auto,
            0 => Proxy::None,
            n if n > 0 => Proxy::Triangles(n as usize),
            n => return Err(bad("proxy", n)),
        })
        .with_exact_metrics(o.exact_metrics);
    Ok(embed::Options {
        convert,
        threads: o.threads,
        source_name: if o.source_name.is_empty() {
            defaults.source_name.clone()
        } else {
            o.source_name.to_string()
        },
    })
}

fn flatten(points: &[LimitPoint]) -> Vec<f64> {
    let mut out = Vec::with_capacity(12 * points.len());
    for p in points {
        let n = p.normal();
        for v in [p.position, p.du, p.dv, n] {
            out.extend_from_slice(&[v.x, v.y, v.z]);
        }
    }
    out
}

fn conversion(c: embed::Conversion) -> FfiConversion {
    let creases = c.control.creases();
    let corners = c.control.corners();
    FfiConversion {
        control: FfiControlMesh {
            face_sizes: c.control.face_sizes(),
            face_indices: c.control.face_indices_flat(),
            positions: c
                .control
                .positions()
                .iter()
                .flat_map(|p| [p.x, p.y, p.z])
                .collect(),
            crease_vertices: creases.iter().flat_map(|&(a, b, _)| [a.0, b.0]).collect(),
            crease_weights: creases.iter().map(|&(_, _, s)| s).collect(),
            corner_vertices: corners.iter().map(|&(v, _)| v.0).collect(),
            corner_weights: corners.iter().map(|&(_, s)| s).collect(),
            uvs: c.uvs.iter().flat_map(|p| [p.x, p.y]).collect(),
            uv_indices: c.uv_indices,
        },
        tiles: c
            .tiles
            .into_iter()
            .map(|t| FfiTile {
                face: t.face,
                resolution: t.resolution,
                values: t.values,
            })
            .collect(),
        metrics: c
            .metrics
            .into_iter()
            .map(|(name, value)| FfiMetric { name, value })
            .collect(),
        report_json: c.report_json,
        control_obj: c.control_obj,
    }
}

#[allow(clippy::too_many_arguments)]
fn embed_limit_points(
    positions: &[f64],
    face_sizes: &[u32],
    face_indices: &[u32],
    crease_vertices: &[u32],
    crease_weights: &[f64],
    corner_vertices: &[u32],
    corner_weights: &[f64],
    b: u8,
) -> Result<Vec<f64>, String> {
    guard(|| {
        let control = ControlArrays {
            mesh: MeshArrays {
                positions,
                face_sizes,
                face_indices,
            },
            crease_vertices,
            crease_weights,
            corner_vertices,
            corner_weights,
        };
        Ok(flatten(&embed::limit_points(&control, backend(b)?)?))
    })
}

#[allow(clippy::too_many_arguments)]
fn embed_evaluate(
    positions: &[f64],
    face_sizes: &[u32],
    face_indices: &[u32],
    crease_vertices: &[u32],
    crease_weights: &[f64],
    corner_vertices: &[u32],
    corner_weights: &[f64],
    faces: &[u32],
    subs: &[u16],
    u: &[f64],
    v: &[f64],
    b: u8,
) -> Result<Vec<f64>, String> {
    guard(|| {
        let n = faces.len();
        if subs.len() != n || u.len() != n || v.len() != n {
            return Err(crate::Error::InvalidArgument(format!(
                "location arrays differ in length (face {n}, sub {}, u {}, v {})",
                subs.len(),
                u.len(),
                v.len()
            )));
        }
        let locations: Vec<SurfaceLocation> = (0..n)
            .map(|i| SurfaceLocation {
                face: FaceId(faces[i]),
                sub: subs[i],
                u: u[i],
                v: v[i],
            })
            .collect();
        let control = ControlArrays {
            mesh: MeshArrays {
                positions,
                face_sizes,
                face_indices,
            },
            crease_vertices,
            crease_weights,
            corner_vertices,
            corner_weights,
        };
        Ok(flatten(&embed::evaluate(
            &control,
            &locations,
            backend(b)?,
        )?))
    })
}

fn embed_convert(
    positions: &[f64],
    face_sizes: &[u32],
    face_indices: &[u32],
    o: &FfiOptions,
    progress: &ProgressSink,
) -> Result<FfiConversion, String> {
    guard(|| {
        let input = MeshArrays {
            positions,
            face_sizes,
            face_indices,
        };
        let o = options(o)?;
        let c = SinkAdapter::new(progress).run(|p| embed::convert(&input, &o, p))?;
        Ok(conversion(c))
    })
}

#[allow(clippy::too_many_arguments)]
fn embed_fit(
    positions: &[f64],
    face_sizes: &[u32],
    face_indices: &[u32],
    control_positions: &[f64],
    control_face_sizes: &[u32],
    control_face_indices: &[u32],
    crease_vertices: &[u32],
    crease_weights: &[f64],
    corner_vertices: &[u32],
    corner_weights: &[f64],
    o: &FfiOptions,
    progress: &ProgressSink,
) -> Result<FfiConversion, String> {
    guard(|| {
        let input = MeshArrays {
            positions,
            face_sizes,
            face_indices,
        };
        let control = ControlArrays {
            mesh: MeshArrays {
                positions: control_positions,
                face_sizes: control_face_sizes,
                face_indices: control_face_indices,
            },
            crease_vertices,
            crease_weights,
            corner_vertices,
            corner_weights,
        };
        let o = options(o)?;
        let c = SinkAdapter::new(progress).run(|p| embed::fit(&input, &control, &o, p))?;
        Ok(conversion(c))
    })
}

fn embed_self_test(what: &str, progress: &ProgressSink) -> Result<(), String> {
    guard(|| SinkAdapter::new(progress).run(|p| embed::self_test(what, p)))
}
