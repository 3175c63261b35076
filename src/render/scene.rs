//! Building the surfaces to render: the limit tessellation with patch
//! coordinates, the error field of the input against the limit surface and
//! the Fitmap colourings.

use rayon::prelude::*;

use super::colormap::{ColourBar, Scale, PATCH_SURFACE, UNPROJECTABLE};
use super::tracer::{PatchUv, Surface, SIDE_U0, SIDE_U1, SIDE_V0, SIDE_V1};
use crate::error::{Error, Result};
use crate::mesh::{ControlMesh, FaceId, TriMesh};
use crate::project::{default_max_dist, project_along_normals};
use crate::raycast::{make_raycaster, RayBackend};
use crate::subdiv::{make_evaluator, Backend, EvalOptions, SurfaceLocation};
use crate::DVec3;

/// A tessellation of the limit surface that remembers, per triangle, the
/// patch it lies on and its patch coordinates.
#[derive(Clone, Debug)]
pub struct LimitTessellation {
    /// Every patch's own `res × res` grid (not welded: border samples are
    /// evaluated once per patch; they agree to rounding).
    pub mesh: TriMesh,
    /// Exact limit normals at the vertices.
    pub normals: Vec<DVec3>,
    pub patch_uv: Vec<PatchUv>,
    /// Per triangle, its patch `(face, sub)`.
    pub patch: Vec<(FaceId, u16)>,
    /// Limit positions of the extraordinary control vertices (see
    /// [`extraordinary_vertices`]).
    pub extraordinary: Vec<DVec3>,
}

impl LimitTessellation {
    /// The exact location of barycentric point `(bu, bv)` of triangle `t`.
    pub fn location(&self, t: usize, bu: f64, bv: f64) -> SurfaceLocation {
        let p = &self.patch_uv[t];
        let w = [1.0 - bu - bv, bu, bv];
        let (mut u, mut v) = (0.0, 0.0);
        for (wk, c) in w.iter().zip(&p.uv) {
            u += wk * c[0] as f64;
            v += wk * c[1] as f64;
        }
        let (face, sub) = self.patch[t];
        SurfaceLocation {
            face,
            sub,
            u: u.clamp(0.0, 1.0),
            v: v.clamp(0.0, 1.0),
        }
    }

    /// The surface to render for `--what patches`.
    pub fn patches_surface(&self) -> Surface {
        Surface {
            mesh: self.mesh.clone(),
            normals: self.normals.clone(),
            base: PATCH_SURFACE,
            vertex_colours: None,
            triangle_colours: None,
            patch_uv: Some(self.patch_uv.clone()),
            markers: self.extraordinary.clone(),
        }
    }
}

/// Extraordinary vertices, with the convention of `report.json`
/// ([`crate::report::IRREGULAR_CONVENTION`]): interior vertices of valence
/// other than 4, boundary vertices with other than 1 or 2 faces.
pub fn extraordinary_vertices(control: &ControlMesh) -> Vec<usize> {
    control
        .vertices()
        .filter(|&v| {
            if control.is_boundary_vertex(v) {
                let f = control.vertex_faces(v).count();
                f != 1 && f != 2
            } else {
                control.valence(v) != 4
            }
        })
        .map(|v| v.idx())
        .collect()
}

/// A per-patch resolution giving about `budget` triangles in all, within
/// `[4, 32]` samples per side.
pub fn auto_patch_res(control: &ControlMesh, budget: usize) -> usize {
    let patches = control.num_patches();
    let r = (budget as f64 / (2.0 * patches.max(1) as f64)).sqrt() as usize + 1;
    r.clamp(4, 32)
}

