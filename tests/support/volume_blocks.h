// Test helpers: a volume file read as one dense grid, and a block of a grid.
#pragma once
#include <array>
#include <cstdint>
#include <string>

#include "cip/readers/volume_reader.h"
#include "cip/volume/dense_grid.h"

namespace cip::test {

inline DenseGrid readVolumeDense(const std::string& path) {
  VolumeReadOptions read;
  read.brickCells = 1 << 20;  // an OpenVDB grid as one brick over its active box
  SparseVolume v = readVolume(path, read);
  return *v.dense();
}

/// The block of `size` points from `begin` (grid indices), placed where it was in the world.
inline DenseGrid crop(const DenseGrid& g, std::array<std::int64_t, 3> begin,
                      std::array<std::int64_t, 3> size) {
  DenseGrid out;
  out.geometry = g.geometry;
  out.allocate(size);
  for (int a = 0; a < 3; ++a)
    out.geometry.origin[a] = g.geometry.origin[a] +
                             static_cast<double>(begin[static_cast<std::size_t>(a)]) * g.geometry.spacing[a];
  for (std::int64_t k = 0; k < size[2]; ++k)
    for (std::int64_t j = 0; j < size[1]; ++j)
      for (std::int64_t i = 0; i < size[0]; ++i)
        out.at(i, j, k) = g.at(begin[0] + i, begin[1] + j, begin[2] + k);
  return out;
}

}  // namespace cip::test
