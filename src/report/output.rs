//! Writing the outputs of `subdfit fit` / `convert` as one unit: every file
//! is written into a staging folder inside the output folder, and only when
//! all of them are complete are they renamed into place. A failure (or a
//! crash) before that point leaves the output folder as it was — at worst a
//! hidden `.subdfit-staging-*` folder after a crash, never a half-written or
//! mismatched set of results.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::analysis::Fitmap;
use crate::displace::{Atlas, DEFAULT_GUTTER};
use crate::error::{Error, Result};
use crate::io::{
    write_atomically, write_control_obj, write_control_obj_with_uvs, write_ply, write_usda,
};
use crate::mesh::{ControlMesh, TriMesh};

use super::{Report, Surfaces};

/// What [`write_outputs`] writes.
pub struct OutputFiles<'a> {
    /// M, for `fitmap.ply`.
    pub mesh: &'a TriMesh,
    pub control: &'a ControlMesh,
    /// The all-quad mesh the atlas is laid out on when `control` has other
    /// faces (see [`super::Converted::quad_control`]): then `control.obj`
    /// and `control.usda` carry `control` without UVs, and
    /// `control_quads.obj` this mesh with them.
    pub quad_control: Option<&'a ControlMesh>,
    pub surfaces: &'a Surfaces,
    /// `fitmap.ply` is written when given.
    pub fitmap: Option<&'a Fitmap>,
    pub report: &'a Report,
}

/// The file names, in the order they are written.
pub const OUTPUT_NAMES: [&str; 7] = [
    "control.obj",
    "control.usda",
    "limit.ply",
    "displaced.ply",
    "displacement.exr",
    "fitmap.ply",
    "report.json",
];

/// Writes `control.obj` (with `vt` into the atlas), `control.usda`,
/// `limit.ply`, `displaced.ply`, `displacement.exr`, `fitmap.ply` (when a
/// Fitmap is given) and `report.json` into `dir` (created if missing), all
/// or nothing (module docs). Returns the paths written.
pub fn write_outputs(dir: &Path, out: &OutputFiles<'_>) -> Result<Vec<PathBuf>> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let created = !dir.exists();
    fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let staging = dir.join(format!(
        ".subdfit-staging-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let result = fs::create_dir(&staging)
        .map_err(|e| Error::io(&staging, e))
        .and_then(|_| write_all(&staging, out))
        .and_then(|names| {
            // Everything that can make a rename fail short of a crash is
            // checked before the first rename, so renaming is all or nothing.
            for name in &names {
                let to = dir.join(name);
                if to.is_dir() {
                    return Err(Error::io(
                        &to,
                        std::io::Error::new(
                            std::io::ErrorKind::AlreadyExists,
                            "a folder is in the way of an output file; move it away",
                        ),
                    ));
                }
            }
            let mut done = Vec::new();
            for name in names {
                let to = dir.join(name);
                fs::rename(staging.join(name), &to).map_err(|e| Error::io(&to, e))?;
                done.push(to);
            }
            Ok(done)
        });
    let _ = fs::remove_dir_all(&staging);
    if result.is_err() && created {
        // Only removes the folder if it is still empty.
        let _ = fs::remove_dir(dir);
    }
    result
}

/// One output file: its name and the code that writes it to a path.
type Job<'a> = (
    &'static str,
    Box<dyn Fn(&Path) -> Result<()> + Send + Sync + 'a>,
);

fn write_all(dir: &Path, out: &OutputFiles<'_>) -> Result<Vec<&'static str>> {
    use rayon::prelude::*;
    let d = &out.surfaces.displacement;
    let atlas = Atlas::new(d.grid.num_patches(), d.grid.res(), DEFAULT_GUTTER)?;
    let uvs: Vec<_> = (0..d.grid.num_patches())
        .map(|f| atlas.corner_uvs(f))
        .collect();
    let (atlas, uvs) = (&atlas, &uvs);
    let mut jobs: Vec<Job<'_>> = Vec::new();
    match out.quad_control {
        None => {
            jobs.push((
                "control.obj",
                Box::new(move |p| write_control_obj_with_uvs(p, out.control, uvs)),
            ));
            jobs.push((
                "control.usda",
                Box::new(move |p| write_usda(p, out.control, Some(uvs))),
            ));
        }
        Some(quads) => {
            jobs.push((
                "control.obj",
                Box::new(move |p| write_control_obj(p, out.control)),
            ));
            jobs.push((
                "control.usda",
                Box::new(move |p| write_usda(p, out.control, None)),
            ));
            jobs.push((
                "control_quads.obj",
                Box::new(move |p| write_control_obj_with_uvs(p, quads, uvs)),
            ));
        }
    }
    jobs.push((
        "limit.ply",
        Box::new(move |p| {
            let lim = &out.surfaces.limit;
            write_ply(p, &lim.positions, &lim.triangles, &[], None)
        }),
    ));
    jobs.push((
        "displaced.ply",
        Box::new(move |p| {
            let dis = &out.surfaces.displaced;
            let offsets: Vec<f32> = d.offsets.iter().map(|&x| x as f32).collect();
            let projected: Vec<f32> = d
                .projected
                .iter()
                .map(|&p| if p { 1.0 } else { 0.0 })
                .collect();
            write_ply(
                p,
                &dis.positions,
                &dis.triangles,
                &[("displacement", &offsets), ("projected", &projected)],
                None,
            )
        }),
    ));
    jobs.push((
        "displacement.exr",
        Box::new(move |p| {
            let exr = atlas.encode_exr(&atlas.bake(d)?)?;
            write_atomically(p, |w| w.write_all(&exr).map_err(|e| Error::io(p, e)))
        }),
    ));
    if let Some(fm) = out.fitmap {
        jobs.push((
            "fitmap.ply",
            Box::new(move |p| {
                let s: Vec<f32> = fm.s.iter().map(|&x| x as f32).collect();
                let m: Vec<f32> = fm.m.iter().map(|&x| x as f32).collect();
                write_ply(
                    p,
                    &out.mesh.positions,
                    &out.mesh.triangles,
                    &[("s", &s), ("m", &m)],
                    None,
                )
            }),
        ));
    }
    jobs.push((
        "report.json",
        Box::new(move |p| {
            let json = serde_json::to_string_pretty(out.report)
                .map_err(|e| Error::InvalidArgument(format!("report.json: {e}")))?;
            write_atomically(p, |w| {
                w.write_all(json.as_bytes())
                    .and_then(|_| w.write_all(b"\n"))
                    .map_err(|e| Error::io(p, e))
            })
        }),
    ));
    // The files are independent: written side by side (encoding the EXR
    // and formatting the PLYs is most of the time), each into its own
    // staging path, so every file's bytes are the same as written one after
    // the other. The first error in the list's order is the one reported.
    jobs.par_iter()
        .map(|(name, job)| job(&dir.join(name)))
        .collect::<Vec<Result<()>>>()
        .into_iter()
        .collect::<Result<()>>()?;
    Ok(jobs.iter().map(|(name, _)| *name).collect())
}
