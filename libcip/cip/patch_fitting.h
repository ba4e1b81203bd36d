/// @file patch_fitting.h
/// @brief The fitted corner-patch construction (PatchMethod::Fitted): side and central coefficients fitted to
/// a reference surface under sign constraints, with corner-plane normals blended towards the edge direction
/// only where a face or cell cannot be made sign-correct.
///
/// Reference: the analytic field (NormalMode::Exact), else the Catmull-Rom tricubic interpolant of the
/// samples. Every decision uses data that all cells sharing it see identically:
///  - isovertex (NormalMode::Gradient): root of the Catmull-Rom cubic along the grid edge, normal = gradient
///  of the
///    tricubic interpolant there (a function of the grid edge's neighbourhood only, shared by its 4 cells);
///  - side coefficient w_f: computed once per grid face from the reference on that face, in the face's
///  canonical
///    frame (faceCrossingsOf), and copied to both cells;
///  - central coefficient: per cell.
/// On each face, w_f is the least-squares fit of the face curve to reference face-curve points, clamped into
/// the interval of w for which the face restriction has the reference's sign at every face sample lying more
/// than a margin from the reference surface. In each cell the central coefficient is fitted to interior
/// reference surface points and clamped into the interval that keeps the reference's sign at interior lattice
/// points away from the surface. When an interval is empty, the face or cell fails, and the normals of all
/// its isovertices move one step from the gradient towards the edge direction (blend levels, shared per
/// isovertex); the affected faces and cells are recomputed. Rounds are deterministic (decisions of a round
/// depend only on the previous round's state), so the result does not depend on the number of threads.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "cip/model.h"

namespace cip {

/// The reference scalar field (value - isovalue) near one cell, in cell-local index coordinates.
struct CellReference {
  /// Analytic field (world coordinates); when null, the tricubic interpolant of `samples` is used.
  const ScalarField* field = nullptr;
  const GridGeometry* geometry = nullptr;
  Vec3 origin = Vec3::Zero();  ///< cell origin, index coordinates
  double isovalue = 0;
  /// Per-axis factors turning index-space gradient components into gradients per smallest grid spacing: the
  /// sign checks measure distances in smallest voxels (spacing.minCoeff() / spacing), as countSpuriousCells
  /// does.
  Vec3 metric = Vec3::Ones();
  /// Samples at cell-local grid points -1..2 per axis (x fastest), extended linearly one point beyond the
  /// grid.
  std::array<double, 64> samples{};

  double value(const Vec3& local) const;
  /// Gradient per local (index) unit.
  Vec3 gradient(const Vec3& local) const;
};

/// Gathers a cell's tricubic stencil from a dense grid: `cell` is the cell's lowest point in the grid's own
/// indices; a point one step outside the grid is extrapolated linearly along that axis (linear fields stay
/// exact).
CellReference tricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell,
                                double isovalue);

/// The Catmull-Rom tricubic interpolant of a dense grid as a field in world coordinates: the reference
/// surface of PatchMethod::Fitted for sampled volumes, usable with countSpuriousCells and measureFidelity.
/// Points outside the grid are evaluated in the nearest cell (extrapolated). The grid must outlive the field.
class TricubicInterpolant : public ScalarField {
 public:
  explicit TricubicInterpolant(const DenseGrid& grid) : grid_(grid) {}
  double value(const Vec3& world) const override;
  Vec3 gradient(const Vec3& world) const override;

 private:
  CellReference at(const Vec3& world, Vec3& local) const;
  const DenseGrid& grid_;
};

/// Isovertex on the grid edge from `point` (grid indices) along `axis`: the root of the Catmull-Rom cubic
/// through the four samples along the edge's line nearest to the linear crossing, and the gradient of the
/// Catmull-Rom tricubic interpolant there (index space, oriented with orientCornerNormal). The end values
/// must bracket the isovalue. Returns the edge parameter in [0,1] and sets `normal`.
double cubicEdgeVertex(const DenseGrid& grid, const std::array<std::int64_t, 3>& point, int axis,
                       double isovalue, Vec3& normal);

struct FittingStats {
  int rounds = 0;                   ///< rounds run (1 = no face or cell needed a blended normal)
  std::size_t blendedVertices = 0;  ///< isovertices whose normal left the gradient
  std::size_t failedFaces = 0;      ///< faces still without a sign-correct coefficient at the last level
  std::size_t failedCells = 0;      ///< cells still without a sign-correct central coefficient
  std::array<std::size_t, 5> levelCount{};  ///< isovertices per final blend level
  /// Cells (model indices, ascending) that end without a sign-correct central coefficient or touch a face
  /// that ends without a sign-correct side coefficient: where the checks could not be met.
  std::vector<std::uint32_t> unresolvedCells;
};

/// Replaces the side and central coefficients and the corner-plane normals of a model built with the paper's
/// construction (loops, pairings and isovertex positions are kept). `reference(c)` returns the reference of
/// cell c; it is called concurrently. Runs in the caller's TBB arena.
FittingStats fitModelPatches(Model& model, const std::function<CellReference(std::size_t)>& reference);

}  // namespace cip
