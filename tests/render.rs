//! The renderer: silhouettes of known size, identical pictures from both
//! ray casters, patch lines where the patch boundaries are, a perfect fit's
//! error map uniformly the zero colour, legends whose labels never overlap
//! and stay inside the picture (with `‰` its own glyph), and report.html
//! checked in a real headless browser.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;
use subdfit::mesh::TriMesh;
use subdfit::raycast::{make_raycaster, RayBackend};
use subdfit::render::colormap::{to_rgb8, CLAY, ZERO};
use subdfit::render::font::{glyph_index, has_glyph, rasterise};
use subdfit::render::image::decode_png;
use subdfit::render::report_html::{write_report_html, ReportHtmlOptions};
use subdfit::render::{
    error_field, render_frame, render_laid_out, render_panels, tessellate_limit, Camera, Frame,
    Panel, RenderOptions, Shading, Surface, View, What,
};
use subdfit::subdiv::Backend;
use subdfit::DVec3;

fn frame(surface: &Surface, backend: RayBackend, cam: &Camera) -> Frame {
    let caster = make_raycaster(backend, &surface.mesh).unwrap();
    render_frame(
        surface,
        caster.as_ref(),
        cam,
        &Shading::default(),
        &mut |_| true,
    )
    .unwrap()
}

fn fit_cam(view: View, mesh: &TriMesh, w: usize, h: usize) -> Camera {
    let (lo, hi) = mesh.bbox();
    Camera::fit(view, lo, hi, w, h)
}

/// A unit sphere seen orthographically has a round silhouette of radius
/// `r * scale` pixels. The icosphere (level 5, 20 480 faces) lies inside
/// the sphere by its sagitta, ≈ e²/8 with edge e ≈ 0.035: 1.5e-4, i.e.
/// 0.014 px at 90 px per unit — negligible. Pixel centres sample the
/// silhouette, so a measured boundary radius is quantised to the pixel grid:
/// along a ray from the centre, the last hit pixel centre lies within
/// √2/2 + 0.5 ≈ 1.2 px inside the true edge; ±1.5 px bounds that. The
/// area-equivalent radius averages the quantisation out: ±0.5 px.
#[test]
fn sphere_silhouette_has_the_expected_radius() {
    let r = 1.0;
    let mesh = icosphere(5, DVec3::new(0.3, -0.2, 0.1), r);
    let surface = Surface::plain(mesh.clone(), CLAY);
    for view in [View::Front, View::Side, View::Top, View::Iso] {
        let cam = fit_cam(view, &mesh, 200, 200);
        let f = frame(&surface, RayBackend::Embree, &cam);
        let expected = r * cam.scale;
        // Front view: the bbox is 2 r wide and fills 90 % of 200 px.
        if view == View::Front {
            assert!((expected - 90.0).abs() < 0.1, "{expected}");
        }
        let hits = f.hit.iter().filter(|&&h| h).count() as f64;
        let area_r = (hits / std::f64::consts::PI).sqrt();
        assert!(
            (area_r - expected).abs() < 0.5,
            "{view:?}: area radius {area_r} px, expected {expected}"
        );
        let (cx, cy, _) = cam.project(DVec3::new(0.3, -0.2, 0.1));
        for k in 0..72 {
            let a = k as f64 * std::f64::consts::TAU / 72.0;
            let (dx, dy) = (a.cos(), a.sin());
            let mut last = 0.0;
            let mut s = 0.0;
            while s < 1.3 * expected {
                let (x, y) = ((cx + s * dx).floor(), (cy + s * dy).floor());
                if x >= 0.0 && y >= 0.0 && (x as usize) < 200 && (y as usize) < 200 {
                    let (x, y) = (x as usize, y as usize);
                    if f.hit[y * 200 + x] {
                        last =
                            ((x as f64 + 0.5 - cx).powi(2) + (y as f64 + 0.5 - cy).powi(2)).sqrt();
                    }
                }
                s += 0.25;
            }
            assert!(
                (last - expected).abs() <= 1.5,
                "{view:?} angle {k}: silhouette at {last} px, expected {expected}"
            );
        }
    }
}

