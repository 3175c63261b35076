//! Differential testing of two limit evaluators: the machinery behind
//! `subdfit diff-limit` and the differential tests, in one place so that the
//! tool and the tests measure the same thing.
//!
//! Deviations are relative to the control mesh's bounding-box diagonal;
//! normal deviations are angles in radians. Locations closer than a margin
//! to an irregular corner are reported apart: there OpenSubdiv's end-cap
//! patches only approximate the limit (and parametrise it differently), so
//! the two evaluators legitimately disagree by an amount that shrinks as the
//! isolation level grows.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::error::Result;
use crate::mesh::{ControlMesh, FaceId, VertexId, INFINITELY_SHARP};
use crate::subdiv::{
    known_differences, KnownDifference, LimitEvaluator, LimitPoint, SurfaceLocation,
};
use crate::DVec3;

/// The worst deviation in one category and where it happened.
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct Worst {
    /// Number of samples compared.
    pub count: usize,
    /// Worst position deviation, relative to the bounding-box diagonal.
    pub position: f64,
    /// Where the worst position deviation happened.
    pub position_at: String,
    /// Worst angle between unit normals, radians.
    pub normal: f64,
    pub normal_at: String,
}

impl Worst {
    fn add(&mut self, at: impl Fn() -> String, dp: f64, dn: f64) {
        self.count += 1;
        if dp > self.position || (dp.is_nan() && !self.position.is_nan()) {
            self.position = dp;
            self.position_at = at();
        }
        if dn > self.normal || (dn.is_nan() && !self.normal.is_nan()) {
            self.normal = dn;
            self.normal_at = at();
        }
    }
}

/// Result of [`compare`].
#[derive(Clone, Debug, Default, Serialize)]
pub struct DiffReport {
    pub backends: [String; 2],
    pub bbox_diagonal: f64,
    /// At control vertices, known differences excluded.
    pub vertices: Worst,
    /// At the known differences (see [`known_differences`]).
    pub known: Worst,
    pub known_differences: Vec<KnownDifference>,
    /// At locations at least `margin` away (in u or v) from every irregular corner.
    pub regular: Worst,
    /// At locations within `margin` of an irregular corner.
    pub near_irregular: Worst,
    pub margin: f64,
}

/// Angle between two vectors' directions (0 when both are zero).
pub fn angle_between(a: DVec3, b: DVec3) -> f64 {
    let (a, b) = (a.normalize_or_zero(), b.normalize_or_zero());
    if a == DVec3::ZERO && b == DVec3::ZERO {
        return 0.0;
    }
    // atan2 of |a×b| and a·b stays accurate for tiny angles, unlike acos.
    a.cross(b).length().atan2(a.dot(b))
}

/// Whether patches around `v` are irregular for a feature-adaptive
/// evaluator (extraordinary valence, darts, uneven creases, corners with a
/// face count other than one): the places where end caps are used.
pub fn is_irregular_vertex(mesh: &ControlMesh, v: VertexId) -> bool {
    let valence = mesh.valence(v);
    let sharp: Vec<f64> = mesh
        .outgoing(v)
        .filter(|&h| !mesh.is_boundary_edge(h.edge()))
        .map(|h| mesh.edge_sharpness(h.edge()))
        .filter(|&s| s > 0.0)
        .collect();
    if mesh.vertex_sharpness(v) > 0.0 && !(mesh.is_boundary_vertex(v) && valence == 2) {
        return true;
    }
    if mesh.is_boundary_vertex(v) {
        return !sharp.is_empty() || !(valence == 2 || valence == 3);
    }
    match sharp.len() {
        0 => valence != 4,
        2 if sharp.iter().all(|&s| s >= INFINITELY_SHARP) => {
            // A regular crease splits the ring into two halves of two faces.
            let hs: Vec<_> = mesh.outgoing(v).collect();
            let k: Vec<usize> = (0..hs.len())
                .filter(|&i| mesh.edge_sharpness(hs[i].edge()) > 0.0)
                .collect();
            valence != 4 || k[1] - k[0] != 2
        }
        _ => true,
    }
}

/// Corners of the sub-quad of `loc` that are irregular, as `(u, v)` corners
/// of the unit square. A non-quad face's centre is always irregular.
fn irregular_corners(
    mesh: &ControlMesh,
    irregular: &[bool],
    loc: &SurfaceLocation,
) -> Vec<(f64, f64)> {
    let verts: Vec<VertexId> = mesh.face_vertices(loc.face).collect();
    let mut out = Vec::new();
    if verts.len() == 4 {
        for (k, c) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
            .into_iter()
            .enumerate()
        {
            if irregular[verts[k].idx()] {
                out.push(c);
            }
        }
    } else {
        // Sub-quad k: (0,0) at corner k, (1,1) at the face centre.
        if irregular[verts[loc.sub as usize].idx()] {
            out.push((0.0, 0.0));
        }
        out.push((1.0, 1.0));
    }
    out
}

