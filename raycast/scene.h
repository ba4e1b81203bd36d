/// @file scene.h
/// @brief What the renderer traces: a scene answers closest-hit and occlusion queries for world-space rays.
/// Implementations: PatchScene (corner-patch model, patch_scene.h) and MeshScene (triangle mesh,
/// mesh_scene.h).
#pragma once
#include <embree3/rtcore.h>

#include <array>
#include <atomic>
#include <cstdint>
#include <limits>
#include <memory>

#include "camera.h"

namespace cip::raycast {

/// The closest surface point along a ray.
struct SurfaceHit {
  double t = 0;                  ///< ray parameter (world distance along the unit direction)
  Vec3 position = Vec3::Zero();  ///< world coordinates
  Vec3 normal = Vec3::UnitZ();   ///< unit normal (world); for patches the gradient direction (towards the
                                 ///< positive side, value > isovalue), not turned towards the viewer
  double meanCurvature = std::numeric_limits<double>::quiet_NaN();  ///< 1 / world units; NaN when unknown
  std::uint32_t id = 0;       ///< model cell index (patches) or triangle index / recorded cell (meshes)
  bool hasCellIndex = false;  ///< cellIndex is valid (patch scenes)
  std::array<std::uint32_t, 3> cellIndex{};  ///< grid index (i,j,k) of the hit cell
};

/// Identifier written for pixels without a hit.
constexpr std::uint32_t kNoHitId = 0xFFFFFFFFu;

class RenderScene {
 public:
  virtual ~RenderScene() = default;
  /// Closest hit with t in [tNear, tFar]; thread-safe.
  virtual bool intersect(const Ray& ray, double tNear, double tFar, SurfaceHit& hit) const = 0;
  /// Whether any surface lies on the ray with t in [tNear, tFar]; thread-safe.
  virtual bool occluded(const Ray& ray, double tNear, double tFar) const = 0;
  /// World box of the geometry (used to frame the default view and scale offsets).
  virtual Box bounds() const = 0;
  /// Embree primitives: non-empty cells or triangles.
  virtual std::size_t primitives() const = 0;
  /// Bytes the scene holds besides its input (the model or mesh): Embree's at their peak, and its own
  /// per-primitive tables.
  virtual std::uint64_t bytes() const = 0;
};

/// An Embree device with error checking; one per scene.
class EmbreeDevice {
 public:
  /// `threads` > 0 bounds the threads Embree builds with (its "threads" setting); 0 = Embree's default (all).
  explicit EmbreeDevice(int threads = 0);
  ~EmbreeDevice();
  EmbreeDevice(const EmbreeDevice&) = delete;
  EmbreeDevice& operator=(const EmbreeDevice&) = delete;
  RTCDevice get() const { return device_; }
  /// Throws cip::Error naming `what` if Embree reported an error since the last check.
  void check(const char* what) const;
  /// Bytes Embree holds for this device's scenes now, and at most so far (its memory monitor's count).
  std::int64_t bytes() const { return bytes_.load(); }
  std::int64_t peakBytes() const { return peak_.load(); }

 private:
  static bool monitor(void* self, ssize_t bytes, bool post);
  RTCDevice device_ = nullptr;
  std::atomic<std::int64_t> bytes_{0}, peak_{0};
};

/// Embree single-ray fields from a world ray (float), with mask = 0xFFFFFFFF (Debian's Embree has ray masks
/// on).
void setEmbreeRay(RTCRay& out, const Ray& ray, double tNear, double tFar);

/// Smallest float >= x (x finite), so that float ray bounds never cut off a double-precision hit.
float roundUpToFloat(double x);
/// Largest float <= x.
float roundDownToFloat(double x);

}  // namespace cip::raycast
