/// @file point_hermite.h
/// @brief The reference's Hermite data at grid points (tricubic_reference.h): the sample and its first, mixed
/// and triple derivatives there, computed box by box with one pass per axis.
///
/// Every entry of a cell's Hermite data depends only on the samples around one of its corners, so the cells
/// and edges that share a grid point share its data. Computed per cell, Reconstruction::Central8 reads the
/// 10^3 samples around the cell and repeats the work of its neighbours; PointHermiteTable
/// (point_hermite_table.h) computes the data of every point a model needs once, over boxes of neighbouring
/// points, and buildModel takes its cells' and edges' data from it. Per cell and per table the arithmetic is
/// the same, so both give the same numbers.
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "cip/reference/reconstruction.h"
#include "cip/volume/dense_grid.h"

namespace cip {

/// The reference's data at one grid point, index dx + 2 dy + 4 dz with d = 1 for a derivative along that
/// axis (per index unit): value, d/dx, d/dy, d2/dxdy, d/dz, d2/dxdz, d2/dydz, d3/dxdydz. A cell's Hermite
/// data are its 8 corners' (cellHermite).
using PointHermite = std::array<double, 8>;

/// How many sample points beyond a cell's corners, along each axis, the cell's reference and its edges'
/// isovertices read: 1 for Monotone (limited first differences, and mixed ones of those), 4 for Central8. A
/// brick of a sparse volume needs that many points around its cells for its references to be the whole
/// volume's (VdbReadOptions::apron); with fewer, its samples are extended at its border as at the volume's.
/// Auto: 4, enough for either (and for the estimate that chooses).
int referenceReach(Reconstruction kind);

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

}  // namespace cip
