/// @file camera.h
/// @brief Pinhole and orthographic cameras in world coordinates, and the default view that frames a box.
#pragma once
#include <Eigen/Geometry>
#include <optional>

#include "cip/core/vec3.h"

namespace cip::raycast {

/// A ray in world coordinates; `direction` has unit length, so ray parameters are world distances.
struct Ray {
  Vec3 origin = Vec3::Zero();
  Vec3 direction = Vec3::UnitZ();
};

/// Axis-aligned box in world coordinates.
struct Box {
  Vec3 lo = Vec3::Zero();
  Vec3 hi = Vec3::Zero();
  Vec3 center() const { return 0.5 * (lo + hi); }
  /// Radius of the bounding sphere (half the diagonal), world units.
  double radius() const { return 0.5 * (hi - lo).norm(); }
};

/// The direction from the framed box's centre towards the default eye: (0.6, -1.0, 0.7), normalised; up is
/// +z.
Vec3 defaultViewDirection();

/// What the user asked for; unset values are filled in by makeCamera.
struct CameraSettings {
  std::optional<Vec3> eye;   ///< world position of the eye
  std::optional<Vec3> look;  ///< world point the view is centred on
  std::optional<Vec3> up;    ///< world up direction (need not be orthogonal to the view)
  double fovDegrees = 35;    ///< vertical field of view (perspective); orthographic: view height at `look`
  bool orthographic = false;
};

class Camera {
 public:
  /// `fovDegrees`: vertical full angle in (0, 180). Orthographic views show a window whose height equals what
  /// the perspective view shows at the distance of `look` (2 |look - eye| tan(fov / 2) world units). Throws
  /// cip::Error for a degenerate eye/look/up or image size.
  Camera(const Vec3& eye, const Vec3& look, const Vec3& up, double fovDegrees, bool orthographic, int width,
         int height);

  /// Ray through the image point (px, py) in pixel units: (0, 0) is the top-left corner of the top-left
  /// pixel, (width, height) the bottom-right corner of the bottom-right pixel; pixel centres are at
  /// half-integers.
  Ray ray(double px, double py) const;

  const Vec3& eye() const { return eye_; }
  const Vec3& look() const { return look_; }
  const Vec3& forward() const { return forward_; }
  const Vec3& right() const { return right_; }
  const Vec3& up() const { return up_; }
  bool orthographic() const { return orthographic_; }
  int width() const { return width_; }
  int height() const { return height_; }
  double fovDegrees() const { return fovDegrees_; }

 private:
  Vec3 eye_, look_, forward_, right_, up_;
  double fovDegrees_;
  bool orthographic_;
  int width_, height_;
  double halfHeight_;  ///< perspective: tan(fov/2); orthographic: half the window height in world units
};

/// The camera from the settings; unset values default so that the box is framed: look = box centre, up = +z
/// (or +y when the view is along z), eye = look + d * defaultViewDirection() with d such that the bounding
/// sphere fits the narrower image dimension with a 5 % margin.
Camera makeCamera(const CameraSettings& settings, const Box& frame, int width, int height);

}  // namespace cip::raycast
