//! Pure-Rust uniform Catmull-Clark refinement with OpenSubdiv 3.5's rules
//! (see [`crate::subdiv`] for the conventions): the independent check of the
//! limit evaluators, and the tessellator of later stages.

use crate::error::{Error, Result};
use crate::mesh::SchemeOptions;
use crate::mesh::{ControlMesh, VertexId};
use crate::subdiv::catmark::topo::{topo_from_mesh, Rules, Topo};
use crate::DVec3;

/// The most levels [`refine_uniform`] accepts: each level multiplies the face
/// count by about 4.
pub const MAX_UNIFORM_LEVELS: u32 = 8;

/// Refines `mesh` `levels` times. Vertex `i` of the result is the child of
/// vertex `i` of `mesh` at every level (vertex points first, then edge
/// points, then face points), and face `f` of the result at level 1 is the
/// quad of parent face `p` at its corner `k`, numbered in order of `(p, k)`.
/// Crease and corner sharpness are carried over, decremented by one per
/// level (`Sdc::Options::CREASE_UNIFORM`).
pub fn refine_uniform(mesh: &ControlMesh, levels: u32) -> Result<ControlMesh> {
    refine_uniform_with(mesh, &SchemeOptions::default(), levels)
}

/// [`refine_uniform`] under the refinement rules of `scheme` (boundary
/// interpolation, creasing method, triangle rule; holes do not change the
/// refinement, and the refined mesh carries no hole tags). Sharpness is
/// rounded to f32 like OpenSubdiv's (see `catmark::topo`).
pub fn refine_uniform_with(
    mesh: &ControlMesh,
    scheme: &SchemeOptions,
    levels: u32,
) -> Result<ControlMesh> {
    if levels > MAX_UNIFORM_LEVELS {
        return Err(Error::InvalidArgument(format!(
            "refine_uniform: {levels} levels requested, at most {MAX_UNIFORM_LEVELS} supported"
        )));
    }
    let ids = topo_from_mesh(mesh, None, Rules::from_scheme(scheme));
    let mut t: Topo<DVec3> = Topo {
        pts: mesh.positions().to_vec(),
        vsharp: ids.vsharp,
        foff: ids.foff,
        fv: ids.fv,
        esharp: ids.esharp,
        rules: ids.rules,
        fe: Vec::new(),
    };
    for _ in 0..levels {
        let adj = t.adjacency();
        t = t.refine(&adj);
    }
    let polys: Vec<&[u32]> = (0..t.num_faces() as u32).map(|f| t.face(f)).collect();
    let mut out = ControlMesh::from_polygons(t.pts.clone(), &polys)?;
    for (&(a, b), &s) in &t.esharp {
        out.set_crease(VertexId(a), VertexId(b), s)?;
    }
    for (v, &s) in t.vsharp.iter().enumerate() {
        if s > 0.0 {
            out.set_corner(VertexId(v as u32), s)?;
        }
    }
    Ok(out)
}

/// One level of Catmull-Clark refinement, the same limit surface, with
/// every infinitely sharp crease and corner still infinitely sharp
/// (`refine_uniform` decrements sharpness per level, as OpenSubdiv does;
/// 10 − 1 would turn a crease semi-sharp at the next level).
pub fn refine_once_keeping_infinite(control: &ControlMesh) -> Result<ControlMesh> {
    use crate::mesh::INFINITELY_SHARP;
    let mut r = refine_uniform(control, 1)?;
    for (a, b, s) in r.creases() {
        if s >= INFINITELY_SHARP - 1.0 {
            r.set_crease(a, b, INFINITELY_SHARP)?;
        }
    }
    for (v, s) in r.corners() {
        if s >= INFINITELY_SHARP - 1.0 {
            r.set_corner(v, INFINITELY_SHARP)?;
        }
    }
    Ok(r)
}