/// Tessellates the limit surface of `control`: `res × res` samples per
/// patch (a non-quad face has one patch per corner, OpenSubdiv's ptex
/// faces, [`crate::subdiv`] conventions). Patch boundaries drawn: all four
/// sides of a quad's patch; on a non-quad face only the sides `u = 0` and
/// `v = 0` of each sub-patch, which run along the control edges at its
/// corner (the others are interior to the face).
pub fn tessellate_limit(
    control: &ControlMesh,
    res: usize,
    backend: Backend,
) -> Result<LimitTessellation> {
    if !(2..=256).contains(&res) {
        return Err(Error::option(
            "tessellation",
            format!("limit tessellation: {res} samples per patch side, expected 2..=256"),
        ));
    }
    let eval = make_evaluator(backend, control, &EvalOptions::default())?;
    let mut patches = Vec::new();
    for f in control.faces() {
        let n = control.face_size(f);
        let (subs, sides) = if n == 4 {
            (1, SIDE_U0 | SIDE_U1 | SIDE_V0 | SIDE_V1)
        } else {
            (n, SIDE_U0 | SIDE_V0)
        };
        for s in 0..subs {
            patches.push((f, s as u16, sides));
        }
    }
    let step = 1.0 / (res - 1) as f64;
    let mut locations = Vec::with_capacity(patches.len() * res * res);
    for &(face, sub, _) in &patches {
        for j in 0..res {
            for i in 0..res {
                locations.push(SurfaceLocation {
                    face,
                    sub,
                    u: i as f64 * step,
                    v: j as f64 * step,
                });
            }
        }
    }
    let pts = eval.evaluate(control.positions(), &locations)?;
    let cells = (res - 1) * (res - 1);
    let mut triangles = Vec::with_capacity(2 * cells * patches.len());
    let mut patch_uv = Vec::with_capacity(2 * cells * patches.len());
    let mut patch = Vec::with_capacity(2 * cells * patches.len());
    for (k, &(face, sub, sides)) in patches.iter().enumerate() {
        let base = (k * res * res) as u32;
        let id = |i: usize, j: usize| base + (j * res + i) as u32;
        let uv = |i: usize, j: usize| [(i as f64 * step) as f32, (j as f64 * step) as f32];
        for j in 0..res - 1 {
            for i in 0..res - 1 {
                // Counter-clockwise in (u, v): the normal is du × dv.
                for tri in [
                    [(i, j), (i + 1, j), (i + 1, j + 1)],
                    [(i, j), (i + 1, j + 1), (i, j + 1)],
                ] {
                    triangles.push(tri.map(|(a, b)| id(a, b)));
                    patch_uv.push(PatchUv {
                        uv: tri.map(|(a, b)| uv(a, b)),
                        sides,
                    });
                    patch.push((face, sub));
                }
            }
        }
    }
    let limits = eval.vertex_limits(control.positions())?;
    let extraordinary = extraordinary_vertices(control)
        .into_iter()
        .map(|v| limits[v].position)
        .collect();
    Ok(LimitTessellation {
        normals: pts.iter().map(|p| p.normal()).collect(),
        mesh: TriMesh {
            positions: pts.iter().map(|p| p.position).collect(),
            triangles,
        },
        patch_uv,
        patch,
        extraordinary,
    })
}

/// "Nice" upper bound for a colour bar: the smallest of 1, 2, 2.5, 5 × 10^k
/// not below `x`; `fallback` when `x` is not a positive number.
pub fn nice_ceil(x: f64, fallback: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return fallback;
    }
    let e = 10f64.powf(x.log10().floor());
    for m in [1.0, 2.0, 2.5, 5.0, 10.0] {
        if m * e >= x * (1.0 - 1e-12) {
            return m * e;
        }
    }
    10.0 * e
}

