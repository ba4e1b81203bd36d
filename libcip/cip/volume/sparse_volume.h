/// @file sparse_volume.h
/// @brief A volume as dense bricks placed in one global grid: what every volume reader hands to buildModel.
///
/// Sparse inputs (OpenVDB) become bricks covering only the cells next to active voxels; dense inputs (raw,
/// NRRD, NIfTI) become one brick owning every cell (fromDense), so callers treat every input the same way:
///     buildModel(volume.geometry, volume.bricks, options, volume.description)
/// gives, for a dense input, exactly the model buildModel(grid, options) gives.
///
/// Geometry: `geometry` is the global grid (dims, world origin of global point (0,0,0), spacing per axis;
/// axis-aligned only). Each brick's DenseGrid holds the values of a box of global points starting at
/// brick.offset, including an apron of points around the cells it owns wherever the global grid has points
/// there (1 by default; brickApron(options) of the model builder for the build asked for),
/// so derivatives at the owned cells' corners match those of the whole volume. Each cell is owned by at most
/// one brick.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cip/volume/dense_grid.h"

namespace cip {

/// A dense block of a possibly sparse volume. Bricks share their border points: each cell belongs to one
/// brick.
struct GridBrick {
  const DenseGrid* grid = nullptr;          ///< samples; only its values and dims are used
  std::array<std::int64_t, 3> offset{};     ///< global index of the brick's point (0,0,0)
  std::array<std::int64_t, 3> cellBegin{};  ///< first cell to build, brick-local index
  std::array<std::int64_t, 3> cellEnd{};    ///< one past the last cell to build, brick-local index
};

struct SparseVolume {
  GridGeometry geometry;          ///< global grid
  std::vector<DenseGrid> grids;   ///< brick samples; bricks[b].grid points to grids[b]
  std::vector<GridBrick> bricks;  ///< placement and owned cells of each brick
  std::string description;        ///< source file, grid name, type and dims (goes into the model's source)
  bool isLevelSet = false;        ///< signed distance data: extract at isovalue 0
  double background = 0;  ///< value of every point not covered by a brick (VDB background; 0 for dense)

  SparseVolume() = default;
  // Bricks point into `grids`: moving keeps the pointers valid (vector storage moves), copying would not.
  SparseVolume(SparseVolume&&) = default;
  SparseVolume& operator=(SparseVolume&&) = default;
  SparseVolume(const SparseVolume&) = delete;
  SparseVolume& operator=(const SparseVolume&) = delete;

  /// The whole volume when it came from a dense grid (one brick, all cells), else nullptr.
  const DenseGrid* dense() const;
  /// Number of cells owned by the bricks.
  std::int64_t ownedCellCount() const;
  /// Smallest and largest finite value over all brick samples (and the background, negated too for level
  /// sets, when the bricks do not cover the whole grid).
  std::pair<double, double> range() const;
  /// Total bytes of brick samples.
  std::size_t sampleBytes() const;
};

/// Wraps a dense grid as a one-brick volume owning every cell (no copy of the values).
SparseVolume fromDense(DenseGrid grid);

/// The non-zero labels of a label map (every brick sample an integer), in increasing order; throws
/// cip::Error naming the first sample that is not an integer. What `extract --labels` and the Python
/// module's `extract_labels` build one model each for.
std::vector<std::int64_t> labelsOf(const SparseVolume& volume);

}  // namespace cip
