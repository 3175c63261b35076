//! Writing the outputs of `subdfit fit` / `convert` as one set.
//!
//! An output folder always holds one run's complete set, never half old and
//! half new, and nothing left from a run in another mode or with other
//! options (a stale `fitmap.ply` beside a mechanical result, a stale
//! `report.html`):
//!
//! 1. the whole set (and any extra file, e.g. `report.html`) is written into
//!    a staging folder beside the output folder,
//!    `PARENT/.NAME.subdfit-staging-PID-N`, on the same file system;
//! 2. files in the output folder that subdfit did not write are hard-linked
//!    into it, so they survive (a sub-folder there is an error before
//!    anything is written: it cannot be carried over atomically);
//! 3. one `renameat2(RENAME_EXCHANGE)` swaps the two folders atomically (a
//!    plain rename when there was no output folder), and the staging path,
//!    which now holds the old set, is removed.
//!
//! A crash before step 3 leaves the output folder as it was, plus at worst
//! a staging folder beside it; the next run removes staging folders of
//! processes that are gone (and the `OUTDIR/.subdfit-staging-*` folders
//! older versions left inside). A signal handler (the binary's) calls
//! [`remove_staging_folders`] so that SIGINT/SIGTERM leave nothing behind.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use crate::analysis::Fitmap;
use crate::displace::{Atlas, AtlasLayout, AtlasMap, TexelType};
use crate::error::{Error, Result};
use crate::io::{
    write_atomically, write_control_obj_with_uvs, write_ply, write_usda_with, UsdOptions,
};
use crate::mesh::{ControlMesh, TriMesh};

use serde::Serialize;

use super::{Report, Surfaces};

/// Writes more files into a staging folder (its argument) before the set is
/// put in place, returning their names: e.g. `report.html`, drawn from the
/// staged files themselves.
pub type ExtraFiles<'a> = &'a mut dyn FnMut(&Path) -> Result<Vec<String>>;

/// What [`write_outputs`] writes.
pub struct OutputFiles<'a, O> {
    /// M, for `fitmap.ply`.
    pub mesh: &'a TriMesh,
    /// The control mesh `control.obj` and `control.usda` carry, with UVs
    /// into the atlas: all quads (in mechanical mode, Lavoué et al.'s
    /// quad/triangle mesh refined once, see
    /// [`super::Converted::quad_control`]).
    pub control: &'a ControlMesh,
    pub surfaces: &'a Surfaces,
    /// `fitmap.ply` is written when given.
    pub fitmap: Option<&'a Fitmap>,
    pub report: &'a Report<O>,
    pub options: &'a OutputOptions,
}

/// How the files are written (not what they hold).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct OutputOptions {
    /// `control.usda`'s `metersPerUnit`: what one unit of the input is
    /// (`--units`; the input is taken to be in metres by default).
    pub meters_per_unit: f64,
    /// `displacement.exr`, or UDIM tiles `displacement.1001.exr`, ….
    pub atlas: AtlasLayout,
    /// 32- or 16-bit float texels.
    pub texels: TexelType,
}

impl Default for OutputOptions {
    fn default() -> Self {
        OutputOptions {
            meters_per_unit: 1.0,
            atlas: AtlasLayout::Single,
            texels: TexelType::Float,
        }
    }
}

/// The file names, in the order they are written (UDIM outputs write
/// `displacement.1001.exr`, … instead of `displacement.exr`, and the same
/// for `displacement_vector.exr`).
pub const OUTPUT_NAMES: [&str; 8] = [
    "control.obj",
    "control.usda",
    "limit.ply",
    "displaced.ply",
    "displacement.exr",
    "displacement_vector.exr",
    "fitmap.ply",
    "report.json",
];

/// Every name subdfit may write into an output folder: a file of these
/// names (or a UDIM tile, [`is_known_name`]) is part of an earlier set and
/// is replaced (or dropped), never carried over. `control_quads.obj` is
/// what older versions wrote in mechanical mode.
pub const KNOWN_NAMES: [&str; 10] = [
    "control.obj",
    "control.usda",
    "control_quads.obj",
    "limit.ply",
    "displaced.ply",
    "displacement.exr",
    "displacement_vector.exr",
    "fitmap.ply",
    "report.json",
    "report.html",
];

/// Staging folders of this process that are not in place yet (for
/// [`remove_staging_folders`]). Held while a set is swapped in, so a signal
/// handler never removes a folder half-way through the swap.
static STAGING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

