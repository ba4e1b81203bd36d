#include "cip/ray/open_face_cap.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

/// The cap at the ray's crossing of `face` at parameter t, if the region above the isovalue begins or ends
/// there.
std::optional<FaceCap> capAt(const CornerPatch& patch, std::uint8_t config, const Vec3& origin,
                             const Vec3& direction, double t, int face, const AcrossFaceSign& across) {
  if ((patch.faceMask >> face) & 1) return std::nullopt;  // a bounding plane: the neighbour continues it
  Vec3 point = origin + t * direction;
  const int axis = cube::faceAxis(face);
  for (int a = 0; a < 3; ++a) point[a] = std::clamp(point[a], 0.0, 1.0);
  point[axis] = cube::faceSide(face);
  const double value = patch.value(point);
  if (value == 0) return std::nullopt;
  const bool positive = value > 0;
  const bool cornersPositive = (config >> cube::faceVertex(face, 0)) & 1;  // the four share it
  if (positive == cornersPositive) return std::nullopt;
  if (across && (across(face, point) > 0) == positive) return std::nullopt;
  return FaceCap{t, face, positive};
}

}  // namespace

FaceCaps openFaceCaps(const CornerPatch& patch, std::uint8_t config, const Vec3& origin,
                      const Vec3& direction, double tMin, double tMax, const AcrossFaceSign& across,
                      std::uint8_t sealed) {
  const std::uint8_t skip = static_cast<std::uint8_t>(patch.faceMask | sealed);
  if (skip == 0x3F) return {};  // every face a bounding plane or sealed
  // The unpadded slabs of the unit cube: the entry is the last slab entered, the exit the first one left.
  double tIn = -std::numeric_limits<double>::infinity(), tOut = std::numeric_limits<double>::infinity();
  int faceIn = -1, faceOut = -1;
  for (int a = 0; a < 3; ++a) {
    if (direction[a] == 0) {
      if (origin[a] < 0 || origin[a] > 1) return {};
      continue;
    }
    const double t0 = (0 - origin[a]) / direction[a], t1 = (1 - origin[a]) / direction[a];
    const bool increasing = direction[a] > 0;
    const double near = increasing ? t0 : t1, far = increasing ? t1 : t0;
    if (near > tIn) {
      tIn = near;
      faceIn = 2 * a + (increasing ? 0 : 1);
    }
    if (far < tOut) {
      tOut = far;
      faceOut = 2 * a + (increasing ? 1 : 0);
    }
  }
  FaceCaps caps;
  if (!(tIn <= tOut)) return caps;
  if (faceIn >= 0 && !((skip >> faceIn) & 1) && tIn >= tMin && tIn <= tMax)
    caps.entry = capAt(patch, config, origin, direction, tIn, faceIn, across);
  if (faceOut >= 0 && !((skip >> faceOut) & 1) && tOut >= tMin && tOut <= tMax && tOut > tIn)
    caps.exit = capAt(patch, config, origin, direction, tOut, faceOut, across);
  return caps;
}

Vec3 capNormal(const FaceCap& cap) {
  // The face's inward normal points into the cell; the normal points towards the positive side.
  Vec3 inward = Vec3::Zero();
  inward[cube::faceAxis(cap.face)] = cube::faceSide(cap.face) == 0 ? 1.0 : -1.0;
  return cap.positiveInside ? inward : Vec3(-inward);
}

}  // namespace cip
