// Limit positions and tangents of a refiner's last level, for the levels
// where OpenSubdiv 3.5's own PrimvarRefiner::Limit cannot be called.
//
// Limit (and LimitFaceVarying) size their mask buffers by
// Vtr::Level::getMaxValence(). Below level 0 that counts vertex edges and
// face sizes but not vertex faces (Level::resizeVertexFaces does not update
// it, unlike completeTopologyFromFaceVertices at level 0). A non-manifold
// vertex of a fin has more faces than edges (an edge shared by 100 quads:
// its level-1 child has 200 faces and 102 edges), so Limit writes its face
// weights past the buffer: heap corruption, and a crash on OpenSubdiv's own
// regression/shapes/catmark_nonman_edge100. `limit_buffers_fit` says when
// Limit is safe; otherwise `limit_with_masks` asks Sdc for the same masks
// and applies them in the same order (face, edge, then vertex weights), so
// the answer is still OpenSubdiv's.
#pragma once

#include <opensubdiv/far/topologyRefiner.h>
#include <opensubdiv/sdc/scheme.h>

#include <algorithm>
#include <stdexcept>
#include <vector>

namespace subdfit::osd {

// Whether every vertex of `level` has no more faces than the smallest max
// valence OpenSubdiv can have recorded for it (vertex edges, face sizes):
// then Limit's buffers hold every mask.
inline bool limit_buffers_fit(const OpenSubdiv::Far::TopologyLevel& level) {
  int max_valence = 0;
  for (int v = 0; v < level.GetNumVertices(); ++v)
    max_valence = std::max(max_valence, level.GetVertexEdges(v).size());
  for (int f = 0; f < level.GetNumFaces(); ++f)
    max_valence = std::max(max_valence, level.GetFaceVertices(f).size());
  for (int v = 0; v < level.GetNumVertices(); ++v)
    if (level.GetVertexFaces(v).size() > max_valence) return false;
  return true;
}

namespace limit_detail {

// Sdc's MASK interface over growable buffers.
class Mask {
 public:
  typedef double Weight;
  void Reset(int edges, int faces) {
    v_.assign(1, 0.0);
    e_.assign(static_cast<std::size_t>(edges), 0.0);
    f_.assign(static_cast<std::size_t>(faces), 0.0);
    nv_ = ne_ = nf_ = 0;
    centers_ = false;
  }
  int GetNumVertexWeights() const { return nv_; }
  int GetNumEdgeWeights() const { return ne_; }
  int GetNumFaceWeights() const { return nf_; }
  void SetNumVertexWeights(int n) { nv_ = n; }
  void SetNumEdgeWeights(int n) { ne_ = n; }
  void SetNumFaceWeights(int n) { nf_ = n; }
  Weight const& VertexWeight(int i) const { return v_[static_cast<std::size_t>(i)]; }
  Weight const& EdgeWeight(int i) const { return e_[static_cast<std::size_t>(i)]; }
  Weight const& FaceWeight(int i) const { return f_[static_cast<std::size_t>(i)]; }
  Weight& VertexWeight(int i) { return v_[static_cast<std::size_t>(i)]; }
  Weight& EdgeWeight(int i) { return e_[static_cast<std::size_t>(i)]; }
  Weight& FaceWeight(int i) { return f_[static_cast<std::size_t>(i)]; }
  bool AreFaceWeightsForFaceCenters() const { return centers_; }
  void SetFaceWeightsForFaceCenters(bool on) { centers_ = on; }

 private:
  std::vector<Weight> v_, e_, f_;
  int nv_ = 0, ne_ = 0, nf_ = 0;
  bool centers_ = false;
};

// Sdc's VERTEX interface for a limit mask: counts and sharpness only.
class Vertex {
 public:
  Vertex(const OpenSubdiv::Far::TopologyLevel& level, int v) : level_(level), v_(v) {}
  int GetNumEdges() const { return level_.GetVertexEdges(v_).size(); }
  int GetNumFaces() const { return level_.GetVertexFaces(v_).size(); }
  float GetSharpness() const { return level_.GetVertexSharpness(v_); }
  float* GetSharpnessPerEdge(float s[]) const {
    auto edges = level_.GetVertexEdges(v_);
    for (int i = 0; i < edges.size(); ++i) s[i] = level_.GetEdgeSharpness(edges[i]);
    return s;
  }