/// Removes the staging folders of every write in progress in this process;
/// for signal handlers, which exit right after (the lock stays held, so no
/// write of this process can put a set in place after it).
pub fn remove_staging_folders() {
    let guard = STAGING.lock().unwrap_or_else(|e| e.into_inner());
    for p in guard.iter() {
        let _ = fs::remove_dir_all(p);
    }
    std::mem::forget(guard);
}

/// Writes `control.obj` (with `vt` into the atlas), `control.usda`,
/// `limit.ply`, `displaced.ply`, `displacement.exr`, `fitmap.ply` (when a
/// Fitmap is given) and `report.json` into `dir` (created if missing) as
/// one set, all or nothing (module docs). Returns the paths written.
pub fn write_outputs<O: Serialize + Sync>(
    dir: &Path,
    out: &OutputFiles<'_, O>,
) -> Result<Vec<PathBuf>> {
    write_outputs_with(dir, out, None)
}

/// [`write_outputs`] with `extra`'s files in the same set.
pub fn write_outputs_with<O: Serialize + Sync>(
    dir: &Path,
    out: &OutputFiles<'_, O>,
    mut extra: Option<ExtraFiles<'_>>,
) -> Result<Vec<PathBuf>> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let (parent, name) = split_dir(dir)?;
    remove_stale_staging(&parent, &name, dir);
    let foreign = foreign_files(dir)?;
    let staging = parent.join(format!(
        ".{name}.subdfit-staging-{}-{}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
    STAGING
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .push(staging.clone());
    let result = fs::create_dir(&staging)
        .map_err(|e| Error::io(&staging, e))
        .and_then(|_| write_all(&staging, out))
        .and_then(|names| {
            let mut names = names;
            if let Some(extra) = extra.as_mut() {
                names.extend(extra(&staging)?);
            }
            for f in &foreign {
                let to = staging.join(f);
                fs::hard_link(dir.join(f), &to).map_err(|e| Error::io(&to, e))?;
            }
            pause_for_tests();
            swap_in(&staging, dir)?;
            Ok(names.iter().map(|n| dir.join(n)).collect())
        });
    let mut registry = STAGING.lock().unwrap_or_else(|e| e.into_inner());
    // After the swap this is the old set; after a failure, the partial one.
    let _ = fs::remove_dir_all(&staging);
    registry.retain(|p| p != &staging);
    result
}

/// `dir`'s parent folder and its own name (the staging folder's is derived
/// from it).
fn split_dir(dir: &Path) -> Result<(PathBuf, String)> {
    let abs = if dir.is_absolute() {
        dir.to_path_buf()
    } else {
        std::env::current_dir()
            .map_err(|e| Error::io(dir, e))?
            .join(dir)
    };
    let bad = || {
        Error::io(
            dir,
            std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "an output folder needs a name and a parent folder",
            ),
        )
    };
    let name = abs
        .file_name()
        .ok_or_else(bad)?
        .to_string_lossy()
        .into_owned();
    if name == "." || name == ".." {
        return Err(bad());
    }
    Ok((abs.parent().ok_or_else(bad)?.to_path_buf(), name))
}

/// Files in `dir` that subdfit did not write (to be carried over into the
/// new set). A sub-folder, or an entry of a known name that is not a file,
/// is an error: it cannot be carried over with the set.
fn foreign_files(dir: &Path) -> Result<Vec<String>> {
    let entries = match fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(e) => return Err(Error::io(dir, e)),
    };
    let mut out = Vec::new();
    for e in entries {
        let e = e.map_err(|e| Error::io(dir, e))?;
        let name = e.file_name().to_string_lossy().into_owned();
        let ty = e.file_type().map_err(|err| Error::io(e.path(), err))?;
        if name.starts_with(".subdfit-staging-") {
            continue;
        }
        if ty.is_dir() {
            return Err(Error::io(
                e.path(),
                std::io::Error::new(
                    std::io::ErrorKind::AlreadyExists,
                    "a folder inside the output folder; subdfit replaces the output folder as \
                     a whole, so move it away (or choose another output folder)",
                ),
            ));
        }
        if !is_known_name(&name) {
            out.push(name);
        }
    }
    out.sort();
    Ok(out)
}

/// Whether subdfit writes files named `name`: [`KNOWN_NAMES`] and the
/// UDIM tiles `displacement.NNNN.exr` and `displacement_vector.NNNN.exr`.
pub fn is_known_name(name: &str) -> bool {
    let udim = ["displacement.", "displacement_vector."]
        .iter()
        .any(|stem| {
            name.strip_prefix(stem)
                .and_then(|r| r.strip_suffix(".exr"))
                .is_some_and(|n| n.len() == 4 && n.bytes().all(|b| b.is_ascii_digit()))
        });
    udim || KNOWN_NAMES.contains(&name)
}

