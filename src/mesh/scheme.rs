//! Subdivision scheme options carried with a control mesh: OpenSubdiv's
//! `Sdc::Options` (boundary interpolation, face-varying linear
//! interpolation, creasing method, triangle subdivision) and the faces
//! tagged as holes. A shape file states them with `t` tags
//! (`crate::io::read_control_file`); the command line can override them.
//!
//! Defaults: the crate's conventions (boundary "edge and corner", as in USD),
//! uniform creasing, Catmark triangles, face-varying data linear everywhere
//! (`FVAR_LINEAR_ALL`, Sdc's default), no holes. OpenSubdiv's own regression
//! harness (`regression/common/far_utils.h`, `GetSdcOptions`) starts from
//! boundary "edge only" instead; a shape file that relies on that should say
//! `t interpolateboundary 1/0/0 2`.

use serde::Serialize;

use crate::mesh::{ControlMesh, FaceId, INFINITELY_SHARP};

/// `Sdc::SchemeType` of the evaluators.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum SubdivScheme {
    /// `SCHEME_CATMARK`: Catmull-Clark.
    #[default]
    Catmark,
    /// `SCHEME_BILINEAR`: every face (an n-gon split at its edge midpoints
    /// and centroid into n quads) is its bilinear patch; the boundary,
    /// creasing and triangle options change nothing, and boundary "none"
    /// makes no holes (`Sdc::SchemeTypeTraits::GetLocalNeighborhoodSize` is
    /// 0 for bilinear).
    Bilinear,
    /// `SCHEME_LOOP`: Loop (1987) subdivision of all-triangle meshes, with
    /// OpenSubdiv's Sdc Loop rules for boundaries, creases and corners
    /// (`sdc/loopScheme.h`). Faces other than triangles are refused, as
    /// OpenSubdiv refuses them; the triangle option changes nothing.
    Loop,
}

/// `Sdc::Options::VtxBoundaryInterpolation`.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum BoundaryInterpolation {
    /// `VTX_BOUNDARY_NONE`: boundary edges are still sharp for the rules,
    /// but faces at a boundary vertex have no limit surface (see
    /// [`SchemeOptions::effective_holes`]).
    None,
    /// `VTX_BOUNDARY_EDGE_ONLY`: boundary edges are infinitely sharp
    /// creases; a corner with one face is smooth along its boundary.
    EdgeOnly,
    /// `VTX_BOUNDARY_EDGE_AND_CORNER`: also every boundary vertex with one
    /// face is an infinitely sharp corner.
    #[default]
    EdgeAndCorner,
}

/// `Sdc::Options::FVarLinearInterpolation` (face-varying data such as UVs;
/// it does not change the limit of the positions).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FVarLinear {
    /// `FVAR_LINEAR_NONE`: smooth everywhere.
    None,
    /// `FVAR_LINEAR_CORNERS_ONLY`.
    CornersOnly,
    /// `FVAR_LINEAR_CORNERS_PLUS1`.
    CornersPlus1,
    /// `FVAR_LINEAR_CORNERS_PLUS2`.
    CornersPlus2,
    /// `FVAR_LINEAR_BOUNDARIES`.
    Boundaries,
    /// `FVAR_LINEAR_ALL` (Sdc's default).
    #[default]
    All,
}

/// `Sdc::Options::CreasingMethod`.
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum CreaseMethod {
    /// `CREASE_UNIFORM`: sharpness decreases by one per level.
    #[default]
    Uniform,
    /// `CREASE_CHAIKIN`: a semi-sharp edge's child takes 3/4 of its
    /// sharpness and 1/4 of the average of the other semi-sharp edges at the
    /// same vertex, minus one (`Sdc::Crease::SubdivideEdgeSharpnessAtVertex`).
    Chaikin,
}

/// `Sdc::Options::TriangleSubdivision` (Catmark only).
#[derive(Copy, Clone, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum TriangleSubdivision {
    /// `TRI_SUB_CATMARK`: the plain Catmull-Clark edge rule.
    #[default]
    Catmark,
    /// `TRI_SUB_SMOOTH`: Hbr's weights at edges of triangles
    /// (`Sdc::Scheme<CATMARK>::assignSmoothMaskForEdge`).
    Smooth,
}

/// The scheme options of one control mesh; see the module doc.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
#[non_exhaustive]
pub struct SchemeOptions {
    pub scheme: SubdivScheme,
    pub boundary: BoundaryInterpolation,
    pub fvar: FVarLinear,
    pub crease_method: CreaseMethod,
    pub triangles: TriangleSubdivision,
    /// Faces without a limit surface (`t hole`), sorted, without repeats.
    /// They still take part in the subdivision rules of their neighbours
    /// (OpenSubdiv's hole tags: `Far::TopologyDescriptor::holeIndices`).
    #[serde(serialize_with = "face_indices")]
    pub holes: Vec<FaceId>,
}

