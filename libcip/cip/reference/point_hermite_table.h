/// @file point_hermite_table.h
/// @brief The reference's Hermite data at every grid point a model needs, computed once and shared by the
/// cells and edges around each point (point_hermite.h computes them).
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "cip/core/collective.h"
#include "cip/reference/point_hermite.h"
#include "cip/reference/tricubic_reference.h"
#include "cip/volume/dense_grid.h"

namespace cip {

/// The reference's data at a set of points of one grid, for a whole model: computed in parallel over tiles of
/// the grid (each tile over the bounding box of its points), looked up by a rank over a bit per grid point
/// (a bit and a half per grid point besides the data).
class PointHermiteTable {
 public:
  PointHermiteTable() = default;
  /// The data at the corners of the given cells (each its lowest point's grid.index; the cell inside the
  /// grid). The table keeps no reference to the grid. With `ranks` (every rank calling with the same
  /// arguments), each rank computes its rankShare of the z-layers of tiles and the ranks exchange them: the
  /// same table.
  PointHermiteTable(const DenseGrid& grid, const std::vector<std::int64_t>& cells, Reconstruction kind,
                    const Collective* ranks = nullptr);

  /// Drops the words of the bit per grid point that hold no point, so that what the table keeps is
  /// proportional to its points, not to the grid (a streamed build keeps one table per slab of the volume);
  /// lookups then search the words left (a binary search instead of an index).
  void compact();

  /// The data at grid point `index` (grid.index), which must be a corner of one of the table's cells (throws
  /// Error otherwise).
  const PointHermite& at(std::int64_t index) const;
  /// The reference of one of the table's cells, given by its lowest point, written into `ref` as
  /// setTricubicReference does (every member set; metric to ones). Throws Error for a cell not in the table.
  void setReference(const std::array<std::int64_t, 3>& cell, double isovalue, CellReference& ref) const;
  std::size_t size() const { return data_.size(); }

  /// The table as bytes (appendVector, collective.h), for the ranks of a streamed build to exchange their
  /// slabs' tables, and the table back from them (throws cip::Error for bytes that end early).
  void appendTo(std::vector<std::uint8_t>& out) const;
  static PointHermiteTable readFrom(ByteReader& in);

 private:
  bool holds(std::int64_t index) const;
  std::size_t rank(std::int64_t index) const;  ///< of a point held
  /// Points held before grid point `index` (<= size()); before compact() only (the constructor uses it).
  std::size_t heldBelow(std::int64_t index) const;
  /// The word of present_ holding grid point `index`'s bit, or -1 when no word holds it.
  std::ptrdiff_t wordOf(std::int64_t index) const;
  std::array<std::int64_t, 3> dims_{0, 0, 0};  ///< of the grid
  std::vector<std::uint64_t> present_;  ///< bit per grid point (grid.index order); compact: nonzero words
  std::vector<std::uint64_t> words_;    ///< compact: which word of the bit per grid point each one is
  bool compact_ = false;
  std::vector<std::uint32_t> before_;  ///< points present in the words before each word of present_
  std::vector<PointHermite> data_;     ///< in grid.index order of the points present
};

}  // namespace cip
