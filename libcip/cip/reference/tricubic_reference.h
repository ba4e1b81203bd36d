/// @file tricubic_reference.h
/// @brief The reference field of sampled volumes: the tricubic Hermite interpolant of the samples, with
/// derivatives at grid points from limited central differences (Reconstruction::Monotone) or 8th-order ones
/// (Reconstruction::Central8).
///
/// The fitted construction places isovertices on it, takes corner normals from it and checks signs against
/// it (patch_fitting.h); the fidelity measures use it as the true surface of real volumes. Monotone is
/// monotone along grid lines, so its edge crossings are the marching-cubes configuration's; Central8 follows
/// smooth data far better but overshoots at steps. Both depend only on the samples around each grid point, so
/// the field is C1 across cells and linear fields are exact. docs/method.md ("The reference of sampled
/// volumes") has the details and measurements.
#pragma once
#include <array>
#include <cstdint>
#include <string>

#include "cip/reference/point_hermite.h"
#include "cip/volume/dense_grid.h"
#include "cip/volume/scalar_field.h"

namespace cip {

/// Cubic Hermite basis on [0, 1] for the data (value at 0, derivative at 0, value at 1, derivative at 1): the
/// weights w at t and, when d is not null, their derivatives.
void hermiteWeights(double t, double* w, double* d);

/// The reference scalar field (value - isovalue) near one cell, in cell-local index coordinates.
struct CellReference {
  /// Analytic field (world coordinates); when null, the tricubic Hermite interpolant in `hermite` is used.
  const ScalarField* field = nullptr;
  const GridGeometry* geometry = nullptr;
  Vec3 origin = Vec3::Zero();  ///< cell origin, index coordinates
  double isovalue = 0;
  /// Per-axis factors turning index-space gradient components into gradients per smallest grid spacing: the
  /// sign checks measure distances in smallest voxels (spacing.minCoeff() / spacing), as countSpuriousCells
  /// does.
  Vec3 metric = Vec3::Ones();
  /// Hermite data of the cell, index i + 4 (j + 4 k) with one index per axis: 0 = at local coordinate 0,
  /// 1 = derivative (per index unit) at 0, 2 = at 1, 3 = derivative at 1. Entry (0, 0, 0) is the sample at
  /// the cell origin, (1, 0, 0) the x-derivative there, (1, 1, 0) the xy mixed derivative, and so on. The
  /// field is sum over i, j, k of hermite[i + 4 (j + 4 k)] w_i(x) w_j(y) w_k(z) with hermiteWeights.
  std::array<double, 64> hermite{};

  double value(const Vec3& local) const;
  /// Gradient per local (index) unit.
  Vec3 gradient(const Vec3& local) const;
  /// value and gradient at once (cheaper than both apart).
  double valueAndGradient(const Vec3& local, Vec3& gradient) const;
};

/// The reference of one cell of a dense grid: `cell` is the cell's lowest point in the grid's own indices.
/// Samples beyond the grid: with Monotone, one point extrapolated linearly along that axis; with Central8,
/// odd reflection (both keep linear fields exact).
CellReference tricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell,
                                double isovalue, Reconstruction kind = Reconstruction::Monotone);
/// tricubicReference written into `ref` (every member set; metric to ones), which spares copying its Hermite
/// data where references are kept in an array.
void setTricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell, double isovalue,
                          CellReference& ref, Reconstruction kind = Reconstruction::Monotone);

/// The reference interpolant of a dense grid as a field in world coordinates, usable with
/// countSpuriousCells and measureFidelity. Points outside the grid are evaluated in the nearest cell
/// (extrapolated). The grid must outlive the field and keep its values. Each thread keeps the Hermite data of
/// the last cell it evaluated, so runs of points in one cell (lattices, Newton steps) build it once.
class TricubicInterpolant : public ScalarField {
 public:
  explicit TricubicInterpolant(const DenseGrid& grid, Reconstruction kind = Reconstruction::Monotone);
  double value(const Vec3& world) const override;
  Vec3 gradient(const Vec3& world) const override;

 private:
  const CellReference& at(const Vec3& world, Vec3& local) const;
  const DenseGrid& grid_;
  Reconstruction kind_;
  std::uint64_t id_;  ///< tells this interpolant's cached cell from another's
};

/// Isovertex on the grid edge from `point` (grid indices) along `axis`: the root of the reference along the
/// edge (a monotone cubic there with Reconstruction::Monotone; the root nearest the linear crossing should
/// there be several), and the reference's gradient at it (index space, oriented with orientCornerNormal). The
/// end values must bracket the isovalue. Returns the edge parameter in [0,1] and sets `normal`. Both depend
/// only on the samples around the edge, so the four cells sharing it agree.
double cubicEdgeVertex(const DenseGrid& grid, const std::array<std::int64_t, 3>& point, int axis,
                       double isovalue, Vec3& normal, Reconstruction kind = Reconstruction::Monotone);
/// cubicEdgeVertex from the reference's data at the edge's ends, `start` at the lower one (as buildModel
/// takes them from a PointHermiteTable).
double cubicEdgeVertex(const PointHermite& start, const PointHermite& end, int axis, double isovalue,
                       Vec3& normal);

}  // namespace cip
