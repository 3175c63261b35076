//! Orthographic cameras fitted to a bounding box.
//!
//! Orthographic rather than perspective: a picture of a fitted surface is
//! read like a technical drawing (patch sizes compare across the image, a
//! sphere's silhouette radius is exactly `r * scale` pixels, which the tests
//! use), and the fit to the box is exact instead of depending on a field of
//! view.

use serde::Serialize;

use crate::raycast::Ray;
use crate::DVec3;

/// Where the camera looks from. Model space is taken as y-up (the
/// convention of the scanned data sets, e.g. the Stanford bunny).
#[derive(Copy, Clone, Debug, PartialEq, Eq, Serialize)]
pub enum View {
    /// From +z, looking down -z.
    Front,
    /// From +x, looking down -x.
    Side,
    /// From +y, looking down -y (screen up is -z).
    Top,
    /// From (+1, +1, +1), y up.
    Iso,
    /// The fixed view showing the most visible surface area (see
    /// [`super::pick_view`]).
    Auto,
}

impl View {
    /// The fixed views [`View::Auto`] chooses from.
    pub const FIXED: [View; 4] = [View::Front, View::Side, View::Top, View::Iso];

    /// Unit viewing direction and approximate screen-up vector.
    fn frame(self) -> (DVec3, DVec3) {
        match self {
            View::Front | View::Auto => (DVec3::NEG_Z, DVec3::Y),
            View::Side => (DVec3::NEG_X, DVec3::Y),
            View::Top => (DVec3::NEG_Y, DVec3::NEG_Z),
            View::Iso => (-DVec3::ONE.normalize(), DVec3::Y),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            View::Front => "front",
            View::Side => "side",
            View::Top => "top",
            View::Iso => "iso",
            View::Auto => "auto",
        }
    }
}

/// An orthographic camera: pixel `(x, y)` (centre at `x + 0.5`, `y + 0.5`)
/// looks along `dir` from the plane through `centre` spanned by `right` and
/// `up`, `scale` pixels per model unit.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct Camera {
    pub width: usize,
    pub height: usize,
    /// Model point at the image centre (on the near side of the box).
    pub centre: DVec3,
    pub dir: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    /// Pixels per model unit.
    pub scale: f64,
    /// Distance from `centre` back to where rays start: the whole box lies
    /// in front of every ray origin.
    pub back: f64,
}

/// Fraction of the image left empty on each side by [`Camera::fit`].
pub const MARGIN: f64 = 0.05;

impl Camera {
    /// The camera of `view` (not [`View::Auto`]: resolve it first) fitted to
    /// the box `(lo, hi)`: the box's projection is centred, and scaled to
    /// fill the image but for [`MARGIN`] on each side of its tighter axis.
    pub fn fit(view: View, lo: DVec3, hi: DVec3, width: usize, height: usize) -> Camera {
        let (dir, up0) = view.frame();
        let right = dir.cross(up0).normalize();
        let up = right.cross(dir).normalize();
        let corners = (0..8).map(|i| {
            DVec3::new(
                if i & 1 == 0 { lo.x } else { hi.x },
                if i & 2 == 0 { lo.y } else { hi.y },
                if i & 4 == 0 { lo.z } else { hi.z },
            )
        });
        let (mut rx, mut ry) = (
            (f64::INFINITY, f64::NEG_INFINITY),
            (f64::INFINITY, f64::NEG_INFINITY),
        );
        for c in corners {
            let (a, b) = (c.dot(right), c.dot(up));
            rx = (rx.0.min(a), rx.1.max(a));
            ry = (ry.0.min(b), ry.1.max(b));
        }
        let mid = 0.5 * (lo + hi);
        let depth = mid.dot(dir);
        let centre = right * 0.5 * (rx.0 + rx.1) + up * 0.5 * (ry.0 + ry.1) + dir * depth;
        let usable = 1.0 - 2.0 * MARGIN;
        // A degenerate extent (a flat mesh seen edge-on, a single point)
        // must not divide by zero: fall back to the other axis or 1.
        let ext = |r: (f64, f64)| (r.1 - r.0).max(0.0);
        let (ex, ey) = (ext(rx), ext(ry));
        let sx = if ex > 0.0 {
            width as f64 * usable / ex
        } else {
            f64::INFINITY
        };
        let sy = if ey > 0.0 {
            height as f64 * usable / ey
        } else {
            f64::INFINITY
        };
        let mut scale = sx.min(sy);
        if !scale.is_finite() || scale <= 0.0 {
            scale = 1.0;
        }
        let diag = (hi - lo).length().max(f64::MIN_POSITIVE);
        Camera {
            width,
            height,
            centre,
            dir,
            right,
            up,
            scale,
            back: 2.0 * diag,
        }
    }

    /// The ray through image point `(px, py)` (pixel units, y down).
    #[inline]
    pub fn ray_at(&self, px: f64, py: f64) -> Ray {
        let sx = (px - 0.5 * self.width as f64) / self.scale;
        let sy = (0.5 * self.height as f64 - py) / self.scale;
        let origin = self.centre + sx * self.right + sy * self.up - self.back * self.dir;
        Ray::new(origin, self.dir)
    }

    /// The ray through the centre of pixel `(x, y)`.
    #[inline]
    pub fn pixel_ray(&self, x: usize, y: usize) -> Ray {
        self.ray_at(x as f64 + 0.5, y as f64 + 0.5)
    }

    /// Image position `(px, py)` of a model point and its ray parameter `t`
    /// along [`Camera::ray_at`].
    pub fn project(&self, p: DVec3) -> (f64, f64, f64) {
        let d = p - self.centre;
        let px = 0.5 * self.width as f64 + d.dot(self.right) * self.scale;
        let py = 0.5 * self.height as f64 - d.dot(self.up) * self.scale;
        (px, py, d.dot(self.dir) + self.back)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_inverts_ray_at() {
        let cam = Camera::fit(
            View::Iso,
            DVec3::splat(-1.0),
            DVec3::new(2.0, 1.0, 0.5),
            320,
            200,
        );
        let p = DVec3::new(0.3, -0.2, 0.1);
        let (px, py, t) = cam.project(p);
        let r = cam.ray_at(px, py);
        assert!((r.at(t) - p).length() < 1e-12);
    }

    #[test]
    fn fit_centres_and_fills() {
        let cam = Camera::fit(
            View::Front,
            DVec3::new(0.0, 0.0, 0.0),
            DVec3::new(4.0, 1.0, 1.0),
            200,
            200,
        );
        // x extent 4 fills 90 % of 200 px.
        assert!((cam.scale - 45.0).abs() < 1e-12);
        let (px, py, _) = cam.project(DVec3::new(2.0, 0.5, 0.5));
        assert!((px - 100.0).abs() < 1e-9 && (py - 100.0).abs() < 1e-9);
        // Right-handed screen: +x to the right, +y up in the front view.
        let (ax, ay, _) = cam.project(DVec3::new(3.0, 1.0, 0.5));
        assert!(ax > 100.0 && ay < 100.0);
    }
}