/// Removes staging folders left by killed runs: beside `dir` (this
/// version's, `.NAME.subdfit-staging-PID-N`) and inside it (older
/// versions', `.subdfit-staging-PID-N`), when process PID is gone.
fn remove_stale_staging(parent: &Path, name: &str, dir: &Path) {
    let beside = format!(".{name}.subdfit-staging-");
    for (folder, prefix) in [(parent, beside.as_str()), (dir, ".subdfit-staging-")] {
        let Ok(entries) = fs::read_dir(folder) else {
            continue;
        };
        for e in entries.flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            let Some(rest) = n.strip_prefix(prefix) else {
                continue;
            };
            let pid = rest.split('-').next().and_then(|p| p.parse::<u32>().ok());
            let alive = pid.is_some_and(|p| Path::new(&format!("/proc/{p}")).exists());
            if !alive {
                let _ = fs::remove_dir_all(e.path());
            }
        }
    }
}

/// Puts the staged set in place: atomically exchanged with the old folder
/// (Linux `renameat2(RENAME_EXCHANGE)`), or renamed when there is none.
/// The registry lock is held so that a signal handler does not remove the
/// staging folder half-way.
fn swap_in(staging: &Path, dir: &Path) -> Result<()> {
    let _held = STAGING.lock().unwrap_or_else(|e| e.into_inner());
    if !dir.exists() {
        return fs::rename(staging, dir).map_err(|e| Error::io(dir, e));
    }
    exchange(staging, dir).map_err(|e| Error::io(dir, e))
}

#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    use std::ffi::CString;
    use std::os::unix::ffi::OsStrExt;
    let c = |p: &Path| {
        CString::new(p.as_os_str().as_bytes())
            .map_err(|e| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))
    };
    let (ca, cb) = (c(a)?, c(b)?);
    // SAFETY: two valid NUL-terminated paths; renameat2 only reads them.
    let r = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            ca.as_ptr(),
            libc::AT_FDCWD,
            cb.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    };
    if r == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// Elsewhere no atomic exchange exists: the old folder is moved aside
/// first (a crash between the two renames leaves no output folder and the
/// old set in the staging path, never a mixed one).
#[cfg(not(target_os = "linux"))]
fn exchange(a: &Path, b: &Path) -> std::io::Result<()> {
    let aside = a.with_extension("old");
    fs::rename(b, &aside)?;
    fs::rename(a, b)?;
    fs::rename(&aside, a)
}