 private:
  const OpenSubdiv::Far::TopologyLevel& level_;
  int v_;
};

template <class P>
void apply(const Mask& m, const P* src, const std::vector<int>& fidx, const std::vector<int>& eidx, int v, P& out) {
  out.Clear();
  for (int i = 0; i < m.GetNumFaceWeights(); ++i) out.AddWithWeight(src[fidx[static_cast<std::size_t>(i)]], m.FaceWeight(i));
  for (int i = 0; i < m.GetNumEdgeWeights(); ++i) out.AddWithWeight(src[eidx[static_cast<std::size_t>(i)]], m.EdgeWeight(i));
  out.AddWithWeight(src[v], m.VertexWeight(0));
}

template <OpenSubdiv::Sdc::SchemeType SCHEME, class P>
void limit(const OpenSubdiv::Far::TopologyRefiner& r, const P* src, P* pos, P* tan1, P* tan2) {
  const OpenSubdiv::Sdc::Scheme<SCHEME> scheme(r.GetSchemeOptions());
  const auto& level = r.GetLevel(r.GetMaxLevel());
  Mask mp, m1, m2;
  std::vector<int> eidx, fidx;
  for (int v = 0; v < level.GetNumVertices(); ++v) {
    auto edges = level.GetVertexEdges(v);
    auto faces = level.GetVertexFaces(v);
    if (edges.size() == 0) {  // an unused vertex: itself, as Limit leaves it
      pos[v].Clear();
      pos[v].AddWithWeight(src[v], 1.0);
      tan1[v].Clear();
      tan2[v].Clear();
      continue;
    }
    mp.Reset(edges.size(), faces.size());
    m1.Reset(edges.size(), faces.size());
    m2.Reset(edges.size(), faces.size());
    scheme.ComputeVertexLimitMask(Vertex(level, v), mp, m1, m2, level.GetVertexRule(v));
    if (mp.AreFaceWeightsForFaceCenters() || m1.AreFaceWeightsForFaceCenters())
      throw std::logic_error("a limit mask with face-centre weights (Limit applies them to opposite vertices)");
    eidx.assign(static_cast<std::size_t>(edges.size()), 0);
    for (int i = 0; i < edges.size(); ++i) {
      auto ev = level.GetEdgeVertices(edges[i]);
      eidx[static_cast<std::size_t>(i)] = ev[0] == v ? ev[1] : ev[0];
    }
    // The vertex opposite in each face, as Limit gathers it.
    auto in_face = level.GetVertexFaceLocalIndices(v);
    fidx.assign(static_cast<std::size_t>(faces.size()), 0);
    for (int i = 0; i < faces.size(); ++i) {
      auto fv = level.GetFaceVertices(faces[i]);
      fidx[static_cast<std::size_t>(i)] = fv[(in_face[i] + 2) % fv.size()];
    }
    apply(mp, src, fidx, eidx, v, pos[v]);
    apply(m1, src, fidx, eidx, v, tan1[v]);
    apply(m2, src, fidx, eidx, v, tan2[v]);
  }
}

}  // namespace limit_detail

// Limit positions and the two tangents of the last level's vertices from
// `src` (that level's points), with Limit's masks; see the file comment.
template <class P>
void limit_with_masks(const OpenSubdiv::Far::TopologyRefiner& r, const P* src, P* pos, P* tan1, P* tan2) {
  using OpenSubdiv::Sdc::SchemeType;
  switch (r.GetSchemeType()) {
    case OpenSubdiv::Sdc::SCHEME_CATMARK:
      limit_detail::limit<OpenSubdiv::Sdc::SCHEME_CATMARK>(r, src, pos, tan1, tan2);
      break;
    case OpenSubdiv::Sdc::SCHEME_LOOP:
      limit_detail::limit<OpenSubdiv::Sdc::SCHEME_LOOP>(r, src, pos, tan1, tan2);
      break;
    default:
      limit_detail::limit<OpenSubdiv::Sdc::SCHEME_BILINEAR>(r, src, pos, tan1, tan2);
      break;
  }
}

}  // namespace subdfit::osd
