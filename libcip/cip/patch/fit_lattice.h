/// @file fit_lattice.h
/// @brief The check lattices of the coefficient fits (face_fit.h, cell_fit.h): lattice axes and the Hermite
/// weights on them, the reference on a face's lattice, the squared bounding planes at lattice coordinates,
/// and the tests of how far a sample lies from the reference surface. Internal to patch/: what the face and
/// the cell fits share (the squared planes also with open_face_sign.cpp); each keeps the rest of its
/// kernels to itself.
#pragma once
#include <array>
#include <cmath>
#include <cstdint>

#include "cip/core/vec3.h"
#include "cip/core/vector_clones.h"
#include "cip/reference/tricubic_reference.h"
#include "cip/topology/cube_topology.h"

namespace cip::fit_lattice {

/// Samples closer than this to the reference surface (first-order estimate |f| / |grad f|, voxels) are not
/// checked.
constexpr double kMarginVoxels = 0.35;
/// The coordinates of a check lattice along each axis of a cell or face (the lattice templates below take
/// one): N points `step` apart, the first InsetQuarters / 4 steps in. The checks use n equally spaced points
/// from 1/4 step to its mirror image (step 1 / (n - 1/2)), i.e. closer to the faces than (a + 1/2) / n, where
/// the central term is strongest far from the bounding planes and wrong signs appear first.
template <int N, int StepOf, int InsetQuarters>
struct LatticeAxis {
  static constexpr int n = N;
  static constexpr double step = 1.0 / (StepOf - 1 + 2 * 0.25);  ///< the spacing of StepOf inset points
  static constexpr double coord(int i) { return (i + 0.25 * InsetQuarters) * step; }
};
/// The distance from a face's edge of the rows next to it, from which the slope of the patch across the edge
/// is taken (the uncrossed edges of a face, the edges of an open face of a cell).
constexpr double kNearEdge = 1e-4;
/// Samples within kMarginVoxels of the reference surface by the first-order estimate are checked anyway if
/// the patch gives them the wrong sign and Newton steps on the reference do not reach its surface within this
/// many voxels (the margin of countSpuriousCells is 0.5).
constexpr double kVerifiedVoxels = 0.3;
/// Weight of the ridge term of the coefficient fits (relative to a fit point at the cell or face centre).
constexpr double kRidge = 1e-3;

/// Hermite weights at the n lattice coordinates (the same on every axis).
template <class Axis, int n = Axis::n>
struct LatticeWeights {
  double w[n][4];
  double byIndex[4][n];  ///< w transposed: weight of Hermite index k at lattice point i is byIndex[k][i]
  LatticeWeights() {
    for (int i = 0; i < n; ++i) {
      hermiteWeights(Axis::coord(i), w[i], nullptr);
      for (int k = 0; k < 4; ++k) byIndex[k][i] = w[i][k];
    }
  }
  static const LatticeWeights& get() {
    static const LatticeWeights weights;
    return weights;
  }
};

/// World coordinates of the n lattice coordinates along each axis of an analytic reference's cell (as
/// CellReference::value maps cell-local points).
template <class Axis, int n = Axis::n>
struct WorldLattice {
  double coordinate[3][n];
  explicit WorldLattice(const CellReference& ref) {
    for (int axis = 0; axis < 3; ++axis)
      for (int i = 0; i < n; ++i)
        coordinate[axis][i] =
            ref.geometry->origin[axis] + ref.geometry->spacing[axis] * (ref.origin[axis] + Axis::coord(i));
  }
};

/// Bit i set where values[i] > 0 (false for NaN), for the `count` <= 64 values: the sign changes of a lattice
/// are found from these bits without a branch per pair. Four values per comparison with AVX2, two with SSE2.
std::uint64_t positiveBits(const double* values, int count);

/// An analytic reference minus the isovalue at the tensor lattice given per axis by `coordinate` (world).
void analyticLattice(const CellReference& ref, const double* const coordinate[3],
                     const std::array<int, 3>& count, const std::array<int, 3>& stride, double* out);

/// Point (u, v) (face frame) of face f in cell-local coordinates.
Vec3 facePoint(int f, double u, double v);

/// Cell-local position of lattice point (a, b) of face f (face frame: a along otherAxes[0], b along
/// otherAxes[1]).
template <class Axis, int n = Axis::n>
Vec3 faceLatticePoint(int f, int a, int b) {
  return facePoint(f, Axis::coord(a), Axis::coord(b));
}

/// The bicubic Hermite interpolant of face data `face` ([u index][v index], Hermite indices as in
/// CellReference) minus `isovalue` on the n x n lattice of the lattice points (index a + n b): contracted
/// along u, then v, each pass over contiguous arrays so that it vectorises.
template <class Axis, int n = Axis::n>
CIP_VECTOR_CLONES void bicubicLattice(const double (&face)[4][4], double isovalue, double* __restrict value) {
  const LatticeWeights<Axis>& weights = LatticeWeights<Axis>::get();  // `value` aliases nothing (restrict)
  const auto& w = weights.w;
  const auto& wt = weights.byIndex;
  double along[4][n];  // contracted along u, per v-Hermite index
  for (int jb = 0; jb < 4; ++jb)
    for (int a = 0; a < n; ++a)
      along[jb][a] =
          wt[0][a] * face[0][jb] + wt[1][a] * face[1][jb] + wt[2][a] * face[2][jb] + wt[3][a] * face[3][jb];
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a)
      value[a + n * b] = w[b][0] * along[0][a] + w[b][1] * along[1][a] + w[b][2] * along[2][a] +
                         w[b][3] * along[3][a] - isovalue;
}

