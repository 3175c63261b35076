//! The outputs of `subdfit fit`: complete, consistent with each other,
//! watertight, deterministic, loadable by Pixar's USD, and all or nothing.

mod fit_support;

use std::collections::HashMap;
use std::path::Path;

use fit_support::*;
use subdfit::convert::{fit_and_write, PipelineOptions};
use subdfit::displace::{read_exr, read_exr_channels, Atlas, DEFAULT_GUTTER};
use subdfit::fit::FitOptions;
use subdfit::mesh::ValidatedMesh;
use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::report::{evaluate_surfaces, MetricsOptions, StageTimer, OUTPUT_NAMES};

fn input() -> ValidatedMesh {
    ValidatedMesh {
        mesh: bumpy_sphere(3),
        report: Default::default(),
    }
}

fn opts() -> PipelineOptions {
    PipelineOptions::default()
        .with_fit(FitOptions::default().with_max_iterations(3))
        .with_metrics(MetricsOptions::default().with_displacement_res(Some(5)))
        .with_fitmap(Some(subdfit::analysis::FitmapOptions::default()))
}

fn run(dir: &Path) -> subdfit::Result<subdfit::convert::Report> {
    let input = input();
    let control = initial_control(&input.mesh);
    let caster = make_raycaster(RayBackend::Embree, &input.mesh).unwrap();
    fit_and_write(
        &input,
        control,
        caster.as_ref(),
        &opts(),
        StageTimer::default(),
        subdfit::convert::FittedRun::Host(Default::default()),
        None,
        dir,
        &mut |_, _| true,
    )
    .map(|(r, _)| r)
}

/// Every undirected edge used by exactly two triangles, in opposite
/// directions.
fn assert_closed_manifold(name: &str, tris: &[[u32; 3]]) {
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for t in tris {
        for k in 0..3 {
            *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
        }
    }
    for (&(a, b), &n) in &directed {
        assert_eq!(n, 1, "{name}: directed edge ({a}, {b}) used {n} times");
        assert_eq!(
            directed.get(&(b, a)),
            Some(&1),
            "{name}: edge ({a}, {b}) is a border"
        );
    }
}

fn ply_triangles(path: &Path) -> Vec<[u32; 3]> {
    let soup = subdfit::io::read_soup(path).unwrap();
    soup.faces()
        .map(|f| {
            assert_eq!(f.len(), 3);
            [f[0], f[1], f[2]]
        })
        .collect()
}

#[test]
fn fit_writes_every_output_consistently() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("out");
    let report = run(&dir).unwrap();
    for name in OUTPUT_NAMES {
        assert!(dir.join(name).is_file(), "{name} missing");
    }
    // Only the outputs: no staging folder, no temporary files left.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), OUTPUT_NAMES.len());

    // Watertight limit and displaced surfaces on a closed input.
    assert_closed_manifold("limit.ply", &ply_triangles(&dir.join("limit.ply")));
    assert_closed_manifold("displaced.ply", &ply_triangles(&dir.join("displaced.ply")));

    // report.json holds what the library reported.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
    let l = json["accuracy"]["limit"]["rms_permille"].as_f64().unwrap();
    assert_eq!(l, report.accuracy.limit.rms_permille);
    assert!(json["control"]["valence_histogram"].is_object());
    assert!(json["control"]["irregular_convention"].is_string());
    assert!(json["stages"]
        .as_array()
        .unwrap()
        .iter()
        .any(|s| s["stage"] == "fit"));

    // control.obj reads back with the same topology, and carries one vt per
    // face corner.
    let control = subdfit::io::read_control_mesh(&dir.join("control.obj")).unwrap();
    assert_eq!(control.num_faces(), report.control.faces);
    let text = std::fs::read_to_string(dir.join("control.obj")).unwrap();
    assert_eq!(
        text.lines().filter(|l| l.starts_with("vt ")).count(),
        4 * control.num_faces()
    );
}

