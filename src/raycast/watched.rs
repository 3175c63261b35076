//! A ray caster that a [`Watch`] can stop between chunks of queries.

use super::{in_spatial_order, ClosestPoint, Hit, Ray, RayCaster};
use crate::error::Result;
use crate::watch::Watch;
use crate::DVec3;

/// Queries per chunk: on Embree a chunk of this many closest-point queries
/// takes ~1–5 ms on one core, so a cancellation waits about that long,
/// while the extra FFI crossings cost nothing measurable.
const CHUNK: usize = 4096;

/// `inner`, with every batch split into chunks of [`CHUNK`] queries and a
/// [`Watch::check`] before each: a cancelled stage ends within one chunk.
/// The answers are those of `inner` (queries are independent of the batch
/// they come in, for both backends).
pub struct Watched<'a> {
    pub inner: &'a dyn RayCaster,
    pub watch: &'a Watch,
}

impl<'a> Watched<'a> {
    pub fn new(inner: &'a dyn RayCaster, watch: &'a Watch) -> Self {
        Watched { inner, watch }
    }

    fn chunked<Q, A>(
        &self,
        queries: &[Q],
        mut each: impl FnMut(&[Q]) -> Result<Vec<A>>,
    ) -> Result<Vec<A>> {
        if queries.len() <= CHUNK {
            self.watch.check()?;
            return each(queries);
        }
        let mut out = Vec::with_capacity(queries.len());
        for c in queries.chunks(CHUNK) {
            self.watch.check()?;
            out.extend(each(c)?);
        }
        Ok(out)
    }
}

impl RayCaster for Watched<'_> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }

    // Whole batches are put in spatial order before they are chunked (the
    // chunks would be too small for the inner caster to gain by it).
    // `line_hits` is the trait's default, two rays per line through here.
    fn first_hits(&self, rays: &[Ray]) -> Result<Vec<Option<Hit>>> {
        in_spatial_order(
            rays,
            |r| r.origin,
            |rays| self.chunked(rays, |c| self.inner.first_hits(c)),
        )
    }

    fn lines_blocked(&self, rays: &[Ray], out: &mut Vec<bool>) -> Result<()> {
        let mut part = Vec::new();
        let all = self.chunked(rays, |c| {
            self.inner.lines_blocked(c, &mut part)?;
            Ok(std::mem::take(&mut part))
        })?;
        *out = all;
        Ok(())
    }

    fn closest_points(&self, points: &[DVec3], max_dist: f64) -> Result<Vec<Option<ClosestPoint>>> {
        in_spatial_order(
            points,
            |p| *p,
            |points| self.chunked(points, |c| self.inner.closest_points(c, max_dist)),
        )
    }

    fn closest_points_within(
        &self,
        points: &[DVec3],
        max_dists: &[f64],
    ) -> Result<Vec<Option<ClosestPoint>>> {
        super::within_in_spatial_order(points, max_dists, |queries| {
            self.chunked(queries, |c| {
                let (p, d): (Vec<DVec3>, Vec<f64>) = c.iter().copied().unzip();
                self.inner.closest_points_within(&p, &d)
            })
        })
    }
}
