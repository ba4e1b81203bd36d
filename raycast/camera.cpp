#include "camera.h"

#include <algorithm>
#include <cmath>

#include "cip/core/error.h"

namespace cip::raycast {

namespace {
constexpr double kPi = 3.14159265358979323846;
}

Vec3 defaultViewDirection() {
  return Vec3(0.6, -1.0, 0.7).normalized();
}

Camera::Camera(const Vec3& eye, const Vec3& look, const Vec3& up, double fovDegrees, bool orthographic,
               int width, int height)
    : eye_(eye),
      look_(look),
      fovDegrees_(fovDegrees),
      orthographic_(orthographic),
      width_(width),
      height_(height) {
  if (width < 1 || height < 1) throw Error("image size must be at least 1x1");
  if (!(fovDegrees > 0 && fovDegrees < 180)) throw Error("field of view must be between 0 and 180 degrees");
  const Vec3 view = look - eye;
  if (!(view.norm() > 0) || !view.allFinite()) throw Error("camera eye and look point must differ");
  forward_ = view.normalized();
  right_ = forward_.cross(up);
  if (!(right_.norm() > 1e-12 * up.norm()) || !right_.allFinite())
    throw Error("camera up direction must not be parallel to the view direction");
  right_.normalize();
  up_ = right_.cross(forward_);
  const double tanHalf = std::tan(0.5 * fovDegrees * kPi / 180.0);
  halfHeight_ = orthographic ? view.norm() * tanHalf : tanHalf;
}

Ray Camera::ray(double px, double py) const {
  // Image plane coordinates in [-aspect, aspect] x [-1, 1], y up.
  const double sx = (2.0 * px / width_ - 1.0) * static_cast<double>(width_) / height_;
  const double sy = 1.0 - 2.0 * py / height_;
  Ray r;
  if (orthographic_) {
    r.origin = eye_ + halfHeight_ * (sx * right_ + sy * up_);
    r.direction = forward_;
  } else {
    r.origin = eye_;
    r.direction = (forward_ + halfHeight_ * (sx * right_ + sy * up_)).normalized();
  }
  return r;
}

Camera makeCamera(const CameraSettings& s, const Box& frame, int width, int height) {
  const Vec3 look = s.look ? *s.look : frame.center();
  Vec3 eye;
  if (s.eye) {
    eye = *s.eye;
  } else {
    const double radius = std::max(frame.radius(), 1e-9);
    const double tanHalf = std::tan(0.5 * s.fovDegrees * kPi / 180.0);
    const double aspect = static_cast<double>(width) / std::max(height, 1);
    const double halfAngle = std::atan(tanHalf * std::min(1.0, aspect));  // the narrower image dimension
    const double distance = 1.05 * radius / std::sin(halfAngle);
    eye = look + distance * defaultViewDirection();
  }
  Vec3 up = s.up ? *s.up : Vec3::UnitZ();
  if (!s.up && std::abs((look - eye).normalized().dot(up)) > 0.999) up = Vec3::UnitY();
  return Camera(eye, look, up, s.fovDegrees, s.orthographic, width, height);
}

}  // namespace cip::raycast
