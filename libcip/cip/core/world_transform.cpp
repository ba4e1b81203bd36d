#include "cip/core/world_transform.h"

#include <cctype>
#include <string>

#include "cip/core/error.h"

namespace cip {

namespace {

/// Signs of the axes of an anatomical frame relative to RAS.
Vec3 signsFromRas(WorldSpace space) {
  switch (space) {
    case WorldSpace::LAS:
      return Vec3(-1, 1, 1);
    case WorldSpace::LPS:
      return Vec3(-1, -1, 1);
    case WorldSpace::RAS:
    case WorldSpace::Unspecified:
      break;
  }
  return Vec3(1, 1, 1);
}

}  // namespace

WorldTransform WorldTransform::of(const GridGeometry& g, WorldSpace output) {
  WorldTransform t;
  Mat3 change = Mat3::Identity();
  t.space = g.space;
  if (output != WorldSpace::Unspecified && output != g.space) {
    if (g.space == WorldSpace::Unspecified)
      throw Error(std::string("cannot give coordinates in ") + toString(output) +
                  ": the volume does not say which anatomical frame its coordinates are in");
    change = signsFromRas(output).cwiseProduct(signsFromRas(g.space)).asDiagonal();
    t.space = output;
  }
  // world = change * (origin + direction * (frame - origin))
  t.linear = change * g.direction;
  t.offset = change * g.origin - t.linear * g.origin;
  t.inverse = t.linear.inverse();
  t.normalMatrix = t.inverse.transpose();
  return t;
}

Eigen::Matrix4d WorldTransform::indexToWorld(const GridGeometry& g) const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = linear * g.spacing.asDiagonal();
  m.topRightCorner<3, 1>() = point(g.origin);
  return m;
}

WorldSpace parseWorldSpace(const std::string& name) {
  std::string n;
  for (char c : name) n += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (n == "ras") return WorldSpace::RAS;
  if (n == "las") return WorldSpace::LAS;
  if (n == "lps") return WorldSpace::LPS;
  throw Error("unknown world space '" + name + "' (expected ras, las or lps)");
}

}  // namespace cip
