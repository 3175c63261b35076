//! The ray-cast renderer: one primary ray per pixel through a
//! [`RayCaster`], a headlight plus ambient occlusion for shape, optional
//! per-vertex / per-triangle colours, anti-aliased patch-boundary lines and
//! point markers.
//!
//! Determinism: the image is processed in bands of rows; each band's rays
//! are cast as one batch (the casters return hits in input order whatever
//! the thread count) and shaded in parallel per pixel with rayon, every
//! pixel depending only on its own hits. The ambient-occlusion directions
//! of a pixel come from a hash of its coordinates (no shared generator), so
//! the picture is the same bit for bit on any number of threads.

use rayon::prelude::*;

use super::camera::Camera;
use super::colormap::{to_rgb8, LINE, MARKER};
use super::image::{Image, Rgb};
use crate::error::{Error, Result};
use crate::mesh::TriMesh;
use crate::raycast::{Hit, Ray, RayCaster};
use crate::DVec3;

/// Where a triangle of a limit-surface tessellation lies in its patch: the
/// patch coordinates of its three corners and which patch sides are control
/// mesh edges, so a hit knows how far it is from a patch boundary.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PatchUv {
    /// `(u, v)` at the triangle's corners.
    pub uv: [[f32; 2]; 3],
    /// Bit mask of the sides drawn as lines: [`SIDE_U0`] … [`SIDE_V1`].
    pub sides: u8,
}

pub const SIDE_U0: u8 = 1;
pub const SIDE_U1: u8 = 2;
pub const SIDE_V0: u8 = 4;
pub const SIDE_V1: u8 = 8;

/// A triangle mesh ready to render: geometry, shading normals and colours.
#[derive(Clone, Debug)]
pub struct Surface {
    pub mesh: TriMesh,
    /// Per-vertex shading normals (any orientation; zero where undefined,
    /// the flat normal is used there).
    pub normals: Vec<DVec3>,
    /// Colour where neither of the next two says otherwise.
    pub base: [f32; 3],
    /// Per-vertex colours, interpolated over the triangles.
    pub vertex_colours: Option<Vec<[f32; 3]>>,
    /// Per-triangle colours overriding the others where `Some`.
    pub triangle_colours: Option<Vec<Option<[f32; 3]>>>,
    /// Per-triangle patch coordinates: patch boundaries are drawn.
    pub patch_uv: Option<Vec<PatchUv>>,
    /// Points marked with a dot where visible (extraordinary vertices).
    pub markers: Vec<DVec3>,
}

impl Surface {
    /// A plain surface of colour `base` with area-weighted vertex normals.
    pub fn plain(mesh: TriMesh, base: [f32; 3]) -> Surface {
        let normals = crate::analysis::normals::vertex_normals(&mesh);
        Surface {
            mesh,
            normals,
            base,
            vertex_colours: None,
            triangle_colours: None,
            patch_uv: None,
            markers: Vec::new(),
        }
    }

    /// Checks the per-vertex and per-triangle arrays against the mesh.
    pub fn check(&self) -> Result<()> {
        let (nv, nt) = (self.mesh.positions.len(), self.mesh.triangles.len());
        let bad = |what: &str, got: usize, want: usize| {
            Err(Error::InvalidArgument(format!(
                "render: {got} {what} for a mesh with {want}"
            )))
        };
        if self.normals.len() != nv {
            return bad("normals", self.normals.len(), nv);
        }
        if let Some(c) = &self.vertex_colours {
            if c.len() != nv {
                return bad("vertex colours", c.len(), nv);
            }
        }
        if let Some(c) = &self.triangle_colours {
            if c.len() != nt {
                return bad("triangle colours", c.len(), nt);
            }
        }
        if let Some(p) = &self.patch_uv {
            if p.len() != nt {
                return bad("patch coordinates", p.len(), nt);
            }
        }
        Ok(())
    }
}

/// Shading parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Shading {
    /// Ambient-occlusion rays per hit pixel (0: no AO).
    pub ao_rays: usize,
    /// AO ray length as a fraction of the bounding-box diagonal: long
    /// enough to darken creases and concavities, short enough that a
    /// distant part of the model does not shade a convex one.
    pub ao_radius: f64,
    /// Width of a patch boundary line in pixels.
    pub line_width: f64,
    /// Radius of a marker dot in pixels.
    pub marker_radius: f64,
    /// Rows per batch of rays (and per progress report).
    pub band_rows: usize,
}