#[test]
fn displacement_atlas_round_trips_and_shared_edges_agree() {
    let input = input();
    let control = initial_control(&input.mesh);
    let caster = make_raycaster(RayBackend::Embree, &input.mesh).unwrap();
    let opts = MetricsOptions::default().with_displacement_res(Some(6));
    let s = evaluate_surfaces(
        &input.mesh,
        &control,
        caster.as_ref(),
        &opts,
        &mut |_, _| true,
    )
    .unwrap();
    let d = &s.displacement;
    let atlas = Atlas::new(d.grid.num_patches(), 6, DEFAULT_GUTTER).unwrap();
    let texels = atlas.bake(d).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("d.exr");
    std::fs::write(&path, atlas.encode_exr(&texels).unwrap()).unwrap();
    let (w, h, back) = read_exr(&path).unwrap();
    assert_eq!((w, h), (atlas.width, atlas.height));
    assert_eq!(back.len(), texels.len());
    assert!(
        back.iter()
            .zip(&texels)
            .all(|(a, b)| a.to_bits() == b.to_bits()),
        "EXR round trip changed texels"
    );
    // Real offsets, not an all-zero image.
    assert!(texels.iter().any(|&t| t.abs() > 1e-5));

    // Texel of grid point (i, j) of patch f, read back from the file
    // through the per-corner UV convention (v up, texel centres).
    let texel = |f: usize, i: usize, j: usize| -> f32 {
        let uv = atlas.uv(f, i, j);
        let x = (uv.x * w as f64 - 0.5).round() as usize;
        let y = ((1.0 - uv.y) * h as f64 - 0.5).round() as usize;
        back[y * w + x]
    };
    // For every edge shared by two patches, the border texels of both
    // tiles are the same numbers (bitwise), in opposite order.
    let r1 = 5;
    let border = |f: usize, side: usize| -> Vec<f32> {
        (0..=r1)
            .map(|k| match side {
                0 => texel(f, k, 0),
                1 => texel(f, r1, k),
                2 => texel(f, r1 - k, r1),
                _ => texel(f, 0, r1 - k),
            })
            .collect()
    };
    let mut edges: HashMap<(u32, u32), (usize, usize)> = HashMap::new();
    let mut checked = 0;
    for f in 0..d.grid.num_patches() {
        let v = d.grid.patch_vertices(f);
        for side in 0..4 {
            let (a, b) = (v[side], v[(side + 1) % 4]);
            if let Some(&(g, gside)) = edges.get(&(b, a)) {
                let mut other = border(g, gside);
                other.reverse();
                let mine = border(f, side);
                assert!(
                    mine.iter()
                        .zip(&other)
                        .all(|(x, y)| x.to_bits() == y.to_bits()),
                    "patch {f} side {side} vs patch {g} side {gside}: {mine:?} vs {other:?}"
                );
                checked += 1;
            }
            edges.insert((a, b), (f, side));
        }
    }
    assert_eq!(
        checked,
        control.num_edges(),
        "every edge of a closed mesh is shared"
    );
    // Gutters repeat the border: the texel just outside corner (0,0).
    let uv = atlas.uv(0, 0, 0);
    let (x, y) = (
        (uv.x * w as f64 - 0.5).round() as usize,
        ((1.0 - uv.y) * h as f64 - 0.5).round() as usize,
    );
    assert_eq!(
        back[(y - 1) * w + x - 1].to_bits(),
        back[y * w + x].to_bits()
    );

    // The vector map on the same layout: channels R, G, B, and at every
    // sample's texel the displacement vector offset · direction (to f32),
    // i.e. the scalar texel times the sample's unit direction.
    let vectors = atlas.bake_vector_images(d).unwrap();
    let vpath = tmp.path().join("v.exr");
    std::fs::write(
        &vpath,
        atlas
            .encode_vector_exr_as(&vectors[0], subdfit::displace::TexelType::Float)
            .unwrap(),
    )
    .unwrap();
    let (vw, vh, channels) = read_exr_channels(&vpath).unwrap();
    assert_eq!((vw, vh), (w, h));
    let names: Vec<&str> = channels.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["B", "G", "R"]);
    let (b, g, r) = (&channels[0].1, &channels[1].1, &channels[2].1);
    let mut worst = 0.0f64;
    for f in 0..d.grid.num_patches() {
        for j in 0..=r1 {
            for i in 0..=r1 {
                let uv = atlas.uv(f, i, j);
                let x = (uv.x * w as f64 - 0.5).round() as usize;
                let y = ((1.0 - uv.y) * h as f64 - 0.5).round() as usize;
                let k = y * w + x;
                let got = subdfit::DVec3::new(r[k] as f64, g[k] as f64, b[k] as f64);
                let s = d.grid.sample(f, i, j) as usize;
                let want = d.offsets[s] * d.directions[s];
                // f32 texels: relative round-off 2^-24 of each component.
                worst = worst.max((got - want).length() / want.length().max(1e-30));
                assert!(
                    (got.dot(d.directions[s]) - back[k] as f64).abs()
                        <= 1e-6 * d.offsets[s].abs().max(1e-12)
                );
            }
        }
    }
    assert!(worst <= 1e-6, "vector texels off by {worst:e} relative");
}