/// Reference values minus the isovalue on face f at its lattice (index a + n b), from the in-plane Hermite
/// data of the face.
template <class Axis, int n = Axis::n>
void referenceFaceLattice(const CellReference& ref, int f, double* value) {
  const int axis = cube::faceAxis(f), side = cube::faceSide(f);
  const auto uv = cube::otherAxes(axis);
  if (ref.field) {
    const WorldLattice<Axis> world(ref);
    const double plane = ref.geometry->origin[axis] + ref.geometry->spacing[axis] * (ref.origin[axis] + side);
    const double* coordinate[3];
    std::array<int, 3> count, stride;
    coordinate[axis] = &plane;
    count[axis] = 1;
    stride[axis] = 0;
    for (int i = 0; i < 2; ++i) {
      coordinate[uv[i]] = world.coordinate[uv[i]];
      count[uv[i]] = n;
      stride[uv[i]] = i == 0 ? 1 : n;
    }
    analyticLattice(ref, coordinate, count, stride, value);
    return;
  }
  constexpr int stride[3] = {1, 4, 16};
  const int su = stride[uv[0]], sv = stride[uv[1]], sn = stride[axis];
  double face[4][4];  // the face's Hermite data, [u index][v index]
  for (int ia = 0; ia < 4; ++ia)
    for (int jb = 0; jb < 4; ++jb)
      face[ia][jb] = ref.hermite[static_cast<std::size_t>(ia * su + jb * sv + 2 * side * sn)];
  bicubicLattice<Axis>(face, ref.isovalue, value);
}

/// The reference gradient (per local unit) at point (u, v) of face f (face frame), as ref.gradient there but
/// from the face's own Hermite data (values and derivatives across it): on the face the weights across it
/// are 0 and 1, so a third of the work.
Vec3 faceGradient(const CellReference& ref, int f, double u, double v);

/// Whether the first-order distance |r| / |grad r| (smallest voxels) of a point with reference value r and
/// gradient g (per local unit) exceeds kMarginVoxels.
inline bool farFromSurface(const CellReference& ref, double r, const Vec3& gradient) {
  return r * r > kMarginVoxels * kMarginVoxels * gradient.cwiseProduct(ref.metric).squaredNorm();
}

/// A product of squared bounding planes at the centre of the face or cell, one for each bit of `planes`:
/// every plane is 1/2 there, so the product is 4^-(bits), exactly.
inline double centreSquares(unsigned planes) {
  return std::ldexp(1.0, -2 * __builtin_popcount(planes));
}

/// The two bits of a squared-face mask (bit 2a: plane x_a = 0, bit 2a + 1: plane x_a = 1) that concern axis
/// a: the pattern of squares() along that axis.
inline int pattern(std::uint8_t mask, int axis) {
  return (mask >> (2 * axis)) & 3;
}

/// Product of the squared face planes along one axis selected by pattern m, at coordinate t.
inline double squares(int m, double t) {
  double s = 1;
  if (m & 1) s *= t * t;
  if (m & 2) s *= (1 - t) * (1 - t);
  return s;
}

/// The n lattice coordinates and the products of squared face planes (squares) at them, per pattern: the
/// same for every cell and face, so computed once.
template <class Axis, int n = Axis::n>
struct LatticeSquares {
  double t[n], sq[4][n];
  LatticeSquares() {
    for (int i = 0; i < n; ++i) {
      t[i] = Axis::coord(i);
      for (int m = 0; m < 4; ++m) sq[m][i] = squares(m, t[i]);
    }
  }
  static const LatticeSquares& get() {
    static const LatticeSquares table;
    return table;
  }
};

/// Whether Newton steps on the reference from cell-local point x0 (reference value r0 != 0) reach its zero
/// set within `radius` smallest voxels: a bound on the distance to the reference surface that, unlike the
/// first-order estimate |r| / |grad r|, is not fooled by a large gradient far from the surface. The reference
/// is the cell's own interpolant, extended polynomially a little beyond the cell.
bool referenceSurfaceWithin(const CellReference& ref, const Vec3& x0, double r0, double radius);

/// A tensor lattice of reference samples (dims axes, n points each): index = sum of coordinate k times
/// stride[k], with strides 1, n, n^2 in order; step[k] is the spacing along lattice axis k in smallest
/// voxels.
struct LatticeLayout {
  int n = 0, dims = 0;
  std::array<int, 3> stride{};
  std::array<double, 3> step{};
  /// Lattice of Axis points over cell axes `axes` (lattice axis k along cell axis axes[k]), reference metric
  /// `metric`.
  template <class Axis>
  static LatticeLayout of(int numAxes, const int* axes, const Vec3& metric) {
    LatticeLayout out;
    out.n = Axis::n;
    out.dims = numAxes;
    for (int k = 0, s = 1; k < numAxes; ++k, s *= Axis::n) {
      out.stride[static_cast<std::size_t>(k)] = s;
      out.step[static_cast<std::size_t>(k)] = Axis::step / metric[axes[k]];
    }
    return out;
  }
};

/// Whether sample `index` of lattice values r (r[index] != 0 unless the sample is on the surface) has a
/// lattice neighbour within `radius` smallest voxels with the value 0 or the other sign: the reference
/// surface then crosses the segment between them and lies within `radius` of the sample. Exact where it
/// applies and much cheaper than Newton steps (referenceSurfaceWithin), which are tried when it does not.
bool neighbourCrosses(const double* r, int index, const LatticeLayout& lattice, double radius);

}  // namespace cip::fit_lattice