impl Default for Shading {
    fn default() -> Self {
        Shading {
            ao_rays: 8,
            ao_radius: 0.1,
            line_width: 1.5,
            marker_radius: 3.0,
            band_rows: 32,
        }
    }
}

/// What a render produced per pixel, before it becomes an [`Image`].
#[derive(Clone, Debug)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    /// Final colour (albedo × shading, lines blended in), in [0, 1].
    pub colour: Vec<[f32; 3]>,
    /// Whether the pixel's ray hit the surface.
    pub hit: Vec<bool>,
    /// Unshaded surface colour (for checking colour maps).
    pub albedo: Vec<[f32; 3]>,
    /// Patch-line coverage in [0, 1].
    pub line: Vec<f32>,
}

impl Frame {
    /// The frame as an RGB8 image over `background`.
    pub fn to_image(&self, background: Rgb) -> Image {
        Image {
            width: self.width,
            height: self.height,
            pixels: self
                .colour
                .iter()
                .zip(&self.hit)
                .map(|(&c, &h)| if h { to_rgb8(c) } else { background })
                .collect(),
        }
    }
}

/// Progress callback: fraction done; returning `false` cancels.
pub type RenderProgress<'a> = dyn FnMut(f64) -> bool + 'a;

/// SplitMix64 finaliser: a well-mixed hash of a pixel's coordinates.
#[inline]
fn hash(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

#[inline]
fn unit(x: u64) -> f64 {
    (x >> 11) as f64 / (1u64 << 53) as f64
}

/// Van der Corput radical inverse in base 2.
#[inline]
fn vdc(k: u32) -> f64 {
    k.reverse_bits() as f64 / 4294967296.0
}

/// An orthonormal basis around unit `n` (Frisvad / Duff et al. 2017).
#[inline]
fn onb(n: DVec3) -> (DVec3, DVec3) {
    let s = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    (
        DVec3::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x),
        DVec3::new(b, s + n.y * n.y * a, -n.y),
    )
}

/// Per hit pixel, what shading needs after the AO rays come back.
#[derive(Copy, Clone)]
struct Sample {
    albedo: [f32; 3],
    /// |n · view| of the shading normal (headlight term).
    facing: f64,
    line: f32,
}

