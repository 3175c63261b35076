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
    let options = &options
        .clone()
        .with_scheme(sc.with_file_holes(options.scheme.clone()));
    if backend == Backend::Rust {
        if let Some((copy, scheme)) = sc.exact_copy_for(&options.scheme) {
            return make_evaluator(backend, &copy, &options.clone().with_scheme(scheme));
        }
    }
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

/// The face-varying evaluator of `backend` for a file read as `sc`: the
/// Rust one on the manifold copy, OpenSubdiv's on the file's own topology
/// (its non-manifold rules apply to face-varying values too). Faces keep
/// their ids and corner order in the copy, so `channel` serves both.
pub fn make_split_fvar_evaluator(
    backend: Backend,
    sc: &SplitControl,
    options: &EvalOptions,
    channel: &crate::mesh::FVarChannel,
) -> Result<Box<dyn crate::subdiv::fvar::FVarEvaluator>> {
    sc.check_scheme(&options.scheme)?;
    if backend == Backend::Rust {
        return Ok(Box::new(rust_split_fvar_evaluator(sc, options, channel)?));
    }
    if sc.is_manifold() {
        return crate::subdiv::fvar::make_fvar_evaluator(backend, &sc.manifold, options, channel);
    }
    Ok(Box::new(super::osd::OsdFVarEvaluator::from_descriptor(
        &OsdDescriptor::of_split(sc),
        options,
        channel,
    )?))
}

/// The Rust face-varying evaluator for a file read as `sc`, on the manifold
/// copy, with OpenSubdiv's rule for non-manifold vertices
/// ([`split_fvar_sharpened`]).
pub fn rust_split_fvar_evaluator(
    sc: &SplitControl,
    options: &EvalOptions,
    channel: &crate::mesh::FVarChannel,
) -> Result<crate::subdiv::fvar::RustFVarEvaluator> {
    let sharpened = split_fvar_sharpened(sc, channel, &options.scheme);
    // OpenSubdiv sees a non-manifold crease vertex as one interior vertex
    // with more faces than edges: its copies are not on a face-varying
    // boundary ("boundaries" would sharpen them), and a fan of one face is
    // no corner, neither by the boundary's corner rule
    // (`SplitControl::exact_copy_for`, as for positions) nor by the
    // face-varying rules that count faces.
    let spanning = sc.crease_copies();
    if let Some((copy, scheme)) = sc.exact_copy_for(&options.scheme) {
        let options = options.clone().with_scheme(scheme);
        return crate::subdiv::fvar::RustFVarEvaluator::with_sharpened(
            &copy, &options, channel, &sharpened, &spanning,
        );
    }
    crate::subdiv::fvar::RustFVarEvaluator::with_sharpened(
        &sc.manifold,
        options,
        channel,
        &sharpened,
        &spanning,
    )
}

/// Per vertex of `sc.manifold`: whether it copies a non-manifold vertex
/// of the file whose face-varying values OpenSubdiv does not find matching
/// (`FVarLevel::completeTopologyFromFaceValues`: more than one value, an
/// edge whose faces disagree at either end, or a boundary the mode
/// linearises or a smooth corner it sharpens). All values of such a vertex
/// are sharp corners there (`allCornersAreSharp` for a non-manifold
/// vertex), while the copy sees only its own fan's seams.
pub fn split_fvar_sharpened(
    sc: &SplitControl,
    channel: &crate::mesh::FVarChannel,
    scheme: &crate::mesh::SchemeOptions,
) -> Vec<bool> {
    use crate::mesh::{BoundaryInterpolation, FVarLinear};
    use std::collections::HashMap;
    let n = sc.positions.len();
    let mut values: Vec<Vec<u32>> = vec![Vec::new(); n];
    let mut faces = vec![0usize; n];
    // Per undirected edge: the values at its (smaller, larger) ends, per use.
    let mut edges: HashMap<(u32, u32), Vec<(u32, u32)>> = HashMap::new();
    let mut k = 0usize;
    for &size in &sc.face_sizes {
        let size = size as usize;
        for i in 0..size {
            let (a, b) = (sc.face_indices[k + i], sc.face_indices[k + (i + 1) % size]);
            let (va, vb) = (channel.indices[k + i], channel.indices[k + (i + 1) % size]);
            values[a as usize].push(va);
            faces[a as usize] += 1;
            let entry = if a < b { (va, vb) } else { (vb, va) };
            edges.entry((a.min(b), a.max(b))).or_default().push(entry);
        }
        k += size;
    }
    let mut mismatch: Vec<bool> = values
        .iter_mut()
        .map(|v| {
            v.sort_unstable();
            v.dedup();
            v.len() > 1
        })
        .collect();
    let mut boundary = vec![false; n];
    for (&(a, b), uses) in &edges {
        if uses.len() == 1 {
            boundary[a as usize] = true;
            boundary[b as usize] = true;
        } else if uses.iter().any(|u| *u != uses[0]) {
            mismatch[a as usize] = true;
            mismatch[b as usize] = true;
        }
    }
    let linear_boundaries = matches!(scheme.fvar, FVarLinear::Boundaries | FVarLinear::All);
    let smooth_corners_sharp =
        scheme.boundary != BoundaryInterpolation::EdgeAndCorner && scheme.fvar != FVarLinear::None;
    for v in 0..n {
        if boundary[v] && !mismatch[v] {
            mismatch[v] =
                (linear_boundaries && faces[v] > 0) || (faces[v] == 1 && smooth_corners_sharp);
        }
    }
    let non_manifold =
        |v: usize| matches!(sc.kinds[v], VertexKind::SharpCorner | VertexKind::Crease);
    sc.origin
        .iter()
        .map(|&o| non_manifold(o as usize) && mismatch[o as usize])
        .collect()
}
