/// @file renderer.h
/// @brief Renders a scene into a multi-channel image, in parallel over image tiles (TBB). The result is
/// identical for any number of threads: every pixel is a pure function of its position (stratified sample
/// positions come from a hash of pixel and sample index; no per-thread random state) and tiles write disjoint
/// pixels.
#pragma once
#include <cstdint>
#include <functional>
#include <vector>

#include "shading.h"

namespace cip::raycast {

/// The rendered channels, row-major, top row first.
struct RenderImage {
  int width = 0, height = 0;
  std::vector<float> rgba;   ///< 4 per pixel, linear RGB premultiplied by A; A = fraction of samples that hit
  std::vector<float> depth;  ///< Z: distance along the pixel-centre ray (world units), +inf where it misses
  std::vector<float> normal;  ///< 3 per pixel: unit normal (world) at the pixel-centre hit, 0 where it misses
  std::vector<std::uint32_t> id;  ///< cell index (patch models) / triangle index (meshes) of the centre hit,
                                  ///< kNoHitId where it misses
  std::vector<float>
      curvature;  ///< mean curvature (1 / world units) averaged over the hit samples, NaN if none

  std::size_t pixels() const { return static_cast<std::size_t>(width) * static_cast<std::size_t>(height); }
};

struct RenderOptions {
  int samplesPerPixel = 1;  ///< stratified; 1 = the pixel centre
  int threads = 0;          ///< 0 = all hardware threads
  int tileSize = 16;        ///< pixels
  ShadingOptions shading;
  /// Called with the fraction of tiles done, from worker threads (never concurrently).
  std::function<void(double)> progress;
};

struct RenderStats {
  double seconds = 0;
  int threads = 0;               ///< worker threads used
  std::int64_t primaryRays = 0;  ///< camera rays (samples plus one centre ray per pixel when spp > 1)
  std::int64_t shadowRays = 0;
  std::int64_t hitPixels = 0;               ///< pixels with A > 0
  double curvatureLo = 0, curvatureHi = 0;  ///< range used by the curvature colour map (curvature mode)
};

/// Sub-pixel position in [0,1)^2 of sample `s` of `spp` in pixel (x, y): stratum (s mod m, s div m) of an m x
/// r grid (m = ceil(sqrt(spp)), r = ceil(spp / m)), jittered by a hash of (x, y, s). spp = 1 gives the centre
/// (0.5, 0.5).
std::pair<double, double> samplePosition(int x, int y, int s, int spp);

/// Renders `scene` seen by `camera`. Curvature mode: the colour map range is options.shading.curvatureRange
/// or, if unset, symmetric about 0 with the 90th percentile of |curvature| over hit pixels; stats gets the
/// range used.
RenderImage render(const RenderScene& scene, const Camera& camera, const RenderOptions& options,
                   RenderStats* stats = nullptr);

}  // namespace cip::raycast