/// The `q`-quantile (0..=1) of the finite values of `x`.
pub fn quantile(x: &[f64], q: f64) -> Option<f64> {
    let mut v: Vec<f64> = x.iter().copied().filter(|a| a.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let i = ((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    Some(v[i])
}

/// The error of an input against a limit surface.
#[derive(Clone, Debug)]
pub struct ErrorField {
    /// Per input vertex, its distance to the limit tessellation in ‰ of the
    /// input's bounding-box diagonal (the "M → S" distance of the metrics,
    /// [`crate::report`]).
    pub permille: Vec<f64>,
    /// Per input triangle, whether normal projection φ from the limit
    /// surface fails to reach it (`report.json`'s "Unp." test, applied at
    /// the triangle's centroid); all `false` without a control mesh.
    pub unprojectable: Vec<bool>,
    /// Upper end of the colour bar (‰): the 99th percentile rounded up to a
    /// nice number (1 ‰ when every distance is 0).
    pub bar_max: f64,
}

/// Distances of `input`'s vertices to `limit` (a tessellation of the limit
/// surface) and, when `control` is given, the projectability of `input`'s
/// triangles exactly as `report.json` measures it: the centroid's closest
/// point on the limit tessellation is located on its patch, evaluated
/// exactly, and φ is cast along the exact limit normal; the centroid is
/// reached when φ lands within one mean edge length of it.
pub fn error_field(
    input: &TriMesh,
    limit: &TriMesh,
    control: Option<&ControlMesh>,
    rays: RayBackend,
) -> Result<ErrorField> {
    let diag = input.bbox_diagonal();
    if input.triangles.is_empty() || !(diag.is_finite() && diag > 0.0) {
        return Err(Error::invalid_data(
            "input mesh",
            "mesh",
            "is empty or has a degenerate bounding box; the error map needs a surface",
        ));
    }
    let limit_caster = make_raycaster(rays, limit)?;
    let closest = limit_caster.closest_points(&input.positions, f64::INFINITY)?;
    let k = 1000.0 / diag;
    let permille: Vec<f64> = closest
        .iter()
        .map(|c| c.map_or(f64::NAN, |c| k * c.distance))
        .collect();
    let mut unprojectable = vec![false; input.triangles.len()];
    if let Some(control) = control {
        let tess = tessellate_limit(control, auto_patch_res(control, 200_000), Backend::Osd)?;
        let tess_caster = make_raycaster(rays, &tess.mesh)?;
        let centroids = input.centroids();
        let locations =
            crate::report::nearest_limit_locations(tess_caster.as_ref(), &centroids, |t, u, v| {
                tess.location(t, u, v)
            })?;
        let eval = make_evaluator(Backend::Osd, control, &EvalOptions::default())?;
        let exact = eval.evaluate(control.positions(), &locations)?;
        let input_caster = make_raycaster(rays, input)?;
        let (hits, _) =
            project_along_normals(input_caster.as_ref(), &exact, default_max_dist(input))?;
        let tol = input.mean_edge_length();
        unprojectable = hits
            .par_iter()
            .zip(&centroids)
            .map(|(h, c)| !matches!(h, Some(h) if (h.point - *c).length() <= tol))
            .collect();
    }
    let bar_max = nice_ceil(quantile(&permille, 0.99).unwrap_or(0.0), 1.0);
    Ok(ErrorField {
        permille,
        unprojectable,
        bar_max,
    })
}

impl ErrorField {
    pub fn bar(&self) -> ColourBar {
        ColourBar {
            title: "distance to limit surface, ‰ of diagonal".into(),
            lo: 0.0,
            hi: self.bar_max,
            scale: Scale::Linear,
            swatch: Some(("unprojectable".into(), UNPROJECTABLE)),
        }
    }

    /// `input` coloured by this field.
    pub fn surface(&self, input: &TriMesh) -> Surface {
        let bar = self.bar();
        let mut s = Surface::plain(input.clone(), bar.colour(0.0));
        s.vertex_colours = Some(self.permille.iter().map(|&d| bar.colour(d)).collect());
        if self.unprojectable.iter().any(|&u| u) {
            s.triangle_colours = Some(
                self.unprojectable
                    .iter()
                    .map(|&u| u.then_some(UNPROJECTABLE))
                    .collect(),
            );
        }
        s
    }
}

/// The two channels of the Fitmap as colourings of M, in the units of the
/// Fitmaps paper's Fig. 3, where d is 1 % of the bounding-box diagonal:
/// the S-fitmap shows the coefficient `a` of the RMS model `E(r) = a r⁴`
/// (`a = F_S⁴`) in units of `1/d³` (so that `E/d = a (r/d)⁴`), on a log
/// scale (it spans orders of magnitude between flat and detailed parts);
/// the M-fitmap shows the patch size limit F_M in units of d, linear.
pub fn fitmap_surfaces(mesh: &TriMesh, s: &[f64], m: &[f64]) -> Result<[(Surface, ColourBar); 2]> {
    let n = mesh.positions.len();
    if s.len() != n || m.len() != n {
        return Err(Error::InvalidArgument(format!(
            "fitmap: {} / {} values for {n} vertices",
            s.len(),
            m.len()
        )));
    }
    let d = mesh.bbox_diagonal() / 100.0;
    if !(d.is_finite() && d > 0.0) {
        return Err(Error::invalid_data(
            "input mesh",
            "mesh",
            "has a degenerate bounding box; the Fitmap picture needs a surface",
        ));
    }
    let a: Vec<f64> = s.iter().map(|&x| x.powi(4) * d.powi(3)).collect();
    let pos: Vec<f64> = a.iter().copied().filter(|&x| x > 0.0).collect();
    let lo = quantile(&pos, 0.02).unwrap_or(1e-3);
    let hi = quantile(&pos, 0.98).unwrap_or(1.0).max(lo * 10.0);
    // Round the log range outwards to 1-2-5 values for readable ticks.
    let lo = 10f64.powf(lo.log10().floor());
    let hi = nice_ceil(hi, 1.0);
    let s_bar = ColourBar {
        title: "S-fitmap a, 1/d³ (d = 1% of diagonal)".into(),
        lo,
        hi,
        scale: Scale::Log,
        swatch: None,
    };
    let md: Vec<f64> = m.iter().map(|&x| x / d).collect();
    let m_bar = ColourBar {
        title: "M-fitmap F_M, d".into(),
        lo: 0.0,
        hi: nice_ceil(md.iter().copied().fold(0.0, f64::max), 25.0),
        scale: Scale::Linear,
        swatch: None,
    };
    let colour = |bar: &ColourBar, v: &[f64]| {
        let mut surf = Surface::plain(mesh.clone(), bar.colour(0.0));
        surf.vertex_colours = Some(v.iter().map(|&x| bar.colour(x)).collect());
        surf
    };
    Ok([
        (colour(&s_bar, &a), s_bar.clone()),
        (colour(&m_bar, &md), m_bar),
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_numbers() {
        assert_eq!(nice_ceil(0.0, 1.0), 1.0);
        assert_eq!(nice_ceil(3.2, 1.0), 5.0);
        assert_eq!(nice_ceil(2.0, 1.0), 2.0);
        assert!((nice_ceil(0.021, 1.0) - 0.025).abs() < 1e-15);
        assert_eq!(nice_ceil(7.0, 1.0), 10.0);
    }

    #[test]
    fn tessellation_of_the_cube_has_patch_coordinates() {
        let cube = crate::fixtures::cube();
        let t = tessellate_limit(&cube, 5, Backend::Rust).unwrap();
        assert_eq!(t.mesh.triangles.len(), 6 * 16 * 2);
        // The cube's 8 vertices have valence 3: all extraordinary.
        assert_eq!(t.extraordinary.len(), 8);
        let l = t.location(0, 0.0, 0.0);
        assert_eq!((l.u, l.v), (0.0, 0.0));
    }
}
