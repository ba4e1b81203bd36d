/// @file mesh_scene.h
/// @brief A triangle mesh (e.g. read from PLY) as Embree triangles, rendered with the same cameras and
/// shading as corner-patch models. Single-precision intersection (Embree's triangles).
#pragma once
#include "cip/mesh/triangle_mesh.h"
#include "scene.h"

namespace cip::raycast {

class MeshScene : public RenderScene {
 public:
  /// Copies the positions to float; `mesh` must outlive the scene (normals and recorded cells are read at
  /// hits). `threads` > 0 bounds the threads of the BVH build (0 = all).
  explicit MeshScene(const TriangleMesh& mesh, int threads = 0);
  ~MeshScene() override;
  MeshScene(const MeshScene&) = delete;
  MeshScene& operator=(const MeshScene&) = delete;

  /// Normal: interpolated vertex normals when the mesh has them, else the facet normal (counter-clockwise
  /// order). id: the triangle's recorded cell when the mesh has them, else the triangle index. Curvature:
  /// unknown (NaN).
  bool intersect(const Ray& ray, double tNear, double tFar, SurfaceHit& hit) const override;
  bool occluded(const Ray& ray, double tNear, double tFar) const override;
  Box bounds() const override { return bounds_; }
  std::size_t primitives() const override { return mesh_.triangles.size(); }
  std::uint64_t bytes() const override { return static_cast<std::uint64_t>(device_.peakBytes()); }

 private:
  const TriangleMesh& mesh_;
  Box bounds_;
  EmbreeDevice device_;
  RTCScene scene_ = nullptr;
};

}  // namespace cip::raycast