#[test]
fn outputs_are_deterministic() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    run(&a).unwrap();
    run(&b).unwrap();
    for name in OUTPUT_NAMES {
        let (x, y) = (
            std::fs::read(a.join(name)).unwrap(),
            std::fs::read(b.join(name)).unwrap(),
        );
        if name == "report.json" {
            // Timings and memory differ from run to run; everything else not.
            let strip = |bytes: &[u8]| {
                let mut v: serde_json::Value = serde_json::from_slice(bytes).unwrap();
                v["stages"] = serde_json::Value::Null;
                v["fit"]["seconds"] = serde_json::Value::Null;
                v
            };
            assert_eq!(strip(&x), strip(&y));
        } else {
            assert!(x == y, "{name} differs between two identical runs");
        }
    }
}

#[test]
fn a_failed_or_cancelled_run_leaves_no_partial_output() {
    let tmp = tempfile::tempdir().unwrap();
    // A folder where limit.ply should go: the write fails before any
    // output file is renamed into place.
    let dir = tmp.path().join("blocked");
    std::fs::create_dir_all(dir.join("limit.ply")).unwrap();
    assert!(run(&dir).is_err());
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["limit.ply"], "only the obstacle may remain");

    // Cancelled from the progress callback: a typed error, nothing created.
    let dir = tmp.path().join("cancelled");
    let input = input();
    let caster = make_raycaster(RayBackend::Embree, &input.mesh).unwrap();
    for stop_at in ["fit", "metrics", "write"] {
        let err = fit_and_write(
            &input,
            initial_control(&input.mesh),
            caster.as_ref(),
            &opts(),
            StageTimer::default(),
            subdfit::convert::FittedRun::Host(Default::default()),
            None,
            &dir,
            &mut |stage, _| stage != stop_at,
        )
        .unwrap_err();
        assert!(
            matches!(&err, subdfit::Error::Cancelled { stage } if stage == stop_at),
            "{err}"
        );
        assert!(
            !dir.exists(),
            "cancelled at {stop_at}: output folder created"
        );
    }
}

