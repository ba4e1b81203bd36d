/// @file dense_grid.h
/// @brief A dense scalar grid: the sampled volume the model is built from.
///
/// Coordinates used throughout cip:
///  - index coordinates: grid point (i,j,k) sits at (i,j,k); x fastest in memory.
///  - world coordinates: world = origin + spacing * index (component-wise; axis-aligned grids only).
///  - cell-local coordinates: cell (i,j,k) is the unit cube [0,1]^3 at index offset (i,j,k).
#pragma once
#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace cip {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

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

/// Dense scalar samples on a GridGeometry, stored as double, x fastest.
struct DenseGrid {
  GridGeometry geometry;
  std::vector<double> values;  ///< size = geometry.pointCount()
  std::string description;  ///< where the data came from (file name, field name), stored in the model header

  std::int64_t index(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return i + geometry.dims[0] * (j + geometry.dims[1] * k);
  }
  double at(std::int64_t i, std::int64_t j, std::int64_t k) const { return values[index(i, j, k)]; }
  double& at(std::int64_t i, std::int64_t j, std::int64_t k) { return values[index(i, j, k)]; }

  /// Allocates dims[0]*dims[1]*dims[2] zeros; throws cip::Error when the product overflows or the size is
  /// absurd (over `maxBytes`), naming the size, before allocating anything.
  void allocate(const std::array<std::int64_t, 3>& dims, std::size_t maxBytes = defaultMaxBytes());
  /// Smallest and largest finite value (NaN and infinities skipped).
  std::pair<double, double> range() const;
  /// Number of NaN or infinite samples.
  std::int64_t nonFiniteCount() const;

  /// Memory limit for one grid: 3/4 of physical memory.
  static std::size_t defaultMaxBytes();
};

/// Checked product of three non-negative extents; throws cip::Error naming the dims if any is negative or the
/// product (times bytesPerElement) overflows 64 bits or exceeds maxBytes.
std::int64_t checkedVolumeSize(const std::array<std::int64_t, 3>& dims, std::size_t bytesPerElement,
                               std::size_t maxBytes);

}  // namespace cip
