//! `report.html`: a conversion at a glance, in one self-contained file —
//! input | patches | displaced side by side, the error map, the Fitmap, and
//! `report.json`'s figures in the layout of Table 1 of the Fitmaps paper.
//! Pictures are PNGs embedded as `data:` URIs and the CSS is inline, so the
//! page opens from disk with no server and no network. One small inline
//! script (it fetches nothing) sets the page title to `ok N` once every one
//! of the N images has decoded, which the headless-browser test reads.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::report::WrittenReport;

use super::{panels, render_panels, Image, RenderOptions, Sources, View, What};
use crate::error::{Error, Result};
use crate::io::write_atomically;
use crate::raycast::{make_raycaster, RayBackend};

/// Options of [`write_report_html`].
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct ReportHtmlOptions {
    pub view: View,
    pub rays: RayBackend,
    /// Size of each of the three side-by-side pictures.
    pub thumb: (usize, usize),
    /// Size of the error map and of the (two-panel) Fitmap picture.
    pub wide: (usize, usize),
}

impl Default for ReportHtmlOptions {
    fn default() -> Self {
        ReportHtmlOptions {
            view: View::Auto,
            rays: RayBackend::Embree,
            thumb: (400, 340),
            wide: (1000, 560),
        }
    }
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn img_tag(img: &Image, alt: &str) -> Result<String> {
    Ok(format!(
        "<img alt=\"{}\" width=\"{}\" height=\"{}\" src=\"data:image/png;base64,{}\">",
        esc(alt),
        img.width,
        img.height,
        super::image::base64(&img.encode_png()?)
    ))
}

fn num(v: Option<f64>, digits: usize) -> String {
    v.map(|x| format!("{x:.digits$}"))
        .unwrap_or_else(|| "–".into())
}

/// Table 1 of the Fitmaps paper for this run: mesh (triangles), algorithm
/// (τ), patches □K, irregular vertices, unprojectable %, RMS error of the
/// limit L and displaced D surface in ‰ of the diagonal.
pub fn table1_html(report: &WrittenReport, mesh_name: &str) -> String {
    let tris = report.input.triangles.unwrap_or(0);
    let tris_k = if tris >= 1000 {
        format!("{}k", (tris as f64 / 1000.0).round())
    } else {
        tris.to_string()
    };
    let tau = report
        .options
        .pipeline
        .as_ref()
        .and_then(|p| p.fitmap.as_ref())
        .and_then(|f| f.tolerance)
        .map(|t| format!("τ = {}%", super::colormap::format_tick(100.0 * t)))
        .unwrap_or_else(|| "given K".into());
    let target = report.had_target_faces();
    let alg = if target { format!("{tau} *") } else { tau };
    let mut s = String::new();
    s += "<table class=\"t1\">\n<thead>\n<tr><th rowspan=\"2\">Mesh (Δ)</th><th rowspan=\"2\">Alg.</th>\
          <th rowspan=\"2\">□K</th><th rowspan=\"2\">Irreg. vert.</th><th rowspan=\"2\">Unp. (%)</th>\
          <th colspan=\"2\">RMS Error</th></tr>\n<tr><th>L</th><th>D</th></tr>\n</thead>\n<tbody>\n";
    let _ = writeln!(
        s,
        "<tr><td>{} ({})</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
        esc(mesh_name),
        tris_k,
        esc(&alg),
        report.control.faces.unwrap_or(0),
        report.control.irregular_vertices.unwrap_or(0),
        num(report.projectability.unprojectable_area_percent, 1),
        num(report.accuracy.limit.rms_permille, 2),
        num(report.accuracy.displaced.rms_permille, 2),
    );
    s += "</tbody>\n</table>\n<p class=\"cap\">As Table 1 of Fitmaps (Panozzo et al. 2011): \
          number of patches □K of the control mesh, irregular vertices, portion of the input \
          not reached correctly by normal projection from the limit surface, RMS error in \
          thousandths of the bounding-box diagonal of the limit (L) and displaced (D) surface.</p>\n";
    s
}

/// Writes `dir/report.html` for the output folder `dir` of `subdfit
/// convert` (or `fit`); `input` names the input mesh when it is not to be
/// read from `fitmap.ply` / `report.json`. Rendered completely in memory
/// and written atomically: on error nothing is written. Returns the path.
pub fn write_report_html(
    dir: &Path,
    input: Option<&Path>,
    opts: &ReportHtmlOptions,
    progress: &mut dyn FnMut(f64) -> bool,
) -> Result<PathBuf> {
    let report_path = dir.join("report.json");
    let report = WrittenReport::read(&report_path)?;
    let mut sources = Sources::new(dir, input)?;
    if !sources.is_dir {
        return Err(Error::option(
            "input",
            format!("{}: report.html needs an output folder", dir.display()),
        ));
    }
    let mesh_name = report
        .input_mesh()
        .and_then(|p| {
            Path::new(p)
                .file_stem()
                .and_then(|s| s.to_str())
                .map(String::from)
        })
        .unwrap_or_else(|| "input".into());
    // One view for every picture, chosen on the input, so they compare.
    let view = if opts.view == View::Auto {
        let mesh = sources.input()?;
        let caster = make_raycaster(opts.rays, mesh)?;
        super::pick_view(mesh, caster.as_ref())?
    } else {
        opts.view
    };
    let jobs = [
        (What::Input, opts.thumb, "input M"),
        (
            What::Patches,
            opts.thumb,
            "patches of the limit surface (red: extraordinary vertices)",
        ),
        (What::Displaced, opts.thumb, "displaced surface"),
        (What::Error, opts.wide, "error map"),
        (What::Fitmap, opts.wide, "Fitmap"),
    ];
    let mut tags = Vec::new();
    for (k, (what, (w, h), alt)) in jobs.iter().enumerate() {
        let ro = RenderOptions::default()
            .with_what(*what)
            .with_view(view)
            .with_size(*w, *h)
            .with_rays(opts.rays);
        let p = panels(&mut sources, &ro)?;
        let n = jobs.len() as f64;
        let img = render_panels(&p, &ro, &mut |f| progress((k as f64 + f) / n))?;
        tags.push(img_tag(&img, alt)?);
    }
    let mut html = String::new();
    let title = format!("subdfit report: {}", mesh_name);
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <title>{}</title>\n<style>\n{}</style>\n</head>\n<body>\n<h1>{}</h1>\n",
        esc(&title),
        CSS,
        esc(&title)
    );
    html += "<div class=\"row\">\n";
    for (tag, cap) in tags[..3].iter().zip(["input", "patches", "displaced"]) {
        let _ = writeln!(html, "<figure>{tag}<figcaption>{cap}</figcaption></figure>");
    }
    html += "</div>\n<h2>Table 1</h2>\n";
    html += &table1_html(&report, &mesh_name);
    let _ = writeln!(
        html,
        "<h2>Error of the input against the limit surface</h2>\n<figure>{}</figure>",
        tags[3]
    );
    let _ = writeln!(
        html,
        "<h2>Fitmap (Fig. 3 of Fitmaps)</h2>\n<figure>{}</figure>",
        tags[4]
    );
    let _ = write!(
        html,
        "<p class=\"cap\">view: {}; generated by subdfit {}</p>\n<script>\n{}</script>\n</body>\n</html>\n",
        view.name(),
        env!("CARGO_PKG_VERSION"),
        SCRIPT
    );
    let out = dir.join("report.html");
    write_atomically(&out, |w| {
        w.write_all(html.as_bytes()).map_err(|e| Error::io(&out, e))
    })?;
    Ok(out)
}

const CSS: &str = "body { font-family: sans-serif; margin: 1.5em; color: #222; background: #fff; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 1.5em; }
.row { display: flex; flex-wrap: wrap; gap: 1em; }
figure { margin: 0; } figcaption { text-align: center; color: #555; }
img { max-width: 100%; height: auto; border: 1px solid #ddd; }
table.t1 { border-collapse: collapse; margin: 0.5em 0; }
table.t1 th, table.t1 td { border-top: 1px solid #999; border-bottom: 1px solid #999; padding: 0.25em 0.8em; text-align: right; }
table.t1 td:first-child, table.t1 th:first-child { text-align: left; }
.cap { color: #555; font-size: 0.9em; max-width: 60em; }
";

/// Checks that every image decoded; fetches nothing.
const SCRIPT: &str = "window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length;
  document.title = (ok === imgs.length ? 'ok ' : 'broken ') + ok + '/' + imgs.length;
});
";