fn differing_pixels(a: &Frame, b: &Frame) -> usize {
    a.to_image([255; 3])
        .pixels
        .iter()
        .zip(&b.to_image([255; 3]).pixels)
        .filter(|(p, q)| (0..3).any(|k| p[k].abs_diff(q[k]) > 2))
        .count()
}

/// Embree (f32, robust mode) and the Rust BVH (f64) agree on first hits but
/// for rays grazing an edge; the pictures, AO and patch lines included,
/// must differ in fewer than 0.1 % of the pixels (a pixel differs when a
/// channel differs by more than 2 levels of 255).
#[test]
fn embree_and_rust_give_the_same_picture() {
    let spot = subdfit::io::read_mesh(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/data/spot.ply"
    )))
    .unwrap()
    .mesh;
    let tess = tessellate_limit(&subdfit::fixtures::cube(), 12, Backend::Osd).unwrap();
    let scenes = [
        ("spot", Surface::plain(spot, CLAY)),
        ("cube patches", tess.patches_surface()),
    ];
    for (name, surface) in scenes {
        let cam = fit_cam(View::Iso, &surface.mesh, 400, 300);
        let a = frame(&surface, RayBackend::Embree, &cam);
        let b = frame(&surface, RayBackend::Rust, &cam);
        let hits = a.hit.iter().filter(|&&h| h).count();
        assert!(hits > 10_000, "{name}: only {hits} pixels hit");
        let n = differing_pixels(&a, &b);
        let frac = n as f64 / (400.0 * 300.0);
        eprintln!(
            "{name}: {n} of 120000 pixels differ ({:.4} %)",
            100.0 * frac
        );
        assert!(frac < 1e-3, "{name}: {n} pixels differ");
    }
}

/// A flat 4 × 4 grid of unit quads seen from the front: with edge-and-corner
/// boundary rules the limit surface of a uniform planar grid is the plane
/// square parametrised linearly (B-splines reproduce linear functions and
/// the boundary rule's phantom points extend them linearly), so the patch
/// boundaries are the lines x = 0..4 exactly. A scanline at y = 1.5 crosses
/// 5 of them, at pixel x = 20 + 90 i (90 px per unit, 5 % margin).
#[test]
fn patch_lines_are_where_the_patch_boundaries_are() {
    let control = subdfit::fixtures::flat_grid(4, 4);
    let tess = tessellate_limit(&control, 9, Backend::Osd).unwrap();
    assert!(tess.extraordinary.is_empty());
    let surface = tess.patches_surface();
    let cam = fit_cam(View::Front, &surface.mesh, 400, 400);
    assert!((cam.scale - 90.0).abs() < 1e-6, "{}", cam.scale);
    let f = frame(&surface, RayBackend::Embree, &cam);
    let img = f.to_image([255; 3]);
    let (_, py, _) = cam.project(DVec3::new(2.0, 1.5, 0.0));
    let y = py.floor() as usize;
    // Dark runs along the scanline (line pixels are near black, the
    // surface is a light blue-grey, the background white).
    let dark: Vec<bool> = (0..400)
        .map(|x| {
            let c = img.get(x, y);
            (c[0] as u32 + c[1] as u32 + c[2] as u32) < 3 * 90
        })
        .collect();
    let mut runs = Vec::new();
    let mut x = 0;
    while x < 400 {
        if dark[x] {
            let s = x;
            while x < 400 && dark[x] {
                x += 1;
            }
            runs.push(0.5 * (s + x) as f64);
        } else {
            x += 1;
        }
    }
    assert_eq!(runs.len(), 5, "dark runs at {runs:?}");
    for (i, c) in runs.iter().enumerate() {
        let (ex, _, _) = cam.project(DVec3::new(i as f64, 1.5, 0.0));
        assert!((c - ex).abs() <= 1.5, "run {i} at {c}, boundary at {ex}");
    }
    // Between the lines the surface is not dark: the lines are thin.
    let dark_px = dark.iter().filter(|&&d| d).count();
    assert!(dark_px <= 5 * 3, "{dark_px} dark pixels: lines too wide");

    // The cube's 8 valence-3 vertices are marked: red dots appear.
    let cube = tessellate_limit(&subdfit::fixtures::cube(), 8, Backend::Osd).unwrap();
    assert_eq!(cube.extraordinary.len(), 8);
    let opts = RenderOptions::default()
        .with_view(View::Iso)
        .with_size(300, 300);
    let img = render_panels(
        &[Panel {
            surface: cube.patches_surface(),
            title: None,
            bar: None,
        }],
        &opts,
        &mut |_| true,
    )
    .unwrap();
    let red = img
        .pixels
        .iter()
        .filter(|c| c[0] > 180 && c[1] < 80 && c[2] < 80)
        .count();
    // 7 of the 8 corners face an iso view; each dot's saturated red core
    // (radius 3 px less the anti-aliased rim) covers ~13 px. At least 7
    // dots' worth of 8 px, at most 8 dots' worth of 30 px.
    assert!(red > 7 * 8 && red < 8 * 30, "{red} red pixels");
}