#[test]
fn control_usda_loads_in_pixar_usd() {
    let ok = std::process::Command::new("python3")
        .args(["-c", "import pxr"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !ok {
        eprintln!(
            "SKIPPED: Pixar's USD (python3 -c 'import pxr') is not available; pip install usd-core"
        );
        return;
    }
    // A control mesh with creases and corners, so the tags are exercised.
    let control = subdfit::fixtures::creased_cube(1);
    let creases = control.creases().len();
    let corners = control.corners().len();
    assert!(
        creases > 0 && corners > 0,
        "fixture without creases or corners"
    );
    let uvs: Vec<_> = (0..control.num_faces())
        .map(|f| Atlas::new(control.num_faces(), 4, 2).unwrap().corner_uvs(f))
        .collect();
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("control.usda");
    subdfit::io::write_usda(&path, &control, Some(&uvs)).unwrap();
    let script = format!(
        r#"
from pxr import Usd, UsdGeom
stage = Usd.Stage.Open({path:?})
assert stage.GetDefaultPrim().GetPath() == "/subdfit"
mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/subdfit/control"))
assert mesh, "no Mesh prim /subdfit/control"
assert mesh.GetSubdivisionSchemeAttr().Get() == "catmullClark"
assert mesh.GetInterpolateBoundaryAttr().Get() == "edgeAndCorner"
assert len(mesh.GetFaceVertexCountsAttr().Get()) == {faces}
assert len(mesh.GetPointsAttr().Get()) == {verts}
assert len(mesh.GetCreaseLengthsAttr().Get()) == {creases}
assert len(mesh.GetCreaseIndicesAttr().Get()) == 2 * {creases}
assert len(mesh.GetCornerIndicesAttr().Get()) == {corners}
st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
assert st and st.GetInterpolation() == "faceVarying", "st primvar"
assert st.GetTypeName() == "texCoord2f[]"
assert len(st.ComputeFlattened()) == 4 * {faces}
print("ok")
"#,
        path = path.display().to_string(),
        faces = control.num_faces(),
        verts = control.num_vertices(),
        creases = creases,
        corners = corners,
    );
    let out = std::process::Command::new("python3")
        .args(["-c", &script])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "USD rejected control.usda:\n{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn adaptive_atlas_reads_the_same_function_along_every_shared_edge() {
    // Per-patch resolutions (`--displacement-samples`): tiles of different
    // sizes. A host's bilinear lookup of the written image, through the
    // per-corner UVs, must give the same value along a shared edge from
    // both tiles (the finer tile's in-between texels interpolate the
    // coarser's), and `displaced.ply` must stay a closed manifold.
    let input = input();
    let control = initial_control(&input.mesh);
    let caster = make_raycaster(RayBackend::Embree, &input.mesh).unwrap();
    // Halfway between every patch at 5² and every patch at 9²: whatever
    // the errors, some tiles are finer than others.
    let at = |r: usize| {
        subdfit::displace::PatchGrid::new(&control, r)
            .unwrap()
            .num_independent()
    };
    let budget = (at(5) + at(9)) / 2;
    let opts = MetricsOptions::default().with_displacement_samples(Some(budget));
    let s = evaluate_surfaces(
        &input.mesh,
        &control,
        caster.as_ref(),
        &opts,
        &mut |_, _| true,
    )
    .unwrap();
    let d = &s.displacement;
    assert!(
        !d.grid.is_uniform(),
        "a budget between levels gives mixed tiles"
    );
    let st = d.stats.adaptive.as_ref().unwrap();
    assert!(st.samples <= budget && st.samples as f64 >= 0.95 * budget as f64);
    assert_closed_manifold("displaced (adaptive)", &s.displaced.triangles);
    let atlas = Atlas::for_grid(&d.grid, subdfit::displace::AtlasLayout::Single).unwrap();
    let img = atlas.bake(d).unwrap();
    let (w, h) = (atlas.width, atlas.height);
    // Bilinear filtering between texel centres at patch parameter (u, v).
    let lookup = |f: usize, u: f64, v: f64| -> f64 {
        let [c0, _, c2, _] = atlas.corner_uvs(f);
        let uv = c0 + (c2 - c0) * subdfit::DVec2::new(u, v);
        let (px, py) = (uv.x * w as f64 - 0.5, (1.0 - uv.y) * h as f64 - 0.5);
        let (x0, y0) = (px.floor(), py.floor());
        let (fx, fy) = (px - x0, py - y0);
        let t = |x: f64, y: f64| img[y as usize * w + x as usize] as f64;
        (t(x0, y0) * (1.0 - fx) + t(x0 + 1.0, y0) * fx) * (1.0 - fy)
            + (t(x0, y0 + 1.0) * (1.0 - fx) + t(x0 + 1.0, y0 + 1.0) * fx) * fy
    };
    let on_side = |side: usize, t: f64| match side {
        0 => (t, 0.0),
        1 => (1.0, t),
        2 => (1.0 - t, 1.0),
        _ => (0.0, 1.0 - t),
    };
    let scale = d.offsets.iter().fold(0.0f64, |m, o| m.max(o.abs()));
    let mut edges: HashMap<(u32, u32), (usize, usize)> = HashMap::new();
    let (mut checked, mut mixed) = (0, 0);
    for f in 0..d.grid.num_patches() {
        let v = d.grid.patch_vertices(f);
        for side in 0..4 {
            let (a, b) = (v[side], v[(side + 1) % 4]);
            if let Some(&(g, gside)) = edges.get(&(b, a)) {
                mixed += usize::from(d.grid.patch_res(f) != d.grid.patch_res(g));
                for k in 0..=64 {
                    let t = k as f64 / 64.0;
                    let (u, v) = on_side(side, t);
                    let (ug, vg) = on_side(gside, 1.0 - t);
                    let (x, y) = (lookup(f, u, v), lookup(g, ug, vg));
                    // f32 texels; the interpolation weights are exact.
                    assert!(
                        (x - y).abs() <= 1e-6 * scale,
                        "patch {f} side {side} / patch {g} side {gside} at {t}: {x} vs {y}"
                    );
                }
                checked += 1;
            }
            edges.insert((a, b), (f, side));
        }
    }
    assert_eq!(checked, control.num_edges());
    assert!(mixed > 0, "no edge between different resolutions");
}
