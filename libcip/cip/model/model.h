/// @file model.h
/// @brief A corner-patch model: the isovertex (corner plane) table shared across cells, and per non-empty
/// cell its loops as indices into that table, its bounding faces and its coefficients.
#pragma once
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cip/core/grid_geometry.h"
#include "cip/core/world_transform.h"
#include "cip/patch/corner_patch.h"
#include "cip/reference/isovertex.h"
#include "cip/reference/reconstruction.h"
#include "cip/topology/cell_loops.h"

namespace cip {

/// One non-empty cell.
struct ModelCell {
  std::array<std::uint32_t, 3> index{};     ///< cell (i,j,k): its lowest grid point, index coordinates
  std::uint8_t config = 0;                  ///< sign configuration (bit v: vertex v has value > isovalue)
  std::uint8_t pairing03 = 0;               ///< ambiguous-face pairings (cell_loops.h)
  std::uint8_t numLoops = 0;                ///< 1..4
  std::array<std::uint8_t, 4> loopSize{};   ///< corners per loop
  std::uint32_t firstCorner = 0;            ///< offset into Model::corners
  std::array<double, 6> faceCoefficient{};  ///< w_f per face (0 for faces that are not bounding planes)
  double central = 0;                       ///< central coefficient w

  int numCorners() const { return loopSize[0] + loopSize[1] + loopSize[2] + loopSize[3]; }
};

/// How the patch coefficients were chosen (stored in the model so results are reproducible).
enum class PatchMethod : std::uint8_t {
  Paper = 0,   ///< corner coefficients 1, side coefficients by the triangle/tetragon rule + eq. 5, central 0
               ///< or eq. 6
  Fitted = 1,  ///< side and central coefficients fitted under sign constraints, normals blended where needed
               ///< (patch_fitting.h)
};
const char* toString(PatchMethod method);

struct Model {
  GridGeometry geometry;  ///< grid points, origin, spacing of the source volume
  double isovalue = 0;
  NormalMode normalMode = NormalMode::Gradient;
  PatchMethod method = PatchMethod::Paper;
  /// The reconstruction of the reference the fitted construction followed (Monotone or Central8, as Auto
  /// chose), when it followed one of the samples; empty for `paper` models, exact normals, and files written
  /// before it was recorded.
  std::optional<Reconstruction> reconstruction;
  std::string source;  ///< free text: where the volume came from

  std::vector<IsoVertex> vertices;  ///< shared corner planes (index coordinates)
  std::vector<ModelCell> cells;     ///< non-empty cells in increasing (k, j, i) order
  std::vector<std::uint32_t>
      corners;  ///< vertex index per corner: cell after cell, loop after loop, in loop order

  /// The loops of cell `c` (edges of each corner, faces), recomputed from its configuration and pairings.
  CellLoops loops(std::size_t c) const;
  /// The cell's patch in cell-local coordinates.
  CornerPatch patch(std::size_t c) const { return patch(c, loops(c)); }
  /// The same, with the cell's loops already at hand.
  CornerPatch patch(std::size_t c, const CellLoops& loops) const;
  /// Cell (i,j,k) origin in index coordinates.
  Vec3 cellOrigin(std::size_t c) const {
    return Vec3(cells[c].index[0], cells[c].index[1], cells[c].index[2]);
  }
  /// Index of the cell with grid index (i,j,k), or -1 if it is empty (binary search).
  std::int64_t findCell(std::int64_t i, std::int64_t j, std::int64_t k) const;
};

/// The sizes of a model's three tables, as a file's header gives them before anything is decoded, and the
/// memory those tables take once decoded: what a reader can say (or refuse) before it allocates.
struct ModelTableCounts {
  std::uint32_t version = 0;  ///< of the file the counts come from
  std::uint64_t vertices = 0;
  std::uint64_t cells = 0;
  /// Exact in version 1 files. Version 2 files do not store it: there it is the bound 4 x vertices (an
  /// isovertex lies on one grid edge, which at most four cells share), which closed surfaces reach.
  std::uint64_t corners = 0;
  bool cornersExact = true;
  /// Bytes of Model::vertices, cells and corners holding these counts.
  std::uint64_t tableBytes() const {
    return vertices * sizeof(IsoVertex) + cells * sizeof(ModelCell) + corners * sizeof(std::uint32_t);
  }
};

/// World box (lo, hi) of the model's non-empty cells under `world` (tight: each cell's box is mapped as a
/// box, so a rotated grid gets the box of its rotated cells); the mapped grid origin twice when the model
/// is empty.
std::pair<Vec3, Vec3> worldBounds(const Model& model, const WorldTransform& world);

}  // namespace cip
