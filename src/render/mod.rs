//! Pictures of a conversion, rendered on the CPU by ray casting through the
//! crate's own [`RayCaster`]s (Embree or the Rust BVH give the same
//! picture): the input, its Fitmap (the two channels of Fitmaps Fig. 3),
//! the limit surface with its patch layout (Fig. 3, 8), the displaced
//! surface, and the error of the input against the limit surface (Fig. 6),
//! plus the self-contained `report.html` ([`report_html`]).
//!
//! Layers: [`camera`] (orthographic views fitted to the box), [`tracer`]
//! (primary rays, headlight + ambient occlusion, patch lines, markers),
//! [`scene`] (limit tessellation with patch coordinates, error field,
//! Fitmap colourings), [`input`] (mesh file or output folder),
//! [`colormap`] (colour maps, colour bars), [`layout`] (where titles,
//! bars and tick labels go, measured so that no two labels overlap),
//! [`font`] (anti-aliased text from an embedded font), [`image`] (RGB8,
//! PNG, base64).

pub mod camera;
pub mod colormap;
pub mod font;
pub mod image;
pub mod input;
pub mod layout;
pub mod report_html;
pub mod scene;
pub mod tracer;

use std::path::Path;

use serde::Serialize;

pub use camera::{Camera, View};
pub use colormap::ColourBar;
pub use image::{Image, Rgb};
pub use input::Sources;
pub use scene::{error_field, fitmap_surfaces, tessellate_limit, ErrorField, LimitTessellation};
pub use tracer::{render_frame, Frame, PatchUv, Shading, Surface};

use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::raycast::{make_raycaster, RayBackend, RayCaster};
use crate::subdiv::Backend;
use colormap::{draw_bar, BACKGROUND, CLAY, TEXT};
pub use layout::{layout_picture, Legend, PictureLayout};

/// What to picture.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub enum What {
    /// The input mesh M, shaded.
    Input,
    /// M coloured by F_S and F_M, two panels with colour bars.
    Fitmap,
    /// The limit surface with patch boundaries and extraordinary vertices.
    Patches,
    /// The limit surface, shaded.
    Limit,
    /// The displaced surface, shaded.
    Displaced,
    /// M coloured by its distance to the limit surface, unprojectable
    /// regions marked.
    Error,
}

impl What {
    pub fn name(self) -> &'static str {
        match self {
            What::Input => "input",
            What::Fitmap => "fitmap",
            What::Patches => "patches",
            What::Limit => "limit",
            What::Displaced => "displaced",
            What::Error => "error",
        }
    }
}

/// Options of [`render`].
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct RenderOptions {
    pub what: What,
    pub view: View,
    pub width: usize,
    pub height: usize,
    pub rays: RayBackend,
    pub shading: Shading,
    /// Triangles of the limit tessellation behind `patches` / `limit` of a
    /// mesh file (patches get `res × res` samples to match).
    pub tessellation_budget: usize,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            what: What::Input,
            view: View::Auto,
            width: 1024,
            height: 768,
            rays: RayBackend::Embree,
            shading: Shading::default(),
            tessellation_budget: 400_000,
        }
    }
}

impl RenderOptions {
    pub fn with_what(mut self, w: What) -> Self {
        self.what = w;
        self
    }
    pub fn with_view(mut self, v: View) -> Self {
        self.view = v;
        self
    }
    pub fn with_size(mut self, width: usize, height: usize) -> Self {
        self.width = width;
        self.height = height;
        self
    }
    pub fn with_rays(mut self, r: RayBackend) -> Self {
        self.rays = r;
        self
    }
    pub fn with_shading(mut self, s: Shading) -> Self {
        self.shading = s;
        self
    }
}

/// Largest picture side accepted (a typo like `10240x7680` should fail
/// rather than allocate gigabytes).
pub const MAX_SIDE: usize = 8192;

/// One panel of a picture: a surface and its colour bar.
pub struct Panel {
    pub surface: Surface,
    pub title: Option<String>,
    pub bar: Option<ColourBar>,
}

/// The panels of `what` from `sources`.
pub fn panels(sources: &mut Sources, opts: &RenderOptions) -> Result<Vec<Panel>> {
    let plain = |surface| Panel {
        surface,
        title: None,
        bar: None,
    };
    Ok(match opts.what {
        What::Input => vec![plain(Surface::plain(sources.input()?.clone(), CLAY))],
        What::Limit if sources.is_dir => {
            vec![plain(Surface::plain(
                sources.surface_file("limit.ply")?,
                CLAY,
            ))]
        }
        What::Limit | What::Patches => {
            let control = sources.control()?;
            let res = scene::auto_patch_res(control, opts.tessellation_budget);
            let tess = tessellate_limit(control, res, Backend::Osd)?;
            if opts.what == What::Limit {
                let mut s = tess.patches_surface();
                s.patch_uv = None;
                s.markers.clear();
                s.base = CLAY;
                vec![plain(s)]
            } else {
                vec![plain(tess.patches_surface())]
            }
        }
        What::Displaced => vec![plain(Surface::plain(
            sources.surface_file("displaced.ply")?,
            CLAY,
        ))],
        What::Error => {
            let limit = sources.surface_file("limit.ply")?;
            let control = sources.control()?.clone();
            let input = sources.input()?;
            let field = error_field(input, &limit, Some(&control), opts.rays)?;
            vec![Panel {
                surface: field.surface(input),
                title: None,
                bar: Some(field.bar()),
            }]
        }
        What::Fitmap => {
            let (mesh, (s, m)) = sources.fitmap(opts.rays)?;
            let [(ss, sb), (ms, mb)] = fitmap_surfaces(mesh, s, m)?;
            vec![
                Panel {
                    surface: ss,
                    title: Some("F_S".into()),
                    bar: Some(sb),
                },
                Panel {
                    surface: ms,
                    title: Some("F_M".into()),
                    bar: Some(mb),
                },
            ]
        }
    })
}

