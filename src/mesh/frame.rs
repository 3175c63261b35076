//! The working frame every conversion runs in: the input translated to its
//! bounding-box centre, divided by its diagonal and snapped to a grid of
//! 2^-30 of that diagonal.
//!
//! Why each part (issue 22, "any scale"):
//! - **Unit diagonal.** Every threshold of the pipeline is a fraction of the
//!   diagonal or of a local radius, but Embree works in f32, whose squares
//!   overflow past ~1e19 and underflow below ~1e-19, and a few round-off
//!   guards are absolute. At unit size a mesh at 1e-20 or 1e20 converts as
//!   it does at 1.
//! - **Centred.** Scans often come in survey coordinates (a 2 m statue at
//!   5e5 m east): in f32 that leaves ~6 cm of resolution to the ray caster.
//!   Centred, the f32 resolution is ~1e-7 of the diagonal wherever the mesh
//!   sits.
//! - **Snapped.** The layout (greedy collapses, Fitmap radius steps) takes
//!   discrete decisions, and a last-bit change of one coordinate can flip
//!   one of them and with it the whole layout: spot scaled by 1+2^-40 gave
//!   74 patches instead of 79. A mesh and its copy scaled by a decimal
//!   factor (1e20, 0.3048 for feet) differ by such last bits once brought
//!   to unit size; rounding to a grid far coarser than those bits and far
//!   finer than any feature (2^-30 ≈ 9.3e-10 of the diagonal: under a
//!   nanometre on a metre-sized part) makes the two working meshes equal
//!   bit for bit except when a coordinate lies within a few ulps of a grid
//!   mid-point (probability ~1e-7 per coordinate).
//!
//! The results are mapped back with [`Frame::from_unit`]; lengths scale by
//! [`Frame::scale`].

use crate::DVec3;

/// Grid step of the snapped working coordinates, as a fraction of the
/// diagonal (see the module docs).
const SNAP: f64 = 1.0 / (1u64 << 30) as f64;

/// A similarity: `unit = snap((p - centre) / scale)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub centre: DVec3,
    pub scale: f64,
}

impl Frame {
    /// The identity (no translation, no scaling, no snapping).
    pub const IDENTITY: Frame = Frame {
        centre: DVec3::ZERO,
        scale: 1.0,
    };

    /// The frame of points with bounding box `(lo, hi)`; the identity when
    /// the box is empty, degenerate or not finite (validation refuses such
    /// meshes before they get here).
    pub fn of_bbox(lo: DVec3, hi: DVec3) -> Frame {
        let diag = (hi - lo).length();
        if !(diag.is_finite() && diag > 0.0) {
            return Frame::IDENTITY;
        }
        Frame {
            centre: 0.5 * (lo + hi),
            scale: diag,
        }
    }

    /// `p` in the working frame, snapped.
    pub fn to_unit(&self, p: DVec3) -> DVec3 {
        if *self == Frame::IDENTITY {
            return p;
        }
        let q = (p - self.centre) / self.scale;
        // x·2^30 and the division by 2^30 are exact; only `round` moves
        // the value. Past 2^52 / 2^30 the coordinate is already on the
        // grid and `round` is the identity.
        (q / SNAP).round() * SNAP
    }

    /// A working-frame point back in the input's coordinates.
    pub fn from_unit(&self, p: DVec3) -> DVec3 {
        if *self == Frame::IDENTITY {
            return p;
        }
        p * self.scale + self.centre
    }

    /// Every point of `ps` into the working frame.
    pub fn points_to_unit(&self, ps: &mut [DVec3]) {
        ps.iter_mut().for_each(|p| *p = self.to_unit(*p));
    }

    /// Every point of `ps` back from the working frame.
    pub fn points_from_unit(&self, ps: &mut [DVec3]) {
        ps.iter_mut().for_each(|p| *p = self.from_unit(*p));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_frame_has_unit_diagonal_and_snaps() {
        let f = Frame::of_bbox(
            DVec3::new(1e6, 1e6, 0.0),
            DVec3::new(1e6 + 3.0, 1e6 + 4.0, 0.0),
        );
        assert_eq!(f.scale, 5.0);
        let lo = f.to_unit(DVec3::new(1e6, 1e6, 0.0));
        let hi = f.to_unit(DVec3::new(1e6 + 3.0, 1e6 + 4.0, 0.0));
        assert!(((hi - lo).length() - 1.0).abs() < 2.0 * SNAP);
        for c in lo.to_array().into_iter().chain(hi.to_array()) {
            assert_eq!((c / SNAP).fract(), 0.0, "{c} is on the grid");
        }
        // Round trip within half a grid step of the diagonal.
        let p = DVec3::new(1e6 + 1.234567891234, 1e6 + 2.0, 0.0);
        assert!((f.from_unit(f.to_unit(p)) - p).length() <= 0.5 * SNAP * 5.0 * 3f64.sqrt());
    }

    #[test]
    fn decimal_rescaling_lands_on_the_same_grid_points() {
        // The reason for snapping: p and fl(p·s) / fl(diag·s) differ in
        // the last bits; on the grid they are the same point.
        let ps: Vec<DVec3> = (0..1000)
            .map(|i| {
                let t = i as f64 * 0.618_033_988_749_895;
                DVec3::new(t.sin(), (2.0 * t).cos(), t.fract())
            })
            .collect();
        let (lo, hi) = crate::mesh::soup::bbox(&ps);
        let a = Frame::of_bbox(lo, hi);
        for s in [1e20, 1e-20, 0.3048, 3.0] {
            let qs: Vec<DVec3> = ps.iter().map(|p| *p * s).collect();
            let (lo, hi) = crate::mesh::soup::bbox(&qs);
            let b = Frame::of_bbox(lo, hi);
            let same = ps
                .iter()
                .zip(&qs)
                .filter(|(p, q)| a.to_unit(**p) == b.to_unit(**q))
                .count();
            assert!(same >= 998, "scale {s}: {same} of 1000 points equal");
        }
    }

    #[test]
    fn degenerate_boxes_give_the_identity() {
        let p = DVec3::new(1.0, 2.0, 3.0);
        assert_eq!(Frame::of_bbox(p, p), Frame::IDENTITY);
        assert_eq!(
            Frame::of_bbox(p, DVec3::new(f64::INFINITY, 2.0, 3.0)),
            Frame::IDENTITY
        );
        assert_eq!(Frame::IDENTITY.to_unit(p), p);
    }
}
