//! Limit evaluation of non-manifold control meshes
//! ([`crate::mesh::SplitControl`], issue 18): OpenSubdiv is given the
//! file's topology as it is and applies its own non-manifold rules; the
//! Rust evaluators get the manifold copy, tagged to have the same surface
//! (see `mesh::nonmanifold`).
//!
//! Both evaluators made here work over the copy's vertices (one per fan of
//! a non-manifold vertex, unused vertices left out), so that
//! [`super::diff`] compares them on the copy's half-edge topology; the
//! OpenSubdiv one turns the copies' positions back into the file's (they
//! must coincide) and hands each copy its vertex's results.
//! [`file_vertex_limits`] gives per-vertex results back in the file's
//! numbering.

use std::collections::HashSet;

use super::osd::{patch_routes, OsdDescriptor, OsdEvaluator};
use super::{
    checked_holes, make_evaluator, Backend, Checked, EvalOptions, KnownDifference, LimitEvaluator,
    LimitPoint, LimitStencils, SurfaceLocation,
};
use crate::error::{Error, Result};
use crate::mesh::{SplitControl, VertexKind};
use crate::DVec3;

/// The chosen evaluator for `sc`, over `sc.manifold`'s vertices (module
/// docs). Refuses scheme options the copy cannot follow
/// ([`SplitControl::check_scheme`]). A manifold file gets exactly
/// [`make_evaluator`]'s.
pub fn make_split_evaluator(
    backend: Backend,
    sc: &SplitControl,
    options: &EvalOptions,
) -> Result<Box<dyn LimitEvaluator>> {
    sc.check_scheme(&options.scheme)?;
    if backend == Backend::Rust || sc.is_manifold() {
        return make_evaluator(backend, &sc.manifold, options);
    }
    let mesh = &sc.manifold;
    let holes = checked_holes(mesh, &options.scheme)?;
    if options.scheme.scheme == super::SubdivScheme::Loop {
        crate::mesh::check_loop_triangles(mesh)?;
    }
    // A sharpened vertex's `Limit` is exact (the corner rule at every
    // level); the others are routed as on a manifold mesh, once each.
    let mut seen = HashSet::new();
    let routes = patch_routes(mesh, options)?
        .into_iter()
        .map(|(c, loc)| (sc.origin[c as usize], loc))
        .filter(|&(v, _)| sc.kinds[v as usize] != VertexKind::SharpCorner && seen.insert(v))
        .collect();
    let osd = OsdEvaluator::from_descriptor(&OsdDescriptor::of_split(sc), routes, options)?;
    Ok(Box::new(Checked {
        inner: SplitOsd {
            osd,
            sc: sc.clone(),
        },
        face_sizes: mesh.face_sizes(),
        holes,
        scheme: options.scheme.scheme,
    }))
}

/// OpenSubdiv on the file's topology, seen over the copy's vertices.
struct SplitOsd {
    osd: OsdEvaluator,
    sc: SplitControl,
}

impl LimitEvaluator for SplitOsd {
    fn name(&self) -> &'static str {
        self.osd.name()
    }
    fn num_control_vertices(&self) -> usize {
        self.sc.origin.len()
    }
    fn vertex_limits(&self, positions: &[DVec3]) -> Result<Vec<LimitPoint>> {
        let lim = self
            .osd
            .vertex_limits(&self.sc.file_positions(positions)?)?;
        Ok(self.sc.origin.iter().map(|&o| lim[o as usize]).collect())
    }
    fn evaluate(
        &self,
        positions: &[DVec3],
        locations: &[SurfaceLocation],
    ) -> Result<Vec<LimitPoint>> {
        self.osd
            .evaluate(&self.sc.file_positions(positions)?, locations)
    }
    /// OpenSubdiv's rows, each weight on the first copy of its vertex
    /// (the copies coincide).
    fn stencils(&self, locations: &[SurfaceLocation]) -> Result<LimitStencils> {
        let mut s = self.osd.stencils(locations)?;
        for i in s.indices.iter_mut() {
            *i = self.sc.copies[*i as usize]
                .first()
                .copied()
                .ok_or_else(|| {
                    Error::backend("OpenSubdiv", format!("stencil on unused vertex {i}"))
                })?;
        }
        Ok(s)
    }
}

/// Per vertex of the file, from per-vertex results over the copy's
/// vertices: a vertex's first copy (its copies share the limit position:
/// the corner's or the crease's); an unused vertex is its own limit with
/// zero derivatives, as OpenSubdiv's `PrimvarRefiner::Limit` leaves a
/// vertex without edges (`far/primvarRefiner.h`).
pub fn file_vertex_limits(sc: &SplitControl, split: &[LimitPoint]) -> Vec<LimitPoint> {
    sc.copies
        .iter()
        .enumerate()
        .map(|(v, c)| match c.first() {
            Some(&first) => split[first as usize],
            None => LimitPoint {
                position: sc.positions[v],
                ..Default::default()
            },
        })
        .collect()
}

/// The copies of non-manifold vertices, for [`super::diff::compare_with_known`]:
/// OpenSubdiv's `Limit` gives such a vertex one normal (from two of its
/// edges, in its own order) where each fan has its own; positions agree.
pub fn split_known_differences(sc: &SplitControl) -> Vec<KnownDifference> {
    (0..sc.origin.len() as u32)
        .filter(|&c| {
            !matches!(
                sc.kinds[sc.origin[c as usize] as usize],
                VertexKind::Manifold | VertexKind::Unused
            )
        })
        .map(|c| KnownDifference {
            vertex: c,
            normal_only: true,
            reason: "copy of a non-manifold vertex: OpenSubdiv gives the vertex one normal, \
                     each fan has its own",
        })
        .collect()
}