/// The fixed view showing the most visible surface area of `mesh`,
/// measured on a 128 × 96 pre-render ([`tracer::visible_area`]); ties go to
/// the earlier of [`View::FIXED`].
pub fn pick_view(mesh: &TriMesh, caster: &dyn RayCaster) -> Result<View> {
    let (lo, hi) = mesh.bbox();
    let mut best = (View::Iso, f64::NEG_INFINITY);
    for v in View::FIXED {
        let cam = Camera::fit(v, lo, hi, 128, 96);
        let a = tracer::visible_area(mesh, caster, &cam)?;
        if a > best.1 * (1.0 + 1e-9) {
            best = (v, a);
        }
    }
    Ok(best.0)
}

/// Text scale of labels for a picture of this size (2 at 1024 × 768).
pub fn text_scale(width: usize, height: usize) -> usize {
    // By area, so that wide multi-panel pictures get readable labels too.
    ((width * height) as f64 / (512.0 * 384.0))
        .sqrt()
        .round()
        .max(1.0) as usize
}

fn check_size(width: usize, height: usize) -> Result<()> {
    if width < 16 || height < 16 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(Error::option(
            "size",
            format!("render: picture size {width}x{height} outside 16..={MAX_SIDE} per side"),
        ));
    }
    Ok(())
}

/// Renders `panels` side by side into one `width × height` picture, each
/// with its title above and colour bar below; all panels share the view
/// (resolved on the first panel when [`View::Auto`]) and the framing of
/// the first panel's box, so they line up.
pub fn render_panels(
    panels: &[Panel],
    opts: &RenderOptions,
    progress: &mut dyn FnMut(f64) -> bool,
) -> Result<Image> {
    Ok(render_panels_laid_out(panels, opts, progress)?.0)
}

/// [`render_panels`], and the layout it drew: every label's rectangle
/// ([`PictureLayout::labels`]).
pub fn render_panels_laid_out(
    panels: &[Panel],
    opts: &RenderOptions,
    progress: &mut dyn FnMut(f64) -> bool,
) -> Result<(Image, PictureLayout)> {
    check_size(opts.width, opts.height)?;
    if panels.is_empty() {
        return Err(Error::option("what", "render: nothing to render"));
    }
    let legends: Vec<Legend> = panels
        .iter()
        .map(|p| Legend {
            title: p.title.as_deref(),
            bar: p.bar.as_ref(),
        })
        .collect();
    let lay = layout_picture(&legends, opts.width, opts.height);
    let mut img = Image::new(opts.width, opts.height, BACKGROUND);
    let n = panels.len();
    let mut view = opts.view;
    let (lo, hi) = panels[0].surface.mesh.bbox();
    for (k, (panel, pl)) in panels.iter().zip(&lay.panels).enumerate() {
        let caster = make_raycaster(opts.rays, &panel.surface.mesh)?;
        if view == View::Auto {
            view = pick_view(&panel.surface.mesh, caster.as_ref())?;
        }
        let cam = Camera::fit(view, lo, hi, pl.w, pl.h);
        let frame = render_frame(
            &panel.surface,
            caster.as_ref(),
            &cam,
            &opts.shading,
            &mut |f| progress((k as f64 + f) / n as f64),
        )?;
        let mut pic = frame.to_image(BACKGROUND);
        tracer::draw_markers(
            &mut pic,
            &panel.surface,
            caster.as_ref(),
            &cam,
            &opts.shading,
        )?;
        img.blit(&pic, pl.x, pl.top);
        if let Some(t) = &pl.title {
            t.draw(&mut img, TEXT);
        }
        if let (Some(bar), Some(bl)) = (&panel.bar, &pl.bar) {
            draw_bar(&mut img, bar, bl);
        }
    }
    Ok((img, lay))
}

/// Renders the picture `opts.what` of `input` (a mesh file or an output
/// folder). `progress(fraction)` is called as rows complete; `false`
/// cancels.
pub fn render(
    input: &Path,
    opts: &RenderOptions,
    progress: &mut dyn FnMut(f64) -> bool,
) -> Result<Image> {
    Ok(render_laid_out(input, opts, progress)?.0)
}

/// [`render`], and the layout it drew ([`render_panels_laid_out`]).
pub fn render_laid_out(
    input: &Path,
    opts: &RenderOptions,
    progress: &mut dyn FnMut(f64) -> bool,
) -> Result<(Image, PictureLayout)> {
    check_size(opts.width, opts.height)?;
    let mut sources = Sources::new(input, None)?;
    let panels = panels(&mut sources, opts)?;
    render_panels_laid_out(&panels, opts, progress)
}

/// Parses `WxH` (e.g. `1024x768`).
pub fn parse_size(s: &str) -> Result<(usize, usize)> {
    let bad = || {
        Error::option(
            "size",
            format!("size '{s}': expected WIDTHxHEIGHT, e.g. 1024x768"),
        )
    };
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let w: usize = w.trim().parse().map_err(|_| bad())?;
    let h: usize = h.trim().parse().map_err(|_| bad())?;
    check_size(w, h)?;
    Ok((w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes() {
        assert_eq!(parse_size("1024x768").unwrap(), (1024, 768));
        assert!(parse_size("1024").is_err());
        assert!(parse_size("0x10").is_err());
        assert!(parse_size("100000x10").is_err());
        assert_eq!(text_scale(1024, 768), 2);
        assert_eq!(text_scale(300, 200), 1);
        assert_eq!(text_scale(1200, 560), 2);
    }
}