/// Barycentrics `(β, γ)` of `q` (in the triangle's plane) w.r.t. `(a, b, c)`.
#[inline]
fn plane_barycentrics(q: DVec3, a: DVec3, b: DVec3, c: DVec3) -> Option<(f64, f64)> {
    let (e1, e2, r) = (b - a, c - a, q - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = d11 * d22 - d12 * d12;
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    let (r1, r2) = (r.dot(e1), r.dot(e2));
    Some(((d22 * r1 - d12 * r2) / det, (d11 * r2 - d12 * r1) / det))
}

/// Patch-line coverage at a hit: for each drawn side, the distance to it in
/// pixels is the patch coordinate over its screen-space gradient, found by
/// intersecting the rays of the next pixel right and down with the hit
/// triangle's plane (ray differentials; the coordinates are affine on the
/// plane). Each side draws half the line width, so a boundary between two
/// patches gets a full-width line centred on it.
fn line_coverage(
    cam: &Camera,
    px: f64,
    py: f64,
    tri: [DVec3; 3],
    puv: &PatchUv,
    b: (f64, f64),
    half_width: f64,
) -> f32 {
    let [a, bb, c] = tri;
    let n = (bb - a).cross(c - a);
    let param = |beta: f64, gamma: f64| {
        let w = [1.0 - beta - gamma, beta, gamma];
        let mut uv = [0.0f64; 2];
        for (wk, c) in w.iter().zip(&puv.uv) {
            uv[0] += wk * c[0] as f64;
            uv[1] += wk * c[1] as f64;
        }
        uv
    };
    let at = |r: Ray| -> Option<[f64; 2]> {
        let dn = r.dir.dot(n);
        // A plane seen edge-on: no finite gradient, no line.
        if dn.abs() < 1e-9 * n.length() * r.dir.length() {
            return None;
        }
        let t = (a - r.origin).dot(n) / dn;
        let (be, ga) = plane_barycentrics(r.at(t), a, bb, c)?;
        Some(param(be, ga))
    };
    let p0 = param(b.0, b.1);
    let (Some(px1), Some(py1)) = (at(cam.ray_at(px + 1.0, py)), at(cam.ray_at(px, py + 1.0)))
    else {
        return 0.0;
    };
    let mut cov = 0.0f64;
    let sides = [
        (SIDE_U0, 0usize, false),
        (SIDE_U1, 0, true),
        (SIDE_V0, 1, false),
        (SIDE_V1, 1, true),
    ];
    for (bit, k, flip) in sides {
        if puv.sides & bit == 0 {
            continue;
        }
        let g = if flip { 1.0 - p0[k] } else { p0[k] };
        let (gx, gy) = (px1[k] - p0[k], py1[k] - p0[k]);
        let grad = (gx * gx + gy * gy).sqrt();
        if grad == 0.0 || !grad.is_finite() {
            continue;
        }
        let d = g.max(0.0) / grad;
        cov = cov.max((half_width + 0.5 - d).clamp(0.0, 1.0));
    }
    cov as f32
}

/// Renders `surf` (with `caster` built over `surf.mesh`) through `cam`.
pub fn render_frame(
    surf: &Surface,
    caster: &dyn RayCaster,
    cam: &Camera,
    shading: &Shading,
    progress: &mut RenderProgress<'_>,
) -> Result<Frame> {
    surf.check()?;
    let (w, h) = (cam.width, cam.height);
    if w == 0 || h == 0 {
        return Err(Error::InvalidArgument(format!(
            "render: image size {w}x{h} is empty"
        )));
    }
    let diag = surf.mesh.bbox_diagonal().max(f64::MIN_POSITIVE);
    let shade = Shader {
        surf,
        cam,
        shading,
        eps: 1e-5 * diag,
        ao_len: shading.ao_radius * diag,
    };
    let mut frame = Frame {
        width: w,
        height: h,
        colour: vec![[0.0; 3]; w * h],
        hit: vec![false; w * h],
        albedo: vec![[0.0; 3]; w * h],
        line: vec![0.0; w * h],
    };
    // Bands of rows: the primary hits and the AO rays of one band are
    // cast as two batches, without holding the whole image's rays.
    let band = shading.band_rows.max(1);
    let mut y0 = 0;
    while y0 < h {
        let y1 = (y0 + band).min(h);
        let npx = (y1 - y0) * w;
        let rays: Vec<Ray> = (0..npx).map(|i| cam.pixel_ray(i % w, y0 + i / w)).collect();
        let hits = caster.first_hits(&rays)?;
        // Shade every hit pixel; collect its AO rays (nao per hit pixel).
        let shaded: Vec<Option<(Sample, Vec<Ray>)>> = hits
            .par_iter()
            .enumerate()
            .map(|(i, hit)| Some(shade.shade(hit.as_ref()?, i % w, y0 + i / w)))
            .collect();
        let ao_rays: Vec<Ray> = shaded
            .iter()
            .flatten()
            .flat_map(|(_, r)| r.iter().copied())
            .collect();
        let ao_hits = caster.first_hits(&ao_rays)?;
        shade.composite(&mut frame, shaded, &ao_hits, y0 * w);
        y0 = y1;
        if !progress(y0 as f64 / h as f64) {
            return Err(Error::Cancelled {
                stage: "render".into(),
            });
        }
    }
    Ok(frame)
}

/// What shading one pixel needs besides its hit: the surface, camera and
/// shading options, the AO rays' offset `eps` and length `ao_len` (both
/// relative to the bounding-box diagonal).
struct Shader<'a> {
    surf: &'a Surface,
    cam: &'a Camera,
    shading: &'a Shading,
    eps: f64,
    ao_len: f64,
}