fn face_indices<S: serde::Serializer>(faces: &[FaceId], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(faces.iter().map(|f| f.0))
}

impl SchemeOptions {
    pub fn with_scheme(mut self, s: SubdivScheme) -> Self {
        self.scheme = s;
        self
    }
    pub fn with_boundary(mut self, b: BoundaryInterpolation) -> Self {
        self.boundary = b;
        self
    }
    pub fn with_fvar(mut self, f: FVarLinear) -> Self {
        self.fvar = f;
        self
    }
    pub fn with_crease_method(mut self, c: CreaseMethod) -> Self {
        self.crease_method = c;
        self
    }
    pub fn with_triangles(mut self, t: TriangleSubdivision) -> Self {
        self.triangles = t;
        self
    }
    /// Sets the hole faces (sorted and deduplicated here).
    pub fn with_holes(mut self, mut holes: Vec<FaceId>) -> Self {
        holes.sort();
        holes.dedup();
        self.holes = holes;
        self
    }

    /// Whether these are the crate's defaults (nothing to state).
    pub fn is_default(&self) -> bool {
        *self == SchemeOptions::default()
    }

    /// Per face of `mesh`: true where there is no limit surface. These are
    /// the tagged holes and, with boundary interpolation "none", every face
    /// at a boundary vertex one of whose boundary edges is not infinitely
    /// sharp by its own tag (OpenSubdiv 3.5,
    /// `TopologyRefinerFactoryBase::prepareComponentTagsAndSharpness`,
    /// `makeBoundaryFacesHoles`).
    pub fn effective_holes(&self, mesh: &ControlMesh) -> Vec<bool> {
        let mut hole = vec![false; mesh.num_faces()];
        for f in &self.holes {
            if let Some(h) = hole.get_mut(f.idx()) {
                *h = true;
            }
        }
        // Both Catmark and Loop have a 1-ring neighbourhood (Sdc's
        // `GetLocalNeighborhoodSize`); bilinear has none and makes no holes.
        if self.boundary == BoundaryInterpolation::None && self.scheme != SubdivScheme::Bilinear {
            for v in mesh.vertices() {
                let soft_boundary = mesh.outgoing(v).any(|h| {
                    mesh.is_boundary_edge(h.edge())
                        && mesh.edge_sharpness(h.edge()) < INFINITELY_SHARP
                });
                if soft_boundary {
                    for f in mesh.vertex_faces(v) {
                        hole[f.idx()] = true;
                    }
                }
            }
        }
        hole
    }
}

/// Loop subdivision is defined on triangles only: the first face of `mesh`
/// that is not one, named, as an error (OpenSubdiv's
/// `TopologyRefinerFactory` refuses such a mesh too, with a less specific
/// message).
pub fn check_loop_triangles(mesh: &ControlMesh) -> crate::error::Result<()> {
    match mesh.faces().find(|&f| mesh.face_size(f) != 3) {
        Some(f) => Err(crate::error::Error::topology(
            format!("face {}", f.0),
            format!(
                "has {} corners; the Loop scheme needs an all-triangle mesh",
                mesh.face_size(f)
            ),
        )),
        None => Ok(()),
    }
}

impl std::fmt::Display for SchemeOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}, boundary {}, face-varying linear {}, creasing {}, triangles {}, {} hole face(s)",
            self.scheme.name(),
            self.boundary.name(),
            self.fvar.name(),
            self.crease_method.name(),
            self.triangles.name(),
            self.holes.len()
        )
    }
}

/// `name()`: the option's name as on the command line and in JSON.
macro_rules! named {
    ($t:ty { $($v:ident => $s:literal),* $(,)? }) => {
        impl $t {
            pub fn name(self) -> &'static str {
                match self { $(<$t>::$v => $s),* }
            }
        }
    };
}
named!(SubdivScheme { Catmark => "catmark", Bilinear => "bilinear", Loop => "loop" });
named!(BoundaryInterpolation { None => "none", EdgeOnly => "edge-only", EdgeAndCorner => "edge-and-corner" });
named!(FVarLinear {
    None => "none", CornersOnly => "corners-only", CornersPlus1 => "corners-plus1",
    CornersPlus2 => "corners-plus2", Boundaries => "boundaries", All => "all"
});
named!(CreaseMethod { Uniform => "uniform", Chaikin => "chaikin" });
named!(TriangleSubdivision { Catmark => "catmark", Smooth => "smooth" });
