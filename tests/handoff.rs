//! The outputs as third-party software reads them (issue 19): USD that
//! usd-core's validators accept, with a material whose texture resolves;
//! creases, corners and UVs in both modes; UDIM tiles and half floats that
//! OpenEXR reads back; mechanical control meshes without doublets; the
//! tessellation option.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::process::Command;

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("data")
        .join(name)
}

fn convert(input: &Path, out: &Path, extra: &[&str]) {
    let o = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .arg("convert")
        .arg(input)
        .arg("-o")
        .arg(out)
        .arg("--quiet")
        .args(extra)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "convert {}: {}",
        input.display(),
        String::from_utf8_lossy(&o.stderr)
    );
}

fn has_python_module(m: &str) -> bool {
    Command::new("python3")
        .args(["-c", &format!("import {m}")])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

/// A unit cube as 12 triangles: coarser than any Fitmap radius, so the
/// organic pipeline makes it its own creased control mesh (creases and
/// corners in organic mode).
fn cube_obj(path: &Path) {
    let mut s = String::new();
    for i in 0..8 {
        s += &format!("v {} {} {}\n", i & 1, (i >> 1) & 1, (i >> 2) & 1);
    }
    for f in [
        [1, 3, 4, 2],
        [5, 6, 8, 7],
        [1, 2, 6, 5],
        [3, 7, 8, 4],
        [1, 5, 7, 3],
        [2, 4, 8, 6],
    ] {
        s += &format!(
            "f {} {} {}\nf {} {} {}\n",
            f[0], f[1], f[2], f[0], f[2], f[3]
        );
    }
    std::fs::write(path, s).unwrap();
}

/// usd-core's validators (UsdValidation where the release has it, the
/// compliance checker before) on `usda`: prints each error and the
/// mesh's counts as JSON on the last line.
const VALIDATE: &str = r#"
import json, os, sys
from pxr import Usd, UsdGeom, UsdShade, Sdf
path = sys.argv[1]
stage = Usd.Stage.Open(path)
errors = []
try:
    from pxr import UsdValidation
    reg = UsdValidation.ValidationRegistry()
    ctx = UsdValidation.ValidationContext(reg.GetOrLoadAllValidators())
    for e in ctx.Validate(stage):
        if e.GetType() == UsdValidation.ValidationErrorType.Error:
            errors.append(e.GetName() + ": " + e.GetMessage())
    how = "UsdValidation"
except ImportError:
    from pxr.UsdUtils.complianceChecker import ComplianceChecker
    c = ComplianceChecker()
    c.CheckCompliance(path)
    errors = list(c.GetErrors()) + list(c.GetFailedChecks())
    how = "ComplianceChecker"
mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/subdfit/control"))
st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
mat, _ = UsdShade.MaterialBindingAPI(mesh.GetPrim()).ComputeBoundMaterial()
tex = stage.GetPrimAtPath("/subdfit/materials/displacement/texture")
file = tex.GetAttribute("inputs:file").Get()
space = tex.GetAttribute("inputs:sourceColorSpace").Get()
surf = UsdShade.Shader(stage.GetPrimAtPath("/subdfit/materials/displacement/surface"))
src = surf.GetInput("displacement").GetConnectedSources()[0]
resolved = file.resolvedPath or ""
pattern = file.path
if "<UDIM>" in pattern:
    resolved = os.path.join(os.path.dirname(path), os.path.normpath(pattern.replace("<UDIM>", "1001")))
print(json.dumps({
    "how": how,
    "errors": errors,
    "meters_per_unit": UsdGeom.GetStageMetersPerUnit(stage),
    "up_axis": UsdGeom.GetStageUpAxis(stage),
    "creases": len(mesh.GetCreaseLengthsAttr().Get() or []),
    "corners": len(mesh.GetCornerIndicesAttr().Get() or []),
    "faces": len(mesh.GetFaceVertexCountsAttr().Get()),
    "st": len(st.ComputeFlattened()) if st else 0,
    "material": str(mat.GetPath()) if mat else "",
    "texture": pattern,
    "texture_exists": os.path.isfile(resolved),
    "color_space": space,
    "displacement_from": str(src[0].source.GetPath()) + "." + src[0].sourceName,
}))
"#;

fn validate(usda: &Path) -> serde_json::Value {
    let o = Command::new("python3")
        .args(["-c", VALIDATE])
        .arg(usda)
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{}: {out}\n{}",
        usda.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    serde_json::from_str(out.lines().last().unwrap()).unwrap()
}

/// `t crease` edges and `t corner` vertices of a control.obj, and its
/// `vt` count.
fn obj_tags(obj: &Path) -> (usize, usize, usize) {
    let text = std::fs::read_to_string(obj).unwrap();
    let mut creases = 0;
    let mut corners = 0;
    let mut vt = 0;
    for l in text.lines() {
        let t: Vec<&str> = l.split_whitespace().collect();
        match t.as_slice() {
            ["t", "crease", counts, ..] => {
                let ints: usize = counts.split('/').next().unwrap().parse().unwrap();
                creases += ints - 1;
            }
            ["t", "corner", ..] => corners += 1,
            ["vt", ..] => vt += 1,
            _ => {}
        }
    }
    (creases, corners, vt)
}

#[test]
fn usd_validates_and_carries_material_creases_corners_uvs_in_both_modes() {
    if !has_python_module("pxr") {
        eprintln!("SKIPPED: Pixar's USD (python3 -c 'import pxr') is absent; pip install usd-core");
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let cube = tmp.path().join("cube.obj");
    cube_obj(&cube);
    let runs: [(&str, PathBuf, &[&str]); 3] = [
        ("spot", data("spot.ply"), &["--tessellation", "4"]),
        ("cube", cube, &["--mode", "organic", "--units", "mm"]),
        (
            "fandisk",
            data("fandisk.ply"),
            &["--mode", "mechanical", "--tessellation", "4"],
        ),
    ];
    for (name, input, extra) in runs {
        let out = tmp.path().join(name);
        convert(&input, &out, extra);
        let v = validate(&out.join("control.usda"));
        eprintln!("{name}: {v}");
        assert_eq!(
            v["errors"],
            serde_json::json!([]),
            "{name}: validator errors"
        );
        let mpu = if name == "cube" { 0.001 } else { 1.0 };
        assert_eq!(v["meters_per_unit"].as_f64(), Some(mpu), "{name}");
        assert_eq!(v["up_axis"], "Y");
        assert_eq!(v["material"], "/subdfit/materials/displacement", "{name}");
        assert_eq!(v["texture"], "./displacement.exr");
        assert_eq!(
            v["texture_exists"], true,
            "{name}: texture does not resolve"
        );
        assert_eq!(v["color_space"], "raw");
        assert_eq!(
            v["displacement_from"],
            "/subdfit/materials/displacement/texture.r"
        );
        let faces = v["faces"].as_u64().unwrap() as usize;
        assert_eq!(v["st"].as_u64().unwrap() as usize, 4 * faces, "{name}: UVs");
        // control.obj carries the same mesh, tags and UVs as control.usda.
        let (creases, corners, vt) = obj_tags(&out.join("control.obj"));
        assert_eq!(vt, 4 * faces, "{name}: control.obj vt");
        assert_eq!(v["creases"].as_u64().unwrap() as usize, creases, "{name}");
        assert_eq!(v["corners"].as_u64().unwrap() as usize, corners, "{name}");
        if name != "spot" {
            // A cube: 12 creased edges and 8 corners, once refined 24 and 8.
            assert!(
                creases >= 12 && corners >= 8,
                "{name}: {creases} creases, {corners} corners"
            );
        }
        assert!(!out.join("control_quads.obj").exists());
    }
}

/// `exrheader`'s text for `path`, or `None` without it (then the OpenEXR
/// Python package is tried by the caller).
fn exrheader(path: &Path) -> Option<String> {
    let o = Command::new("exrheader").arg(path).output().ok()?;
    assert!(o.status.success(), "exrheader {}", path.display());
    Some(String::from_utf8_lossy(&o.stdout).into_owned())
}

#[test]
fn udim_tiles_and_half_floats_read_back_in_openexr() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("spot");
    convert(
        &data("spot.ply"),
        &out,
        // One R × R grid per patch, so 8 × 8 patches per tile; the
        // adaptive atlas's UDIM tiles are checked below.
        &[
            "--atlas",
            "udim",
            "--half",
            "--tessellation",
            "4",
            "--displacement-allocation",
            "uniform",
        ],
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let patches = report["control"]["faces"].as_u64().unwrap() as usize;
    let res = report["projectability"]["displacement"]["resolution"]
        .as_u64()
        .unwrap() as usize;
    // 8 × 8 patches per tile.
    let tiles = patches.div_ceil(64);
    assert!(tiles >= 2, "spot should need several UDIM tiles");
    assert!(!out.join("displacement.exr").exists());
    for k in 0..tiles {
        let p = out.join(format!("displacement.{}.exr", 1001 + k));
        assert!(p.is_file(), "{} missing", p.display());
        // Our own reader, and the tile's size: 8 tiles of pitch R + 8
        // rounded up to 8.
        let (w, h, texels) = subdfit::displace::read_exr(&p).unwrap();
        let pitch = (res + 8).div_ceil(8) * 8;
        assert_eq!((w, h), (8 * pitch, 8 * pitch));
        assert!(texels.iter().any(|t| t.abs() > 0.0));
        // Its vector twin: same size, R, G, B, half floats too.
        let pv = out.join(format!("displacement_vector.{}.exr", 1001 + k));
        let (vw, vh, ch) = subdfit::displace::read_exr_channels(&pv).unwrap();
        assert_eq!((vw, vh), (w, h));
        assert_eq!(
            ch.iter().map(|c| c.0.as_str()).collect::<Vec<_>>(),
            ["B", "G", "R"]
        );
        if let Some(text) = exrheader(&pv) {
            assert!(text.contains("R, 16-bit floating-point"), "{text}");
        }
        match exrheader(&p) {
            Some(text) => {
                assert!(
                    text.contains("Y, 16-bit floating-point"),
                    "{}: not half floats:\n{text}",
                    p.display()
                );
                let window = format!("(0 0) - ({} {})", w - 1, h - 1);
                assert!(text.contains(&window), "{text}");
            }
            None if has_python_module("OpenEXR") => {
                let script = "import OpenEXR,sys; f=OpenEXR.InputFile(sys.argv[1]); \
                              print(f.header()['channels']['Y'].type)";
                let o = Command::new("python3")
                    .args(["-c", script])
                    .arg(&p)
                    .output()
                    .unwrap();
                assert!(String::from_utf8_lossy(&o.stdout).contains("HALF"));
            }
            None => eprintln!("SKIPPED (OpenEXR part): neither exrheader nor OpenEXR (Python)"),
        }
    }
    assert!(!out
        .join(format!("displacement.{}.exr", 1001 + tiles))
        .exists());
    // UVs in UDIM space: the last patch's corners lie in its tile's square.
    let text = std::fs::read_to_string(out.join("control.obj")).unwrap();
    let vts = obj_uvs(&text);
    let last = &vts[vts.len() - 4..];
    let tile = (tiles - 1) as f64;
    assert!(
        last.iter()
            .all(|&(u, v)| u > tile && u < tile + 1.0 && v > 0.0 && v < 1.0),
        "{last:?}"
    );
    let usda = std::fs::read_to_string(out.join("control.usda")).unwrap();
    assert!(usda.contains("@./displacement.<UDIM>.exr@"));
    if has_python_module("pxr") {
        let v = validate(&out.join("control.usda"));
        assert_eq!(v["errors"], serde_json::json!([]));
        assert_eq!(v["texture_exists"], true);
    }
}

/// Interior vertices with two neighbours, of a control.obj.
/// The adaptive atlas (the default) in UDIM tiles: tiles of different
/// sizes shelf-packed, so only what does not depend on the packing is
/// asserted: each patch's UVs lie inside one tile's unit square, every
/// tile a patch uses exists (scalar and vector, half floats, same size,
/// not all zero), and no file is written for a tile no patch uses.
#[test]
fn adaptive_udim_tiles_hold_every_patch() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("spot");
    convert(
        &data("spot.ply"),
        &out,
        &["--atlas", "udim", "--half", "--tessellation", "4"],
    );
    let text = std::fs::read_to_string(out.join("control.obj")).unwrap();
    let vts = obj_uvs(&text);
    let mut used = std::collections::BTreeSet::new();
    for l in text.lines().filter_map(|l| l.strip_prefix("f ")) {
        let tiles: Vec<usize> = l
            .split_whitespace()
            .map(|c| {
                let vt: usize = c.split('/').nth(1).unwrap().parse().unwrap();
                let (u, v) = vts[vt - 1];
                assert!(
                    u > 0.0 && v > 0.0 && v < 1.0,
                    "UV ({u}, {v}) outside the tiles"
                );
                assert!(u.fract() > 0.0, "UV ({u}, {v}) on a tile's border");
                u.floor() as usize
            })
            .collect();
        assert!(
            tiles.iter().all(|&t| t == tiles[0]),
            "face `f {l}` spans tiles"
        );
        used.insert(tiles[0]);
    }
    let last = *used.iter().next_back().unwrap();
    assert_eq!(used.len(), last + 1, "tiles used: {used:?}");
    for k in 0..=last {
        let p = out.join(format!("displacement.{}.exr", 1001 + k));
        let (w, h, texels) = subdfit::displace::read_exr(&p).unwrap();
        assert!(
            texels.iter().any(|t| t.abs() > 0.0),
            "{} all zero",
            p.display()
        );
        let pv = out.join(format!("displacement_vector.{}.exr", 1001 + k));
        let (vw, vh, _) = subdfit::displace::read_exr_channels(&pv).unwrap();
        assert_eq!((vw, vh), (w, h));
    }
    assert!(!out
        .join(format!("displacement.{}.exr", 1002 + last))
        .exists());
    assert!(!out.join("displacement.exr").exists());
}

/// The `vt` lines of an OBJ text, in order.
fn obj_uvs(text: &str) -> Vec<(f64, f64)> {
    text.lines()
        .filter_map(|l| l.strip_prefix("vt "))
        .map(|l| {
            let mut it = l.split_whitespace().map(|x| x.parse::<f64>().unwrap());
            (it.next().unwrap(), it.next().unwrap())
        })
        .collect()
}

fn interior_valence_two(obj: &Path) -> Vec<u32> {
    let c = subdfit::io::read_control_mesh(obj).unwrap();
    c.vertices()
        .filter(|&v| !c.is_boundary_vertex(v) && c.valence(v) == 2)
        .map(|v| v.0)
        .collect()
}

#[test]
fn mechanical_fandisk_has_no_doublets_and_tessellation_follows_the_option() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("fandisk");
    convert(
        &data("fandisk.ply"),
        &out,
        &["--mode", "mechanical", "--tessellation", "3"],
    );
    assert_eq!(
        interior_valence_two(&out.join("control.obj")),
        Vec::<u32>::new()
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let written = report["control_written"]["faces"].as_u64().unwrap() as usize;
    let compact = report["control"]["faces"].as_u64().unwrap() as usize;
    assert!(written > compact, "the written mesh is the refined one");
    assert_eq!(report["tessellation"]["segments_per_patch_side"], 3);
    // 3 × 3 cells per patch, two triangles each.
    let limit = subdfit::io::read_mesh(&out.join("limit.ply")).unwrap().mesh;
    assert_eq!(limit.triangles.len(), 18 * written);
    // Welded and closed: every edge of displaced.ply in exactly two
    // triangles, creases included (one offset and one direction per
    // crease sample, module docs of `displace`).
    let d = subdfit::io::read_mesh(&out.join("displaced.ply"))
        .unwrap()
        .mesh;
    let mut edges: HashMap<(u32, u32), usize> = HashMap::new();
    for t in &d.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *edges.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let open: HashSet<_> = edges.iter().filter(|(_, &n)| n != 2).collect();
    assert!(
        open.is_empty(),
        "{} edges not shared by two triangles",
        open.len()
    );
}

#[test]
fn default_tessellation_meets_its_chord_error_rule() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("spot");
    convert(&data("spot.ply"), &out, &[]);
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let t = &r["tessellation"];
    eprintln!("spot tessellation: {t}");
    let rms_l = r["accuracy"]["limit"]["rms_permille"].as_f64().unwrap();
    let n = t["segments_per_patch_side"].as_u64().unwrap();
    assert!(n.is_power_of_two() && (16..=64).contains(&n));
    assert_eq!(t["given"], false);
    assert!(t["chord_error_rms_permille"].as_f64().unwrap() <= 0.1 * rms_l);
    assert!(t["chord_error_max_permille"].as_f64().unwrap() <= rms_l);
    assert_eq!(t["target_met"], true);
    let limit = subdfit::io::read_mesh(&out.join("limit.ply")).unwrap().mesh;
    let faces = r["control"]["faces"].as_u64().unwrap();
    assert_eq!(limit.triangles.len() as u64, 2 * n * n * faces);
}

