/// @file shading.h
/// @brief Surface shading modes: lit (Phong), cell colours, normals, depth, mean curvature and isophotes.
/// All colours are linear RGB in [0, 1].
#pragma once
#include <optional>
#include <string>
#include <utility>

#include "scene.h"

namespace cip::raycast {

enum class ShadingMode { Phong, Cells, Normal, Depth, Curvature, Isophotes };

/// Parses phong, cells, normal, depth, curvature or isophotes; throws cip::Error otherwise.
ShadingMode parseShadingMode(const std::string& name);
const char* toString(ShadingMode mode);

struct ShadingOptions {
  ShadingMode mode = ShadingMode::Phong;
  bool shadows = false;  ///< key light casts shadows (one shadow ray per shaded sample)
  /// Mean curvature (1 / world units) mapped to the ends of the colour map; unset: chosen from the image.
  std::optional<std::pair<double, double>> curvatureRange;
  int isophoteBands = 12;  ///< stripes over n.l in [0, 1]
};

/// Per-view constants of the shading: the lights follow the camera (key light above left of the eye, fill
/// light to the right), so every view is lit the same way.
struct ShadingFrame {
  Vec3 keyLight;     ///< unit direction towards the key light (world)
  Vec3 fillLight;    ///< unit direction towards the fill light (world)
  Vec3 eye;          ///< camera position (orthographic: a point on the image plane)
  Vec3 forward;      ///< camera view direction
  double depthNear;  ///< depth shading: distance mapped to white
  double depthFar;   ///< depth shading: distance mapped to black
  double rayOffset;  ///< shadow-ray start offset along the normal (world units)
};

ShadingFrame makeShadingFrame(const Camera& camera, const Box& sceneBounds);

/// The shaded sample: colour, and for the curvature mode the lighting factor the colour map is later
/// multiplied by.
struct ShadedSample {
  Vec3 rgb = Vec3::Zero();
  double light = 1;  ///< diffuse lighting factor in [0, 1]
};

/// Shades one hit seen along `ray`. Uses `scene` only for shadow rays. Curvature mode returns the lighting
/// factor only (the colour is applied per pixel once the curvature range is known, see curvatureColour).
/// `shadowRays` is incremented for each shadow ray cast.
ShadedSample shade(const SurfaceHit& hit, const Ray& ray, const RenderScene& scene, const ShadingFrame& frame,
                   const ShadingOptions& options, std::int64_t& shadowRays);

/// Diverging colour map: blue (lo) - white (mid-range) - red (hi); values outside the range are clamped.
Vec3 curvatureColour(double curvature, double lo, double hi);

/// Cell colour: two palettes alternating with the parity of i+j+k (face neighbours always differ), the shade
/// within a palette from a hash of the index. For hits without a cell index, a colour from a hash of the id.
Vec3 cellColour(const SurfaceHit& hit);

}  // namespace cip::raycast