impl Shader<'_> {
    /// The sample of pixel `(x, y)` whose primary ray hit `hit`, and its
    /// ambient-occlusion rays (none when `ao_rays = 0`).
    fn shade(&self, hit: &Hit, x: usize, y: usize) -> (Sample, Vec<Ray>) {
        let (surf, cam) = (self.surf, self.cam);
        let mesh = &surf.mesh;
        let t = hit.triangle as usize;
        let tri = mesh.triangle(t);
        let [ia, ib, ic] = mesh.triangles[t];
        let (bu, bv) = (hit.u, hit.v);
        let bw = 1.0 - bu - bv;
        let p = bw * tri[0] + bu * tri[1] + bv * tri[2];
        let view = cam.dir;
        let mut ng = (tri[1] - tri[0]).cross(tri[2] - tri[0]).normalize_or_zero();
        if ng.dot(view) > 0.0 {
            ng = -ng;
        }
        let ns_raw = bw * surf.normals[ia as usize]
            + bu * surf.normals[ib as usize]
            + bv * surf.normals[ic as usize];
        let mut ns = ns_raw.normalize_or_zero();
        if ns == DVec3::ZERO || !ns.is_finite() {
            ns = ng;
        }
        // Two-sided lighting: scans are open and not always
        // consistently oriented.
        if ns.dot(view) > 0.0 {
            ns = -ns;
        }
        let albedo = surf
            .triangle_colours
            .as_ref()
            .and_then(|c| c[t])
            .unwrap_or_else(|| match &surf.vertex_colours {
                Some(c) => {
                    let (a, b, cc) = (c[ia as usize], c[ib as usize], c[ic as usize]);
                    let (bw, bu, bv) = (bw as f32, bu as f32, bv as f32);
                    [0, 1, 2].map(|k| bw * a[k] + bu * b[k] + bv * cc[k])
                }
                None => surf.base,
            });
        let line = match &surf.patch_uv {
            Some(puv) => line_coverage(
                cam,
                x as f64 + 0.5,
                y as f64 + 0.5,
                tri,
                &puv[t],
                (bu, bv),
                0.5 * self.shading.line_width,
            ),
            None => 0.0,
        };
        let ao = self.ao_rays(p + self.eps * ng, ng, ns, x, y);
        let sample = Sample {
            albedo,
            facing: -ns.dot(view),
            line,
        };
        (sample, ao)
    }

    /// The AO rays of pixel `(x, y)` from `origin` (the hit lifted off the
    /// surface), around the shading normal `ns` on the front side of the
    /// geometric normal `ng`.
    fn ao_rays(&self, origin: DVec3, ng: DVec3, ns: DVec3, x: usize, y: usize) -> Vec<Ray> {
        let nao = self.shading.ao_rays;
        let mut ao = Vec::with_capacity(nao);
        if nao > 0 {
            let hsh = hash(((y as u64) << 32) | x as u64);
            let (r1, r2) = (unit(hsh), unit(hash(hsh)));
            let (t1, t2) = onb(ns);
            for k in 0..nao {
                // Stratified cosine-weighted hemisphere samples,
                // rotated per pixel (Cranley-Patterson).
                // Directions within 60° of the normal only
                // (u1 ≤ 3/4): grazing rays carry little cosine
                // weight but, hitting or not depending on the
                // pixel's rotation, most of the noise.
                let u1 = 0.75 * ((k as f64 + 0.5) / nao as f64 + r1).fract();
                let u2 = (vdc(k as u32) + r2).fract();
                let (r, phi) = (u1.sqrt(), std::f64::consts::TAU * u2);
                let mut d = r * phi.cos() * t1 + r * phi.sin() * t2 + (1.0 - u1).sqrt() * ns;
                // Keep the ray on the geometric front side.
                let dn = d.dot(ng);
                if dn < 0.0 {
                    d -= 2.0 * dn * ng;
                }
                ao.push(Ray {
                    origin,
                    dir: d,
                    tmin: 0.0,
                    tmax: self.ao_len,
                });
            }
        }
        ao
    }

    /// Lights the shaded pixels of one band (starting at pixel `first` of
    /// the frame) with their AO hits, in band order, into `frame`.
    fn composite(
        &self,
        frame: &mut Frame,
        shaded: Vec<Option<(Sample, Vec<Ray>)>>,
        ao_hits: &[Option<Hit>],
        first: usize,
    ) {
        let ao_len = self.ao_len;
        let mut k = 0;
        for (i, s) in shaded.into_iter().enumerate() {
            let Some((s, rays)) = s else { continue };
            let n = rays.len();
            // Occlusion fades with the hit distance, (1 - t/len)²: a
            // blocker at the end of the AO radius counts for nothing, so the
            // estimate varies smoothly from pixel to pixel (less noise than
            // counting hits at a few rays per pixel).
            let occluded: f64 = ao_hits[k..k + n]
                .iter()
                .flatten()
                .map(|h| (1.0 - (h.t / ao_len).clamp(0.0, 1.0)).powi(2))
                .sum();
            k += n;
            let ao = if n == 0 {
                1.0
            } else {
                1.0 - occluded / n as f64
            };
            // Ambient (occluded) plus headlight diffuse, the latter also
            // darkened in occluded creases so that concavities read.
            let light = 0.30 * ao + 0.70 * s.facing.max(0.0) * (0.55 + 0.45 * ao);
            let mut c = s.albedo.map(|a| (a as f64 * light) as f32);
            let l = s.line;
            for j in 0..3 {
                c[j] = c[j] * (1.0 - l) + LINE[j] * l;
            }
            let idx = first + i;
            frame.colour[idx] = c;
            frame.hit[idx] = true;
            frame.albedo[idx] = s.albedo;
            frame.line[idx] = l;
        }
    }
}