/// The input is the limit surface itself (its tessellation): every vertex
/// lies on the limit tessellation (distance 0 ‰) and φ reaches every
/// triangle, so every hit pixel has exactly the colour map's zero colour.
/// The same input scaled by 2 % is not a perfect fit and must show other
/// colours (the check can fail).
#[test]
fn perfect_fit_error_map_is_uniformly_zero() {
    let control = subdfit::fixtures::cube();
    let tess = tessellate_limit(&control, 9, Backend::Osd).unwrap();
    let limit = tess.mesh.clone();
    let field = error_field(&limit, &limit, Some(&control), RayBackend::Embree).unwrap();
    let max = field.permille.iter().cloned().fold(0.0, f64::max);
    assert!(max < 1e-9, "max distance {max} ‰");
    assert!(field.unprojectable.iter().all(|&u| !u));
    let surface = field.surface(&limit);
    let cam = fit_cam(View::Iso, &limit, 240, 180);
    let f = frame(&surface, RayBackend::Embree, &cam);
    let mut hits = 0;
    for (a, &h) in f.albedo.iter().zip(&f.hit) {
        if h {
            hits += 1;
            // The 8-bit colour: interpolating three equal colours with
            // barycentrics is exact only up to f32 rounding.
            assert_eq!(to_rgb8(*a), to_rgb8(ZERO));
        }
    }
    assert!(hits > 5000, "{hits}");

    let mut off = limit.clone();
    for p in &mut off.positions {
        *p *= 1.02;
    }
    let field = error_field(&off, &limit, Some(&control), RayBackend::Embree).unwrap();
    let f = frame(&field.surface(&off), RayBackend::Embree, &cam);
    let non_zero = f
        .albedo
        .iter()
        .zip(&f.hit)
        .filter(|(a, &h)| h && to_rgb8(**a) != to_rgb8(ZERO))
        .count();
    assert!(
        non_zero > hits / 2,
        "{non_zero} of {hits} pixels show an error"
    );
}

fn chromium() -> Option<PathBuf> {
    for name in ["chromium", "chromium-browser"] {
        if let Ok(out) = Command::new("which").arg(name).output() {
            if out.status.success() {
                let p = String::from_utf8_lossy(&out.stdout).trim().to_string();
                if !p.is_empty() {
                    return Some(PathBuf::from(p));
                }
            }
        }
    }
    None
}

