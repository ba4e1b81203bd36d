/// @file patch_scene.h
/// @brief A corner-patch model as an Embree user geometry: one primitive per non-empty cell, exact ray-patch
/// intersection in double precision (cip/ray/ray_patch.h), normals and curvature from the patch's exact
/// derivatives. Rays come in world coordinates and are mapped into the model's axis-aligned grid frame
/// (world_transform.h), so the patches stay exact under any rotation, flip or shear of the volume.
#pragma once
#include <optional>
#include <vector>

#include "cip/model/model.h"
#include "cip/patch/corner_patch.h"
#include "cip/ray/open_face_cap.h"
#include "scene.h"

namespace cip::raycast {

struct PatchSceneOptions {
  /// Hits carry the mean curvature (from the patch's Hessian); without it they carry NaN and only the
  /// gradient is computed. Only the curvature shading mode uses it.
  bool curvature = true;
  /// Threads for building the scene (patches and BVH); 0 = all.
  int threads = 0;
  /// World frame of rays and hits: the model's own (Unspecified), or RAS/LAS/LPS converted from it.
  WorldSpace space = WorldSpace::Unspecified;
};

class PatchScene : public RenderScene {
 public:
  /// Builds the scene (the Embree BVH over the cell boxes, in parallel; patches are assembled per query).
  /// `model` must outlive the scene.
  explicit PatchScene(const Model& model, const PatchSceneOptions& options = {});
  ~PatchScene() override;
  PatchScene(const PatchScene&) = delete;
  PatchScene& operator=(const PatchScene&) = delete;

  bool intersect(const Ray& ray, double tNear, double tFar, SurfaceHit& hit) const override;
  bool occluded(const Ray& ray, double tNear, double tFar) const override;
  /// World box of the non-empty cells (in the frame of PatchSceneOptions::space).
  Box bounds() const override { return bounds_; }
  std::size_t primitives() const override { return model_.cells.size(); }
  std::uint64_t bytes() const override {
    return zeroMasks_.size() * sizeof(std::uint64_t) + static_cast<std::uint64_t>(device_.peakBytes());
  }

  // Used by the Embree callbacks.
  const Model& model() const { return model_; }
  /// The cell's patch, assembled from the model when asked for (cheaper than faulting in a table of ~0.8 KB
  /// per cell, which was 7 % of a 1024x1024 render's whole process), through a small cache per thread: the
  /// rays of a tile meet the same few cells in turn. Valid until the thread asks for another cell (signAcross
  /// does not use the cache, so a caller may hold its cell's patch across it).
  const CornerPatch& patch(std::uint32_t cell) const;
  /// The cell's sub-boxes where its patch may vanish (patch_bounds.h), and those on an open face's layer
  /// where it may have the other sign than the face's corners (a hole closed by a cap, open_face_cap.h).
  std::uint64_t zeroMask(std::uint32_t cell) const { return zeroMasks_[cell]; }
  /// Cell-local coordinates of a world point in cell `cell`.
  Vec3 worldToLocal(const Vec3& world, std::uint32_t cell) const;
  /// Cell-local coordinates of a point of the model's grid frame in cell `cell`.
  Vec3 frameToLocal(const Vec3& frame, std::uint32_t cell) const;
  /// The map from the model's grid frame (where the BVH and the patches are) to the world of the rays.
  const WorldTransform& world() const { return world_; }
  /// Sign (+1 above the isovalue, -1 below) of the region across `face` of cell `cell` at `local` (cell-local
  /// coordinates of a point on the face): the neighbouring cell's patch there when that cell is non-empty
  /// (and not zero there), else the face corners' sign (open_face_cap.h).
  int signAcross(std::uint32_t cell, int face, const Vec3& local) const;

 private:
  void build();  ///< patches, bounds and BVH (run inside the options' thread arena)

  /// The world ray in the model's grid frame (same parameter t).
  Ray toFrame(const Ray& ray) const;
  /// Surface data at the hit of cell `cell` at ray parameter t (the ray in the world and in the grid frame):
  /// position, normal (world gradient direction) and, if the scene was built with curvature, mean curvature
  /// in world units from the exact gradient and Hessian.
  /// At a cap (a hole of the patch surface closed by a piece of an open face, open_face_cap.h) the normal is
  /// the face's, and the curvature 0.
  SurfaceHit surfaceAt(const Ray& worldRay, const Ray& frameRay, double t, std::uint32_t cell,
                       const std::optional<FaceCap>& cap) const;

  const Model& model_;
  std::uint64_t serial_;  ///< distinguishes this scene's entries in the per-thread patch caches
  WorldTransform world_;
  Mat3 gradientToWorld_;  ///< cell-local gradient -> world gradient (world_.indexGradientToWorld)
  bool curvature_ = true;
  Box bounds_;
  std::vector<std::uint64_t> zeroMasks_;  ///< per cell, zeroMask()
  EmbreeDevice device_;
  RTCScene scene_ = nullptr;
};

/// Mean curvature (1 / world units) of the level set of f at a point from f's world gradient g and Hessian H:
/// div(g / |g|) / 2 = (|g|^2 tr H - g^T H g) / (2 |g|^3). Positive where the surface bends away from the
/// gradient direction (e.g. +1/r on a sphere whose field grows outwards). NaN when g = 0.
double meanCurvature(const Vec3& gradient, const Mat3& hessian);

}  // namespace cip::raycast
