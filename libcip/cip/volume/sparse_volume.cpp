#include "cip/volume/sparse_volume.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "cip/core/error.h"

namespace cip {

SparseVolume fromDense(DenseGrid grid) {
  SparseVolume volume;
  volume.geometry = grid.geometry;
  volume.description = grid.description;
  volume.grids.push_back(std::move(grid));
  GridBrick brick;
  brick.grid = &volume.grids.front();
  for (int a = 0; a < 3; ++a) brick.cellEnd[a] = std::max<std::int64_t>(0, volume.geometry.dims[a] - 1);
  volume.bricks.push_back(brick);
  return volume;
}

const DenseGrid* SparseVolume::dense() const {
  if (bricks.size() != 1 || grids.size() != 1) return nullptr;
  const GridBrick& b = bricks.front();
  for (int a = 0; a < 3; ++a) {
    if (b.offset[a] != 0 || b.cellBegin[a] != 0 || b.grid->geometry.dims[a] != geometry.dims[a] ||
        b.cellEnd[a] != std::max<std::int64_t>(0, geometry.dims[a] - 1)) {
      return nullptr;
    }
  }
  return b.grid;
}

std::int64_t SparseVolume::ownedCellCount() const {
  std::int64_t n = 0;
  for (const auto& b : bricks) {
    std::int64_t c = 1;
    for (int a = 0; a < 3; ++a) c *= std::max<std::int64_t>(0, b.cellEnd[a] - b.cellBegin[a]);
    n += c;
  }
  return n;
}

std::pair<double, double> SparseVolume::range() const {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto& g : grids) {
    auto r = g.range();
    lo = std::min(lo, r.first);
    hi = std::max(hi, r.second);
  }
  if (!dense() && std::isfinite(background)) {
    lo = std::min(lo, background);
    hi = std::max(hi, background);
    if (isLevelSet) lo = std::min(lo, -background);  // inside a narrow band the tree holds -background
  }
  return {lo, hi};
}

std::size_t SparseVolume::sampleBytes() const {
  std::size_t n = 0;
  for (const auto& g : grids) n += g.values.size() * sizeof(double);
  return n;
}

std::vector<std::int64_t> labelsOf(const SparseVolume& volume) {
  std::vector<std::int64_t> labels;
  for (const GridBrick& b : volume.bricks) {
    for (const double v : b.grid->values) {
      if (!(std::abs(v) < 9e15) || v != std::round(v))
        throw Error("labels need a label map (integer samples); found " + std::to_string(v));
      const auto l = static_cast<std::int64_t>(v);
      if (l != 0 && (labels.empty() || labels.back() != l) &&
          !std::binary_search(labels.begin(), labels.end(), l))
        labels.insert(std::upper_bound(labels.begin(), labels.end(), l), l);
    }
  }
  return labels;
}

}  // namespace cip
