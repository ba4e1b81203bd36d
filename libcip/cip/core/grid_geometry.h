/// @file grid_geometry.h
/// @brief Where a grid of samples sits in the world: its points per axis, origin and spacing.
///
/// Coordinates used throughout cip:
///  - index coordinates: grid point (i,j,k) sits at (i,j,k); x fastest in memory.
///  - world coordinates: world = origin + spacing * index (component-wise; axis-aligned grids only).
///  - cell-local coordinates: cell (i,j,k) is the unit cube [0,1]^3 at index offset (i,j,k).
#pragma once
#include <array>
#include <cstdint>

#include "cip/core/vec3.h"

namespace cip {

/// Grid placement shared by grids and models: number of grid points per axis, world origin of point (0,0,0),
/// and world spacing between neighbouring points per axis.
struct GridGeometry {
  std::array<std::int64_t, 3> dims{0, 0, 0};  ///< grid points per axis (cells per axis = dims - 1)
  Vec3 origin = Vec3::Zero();                 ///< world position of grid point (0,0,0)
  Vec3 spacing = Vec3::Ones();                ///< world distance between neighbouring points, per axis (> 0)

  Vec3 indexToWorld(const Vec3& index) const { return origin + spacing.cwiseProduct(index); }
  Vec3 worldToIndex(const Vec3& world) const { return (world - origin).cwiseQuotient(spacing); }
  std::int64_t pointCount() const { return dims[0] * dims[1] * dims[2]; }
};

}  // namespace cip
