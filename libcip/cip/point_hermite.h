/// @file point_hermite.h
/// @brief The reference's Hermite data at grid points (tricubic_reference.h): the sample and its first, mixed
/// and triple derivatives there, computed box by box with one pass per axis.
///
/// Every entry of a cell's Hermite data depends only on the samples around one of its corners, so the cells
/// and edges that share a grid point share its data. Computed per cell, Reconstruction::Central8 reads the
/// 10^3 samples around the cell and repeats the work of its neighbours; PointHermiteTable computes the data
/// of every point a model needs once, over boxes of neighbouring points, and buildModel takes its cells' and
/// edges' data from it. Per cell and per table the arithmetic is the same, so both give the same numbers.
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "cip/dense_grid.h"
#include "cip/tricubic_reference.h"

namespace cip {

/// The data at `count` points of the box of grid points lo + [0, size) per axis (the box inside the grid),
/// given box-local in `at`, written to `out`. The passes run over the whole box (x, then y, then z), so a box
/// pays off when its points are dense. Samples beyond the grid as tricubicReference says (odd reflection
/// through the border point, reaching referenceReach(kind) points). `kind` must be resolved (not Auto).
void hermiteInBox(const DenseGrid& grid, Reconstruction kind, const std::array<std::int64_t, 3>& lo,
                  const std::array<int, 3>& size, const std::array<int, 3>* at, std::size_t count,
                  PointHermite* out);

/// A cell's Hermite data in CellReference::hermite's layout from its corners' data, corner index
/// x + 2 y + 4 z as in cube_topology.h.
void cellHermite(const std::array<const PointHermite*, 8>& corners, std::array<double, 64>& out);

/// The reference's data at a set of points of one grid, for a whole model: computed in parallel over tiles of
/// the grid (each tile over the bounding box of its points), looked up by a rank over a bit per grid point
/// (a bit and a half per grid point besides the data).
class PointHermiteTable {
 public:
  PointHermiteTable() = default;
  /// The data at the corners of the given cells (each its lowest point's grid.index; the cell inside the
  /// grid). The grid must outlive the table.
  PointHermiteTable(const DenseGrid& grid, const std::vector<std::int64_t>& cells, Reconstruction kind);

  /// The data at grid point `index` (grid.index), which must be a corner of one of the table's cells (throws
  /// Error otherwise).
  const PointHermite& at(std::int64_t index) const;
  /// The reference of one of the table's cells, given by its lowest point, written into `ref` as
  /// setTricubicReference does (every member set; metric to ones). Throws Error for a cell not in the table.
  void setReference(const std::array<std::int64_t, 3>& cell, double isovalue, CellReference& ref) const;
  std::size_t size() const { return data_.size(); }

 private:
  bool holds(std::int64_t index) const;
  std::size_t rank(std::int64_t index) const;  ///< of a point held
  const DenseGrid* grid_ = nullptr;
  std::vector<std::uint64_t> present_;  ///< bit per grid point (grid.index order)
  std::vector<std::uint32_t> before_;   ///< points present in the words before each word of present_
  std::vector<PointHermite> data_;      ///< in grid.index order of the points present
};

}  // namespace cip