/// Draws `surf.markers` that are visible from `cam` as dots on `img`.
pub fn draw_markers(
    img: &mut Image,
    surf: &Surface,
    caster: &dyn RayCaster,
    cam: &Camera,
    shading: &Shading,
) -> Result<()> {
    if surf.markers.is_empty() {
        return Ok(());
    }
    let diag = surf.mesh.bbox_diagonal();
    let proj: Vec<(f64, f64, f64)> = surf.markers.iter().map(|&p| cam.project(p)).collect();
    let rays: Vec<Ray> = proj.iter().map(|&(x, y, _)| cam.ray_at(x, y)).collect();
    let hits = caster.first_hits(&rays)?;
    let r = shading.marker_radius;
    for ((x, y, t), hit) in proj.into_iter().zip(hits) {
        // Visible: the first hit along the marker's ray is the marker (up
        // to the tessellation's chordal error).
        let visible = matches!(hit, Some(h) if (h.t - t).abs() <= 2e-3 * diag);
        if !visible {
            continue;
        }
        let rr = r.ceil() as i64 + 1;
        for dy in -rr..=rr {
            for dx in -rr..=rr {
                let (qx, qy) = (x.floor() as i64 + dx, y.floor() as i64 + dy);
                let d = ((qx as f64 + 0.5 - x).powi(2) + (qy as f64 + 0.5 - y).powi(2)).sqrt();
                // Dark rim one pixel wide, red core; anti-aliased edge.
                let a = (r + 1.0 + 0.5 - d).clamp(0.0, 1.0);
                img.blend(qx, qy, [40, 0, 0], a);
                let a = (r + 0.5 - d).clamp(0.0, 1.0);
                img.blend(qx, qy, MARKER, a);
            }
        }
    }
    Ok(())
}

/// Visible surface area of `mesh` seen through `cam`, estimated from a
/// render at the camera's resolution: each hit pixel sees `1 / scale²` of
/// screen area, i.e. that over `|n · d|` of surface (the cosine clamped at
/// 0.2 so that grazing pixels do not dominate).
pub fn visible_area(mesh: &TriMesh, caster: &dyn RayCaster, cam: &Camera) -> Result<f64> {
    let rays: Vec<Ray> = (0..cam.width * cam.height)
        .map(|i| cam.pixel_ray(i % cam.width, i / cam.width))
        .collect();
    let hits = caster.first_hits(&rays)?;
    let px = 1.0 / (cam.scale * cam.scale);
    Ok(hits
        .iter()
        .flatten()
        .map(|h| {
            let [a, b, c] = mesh.triangle(h.triangle as usize);
            let n = (b - a).cross(c - a).normalize_or_zero();
            px / n.dot(cam.dir).abs().max(0.2)
        })
        .sum())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn onb_is_orthonormal() {
        for n in [DVec3::Z, -DVec3::Z, DVec3::new(0.3, -0.5, 0.8).normalize()] {
            let (a, b) = onb(n);
            assert!(a.dot(b).abs() < 1e-12 && a.dot(n).abs() < 1e-12 && b.dot(n).abs() < 1e-12);
            assert!((a.length() - 1.0).abs() < 1e-12 && (b.length() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn barycentrics_outside_the_triangle() {
        let (a, b, c) = (DVec3::ZERO, DVec3::X, DVec3::Y);
        let (be, ga) = plane_barycentrics(DVec3::new(2.0, -1.0, 0.0), a, b, c).unwrap();
        assert!((be - 2.0).abs() < 1e-12 && (ga + 1.0).abs() < 1e-12);
    }
}