/// report.html of a real conversion (the bundled spot) opens in headless
/// Chromium from disk with no console errors, every image decodes (the
/// page's own check sets the title to "ok N/N"), and a screenshot of it is
/// not blank.
#[test]
fn report_html_loads_in_headless_chromium() {
    let Some(chrome) = chromium() else {
        if std::env::var_os("SUBDFIT_REQUIRE_CHROMIUM").is_some() {
            panic!("chromium is not installed but SUBDFIT_REQUIRE_CHROMIUM is set (scripts/install-deps.sh installs it)");
        }
        eprintln!("SKIPPED: chromium is not installed (scripts/install-deps.sh installs it; set SUBDFIT_REQUIRE_CHROMIUM to make this a failure)");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mesh_path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/data/spot.ply"));
    let input = subdfit::io::read_mesh(&mesh_path).unwrap();
    let extra = subdfit::convert::HostRecord::convert(mesh_path.display().to_string());
    subdfit::convert::convert(
        &input,
        &subdfit::convert::ConvertOptions::default(),
        extra,
        &out,
        &mut |_, _| true,
    )
    .unwrap();
    let opts = ReportHtmlOptions::default();
    let html = write_report_html(&out, Some(&mesh_path), &opts, &mut |_| true).unwrap();
    let text = std::fs::read_to_string(&html).unwrap();
    assert_eq!(text.matches("<img ").count(), 5);
    assert!(
        !text.contains("http://") && !text.contains("https://"),
        "the page must not reach the network"
    );
    let url = format!("file://{}", html.display());
    let profile = dir.path().join("profile");
    let base = |cmd: &mut Command| {
        cmd.args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-extensions",
            "--enable-logging=stderr",
            "--v=0",
            "--virtual-time-budget=10000",
        ])
        .arg(format!("--user-data-dir={}", profile.display()));
    };
    let mut cmd = Command::new(&chrome);
    base(&mut cmd);
    let dom = cmd.arg("--dump-dom").arg(&url).output().unwrap();
    assert!(
        dom.status.success(),
        "chromium --dump-dom failed: {}",
        String::from_utf8_lossy(&dom.stderr)
    );
    let dom_text = String::from_utf8_lossy(&dom.stdout);
    let stderr = String::from_utf8_lossy(&dom.stderr);
    assert!(
        dom_text.contains("<title>ok 5/5</title>"),
        "images did not all decode: title in {}",
        dom_text
            .lines()
            .find(|l| l.contains("<title>"))
            .unwrap_or("(no title)")
    );
    for line in stderr.lines() {
        let l = line.to_ascii_lowercase();
        assert!(
            !(l.contains("console") && (l.contains("error") || l.contains("uncaught"))),
            "console error: {line}"
        );
    }
    let shot = dir.path().join("shot.png");
    let mut cmd = Command::new(&chrome);
    base(&mut cmd);
    let st = cmd
        .arg(format!("--screenshot={}", shot.display()))
        .arg("--window-size=1280,1600")
        .arg(&url)
        .output()
        .unwrap();
    assert!(
        st.status.success(),
        "screenshot failed: {}",
        String::from_utf8_lossy(&st.stderr)
    );
    let img = decode_png(&std::fs::read(&shot).unwrap()).unwrap();
    assert_eq!((img.width, img.height), (1280, 1600));
    let lum: Vec<f64> = img
        .pixels
        .iter()
        .map(|c| (c[0] as f64 + c[1] as f64 + c[2] as f64) / 3.0)
        .collect();
    let mean = lum.iter().sum::<f64>() / lum.len() as f64;
    let var = lum.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / lum.len() as f64;
    // A blank page is one colour (variance 0); pictures on white give
    // thousands of levels². 100 (a standard deviation of 10 levels) is far
    // from both.
    assert!(var > 100.0, "screenshot looks blank: variance {var}");
    // Shaded pictures: many distinct colours, not a page of text.
    let mut colours: Vec<[u8; 3]> = img.pixels.clone();
    colours.sort_unstable();
    colours.dedup();
    assert!(colours.len() > 1000, "{} colours", colours.len());
}

