#include "cip/core/grid_geometry.h"

#include <cmath>
#include <string>

#include "cip/core/error.h"

namespace cip {

const char* toString(WorldSpace space) {
  switch (space) {
    case WorldSpace::RAS:
      return "RAS";
    case WorldSpace::LAS:
      return "LAS";
    case WorldSpace::LPS:
      return "LPS";
    case WorldSpace::Unspecified:
      break;
  }
  return "unspecified";
}

void setAxes(GridGeometry& geometry, const Mat3& columns, const char* what) {
  if (!columns.allFinite()) throw Error(std::string(what) + ": the index-to-world matrix is not finite");
  Mat3 direction;
  Vec3 spacing;
  for (int a = 0; a < 3; ++a) {
    spacing[a] = columns.col(a).norm();
    if (!(spacing[a] > 0) || !std::isfinite(spacing[a]))
      throw Error(std::string(what) + ": index axis " + std::to_string(a) + " has no length in the world");
    direction.col(a) = columns.col(a) / spacing[a];
  }
  if (!(std::abs(direction.determinant()) >= 1e-6))
    throw Error(std::string(what) + ": the index-to-world matrix is singular (axes are linearly dependent)");
  geometry.spacing = spacing;
  geometry.direction = direction;
}

}  // namespace cip
