/// @file dense_grid.h
/// @brief A dense scalar grid: the sampled volume the model is built from (coordinates: grid_geometry.h).
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "cip/core/grid_geometry.h"

namespace cip {

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

/// Smallest and largest finite value of values[0, n) (NaN and infinities skipped; infinity and -infinity when
/// none is finite), branch-free in four independent lanes.
std::pair<double, double> finiteRange(const double* values, std::size_t n);

/// Checked product of three non-negative extents; throws cip::Error naming the dims if any is negative or the
/// product (times bytesPerElement) overflows 64 bits or exceeds maxBytes.
std::int64_t checkedVolumeSize(const std::array<std::int64_t, 3>& dims, std::size_t bytesPerElement,
                               std::size_t maxBytes);

}  // namespace cip