/// The bundled spot converted into `dir/out` (default options).
fn convert_spot(dir: &Path) -> PathBuf {
    let out = dir.join("out");
    let mesh_path = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/data/spot.ply"));
    let input = subdfit::io::read_mesh(&mesh_path).unwrap();
    let extra = subdfit::convert::HostRecord::convert(mesh_path.display().to_string());
    subdfit::convert::convert(
        &input,
        &subdfit::convert::ConvertOptions::default(),
        extra,
        &out,
        &mut |_, _| true,
    )
    .unwrap();
    out
}

/// Every picture kind of a real conversion (spot), at the default size and
/// at small and wide ones: the labels the renderer placed (from its
/// layout) never overlap, each lies inside the picture, uses only glyphs
/// the embedded font has, and was drawn (its box holds ink, anti-aliased:
/// grey levels between ink and paper). The error legend prints `‰` with a
/// glyph of its own: the font maps U+2030 to a glyph other than `%`'s, and
/// the two rasterise differently.
#[test]
fn legends_have_no_overlapping_labels_and_a_real_per_mille() {
    assert!(has_glyph('‰') && has_glyph('%'));
    assert_ne!(glyph_index('‰'), glyph_index('%'));
    let (pm, pc) = (rasterise("‰", 18.0), rasterise("%", 18.0));
    assert_ne!(pm, pc);
    // Per mille is the wider sign (a third zero).
    assert!(pm.ink() > 1.2 * pc.ink(), "{} vs {}", pm.ink(), pc.ink());

    let dir = tempfile::tempdir().unwrap();
    let out = convert_spot(dir.path());
    let kinds = [
        What::Input,
        What::Fitmap,
        What::Patches,
        What::Limit,
        What::Displaced,
        What::Error,
    ];
    let mut per_mille_drawn = false;
    for what in kinds {
        for (w, h) in [(1024, 768), (320, 240), (1600, 300)] {
            let opts = RenderOptions::default().with_what(what).with_size(w, h);
            let (img, lay) = render_laid_out(&out, &opts, &mut |_| true).unwrap();
            let labels = lay.labels();
            let name = format!("{} {w}x{h}", what.name());
            let expected = match what {
                What::Fitmap => 2 * 3,
                What::Error => 3,
                _ => 0,
            };
            // Panel and bar titles, swatch label, at least the low tick.
            assert!(labels.len() >= expected, "{name}: {labels:?}");
            for (i, a) in labels.iter().enumerate() {
                assert!(a.rect.inside(w, h), "{name}: {a:?} leaves the picture");
                for b in &labels[i + 1..] {
                    assert!(!a.rect.overlaps(&b.rect), "{name}: {a:?} overlaps {b:?}");
                }
                for c in a.text.chars() {
                    assert!(has_glyph(c), "{name}: no glyph for {c:?} in {:?}", a.text);
                }
                let r = a.rect;
                // Ink: darker than 110 (the text colour is 20, the paper 255;
                // a 9 px stem of the light face covers about half a pixel).
                let mut dark = 0;
                let mut grey = 0;
                for y in r.y..r.bottom() {
                    for x in r.x..r.right() {
                        let p = img.get(x as usize, y as usize);
                        let l = (p[0] as u32 + p[1] as u32 + p[2] as u32) / 3;
                        dark += (l < 110) as usize;
                        grey += (110..240).contains(&l) as usize;
                    }
                }
                assert!(dark > 0 && grey > 0, "{name}: {:?} not drawn", a.text);
                per_mille_drawn |= a.text.contains('‰');
            }
            if what == What::Error && w == 1024 {
                let bar = lay.panels[0].bar.as_ref().unwrap();
                let t = bar.title.as_ref().unwrap();
                assert!(t.text.contains('‰'), "{t:?}");
                assert!(bar.tick_labels.len() >= 3, "{:?}", bar.tick_labels);
            }
        }
    }
    assert!(per_mille_drawn);
}