#[test]
fn crease_samples_are_displaced_along_the_mean_of_the_patch_normals() {
    use subdfit::displace::{sample_directions, PatchGrid};
    use subdfit::subdiv::{make_evaluator, Backend, EvalOptions};
    // A refined cube with infinitely sharp chains along some original
    // edges: two patches with different normals meet at each.
    let control = subdfit::fixtures::creased_cube(1);
    let ev = make_evaluator(Backend::Osd, &control, &EvalOptions::default()).unwrap();
    let grid = PatchGrid::new(&control, 5).unwrap();
    let limit = ev.evaluate(control.positions(), grid.locations()).unwrap();
    let dirs = sample_directions(&control, ev.as_ref(), &grid, &limit).unwrap();
    let sharp: HashSet<(u32, u32)> = control
        .creases()
        .iter()
        .filter(|c| c.2 >= 10.0)
        .map(|c| (c.0 .0.min(c.1 .0), c.0 .0.max(c.1 .0)))
        .collect();
    assert!(!sharp.is_empty());
    let mut checked = 0;
    for f in 0..grid.num_patches() {
        let vs = grid.patch_vertices(f);
        if !sharp.contains(&(vs[0].min(vs[1]), vs[0].max(vs[1]))) {
            continue;
        }
        // The middle of side 0: the patch's own normal and the direction.
        let s = grid.sample(f, 2, 0) as usize;
        let own = ev
            .evaluate(
                control.positions(),
                &[subdfit::subdiv::SurfaceLocation::quad(
                    subdfit::mesh::FaceId(f as u32),
                    0.5,
                    0.0,
                )],
            )
            .unwrap()[0]
            .normal();
        let d = dirs[s];
        assert!((d.length() - 1.0).abs() < 1e-12);
        let between = own.dot(d);
        // Two patches meet there; the direction is their bisector: the
        // same angle to both, less than either normal's to the other.
        assert!(
            between < 1.0 - 1e-6,
            "patch {f}: direction is one patch's normal"
        );
        let other = (2.0 * between * d - own).normalize();
        assert!((other.dot(d) - between).abs() < 1e-9);
        checked += 1;
    }
    assert!(checked > 0);
}
