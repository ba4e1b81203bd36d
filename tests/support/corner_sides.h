// Whether a model's patches keep the grid points of its cells on their samples' side of the isovalue: the
// property the mask's reference and the raised isovalue of integer samples must keep.
#pragma once

#include "cip/model/model.h"
#include "cip/volume/dense_grid.h"

namespace cip::test {

/// Grid points of crossed cells whose patch puts them on the other side than their sample: each corner of
/// each cell, 1e-4 voxel inside the cell (at the corner itself every face plane through it vanishes).
inline int wrongSideCorners(const Model& model, const DenseGrid& samples, double iso) {
  int wrong = 0;
  for (std::size_t c = 0; c < model.cells.size(); ++c) {
    const CornerPatch patch = model.patch(c);
    const auto& index = model.cells[c].index;
    for (int v = 0; v < 8; ++v) {
      const int d[3] = {v & 1, (v >> 1) & 1, v >> 2};
      const Vec3 local(d[0] ? 1 - 1e-4 : 1e-4, d[1] ? 1 - 1e-4 : 1e-4, d[2] ? 1 - 1e-4 : 1e-4);
      const bool inside = samples.at(index[0] + d[0], index[1] + d[1], index[2] + d[2]) > iso;
      if ((patch.value(local) > 0) != inside) ++wrong;
    }
  }
  return wrong;
}

}  // namespace cip::test