/// Hidden test hook: `SUBDFIT_TEST_PAUSE_BEFORE_SWAP_MS` holds a staged set
/// that long before the swap, so that tests can kill a run mid-write.
fn pause_for_tests() {
    if let Some(ms) = crate::switches::parsed::<u64>("SUBDFIT_TEST_PAUSE_BEFORE_SWAP_MS") {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

/// One output file: its name and the code that writes it to a path.
type Job<'a> = (String, Box<dyn Fn(&Path) -> Result<()> + Send + Sync + 'a>);

/// The stem of the maps written beside B-spline coefficient maps for hosts
/// with only a bilinear lookup: `displacement_bilinear[_vector][.<UDIM>].exr`.
pub const BILINEAR_STEM: &str = "displacement_bilinear";

/// Scalar and vector images (per UDIM tile) of the B-spline evaluated at
/// every sample, laid out as bilinear samples, when `d` is a B-spline
/// reconstruction; `None` otherwise. USD's `UsdUVTexture` has no filter
/// choice and its hosts read bilinearly (docs/handoff.md), so the USD
/// material binds these: a bilinear host gets the surface that
/// interpolates the B-spline surface at the samples, within the error
/// that tests/blender.rs measures, instead of reading coefficients as
/// samples (on spot 1.4 % of the diagonal off `displaced.ply`).
#[allow(clippy::type_complexity)]
fn bilinear_maps(
    atlas: &Atlas,
    d: &crate::displace::Displacement,
) -> Result<Option<(Vec<Vec<f32>>, Vec<[Vec<f32>; 3]>)>> {
    use crate::displace::{BsplineTiles, Reconstruction};
    if d.reconstruction != Reconstruction::Bspline {
        return Ok(None);
    }
    let tiles = BsplineTiles::new(&d.grid);
    let scalar = atlas.bake_sample_images(d, &tiles.at_samples(|s| d.offsets[s]))?;
    let v = d.vectors();
    let at = tiles.at_samples(|s| v[s]);
    let channel = |c: usize| -> Vec<f64> { at.iter().map(|p| p[c]).collect() };
    let [x, y, z] = [0, 1, 2].map(|c| atlas.bake_sample_images(d, &channel(c)));
    let vector = x?
        .into_iter()
        .zip(y?)
        .zip(z?)
        .map(|((x, y), z)| [x, y, z])
        .collect();
    Ok(Some((scalar, vector)))
}

fn write_all<O: Serialize + Sync>(dir: &Path, out: &OutputFiles<'_, O>) -> Result<Vec<String>> {
    use rayon::prelude::*;
    let d = &out.surfaces.displacement;
    let atlas = Atlas::for_grid(&d.grid, out.options.atlas)?;
    let uvs: Vec<_> = (0..d.grid.num_patches())
        .map(|f| atlas.corner_uvs(f))
        .collect();
    let images = atlas.bake_images(d)?;
    let vectors = atlas.bake_vector_images(d)?;
    let sampled = bilinear_maps(&atlas, d)?;
    let (atlas, uvs) = (&atlas, &uvs);
    let texture = atlas.texture_pattern().to_string();
    let usd = UsdOptions {
        meters_per_unit: out.options.meters_per_unit,
        // B-spline maps: USD binds their samples (`bilinear_maps`).
        texture: Some(match &sampled {
            Some(_) => texture.replacen("displacement", BILINEAR_STEM, 1),
            None => texture,
        }),
    };
    let usd = &usd;
    let mut jobs: Vec<Job<'_>> = Vec::new();
    jobs.push((
        "control.obj".into(),
        Box::new(move |p| write_control_obj_with_uvs(p, out.control, uvs)),
    ));
    jobs.push((
        "control.usda".into(),
        Box::new(move |p| write_usda_with(p, out.control, Some(uvs), usd)),
    ));
    jobs.push((
        "limit.ply".into(),
        Box::new(move |p| {
            let lim = &out.surfaces.limit;
            write_ply(p, &lim.positions, &lim.triangles, &[], None)
        }),
    ));
    jobs.push((
        "displaced.ply".into(),
        Box::new(move |p| {
            let dis = &out.surfaces.displaced;
            let surf = out.surfaces;
            let offsets: Vec<f32> = surf.displaced_offsets.iter().map(|&x| x as f32).collect();
            let projected: Vec<f32> = surf
                .displaced_projected
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
    // Each image encoded in its own job (the UDIM tiles side by side).
    for (k, img) in images.iter().enumerate() {
        jobs.push((
            atlas.file_name(k),
            Box::new(move |p| {
                let exr = atlas.encode_exr_as(img, out.options.texels)?;
                write_atomically(p, |w| w.write_all(&exr).map_err(|e| Error::io(p, e)))
            }),
        ));
    }
    for (k, xyz) in vectors.iter().enumerate() {
        jobs.push((
            atlas.file_name_of(AtlasMap::Vector, k),
            Box::new(move |p| {
                let exr = atlas.encode_vector_exr_as(xyz, out.options.texels)?;
                write_atomically(p, |w| w.write_all(&exr).map_err(|e| Error::io(p, e)))
            }),
        ));
    }
    if let Some((scalar, vector)) = &sampled {
        for (k, img) in scalar.iter().enumerate() {
            jobs.push((
                atlas
                    .file_name(k)
                    .replacen("displacement", BILINEAR_STEM, 1),
                Box::new(move |p| {
                    let exr = atlas.encode_exr_as(img, out.options.texels)?;
                    write_atomically(p, |w| w.write_all(&exr).map_err(|e| Error::io(p, e)))
                }),
            ));
        }
        for (k, xyz) in vector.iter().enumerate() {
            jobs.push((
                atlas
                    .file_name_of(AtlasMap::Vector, k)
                    .replacen("displacement", BILINEAR_STEM, 1),
                Box::new(move |p| {
                    let exr = atlas.encode_vector_exr_as(xyz, out.options.texels)?;
                    write_atomically(p, |w| w.write_all(&exr).map_err(|e| Error::io(p, e)))
                }),
            ));
        }
    }
    if let Some(fm) = out.fitmap {
        jobs.push((
            "fitmap.ply".into(),
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
        "report.json".into(),
        Box::new(move |p| {
            let json = serde_json::to_string_pretty(out.report)
                .map_err(|e| Error::internal(format!("report.json: {e}")))?;
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
    Ok(jobs.into_iter().map(|(name, _)| name).collect())
}