/// `n` random locations, uniform in `(u, v)` over uniformly chosen
/// sub-quads (ptex faces), from a fixed seed.
pub fn random_locations(mesh: &ControlMesh, n: usize, seed: u64) -> Vec<SurfaceLocation> {
    let mut ptex: Vec<(FaceId, u16)> = Vec::new();
    for f in mesh.faces() {
        let k = mesh.face_size(f);
        if k == 4 {
            ptex.push((f, 0));
        } else {
            ptex.extend((0..k as u16).map(|s| (f, s)));
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let (face, sub) = ptex[rng.gen_range(0..ptex.len())];
            SurfaceLocation {
                face,
                sub,
                u: rng.gen::<f64>(),
                v: rng.gen::<f64>(),
            }
        })
        .collect()
}

/// Compares `a` and `b` at every control vertex and at `locations`.
pub fn compare(
    mesh: &ControlMesh,
    a: &dyn LimitEvaluator,
    b: &dyn LimitEvaluator,
    locations: &[SurfaceLocation],
    margin: f64,
) -> Result<DiffReport> {
    let diag = mesh.bbox_diagonal().max(f64::MIN_POSITIVE);
    let known = known_differences(mesh);
    let mut is_known = vec![false; mesh.num_vertices()];
    for k in &known {
        is_known[k.vertex as usize] = true;
    }
    let mut report = DiffReport {
        backends: [a.name().to_string(), b.name().to_string()],
        bbox_diagonal: diag,
        known_differences: known,
        margin,
        ..Default::default()
    };
    let p = mesh.positions();
    let (va, vb) = (a.vertex_limits(p)?, b.vertex_limits(p)?);
    for (i, (x, y)) in va.iter().zip(&vb).enumerate() {
        let dp = (x.position - y.position).length() / diag;
        let dn = angle_between(x.normal(), y.normal());
        let at = || format!("vertex {i}");
        if is_known[i] {
            report.known.add(at, dp, dn);
        } else {
            report.vertices.add(at, dp, dn);
        }
    }
    let irregular: Vec<bool> = mesh
        .vertices()
        .map(|v| is_irregular_vertex(mesh, v))
        .collect();
    let (la, lb): (Vec<LimitPoint>, Vec<LimitPoint>) =
        (a.evaluate(p, locations)?, b.evaluate(p, locations)?);
    for (i, loc) in locations.iter().enumerate() {
        let (x, y) = (la[i], lb[i]);
        let dp = (x.position - y.position).length() / diag;
        let dn = angle_between(x.normal(), y.normal());
        let near = irregular_corners(mesh, &irregular, loc)
            .iter()
            .any(|&(cu, cv)| (loc.u - cu).abs() < margin && (loc.v - cv).abs() < margin);
        let at = || {
            format!(
                "face {} sub {} (u, v) = ({:.6}, {:.6})",
                loc.face.0, loc.sub, loc.u, loc.v
            )
        };
        if near {
            report.near_irregular.add(at, dp, dn);
        } else {
            report.regular.add(at, dp, dn);
        }
    }
    Ok(report)
}

impl std::fmt::Display for DiffReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{} vs {} (deviations relative to the bbox diagonal {:.6e}; normals in rad)",
            self.backends[0], self.backends[1], self.bbox_diagonal
        )?;
        let line = |f: &mut std::fmt::Formatter<'_>, name: &str, w: &Worst| {
            if w.count == 0 {
                return writeln!(f, "  {name:<28} (none)");
            }
            writeln!(
                f,
                "  {name:<28} n={:<7} position {:.3e} at {}\n  {:<28}           normal   {:.3e} at {}",
                w.count, w.position, w.position_at, "", w.normal, w.normal_at
            )
        };
        line(f, "control vertices", &self.vertices)?;
        line(f, "random locations", &self.regular)?;
        let near = format!("near irregular (< {})", self.margin);
        line(f, &near, &self.near_irregular)?;
        if !self.known_differences.is_empty() {
            line(f, "known differences", &self.known)?;
            for k in &self.known_differences {
                writeln!(f, "    vertex {}: {}", k.vertex, k.reason)?;
            }
        }
        Ok(())
    }
}
