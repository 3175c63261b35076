//! `subdfit limit` and `subdfit diff-limit`: differential testing of
//! Catmull-Clark limit evaluation as a user feature.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use subdfit::mesh::{
    BoundaryInterpolation, CreaseMethod, FVarChannel, FVarLinear, FaceId, SchemeOptions,
    SplitControl, SubdivScheme, TriangleSubdivision,
};
use subdfit::subdiv::{
    diff, file_vertex_limits, make_split_evaluator, make_split_fvar_evaluator,
    rust_split_fvar_evaluator, split_known_differences, Backend, EvalOptions, LimitPoint,
    SurfaceLocation,
};

#[derive(Copy, Clone, Debug, ValueEnum)]
pub enum BackendArg {
    /// OpenSubdiv 3.5 (Far), feature-adaptive patches.
    Osd,
    /// The pure-Rust exact evaluator.
    Rust,
}

impl From<BackendArg> for Backend {
    fn from(b: BackendArg) -> Self {
        match b {
            BackendArg::Osd => Backend::Osd,
            BackendArg::Rust => Backend::Rust,
        }
    }
}

#[derive(Copy, Clone, Debug, ValueEnum)]
pub enum SchemeArg {
    Catmark,
    Bilinear,
    /// Loop subdivision (all-triangle meshes only).
    Loop,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
pub enum BoundaryArg {
    None,
    EdgeOnly,
    EdgeAndCorner,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
pub enum FVarArg {
    None,
    CornersOnly,
    CornersPlus1,
    CornersPlus2,
    Boundaries,
    All,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
pub enum CreaseArg {
    Uniform,
    Chaikin,
}

#[derive(Copy, Clone, Debug, ValueEnum)]
pub enum TrianglesArg {
    Catmark,
    Smooth,
}

/// Scheme options; each one given here overrides the shape file's tag.
#[derive(Args)]
pub struct SchemeArgs {
    /// Subdivision scheme (default catmark; shape files do not say: OpenSubdiv's
    /// shapes state it in their test harness). Loop needs all triangles.
    #[arg(long, value_enum)]
    scheme: Option<SchemeArg>,
    /// Boundary interpolation (`t interpolateboundary`).
    #[arg(long, value_enum)]
    boundary: Option<BoundaryArg>,
    /// Face-varying linear interpolation (`t facevaryinginterpolateboundary`).
    #[arg(long, value_enum)]
    fvar: Option<FVarArg>,
    /// Creasing method (`t creasemethod`).
    #[arg(long, value_enum)]
    crease_method: Option<CreaseArg>,
    /// Triangle subdivision rule (`t smoothtriangles`).
    #[arg(long, value_enum)]
    triangles: Option<TrianglesArg>,
    /// Hole faces, 0-based and comma-separated (`t hole`); replaces the
    /// file's list (`--holes ''` for none).
    #[arg(long, value_delimiter = ',', num_args = 0..)]
    holes: Option<Vec<u32>>,
}

impl SchemeArgs {
    /// The file's options with the command line's on top.
    fn apply(&self, mut s: SchemeOptions) -> SchemeOptions {
        if let Some(k) = self.scheme {
            s = s.with_scheme(match k {
                SchemeArg::Catmark => SubdivScheme::Catmark,
                SchemeArg::Bilinear => SubdivScheme::Bilinear,
                SchemeArg::Loop => SubdivScheme::Loop,
            });
        }
        if let Some(b) = self.boundary {
            s = s.with_boundary(match b {
                BoundaryArg::None => BoundaryInterpolation::None,
                BoundaryArg::EdgeOnly => BoundaryInterpolation::EdgeOnly,
                BoundaryArg::EdgeAndCorner => BoundaryInterpolation::EdgeAndCorner,
            });
        }
        if let Some(f) = self.fvar {
            s = s.with_fvar(match f {
                FVarArg::None => FVarLinear::None,
                FVarArg::CornersOnly => FVarLinear::CornersOnly,
                FVarArg::CornersPlus1 => FVarLinear::CornersPlus1,
                FVarArg::CornersPlus2 => FVarLinear::CornersPlus2,
                FVarArg::Boundaries => FVarLinear::Boundaries,
                FVarArg::All => FVarLinear::All,
            });
        }
        if let Some(c) = self.crease_method {
            s = s.with_crease_method(match c {
                CreaseArg::Uniform => CreaseMethod::Uniform,
                CreaseArg::Chaikin => CreaseMethod::Chaikin,
            });
        }
        if let Some(t) = self.triangles {
            s = s.with_triangles(match t {
                TrianglesArg::Catmark => TriangleSubdivision::Catmark,
                TrianglesArg::Smooth => TriangleSubdivision::Smooth,
            });
        }
        if let Some(h) = &self.holes {
            s = s.with_holes(h.iter().map(|&f| FaceId(f)).collect());
        }
        s
    }
}

/// Reads the control mesh (non-manifold as OpenSubdiv takes it), the
/// scheme options in force (file, then flags) and the file's texture
/// coordinates.
fn read_with_scheme(
    path: &Path,
    args: &SchemeArgs,
) -> Result<(SplitControl, SchemeOptions, Option<FVarChannel>)> {
    let file = subdfit::io::read_control_split(path).context("control mesh")?;
    let (sc, scheme) = (file.split, args.apply(file.scheme));
    let faces = sc.face_sizes.len();
    if let Some(f) = scheme.holes.iter().find(|f| f.idx() >= faces) {
        bail!(
            "{}: hole face {} out of range (the mesh has {faces} faces)",
            path.display(),
            f.0,
        );
    }
    sc.check_scheme(&scheme).context("control mesh")?;
    // Boundary "none" holes every face at a soft boundary vertex, in all of
    // its fans: stated with the other holes, so both backends and the
    // sampling agree.
    let scheme = sc.with_file_holes(scheme);
    if let Some(note) = &file.uv_note {
        eprintln!("warning: {note}");
    }
    Ok((sc, scheme, file.uv))
}

#[derive(Args)]
pub struct LimitArgs {
    /// Control mesh (OBJ shape file: every `t` tag honoured, see README).
    control: PathBuf,
    #[command(flatten)]
    scheme: SchemeArgs,
    #[arg(long, value_enum, default_value_t = BackendArg::Osd)]
    backend: BackendArg,
    /// CSV of locations with header `face,u,v` (quad faces) or
    /// `face,sub,u,v`; without it, one row per control vertex.
    #[arg(long)]
    at: Option<PathBuf>,
    /// OpenSubdiv's adaptive isolation level (1-10).
    #[arg(long, default_value_t = 10)]
    isolation: u8,
    /// Output CSV.
    #[arg(short, long)]
    output: PathBuf,
}

#[derive(Args)]
pub struct DiffArgs {
    /// Control mesh (OBJ shape file: every `t` tag honoured, see README).
    control: PathBuf,
    #[command(flatten)]
    scheme: SchemeArgs,
    /// Random locations compared besides the control vertices.
    #[arg(long, default_value_t = 10_000)]
    samples: usize,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// OpenSubdiv's adaptive isolation level (1-10).
    #[arg(long, default_value_t = 10)]
    isolation: u8,
    /// Largest position deviation allowed (relative to the bounding-box
    /// diagonal) at control vertices and at locations away from irregular
    /// corners; control vertices are held to a tenth of it.
    #[arg(long, default_value_t = 1e-8)]
    tolerance: f64,
    /// Largest normal deviation allowed away from irregular corners, radians.
    #[arg(long, default_value_t = 1e-6)]
    normal_tolerance: f64,
    /// Locations closer than this (in u and v) to an irregular corner are
    /// reported apart and not held to a tolerance: OpenSubdiv's end-cap
    /// patches approximate (and reparametrise) the limit there, by an amount
    /// that shrinks as `--isolation` grows.
    #[arg(long, default_value_t = 0.01)]
    margin: f64,
    /// Normal deviation allowed at control vertices, radians. Vertices
    /// OpenSubdiv evaluates on its patches (semi-sharp features still sharp
    /// at level 1: a Gregory end cap where the vertex is extraordinary once
    /// they run out) are reported apart with their size, not held to it.
    #[arg(long, default_value_t = 1e-5)]
    vertex_normal_tolerance: f64,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
    /// Test hook: break the Rust evaluator's limit mask of this control
    /// vertex (its own weight + 1e-3), to check that a defect is caught.
    #[arg(long, hide = true)]
    break_mask: Option<u32>,
}

fn read_locations(path: &Path) -> Result<Vec<SurfaceLocation>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines
        .next()
        .with_context(|| format!("{}: empty file", path.display()))?;
    let cols: Vec<&str> = header.split(',').map(str::trim).collect();
    let with_sub = match cols.as_slice() {
        ["face", "u", "v"] => false,
        ["face", "sub", "u", "v"] => true,
        _ => bail!(
            "{}: line 1: expected the header `face,u,v` or `face,sub,u,v`",
            path.display()
        ),
    };
    let mut out = Vec::new();
    for (i, line) in lines {
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let ctx = || format!("{}: line {}", path.display(), i + 1);
        if f.len() != cols.len() {
            bail!(
                "{}: expected {} fields, found {}",
                ctx(),
                cols.len(),
                f.len()
            );
        }
        let face: u32 = f[0]
            .parse()
            .with_context(|| format!("{}: bad face index `{}`", ctx(), f[0]))?;
        let sub: u16 = if with_sub {
            f[1].parse()
                .with_context(|| format!("{}: bad sub-face `{}`", ctx(), f[1]))?
        } else {
            0
        };
        let k = if with_sub { 2 } else { 1 };
        let u: f64 = f[k]
            .parse()
            .with_context(|| format!("{}: bad u `{}`", ctx(), f[k]))?;
        let v: f64 = f[k + 1]
            .parse()
            .with_context(|| format!("{}: bad v `{}`", ctx(), f[k + 1]))?;
        out.push(SurfaceLocation {
            face: FaceId(face),
            sub,
            u,
            v,
        });
    }
    Ok(out)
}

fn write_row(w: &mut dyn Write, prefix: &str, p: &LimitPoint) -> std::io::Result<()> {
    let n = p.normal();
    writeln!(
        w,
        "{prefix},{},{},{},{},{},{}",
        p.position.x, p.position.y, p.position.z, n.x, n.y, n.z
    )
}

pub fn limit(a: LimitArgs) -> Result<ExitCode> {
    let (sc, scheme, uv) = read_with_scheme(&a.control, &a.scheme)?;
    // Evaluators work over the manifold copy's vertices; vertex rows are
    // the file's (`file_vertex_limits`).
    let mesh = &sc.manifold;
    // State the rules the numbers follow: a file's tags change the surface.
    crate::emit(&format!("scheme: {scheme}"))?;
    let opts = EvalOptions::default()
        .with_isolation_level(a.isolation)
        .with_scheme(scheme);
    let eval = make_split_evaluator(a.backend.into(), &sc, &opts)?;
    let out = &a.output;
    let io = |e: std::io::Error| subdfit::Error::Io {
        path: out.clone(),
        source: e,
    };
    match &a.at {
        None => {
            let pts = file_vertex_limits(&sc, &eval.vertex_limits(mesh.positions())?);
            subdfit::io::write_atomically(out, |w| {
                writeln!(w, "vertex,x,y,z,nx,ny,nz").map_err(io)?;
                for (i, p) in pts.iter().enumerate() {
                    write_row(w, &i.to_string(), p).map_err(io)?;
                }
                Ok(())
            })?;
        }
        Some(at) => {
            let locs = read_locations(at)?;
            let pts = eval.evaluate(mesh.positions(), &locs)?;
            // Face-varying data is per face corner, so it has a value at a
            // location, not at a control vertex: columns with `--at` only.
            let uvs = match &uv {
                Some(ch) => Some(
                    make_split_fvar_evaluator(a.backend.into(), &sc, &opts, ch)?.evaluate(&locs)?,
                ),
                None => None,
            };
            subdfit::io::write_atomically(out, |w| {
                let uv_head = if uvs.is_some() {
                    ",s,t,ds_du,dt_du,ds_dv,dt_dv"
                } else {
                    ""
                };
                writeln!(w, "face,u,v,x,y,z,nx,ny,nz{uv_head}").map_err(io)?;
                for (k, (l, p)) in locs.iter().zip(&pts).enumerate() {
                    let n = p.normal();
                    write!(
                        w,
                        "{},{},{},{},{},{},{},{},{}",
                        l.face.0, l.u, l.v, p.position.x, p.position.y, p.position.z, n.x, n.y, n.z
                    )
                    .map_err(io)?;
                    if let Some(t) = &uvs {
                        let q = &t[k];
                        write!(
                            w,
                            ",{},{},{},{},{},{}",
                            q.position.x, q.position.y, q.du.x, q.du.y, q.dv.x, q.dv.y
                        )
                        .map_err(io)?;
                    }
                    writeln!(w).map_err(io)?;
                }
                Ok(())
            })?;
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The face-varying comparison of `diff-limit`, when the file has UVs.
fn diff_uvs(
    sc: &SplitControl,
    opts: &EvalOptions,
    uv: Option<&FVarChannel>,
    locs: &[SurfaceLocation],
    margin: f64,
) -> Result<Option<diff::FVarDiffReport>> {
    let Some(ch) = uv else { return Ok(None) };
    let rust = rust_split_fvar_evaluator(sc, opts, ch)?;
    let osd = make_split_fvar_evaluator(Backend::Osd, sc, opts, ch)?;
    Ok(Some(diff::compare_fvar(
        rust.fvar_mesh(),
        osd.as_ref(),
        &rust,
        locs,
        margin,
    )?))
}

pub fn diff_limit(a: DiffArgs) -> Result<ExitCode> {
    let (sc, scheme, uv) = read_with_scheme(&a.control, &a.scheme)?;
    // Compared over the manifold copy (same faces, a vertex per fan).
    let mesh = &sc.manifold;
    let opts = EvalOptions::default()
        .with_isolation_level(a.isolation)
        .with_scheme(scheme.clone());
    let osd = make_split_evaluator(Backend::Osd, &sc, &opts)?;
    let rust_opts = match a.break_mask {
        Some(v) => opts.clone().with_broken_mask(v, 1e-3),
        None => opts,
    };
    let rust = make_split_evaluator(Backend::Rust, &sc, &rust_opts)?;
    let mut locs = diff::random_locations_with(mesh, &scheme, a.samples, a.seed);
    locs.extend(diff::near_irregular_locations_with(
        mesh, &scheme, 8, a.margin, a.seed,
    ));
    let mut report = diff::compare_with_known(
        mesh,
        &scheme,
        osd.as_ref(),
        rust.as_ref(),
        &locs,
        a.margin,
        split_known_differences(&sc),
    )?;
    // The size of OpenSubdiv's f32 sharpness: what it does to the surface.
    let (dp, dn) = diff::f32_sharpness_effect(mesh, &rust_opts, &locs)?;
    report.set_f32_effect(dp, dn);
    let uv_report = diff_uvs(&sc, &rust_opts, uv.as_ref(), &locs, a.margin)?;
    let mut failures = Vec::new();
    let mut check = |what: &str, value: f64, tol: f64| {
        // NaN counts as a failure.
        if value.is_nan() || value > tol {
            failures.push(format!("{what} {value:.3e} > {tol:.1e}"));
        }
    };
    check(
        "control-vertex position",
        report.vertices.position,
        a.tolerance / 10.0,
    );
    check(
        "control-vertex normal",
        report.vertices.normal,
        a.vertex_normal_tolerance,
    );
    check("position", report.regular.position, a.tolerance);
    check("normal", report.regular.normal, a.normal_tolerance);
    check(
        "position without a tangent plane",
        report.singular.position,
        a.tolerance,
    );
    if let Some(u) = &uv_report {
        // UVs are held to the position tolerance, relative to their extent.
        check("face-varying value", u.regular.position, a.tolerance);
        check("face-varying derivative", u.regular.normal, a.tolerance);
    }
    if a.json {
        let mut v = serde_json::to_value(&report)?;
        v["face_varying"] = serde_json::to_value(&uv_report)?;
        v["failures"] = serde_json::to_value(&failures)?;
        crate::emit(&serde_json::to_string_pretty(&v)?)?;
    } else {
        let mut text = report.to_string();
        if let Some(u) = &uv_report {
            text += &format!(
                "  face-varying (UV extent {:.6e}): n={} value {:.3e} derivative {:.3e} at {}; \
                 near irregular n={} value {:.3e}\n",
                u.uv_extent,
                u.regular.count,
                u.regular.position,
                u.regular.normal,
                u.regular.position_at,
                u.near_irregular.count,
                u.near_irregular.position
            );
        }
        if failures.is_empty() {
            text += "OK: within tolerance";
        } else {
            for f in &failures {
                text += &format!("FAIL: {f}\n");
            }
        }
        crate::emit(&text)?;
    }
    Ok(if failures.is_empty() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}
