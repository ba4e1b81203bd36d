#include "cip/model/patch_fitting.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "cip/core/error.h"
#include "cip/core/vector_clones.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/patch/sign_constraints.h"
#include "cip/reference/tricubic_reference.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

/// Blend levels of a corner-plane normal: n = normalize((1 - beta) n_gradient + beta e_edge).
constexpr std::array<double, 5> kBlend{0.0, 0.25, 0.5, 0.75, 1.0};
constexpr int kMaxLevel = static_cast<int>(kBlend.size()) - 1;
/// Samples per axis of the sign checks: face lattice (kFaceLattice^2) and cell lattice (kCellLattice^3).
constexpr int kFaceLattice = 7, kCellLattice = 6;
/// Samples near the surface that the clamping of a cell's coefficient found on the wrong side, from which on
/// the staggered lattice is checked too (fitCell). About 5 % of the cells on CT and fog volumes reach 6; 3
/// (a quarter of the cells) removed no more wrong-sign cells, 12 fewer.
constexpr int kStaggeredTrigger = 6;
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
using CellAxis = LatticeAxis<kCellLattice, kCellLattice, 1>;
using FaceAxis = LatticeAxis<kFaceLattice, kFaceLattice, 1>;
/// The lattice of the sign checks on the faces of a cell that are not bounding planes (openFaceSamples):
/// 1/3 apart, border included, and a row kNearEdge inside each border, where the slope of the patch across
/// the edge is taken from.
constexpr double kNearEdge = 1e-4;
struct OpenFaceAxis {
  static constexpr int n = 6;
  static constexpr double step = 1.0 / 3;  ///< the spacing of the regular points
  static constexpr double coord(int i) {
    return i == 0 ? 0.0 : i == 1 ? kNearEdge : i == n - 2 ? 1 - kNearEdge : i == n - 1 ? 1.0 : (i - 1) * step;
  }
};
/// The points halfway between those of CellAxis: with it, a body-centred lattice (see fitCell).
using StaggeredCellAxis = LatticeAxis<kCellLattice - 1, kCellLattice, 3>;
/// Samples within kMarginVoxels of the reference surface by the first-order estimate are checked anyway if
/// the patch gives them the wrong sign and Newton steps on the reference do not reach its surface within this
/// many voxels (the margin of countSpuriousCells is 0.5).
constexpr double kVerifiedVoxels = 0.3;
/// Cells per block of the fitting rounds (references kept for one block at a time). A block's references
/// (about 300 KB) then stay in cache from its face fits to its cell fits: against 4096, gyroid at N = 32 fits
/// about 4 % faster.
constexpr std::size_t kBlockCells = 512;
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

#if defined(CIP_HAS_AVX2_KERNELS)
/// positiveBits (below) for the values up to a multiple of four, four per comparison; `done` is that count.
CIP_AVX2_KERNEL std::uint64_t positiveBitsAvx2(const double* values, int count, int& done) {
  std::uint64_t bits = 0;
  const __m256d zero = _mm256_setzero_pd();
  int i = 0;
  for (; i + 4 <= count; i += 4)
    bits |= static_cast<std::uint64_t>(
                _mm256_movemask_pd(_mm256_cmp_pd(_mm256_loadu_pd(values + i), zero, _CMP_GT_OQ)))
            << i;
  done = i;
  return bits;
}
#endif

/// Bit i set where values[i] > 0 (false for NaN), for the `count` <= 64 values: the sign changes of a lattice
/// are found from these bits without a branch per pair. Four values per comparison with AVX2, two with SSE2.
std::uint64_t positiveBits(const double* values, int count) {
  std::uint64_t bits = 0;
  int i = 0;
#if defined(CIP_HAS_AVX2_KERNELS)
  if (hasAvx2()) bits = positiveBitsAvx2(values, count, i);
#endif
#if defined(__SSE2__)
  const __m128d zero = _mm_setzero_pd();
  for (; i + 2 <= count; i += 2)
    bits |= static_cast<std::uint64_t>(_mm_movemask_pd(_mm_cmpgt_pd(_mm_loadu_pd(values + i), zero))) << i;
#endif
  for (; i < count; ++i) bits |= std::uint64_t{values[i] > 0} << i;
  return bits;
}

/// An analytic reference minus the isovalue at the tensor lattice given per axis by `coordinate` (world).
void analyticLattice(const CellReference& ref, const double* const coordinate[3],
                     const std::array<int, 3>& count, const std::array<int, 3>& stride, double* out) {
  ref.field->valuesOnLattice(coordinate[0], coordinate[1], coordinate[2], count, stride, out);
  for (int d = 0; d < count[2]; ++d)
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a) out[a * stride[0] + b * stride[1] + d * stride[2]] -= ref.isovalue;
}

/// The tricubic interpolant (Hermite data `hermite` as in CellReference, minus `isovalue`) on the n^3
/// lattice of the lattice points in line order: point i along axis L on line (p, q) of axes P, Q at index
/// i + n (p + n q). Contracted one axis at a time, Q, P, then L, each pass over contiguous arrays so that it
/// vectorises (the weights are the same on every axis).
template <class Axis, int n = Axis::n>
CIP_VECTOR_CLONES void tricubicLatticeInLineOrder(const double* hermite, double isovalue, int L, int P, int Q,
                                                  double* __restrict out) {
  // `out` aliases neither the weights nor the local arrays (restrict), so the passes stay vectorised.
  const LatticeWeights<Axis>& weights = LatticeWeights<Axis>::get();
  const auto& w = weights.w;
  constexpr int stride[3] = {1, 4, 16};
  double h[4][16];  // [Q index][L index + 4 P index]
  for (int iQ = 0; iQ < 4; ++iQ)
    for (int iP = 0; iP < 4; ++iP)
      for (int iL = 0; iL < 4; ++iL)
        h[iQ][iL + 4 * iP] = hermite[iL * stride[L] + iP * stride[P] + iQ * stride[Q]];
  double alongQ[n][16];
  for (int q = 0; q < n; ++q)
    for (int k = 0; k < 16; ++k)
      alongQ[q][k] = w[q][0] * h[0][k] + w[q][1] * h[1][k] + w[q][2] * h[2][k] + w[q][3] * h[3][k];
  double alongP[n][n][4];
  for (int q = 0; q < n; ++q)
    for (int p = 0; p < n; ++p)
      for (int iL = 0; iL < 4; ++iL)
        alongP[q][p][iL] = w[p][0] * alongQ[q][iL] + w[p][1] * alongQ[q][iL + 4] +
                           w[p][2] * alongQ[q][iL + 8] + w[p][3] * alongQ[q][iL + 12];
  const auto& wt = weights.byIndex;
  for (int q = 0; q < n; ++q)
    for (int p = 0; p < n; ++p) {
      const double* c = alongP[q][p];
      double* line = out + n * (p + n * q);
      for (int i = 0; i < n; ++i)
        line[i] = wt[0][i] * c[0] + wt[1][i] * c[1] + wt[2][i] * c[2] + wt[3][i] * c[3] - isovalue;
    }
}

/// Reference values at the cell lattice (CellAxis per axis) in the line order of PatchLines along axis
/// L (lattice point i along L on line (p, q) of the other axes at index i + n (p + n q)); an analytic
/// reference is evaluated through valuesOnLattice.
template <class Axis, int n = Axis::n>
void referenceCellLattice(const CellReference& ref, int L, double* out) {
  const auto other = cube::otherAxes(L);
  if (ref.field) {
    const WorldLattice<Axis> world(ref);
    const double* coordinate[3] = {world.coordinate[0], world.coordinate[1], world.coordinate[2]};
    std::array<int, 3> stride;
    stride[L] = 1;
    stride[other[0]] = n;
    stride[other[1]] = n * n;
    analyticLattice(ref, coordinate, {n, n, n}, stride, out);
    return;
  }
  tricubicLatticeInLineOrder<Axis>(ref.hermite.data(), ref.isovalue, L, other[0], other[1], out);
}

/// Point (u, v) (face frame) of face f in cell-local coordinates.
Vec3 facePoint(int f, double u, double v) {
  const int axis = cube::faceAxis(f);
  const auto uv = cube::otherAxes(axis);
  Vec3 x;
  x[axis] = cube::faceSide(f);
  x[uv[0]] = u;
  x[uv[1]] = v;
  return x;
}

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
  const LatticeWeights<Axis>& weights = LatticeWeights<Axis>::get();  // `value` aliases nothing, as above
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
Vec3 faceGradient(const CellReference& ref, int f, double u, double v) {
  const int axis = cube::faceAxis(f), side = cube::faceSide(f);
  const auto uv = cube::otherAxes(axis);
  if (ref.field) {
    Vec3 x;
    x[axis] = side;
    x[uv[0]] = u;
    x[uv[1]] = v;
    return ref.gradient(x);
  }
  constexpr int stride[3] = {1, 4, 16};
  const int su = stride[uv[0]], sv = stride[uv[1]], sn = stride[axis];
  double wu[4], du[4], wv[4], dv[4];
  hermiteWeights(u, wu, du);
  hermiteWeights(v, wv, dv);
  Vec3 g = Vec3::Zero();
  for (int jb = 0; jb < 4; ++jb) {
    double value = 0, alongU = 0, across = 0;
    for (int ia = 0; ia < 4; ++ia) {
      const double* h = &ref.hermite[static_cast<std::size_t>(ia * su + jb * sv + 2 * side * sn)];
      value += wu[ia] * h[0];
      alongU += du[ia] * h[0];
      across += wu[ia] * h[sn];
    }
    g[uv[0]] += wv[jb] * alongU;
    g[uv[1]] += dv[jb] * value;
    g[axis] += wv[jb] * across;
  }
  return g;
}

/// Whether the first-order distance |r| / |grad r| (smallest voxels) of a point with reference value r and
/// gradient g (per local unit) exceeds kMarginVoxels.
bool farFromSurface(const CellReference& ref, double r, const Vec3& gradient) {
  return r * r > kMarginVoxels * kMarginVoxels * gradient.cwiseProduct(ref.metric).squaredNorm();
}

/// A product of squared bounding planes at the centre of the face or cell, one for each bit of `planes`:
/// every plane is 1/2 there, so the product is 4^-(bits), exactly.
double centreSquares(unsigned planes) {
  return std::ldexp(1.0, -2 * __builtin_popcount(planes));
}

/// The two bits of a squared-face mask (bit 2a: plane x_a = 0, bit 2a + 1: plane x_a = 1) that concern axis
/// a.
int pattern(std::uint8_t mask, int axis) {
  return (mask >> (2 * axis)) & 3;
}

/// Product of the squared face planes along one axis selected by pattern m, at coordinate t.
double squares(int m, double t) {
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

/// The terms of valueWithoutCentral as coefficient * (normal . x + offset) * squared face planes (mask): a
/// corner term's factor is its corner plane, a side term's the constant 1 (normal 0, offset 1). Listed once
/// per cell for all its lattices.
struct LinearTerms {
  struct Term {  // every member is set where a term is listed (no default values: the array is not cleared)
    double coefficient;
    Vec3 normal;
    double offset;
    std::uint8_t mask;
  };
  std::array<Term, CornerPatch::kMaxTerms> term;
  int count = 0;
  std::uint8_t faceMask = 0;  ///< the patch's bounding planes (the central term's mask)

  explicit LinearTerms(const CornerPatch& patch) : faceMask(patch.faceMask) {
    std::array<PatchTerm, CornerPatch::kMaxTerms> terms;
    const int n = patch.terms(terms);
    for (int k = 0; k < n; ++k) {
      const PatchTerm& t = terms[static_cast<std::size_t>(k)];
      if (t.corner < 0 && t.faceSquares == patch.faceMask) continue;  // the central term
      Term& out = term[static_cast<std::size_t>(count++)];
      out.coefficient = t.coefficient;
      out.mask = t.faceSquares;
      if (t.corner >= 0) {
        out.normal = patch.normal[t.corner];
        out.offset = -patch.normal[t.corner].dot(patch.point[t.corner]);
      } else {
        out.normal = Vec3::Zero();
        out.offset = 1;
      }
    }
  }
  template <class F>
  void forEach(F&& fn) const {
    for (int k = 0; k < count; ++k) {
      const Term& t = term[static_cast<std::size_t>(k)];
      fn(t.coefficient, t.normal, t.offset, t.mask);
    }
  }
};

/// The patch on the lattice lines of a cell along one axis L (the other two axes at lattice coordinates):
/// every term is a corner plane (linear) times squared face planes, each depending on one coordinate, so on
/// the line through lattice point (p, q) of the other axes
///   valueWithoutCentral(x) = sum_m s_m(x) (A_m[p, q] + x B_m[p, q]),  centralBasis(x) = s_c(x) C[p, q],
/// with s_m(x) the product of the squared face planes across L selected by m (bit 0: plane x = 0, bit 1: x =
/// 1). Building A, B, C costs O(terms n^2); each lattice point or fit point on a line then costs a few flops.
template <class Axis, int n = Axis::n>
class PatchLines {
 public:
  PatchLines(const LinearTerms& terms, int lineAxis) : axis_(lineAxis), other_(cube::otherAxes(lineAxis)) {
    stride_[axis_] = 1;
    stride_[other_[0]] = n;
    stride_[other_[1]] = n * n;
    const LatticeSquares<Axis>& table = LatticeSquares<Axis>::get();
    std::copy(table.t, table.t + n, t_);
    std::copy(&table.sq[0][0], &table.sq[0][0] + 4 * n, &s_[0][0]);
    // A term c (n . x + o) s_mL(x_L) s_mP(x_P) s_mQ(x_Q) adds s_mP[p] (t[p] X[q] + Y[q]) to A_mL[p, q] and
    // s_mP[p] Z[q] to B_mL[p, q], with X = c n_P s_mQ, Y = c (o + n_Q t) s_mQ and Z = c n_L s_mQ: the terms
    // are summed per pattern pair (mL, mP) along q first, then each pair spreads over the lines once.
    double x[16][n], y[16][n], z[16][n];
    unsigned pairs = 0;
    auto add = [&](double coefficient, const Vec3& normal, double offset, std::uint8_t mask) {
      const int mL = pattern(mask, axis_), mP = pattern(mask, other_[0]), mQ = pattern(mask, other_[1]);
      const int pair = 4 * mL + mP;
      if (!((pairs >> pair) & 1)) {
        pairs |= 1u << pair;
        for (int q = 0; q < n; ++q) x[pair][q] = y[pair][q] = z[pair][q] = 0;
      }
      for (int q = 0; q < n; ++q) {
        const double c = coefficient * s_[mQ][q];
        x[pair][q] += c * normal[other_[0]];
        y[pair][q] += c * (offset + normal[other_[1]] * t_[q]);
        z[pair][q] += c * normal[axis_];
      }
    };
    terms.forEach(add);
    for (unsigned rest = pairs; rest; rest &= rest - 1) {
      const int pair = __builtin_ctz(rest), mL = pair / 4, mP = pair % 4;
      const bool first = !((used_ >> mL) & 1);
      used_ |= 1u << mL;
      double* a = a_[static_cast<std::size_t>(mL)].data();
      double* b = b_[static_cast<std::size_t>(mL)].data();
      for (int q = 0; q < n; ++q)
        for (int p = 0; p < n; ++p) {
          const double da = s_[mP][p] * (t_[p] * x[pair][q] + y[pair][q]), db = s_[mP][p] * z[pair][q];
          a[p + n * q] = first ? da : a[p + n * q] + da;
          b[p + n * q] = first ? db : b[p + n * q] + db;
        }
    }
    central_ = pattern(terms.faceMask, axis_);
    const int cP = pattern(terms.faceMask, other_[0]), cQ = pattern(terms.faceMask, other_[1]);
    for (int q = 0; q < n; ++q)
      for (int p = 0; p < n; ++p) c_[static_cast<std::size_t>(p + n * q)] = s_[cP][p] * s_[cQ][q];
  }

  /// The cell lattice in line order: point i along the line axis on line (p, q) has index i + n (p + n q).
  static int index(int i, int p, int q) { return i + n * (p + n * q); }
  /// Cell-local position of lattice point `index`.
  Vec3 point(int index) const {
    Vec3 x;
    x[axis_] = Axis::coord(index % n);
    x[other_[0]] = Axis::coord(index / n % n);
    x[other_[1]] = Axis::coord(index / (n * n));
    return x;
  }
  /// Gradient (per local unit) of lattice values r at lattice point `index`, by central differences
  /// (one-sided at the lattice border).
  Vec3 gradient(const double* r, int index) const {
    const int c[3] = {index % n, index / n % n, index / (n * n)};
    const int axes[3] = {axis_, other_[0], other_[1]};
    Vec3 g;
    for (int k = 0; k < 3; ++k) {
      const int up = c[k] + 1 < n ? 1 : 0, down = c[k] > 0 ? 1 : 0, step = stride_[axes[k]];
      g[axes[k]] = (r[index + up * step] - r[index - down * step]) / (Axis::step * (up + down));
    }
    return g;
  }

  /// valueWithoutCentral and centralBasis at every lattice point.
  void lattice(double* __restrict value, double* __restrict basis) const {
    int patterns[4], numPatterns = 0;
    for (int m = 0; m < 4; ++m)
      if ((used_ >> m) & 1) patterns[numPatterns++] = m;
    for (int q = 0; q < n; ++q)
      for (int p = 0; p < n; ++p) {
        const std::size_t pq = static_cast<std::size_t>(p + n * q);
        double v[n];
        for (int i = 0; i < n; ++i) v[i] = 0;
        for (int k = 0; k < numPatterns; ++k) {
          const int m = patterns[k];
          const double a = a_[m][pq], b = b_[m][pq];
          for (int i = 0; i < n; ++i) v[i] += s_[m][i] * (a + t_[i] * b);
        }
        for (int i = 0; i < n; ++i) {
          value[index(i, p, q)] = v[i];
          basis[index(i, p, q)] = s_[central_][i] * c_[pq];
        }
      }
  }

  /// valueWithoutCentral (returned) and centralBasis at coordinate x along the line (p, q).
  double at(double x, int p, int q, double& basis) const {
    const std::size_t pq = static_cast<std::size_t>(p + n * q);
    const double x2 = x * x, y2 = (1 - x) * (1 - x), s[4] = {1, x2, y2, x2 * y2};  // squares(m, x)
    double v = 0;
    for (int m = 0; m < 4; ++m)
      if ((used_ >> m) & 1) v += s[m] * (a_[m][pq] + x * b_[m][pq]);
    basis = s[central_] * c_[pq];
    return v;
  }

 private:
  int axis_;
  std::array<int, 2> other_;
  std::array<int, 3> stride_;  ///< lattice index steps along x, y, z
  int central_ = 0;
  unsigned used_ = 0;
  double t_[n], s_[4][n];
  std::array<std::array<double, n * n>, 4> a_, b_;  ///< valid for the patterns in used_
  std::array<double, n * n> c_;                     ///< every entry set by the constructor
};

/// valueWithoutCentral and centralBasis of a patch on face f's lattice (face frame, index a + n b), by
/// separable products as in PatchLines.
template <class Axis, int n = Axis::n>
void patchFaceLattice(const LinearTerms& terms, int f, double* __restrict value, double* __restrict basis) {
  const int axis = cube::faceAxis(f);
  const double side = cube::faceSide(f);
  const auto uv = cube::otherAxes(axis);
  const LatticeSquares<Axis>& table = LatticeSquares<Axis>::get();  // the outputs alias nothing (restrict)
  const auto& t = table.t;
  const auto& sq = table.sq;
  // A term adds su[a] (t[a] X[b] + Y[b]) with X = across sv n_u and Y = across sv (constant + n_v t): the
  // terms are summed per pattern along u first (as in PatchLines).
  double x[4][n], y[4][n];
  unsigned patterns = 0;
  auto add = [&](double coefficient, const Vec3& normal, double offset, std::uint8_t mask) {
    const double across = coefficient * squares(pattern(mask, axis), side);
    if (across == 0) return;
    const int mu = pattern(mask, uv[0]);
    const double* sv = sq[pattern(mask, uv[1])];
    if (!((patterns >> mu) & 1)) {
      patterns |= 1u << mu;
      for (int b = 0; b < n; ++b) x[mu][b] = y[mu][b] = 0;
    }
    const double constant = normal[axis] * side + offset;
    for (int b = 0; b < n; ++b) {
      x[mu][b] += across * sv[b] * normal[uv[0]];
      y[mu][b] += across * sv[b] * (constant + normal[uv[1]] * t[b]);
    }
  };
  terms.forEach(add);
  std::fill(value, value + n * n, 0.0);
  for (unsigned rest = patterns; rest; rest &= rest - 1) {
    const int mu = __builtin_ctz(rest);
    for (int b = 0; b < n; ++b)
      for (int a = 0; a < n; ++a) value[a + n * b] += sq[mu][a] * (t[a] * x[mu][b] + y[mu][b]);
  }
  const double across = squares(pattern(terms.faceMask, axis), side);
  const double* su = sq[pattern(terms.faceMask, uv[0])];
  const double* sv = sq[pattern(terms.faceMask, uv[1])];
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) basis[a + n * b] = across * su[a] * sv[b];
}

/// valueWithoutCentral and centralBasis of a patch on face f at any point (u, v) of the face frame: each
/// term is a linear function of (u, v) times squared face planes across u and across v (patterns mu, mv),
/// so the terms of one pattern pair sum to one linear function. For the points off a lattice
/// (openFaceSamples' ridge points and searches): a few flops per pattern pair instead of every term's planes.
class FacePatch {
 public:
  /// Nothing set: set() makes it (a default-constructed member array is not zero-filled, unlike the storage
  /// of an empty std::optional, which the compiler cleared per open face).
  FacePatch() {}
  void set(const LinearTerms& terms, int f) {
    pairs_ = 0;
    const int axis = cube::faceAxis(f);
    const double side = cube::faceSide(f);
    const auto uv = cube::otherAxes(axis);
    terms.forEach([&](double coefficient, const Vec3& normal, double offset, std::uint8_t mask) {
      const double across = coefficient * squares(pattern(mask, axis), side);
      if (across == 0) return;
      const int pair = pattern(mask, uv[0]) + 4 * pattern(mask, uv[1]);
      Linear& l = linear_[pair];
      if (!((pairs_ >> pair) & 1)) {
        pairs_ |= 1u << pair;
        l = Linear{0, 0, 0};
      }
      l.u += across * normal[uv[0]];
      l.v += across * normal[uv[1]];
      l.constant += across * (normal[axis] * side + offset);
    });
    centralAcross_ = squares(pattern(terms.faceMask, axis), side);
    centralPair_ = pattern(terms.faceMask, uv[0]) + 4 * pattern(terms.faceMask, uv[1]);
  }
  /// valueWithoutCentral (first) and centralBasis (second) at (u, v).
  std::pair<double, double> at(double u, double v) const {
    const double su[4] = {1, u * u, (1 - u) * (1 - u), u * u * (1 - u) * (1 - u)};
    const double sv[4] = {1, v * v, (1 - v) * (1 - v), v * v * (1 - v) * (1 - v)};
    double value = 0;
    for (unsigned rest = pairs_; rest; rest &= rest - 1) {
      const int pair = __builtin_ctz(rest);
      const Linear& l = linear_[pair];
      value += su[pair & 3] * sv[pair >> 2] * (l.u * u + l.v * v + l.constant);
    }
    return {value, centralAcross_ * su[centralPair_ & 3] * sv[centralPair_ >> 2]};
  }

 private:
  struct Linear {  // no default values: an entry is cleared where its pair is first met
    double u, v, constant;
  };
  std::array<Linear, 16> linear_;  ///< per pattern pair mu + 4 mv; valid for the pairs in pairs_
  unsigned pairs_;
  double centralAcross_;
  int centralPair_;
};

/// Whether Newton steps on the reference from cell-local point x0 (reference value r0 != 0) reach its zero
/// set within `radius` smallest voxels: a bound on the distance to the reference surface that, unlike the
/// first-order estimate |r| / |grad r|, is not fooled by a large gradient far from the surface. The reference
/// is the cell's own interpolant, extended polynomially a little beyond the cell.
bool referenceSurfaceWithin(const CellReference& ref, const Vec3& x0, double r0, double radius) {
  const Vec3& m = ref.metric;  // voxel coordinates y = x / m
  Vec3 x = x0, gradient = ref.gradient(x0);
  double value = r0;
  for (int it = 0; it < 8; ++it) {
    const Vec3 gy = gradient.cwiseProduct(m);
    const double gg = gy.squaredNorm();
    if (!(gg > 0)) return false;
    const Vec3 next = x - (value / gg) * gy.cwiseProduct(m);
    const double travelled = (next - x0).cwiseQuotient(m).norm();
    if (travelled > radius) return false;
    const double nextValue = ref.valueAndGradient(next, gradient);
    // A sign change between two points within the radius (a ball is convex) puts the surface within it.
    if ((nextValue > 0) != (r0 > 0) || nextValue == 0) return true;
    if (std::abs(nextValue) <= 1e-9 * std::abs(r0)) return true;
    x = next;
    value = nextValue;
  }
  return false;
}

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
bool neighbourCrosses(const double* r, int index, const LatticeLayout& lattice, double radius) {
  const double r0 = r[index];
  if (r0 == 0) return true;
  auto crosses = [&](double v) { return v == 0 || (v > 0) != (r0 > 0); };
  for (int k = 0; k < lattice.dims; ++k) {
    const auto kk = static_cast<std::size_t>(k);
    if (lattice.step[kk] > radius) continue;
    const int s = lattice.stride[kk], c = index / s % lattice.n;
    if ((c > 0 && crosses(r[index - s])) || (c + 1 < lattice.n && crosses(r[index + s]))) return true;
  }
  return false;
}

/// faceRestriction at the face lattice (index a + n b), by separable products: the perpendicular planes of
/// canonical edges 0, 1 depend on v only (v, 1 - v), those of edges 2, 3 on u only (u, 1 - u).
template <class Axis, int n = Axis::n>
CIP_VECTOR_CLONES void faceRestrictionLattice(const FaceCrossings& face, double* __restrict cornerPart,
                                              double* __restrict sideBasis) {
  // The product of the squared perpendicular planes of a set of crossed edges: those of edges 0, 1 (v, 1 - v)
  // depend on v, those of edges 2, 3 (u, 1 - u) on u, so it is su[a] sv[b] with the squares of
  // LatticeSquares for the patterns (edges >> 2) & 3 along u and edges & 3 along v.
  const LatticeSquares<Axis>& table = LatticeSquares<Axis>::get();  // the outputs alias nothing (restrict)
  const auto& t = table.t;
  const double* u = table.sq[(face.crossed >> 2) & 3];
  const double* v = table.sq[face.crossed & 3];
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) {
      sideBasis[static_cast<std::size_t>(a + n * b)] = u[a] * v[b];
      cornerPart[static_cast<std::size_t>(a + n * b)] = 0;
    }
  for (int k = 0; k < 4; ++k) {
    if (!((face.crossed >> k) & 1)) continue;
    const unsigned others = face.crossed & ~(1u << k);
    u = table.sq[(others >> 2) & 3];
    v = table.sq[others & 3];
    const Vec2 normal = face.weight[k] * face.normal[k];
    const double nu = normal.x(), nv = normal.y(), offset = -normal.dot(face.point[k]);
    for (int b = 0; b < n; ++b) {
      const double along = nv * t[b], across = v[b];
      double* row = cornerPart + n * b;
      for (int a = 0; a < n; ++a) row[a] += (nu * t[a] + along + offset) * u[a] * across;
    }
  }
}

/// Points per canonical edge of a face for uncrossedEdgeSamples, ends included.
constexpr int kEdgePoints = 9;

/// The canonical vertex (a + 2 b at (u, v) = (a, b)) at the start of canonical edge k.
constexpr int kEdgeStartVertex[4] = {0, 2, 0, 1};

/// The point at parameter t of canonical edge k of a face (face frame).
Vec2 canonicalEdgePoint(int k, double t) {
  const double fixed = k & 1;
  return k < 2 ? Vec2(t, fixed) : Vec2(fixed, t);
}

/// The 7 points inside an edge at which referenceKeepsEdgeSign looks: 1/8 apart.
struct EdgeCheckAxis {
  static constexpr int n = 7;
  static constexpr double coord(int i) { return (i + 1) / 8.0; }
};

/// Whether the reference keeps the sign of the vertices (`positive`) along canonical edge k of face f of a
/// cell, at 7 points inside it. Where it does not, the reference surface itself crosses the edge (twice:
/// the configuration calls it uncrossed), and a side coefficient made to keep the vertices' sign along it
/// parts the patch from the reference there (Marschner-Lobb, whose ripples cross many such edges: 0.8
/// degrees more mean normal error at N = 64 in exact mode).
bool referenceKeepsEdgeSign(const CellReference& ref, int f, int k, bool positive) {
  const int e = cube::faceEdge(f, k), axis = cube::edgeAxis(e);
  const auto others = cube::otherAxes(axis);
  Vec3 x;
  x[others[0]] = e & 1;
  x[others[1]] = (e >> 1) & 1;
  constexpr int stride[3] = {1, 4, 16};
  // The reference along the edge is the cubic Hermite segment of its end data (values and slopes along it).
  const LatticeWeights<EdgeCheckAxis>& weights = LatticeWeights<EdgeCheckAxis>::get();
  double r[7];
  if (ref.field) {  // the 7 points as a lattice, which fields evaluate faster than point by point
    double along[7], fixed[2];
    const GridGeometry& g = *ref.geometry;
    for (int j = 0; j < 7; ++j)
      along[j] = g.origin[axis] + g.spacing[axis] * (ref.origin[axis] + EdgeCheckAxis::coord(j));
    for (int i = 0; i < 2; ++i)
      fixed[i] = g.origin[others[i]] + g.spacing[others[i]] * (ref.origin[others[i]] + x[others[i]]);
    const double* coordinate[3];
    std::array<int, 3> count{1, 1, 1}, strides{0, 0, 0};
    coordinate[axis] = along;
    coordinate[others[0]] = &fixed[0];
    coordinate[others[1]] = &fixed[1];
    count[axis] = 7;
    strides[axis] = 1;
    analyticLattice(ref, coordinate, count, strides, r);
  } else {
    const double* h =
        ref.hermite.data() + 2 * (e & 1) * stride[others[0]] + 2 * ((e >> 1) & 1) * stride[others[1]];
    const int s = stride[axis];
    for (int j = 0; j < 7; ++j) {
      const double* w = weights.w[j];
      r[j] = w[0] * h[0] + w[1] * h[s] + w[2] * h[2 * s] + w[3] * h[3 * s] - ref.isovalue;
    }
  }
  for (int j = 0; j < 7; ++j)
    if ((r[j] > 0) != positive) return false;
  return true;
}

/// Sign samples on canonical edge k of a face, an edge without a crossing (kEdgePoints of them), written as
/// the fit's samples are: the sign wanted (+1 or -1: that of the edge's vertices, `positive`) in r, the face
/// restriction's corner part R in a and its side basis D in b. On such an edge the patch is the face
/// restriction times a factor > 0, or, where the edge lies on a second bounding plane, zero along the edge
/// itself and the restrictions of both faces times the squared distance from each next to it. Either way a
/// restriction of the wrong sign on the edge puts the patch's zero set on a face that no neighbouring patch
/// continues: a hole. Ends where D = 0 (next to a crossing, where the corner planes alone decide) are left
/// out unless the corner planes give them the wrong sign (then no coefficient meets them); in their place a
/// point where the bound of w peaks next to such an end may follow (below). The kEdgePoints - 2 points inside
/// the edge come first, then the ends (or their ridge points). Returns the number of samples (at most
/// kEdgePoints).
int uncrossedEdgeSamples(const FaceCrossings& fc, int k, bool positive, double* r, double* a, double* b) {
  // The edge's points (t = j / (kEdgePoints - 1)), and a point kNearEdge inside each end for the slope there.
  constexpr int m = kEdgePoints + 2, kStart = kEdgePoints, kEnd = kEdgePoints + 1;
  double t[m];
  for (int j = 0; j < kEdgePoints; ++j) t[j] = static_cast<double>(j) / (kEdgePoints - 1);
  t[kStart] = kNearEdge;
  t[kEnd] = 1 - kNearEdge;
  int count = 0;
  const double sign = positive ? 1.0 : -1.0;
  // faceRestriction at the points, all at once. The squared perpendicular planes of canonical edges 0..3
  // are v^2, (1 - v)^2, u^2, (1 - u)^2; along this edge the one of the parallel edge is 1 (that of the
  // edge itself, uncrossed, is not used), those of the two perpendicular edges t^2 and (1 - t)^2.
  const double fixed = k & 1;
  const int first = k < 2 ? 2 : 0;  // the perpendicular edges: first (at t = 0) and first + 1 (at t = 1)
  double square[2][m], cornerPart[m], sideBasis[m];
  for (int j = 0; j < m; ++j) {
    square[0][j] = t[j] * t[j];
    square[1][j] = (1 - t[j]) * (1 - t[j]);
    cornerPart[j] = 0;
    sideBasis[j] = 1;
  }
  auto perpendicularSquare = [&](int c) -> const double* {
    return c == first ? square[0] : c == first + 1 ? square[1] : nullptr;  // null: the parallel edge, 1
  };
  for (int c = 0; c < 4; ++c) {
    if (!((fc.crossed >> c) & 1)) continue;
    const Vec2 n = fc.weight[c] * fc.normal[c];
    const double along = k < 2 ? n.x() : n.y(), offset = (k < 2 ? n.y() : n.x()) * fixed - n.dot(fc.point[c]);
    double term[m];
    for (int j = 0; j < m; ++j) term[j] = along * t[j] + offset;
    for (int o = 0; o < 4; ++o) {
      if (o == c || !((fc.crossed >> o) & 1)) continue;
      if (const double* sq = perpendicularSquare(o))
        for (int j = 0; j < m; ++j) term[j] *= sq[j];
    }
    for (int j = 0; j < m; ++j) cornerPart[j] += term[j];
    if (const double* sq = perpendicularSquare(c))
      for (int j = 0; j < m; ++j) sideBasis[j] *= sq[j];
  }
  auto add = [&](double cp, double sb) {
    r[count] = sign, a[count] = cp, b[count] = sb;
    ++count;
  };
  for (int j = 1; j < kEdgePoints - 1; ++j) add(cornerPart[j], sideBasis[j]);  // D > 0 inside
  for (int j : {0, kEdgePoints - 1}) {
    if (sideBasis[j] > 0 || sign * cornerPart[j] < 0) {
      add(cornerPart[j], sideBasis[j]);
      continue;
    }
    // An end next to a crossing (D = 0 there, and D grows with the squared distance d from it) with R of
    // the right sign or 0: where R starts towards the other sign, R = R0 + R1 d + ... (s R0 >= 0,
    // s R1 < 0), the bound -s R / D rises to a narrow ridge near d = -2 R0 / R1, often before the next
    // point. That point is a sample (R1 from the point kNearEdge inside).
    const double r0 = sign * cornerPart[j], r1 = (sign * cornerPart[j == 0 ? kStart : kEnd] - r0) / kNearEdge;
    if (!(r1 < 0) || !(-2 * r0 / r1 < 1.0 / (kEdgePoints - 1))) continue;
    const double d = std::max(-2 * r0 / r1, kNearEdge);
    const FaceRestriction fr = faceRestriction(fc, canonicalEdgePoint(k, j == 0 ? d : 1 - d));
    add(fr.cornerPart, fr.sideBasis);
  }
  return count;
}

struct FaceEntry {
  std::array<std::uint32_t, 2> cell{};
  std::array<std::int8_t, 2> face{};
  int count = 0;
};

struct FaceResult {
  double coefficient = 0;
  bool ok = true;
  /// Canonical edges (bit k) without a crossing that the reference keeps at the vertices' sign, where the
  /// edge's samples cannot be met together with the lattice's and, with the lattice's coefficient, the face
  /// restriction has the other sign at one of the edge's points inside (not only at an end or at a ridge
  /// point next to a crossing). Where such an edge lies on a face that is open in one of the face's cells,
  /// the patch's zero set ends there: a hole (see fitModelPatches).
  std::uint8_t holeEdges = 0;
};

/// The side coefficient of face f of a cell (its first cell) with corner data `patch` (coefficients unused),
/// ambiguous-face pairings `pairing03`, configuration `config` and reference `ref`. Where no value meets
/// every counting sample, the result is not ok and the coefficient is the fit, or with
/// `fallBackToLeastContradicted` the value the fewest counting samples contradict, nearest to the fit (for
/// the faces still failed after the fallback rounds). Where the samples of the uncrossed edges cannot be met
/// together with the lattice's, the lattice's alone decide.
FaceResult fitFace(const CornerPatch& patch, std::uint8_t config, std::uint8_t pairing03, int f,
                   const CellReference& ref, bool fallBackToLeastContradicted = false) {
  FaceCrossings fc = faceCrossingsOf(patch, f, (pairing03 >> f) & 1);
  using Axis = FaceAxis;
  constexpr int n = Axis::n;
  constexpr int kEdgeSamples = 2 * kEdgePoints;
  std::array<double, n * n + kEdgeSamples> r, cornerPart, sideBasis;
  referenceFaceLattice<Axis>(ref, f, r.data());
  faceRestrictionLattice<Axis>(fc, cornerPart.data(), sideBasis.data());
  // Reference face-curve points: sign changes between neighbouring samples, linearly interpolated.
  double num = 0, den = 0;
  int fitCount = 0;
  auto addPoint = [&](const Vec2& q) {
    const FaceRestriction fr = faceRestriction(fc, q);
    num += fr.cornerPart * fr.sideBasis;
    den += fr.sideBasis * fr.sideBasis;
    ++fitCount;
  };
  auto addFit = [&](const Vec2& q0, double r0, const Vec2& q1, double r1) {
    addPoint(q0 + r0 / (r0 - r1) * (q1 - q0));
  };
  // Sign changes between lattice neighbours as bits (most pairs have none: no branch per pair), visited in
  // lattice order.
  static_assert(n * n <= 64, "face lattice signs in one word");
  const std::uint64_t signs = positiveBits(r.data(), n * n);
  std::uint64_t lastColumn = 0;
  for (int b = 0; b < n; ++b) lastColumn |= std::uint64_t{1} << (n - 1 + n * b);
  const std::uint64_t alongU = (signs ^ (signs >> 1)) & ~lastColumn & ((std::uint64_t{1} << (n * n)) - 1);
  const std::uint64_t alongV = (signs ^ (signs >> n)) & ((std::uint64_t{1} << (n * (n - 1))) - 1);
  for (std::uint64_t pairs = alongU | alongV; pairs; pairs &= pairs - 1) {
    const int k = __builtin_ctzll(pairs), a = k % n, b = k / n;
    const Vec2 q(Axis::coord(a), Axis::coord(b));
    if ((alongU >> k) & 1) addFit(q, r[k], Vec2(Axis::coord(a + 1), q.y()), r[k + 1]);
    if ((alongV >> k) & 1) addFit(q, r[k], Vec2(q.x(), Axis::coord(b + 1)), r[k + n]);
  }
  if (fitCount == 0) {
    // The reference curve passes between the samples (close to a face vertex): use the side points instead.
    std::array<std::array<int, 2>, 2> segments;
    int numSegments = faceSegments(fc, segments);
    for (int k = 0; k < numSegments; ++k) addPoint(sidePoint(fc, segments[k][0], segments[k][1]));
  }
  // Ridge term towards 0 at the scale of the side basis at the face centre: where every fit point has a tiny
  // side basis (a face curve hugging a face vertex) w hardly moves the face curve but would still weigh on
  // the interior.
  const double dCentre = centreSquares(fc.crossed);  // faceRestriction(fc, (0.5, 0.5)).sideBasis
  den += kRidge * dCentre * dCentre * std::max(1, fitCount);
  const LatticeLayout faceLayout =
      LatticeLayout::of<Axis>(2, cube::otherAxes(cube::faceAxis(f)).data(), ref.metric);
  auto far = [&](int i) {
    return i >= n * n ||
           farFromSurface(ref, r[i], faceGradient(ref, f, Axis::coord(i % n), Axis::coord(i / n)));
  };
  auto confirmFar = [&](int i) {
    return !neighbourCrosses(r.data(), i, faceLayout, kVerifiedVoxels) &&
           !referenceSurfaceWithin(ref, faceLatticePoint<Axis>(f, i % n, i / n), r[i], kVerifiedVoxels);
  };
  thread_local SignConstraintSolver solver;
  solver.reset();
  const double fitted = -num / den;
  const SignSamples lattice{r.data(), cornerPart.data(), sideBasis.data(), n * n};
  const SignedCoefficient alone = solver.solve(fitted, lattice, far, confirmFar);
  FaceResult out;
  out.ok = alone.feasible;
  out.coefficient = alone.value;
  if (!alone.feasible) {
    if (fallBackToLeastContradicted)
      out.coefficient = leastContradicted(alone.value, lattice, far, confirmFar);
    return out;
  }
  // The face's edges without a crossing: there the face restriction must keep the sign of the edge's
  // vertices everywhere, or the patch's zero set reaches the edge, where no patch continues it (a hole; see
  // uncrossedEdgeSamples). An edge whose samples the lattice's coefficient fails joins the samples (they
  // count always), unless the reference itself crosses it (referenceKeepsEdgeSign).
  int count = n * n;
  // Joined edges with the wrong sign inside (not only at an end, where an isovertex on a grid point makes the
  // restriction 0 up to rounding, or at a ridge point next to a crossing, a sliver).
  std::uint8_t pointFails = 0;
  for (int k = 0; k < 4; ++k) {
    if ((fc.crossed >> k) & 1) continue;
    const bool positive = (config >> cube::faceVertex(f, kEdgeStartVertex[k])) & 1;
    const int added = uncrossedEdgeSamples(fc, k, positive, &r[static_cast<std::size_t>(count)],
                                           &cornerPart[static_cast<std::size_t>(count)],
                                           &sideBasis[static_cast<std::size_t>(count)]);
    bool fails = false, pointFailsHere = false;
    for (int i = count; i < count + added; ++i) {
      const double a = cornerPart[static_cast<std::size_t>(i)], b = sideBasis[static_cast<std::size_t>(i)];
      fails |= CoefficientInterval::slack(positive, a, b, alone.value) < 0;  // with the clamp's margin
      const double v = a + alone.value * b;
      pointFailsHere |= i < count + kEdgePoints - 2 && (positive ? v < 0 : v > 0);
    }
    if (fails && referenceKeepsEdgeSign(ref, f, k, positive)) {
      count += added;
      pointFails = static_cast<std::uint8_t>(pointFails | (unsigned{pointFailsHere} << k));
    }
  }
  if (count == n * n) return out;
  // No value meets the edges together with the lattice (the reference bulges towards an edge, or the corner
  // planes tilt across it): the lattice's stays, as without the edges, and the patch may cross the edge
  // there, a hole (docs/method.md, "Holes"). Failing the face instead makes the fallback rounds blend
  // normals, which spread failures (docs/method.md, step 7).
  const SignedCoefficient both =
      solver.solve(fitted, {r.data(), cornerPart.data(), sideBasis.data(), count}, far, confirmFar);
  if (both.feasible)
    out.coefficient = both.value;
  else
    out.holeEdges = pointFails;
  return out;
}

/// Samples that openFaceSamples writes at most per face: the lattice, a point next to each lattice point of
/// the border and the end of one search per edge.
constexpr int kOpenFaceSamples = OpenFaceAxis::n * OpenFaceAxis::n + 4 * OpenFaceAxis::n + 4;

/// Sign samples of the central coefficient on face f of a cell, a face that is not a bounding plane, written
/// as the fit's samples are: the sign of the face's corners (`positive`) as +1 or -1 in r, the patch without
/// the central term A in a, the central basis C in b. The patch must keep that sign on the whole face: no
/// patch across continues a zero set that reaches it, so a wrong sign there is a hole. The samples are the
/// OpenFaceAxis lattice, border included (where C = 0, on the face's edges with bounding planes, the side
/// coefficients decide, uncrossedEdgeSamples, and the sample is written as met), and points next to such
/// edges where a ridge of the bound may lie: with s the sign, s (A + w C) > 0 means s w > -s A / C, and
/// next to the edge C grows with the squared distance d from it while A starts at its value A0 there, so
/// with A = A0 + A1 d + ..., s A0 > 0 and s A1 < 0 the bound rises to a narrow ridge near d = -2 A0 / A1,
/// often before the lattice's first row (A1 from the lattice's row kNearEdge inside). From the highest such
/// point of each edge a compass search follows the ridge (along the edge, and towards a corner where two
/// such edges meet), and its end is one more sample. Returns the number of samples (at most
/// kOpenFaceSamples).
int openFaceSamples(const LinearTerms& terms, int f, bool positive, double* r, double* a, double* b) {
  using Axis = OpenFaceAxis;
  constexpr int n = Axis::n;
  const double sign = positive ? 1.0 : -1.0;
  patchFaceLattice<Axis>(terms, f, a, b);
  FacePatch face;  // for the ridge points, set where the first is needed
  bool faceSet = false;
  const double* av = a;  // the lattice's A and C, read by the ridge search before the edges are replaced
  const double* cv = b;
  int count = n * n;
  auto add = [&](double aa, double cc) {
    r[count] = sign, a[count] = aa, b[count] = cc;
    ++count;
  };
  // The lattice index of point i along edge e (v = 0, v = 1, u = 0, u = 1), j rows in.
  auto edgeIndex = [](int e, int i, int j) {
    return e == 0 ? i + n * j : e == 1 ? i + n * (n - 1 - j) : e == 2 ? j + n * i : n - 1 - j + n * i;
  };
  unsigned planeEdges = 0;  // the edges with bounding planes
  for (int e = 0; e < 4; ++e) {
    // The face coordinates at position `along` on edge e and distance d from it, and edgeIndex on it.
    auto at = [&](double along, double d) {
      return e < 2 ? Vec2(along, e == 0 ? d : 1 - d) : Vec2(e == 2 ? d : 1 - d, along);
    };
    auto index = [&](int i, int j) { return edgeIndex(e, i, j); };
    if (cv[index(n / 2, 0)] > 0) continue;  // not an edge with a bounding plane
    planeEdges |= 1u << e;
    // The edge's ridge point with the highest bound: face coordinates, A, C and distance from the edge.
    double bu = 0, bv = 0, ba = 0, bc = 0, best = -std::numeric_limits<double>::infinity(), ridgeStep = 0;
    for (int i = 2; i < n - 2; ++i) {
      const double a0 = sign * av[index(i, 0)], slope = (sign * av[index(i, 1)] - a0) / kNearEdge;
      if (!(a0 > 0) || !(slope < 0) || !(-2 * a0 / slope < Axis::step)) continue;
      const double d = std::max(-2 * a0 / slope, kNearEdge);
      const Vec2 p = at(Axis::coord(i), d);
      if (!faceSet) face.set(terms, f), faceSet = true;
      const auto [aa, cc] = face.at(p.x(), p.y());
      add(aa, cc);
      if (cc > 0 && -sign * aa / cc > best)
        best = -sign * aa / cc, bu = p.x(), bv = p.y(), ba = aa, bc = cc, ridgeStep = d;
    }
    if (!(ridgeStep > 0)) continue;
    for (double step = 0.5 * ridgeStep; step > 1e-3 * ridgeStep;) {
      bool moved = false;
      for (int dir = 0; dir < 4; ++dir) {
        const double uu = std::clamp(bu + (dir == 0 ? step : dir == 1 ? -step : 0.0), 0.0, 1.0);
        const double vv = std::clamp(bv + (dir == 2 ? step : dir == 3 ? -step : 0.0), 0.0, 1.0);
        const auto [aa, cc] = face.at(uu, vv);
        if (cc > 0 && -sign * aa / cc > best) {
          best = -sign * aa / cc, bu = uu, bv = vv, ba = aa, bc = cc;
          moved = true;
        }
      }
      if (!moved) step *= 0.5;
    }
    add(ba, bc);
  }
  std::fill(r, r + n * n, sign);
  // On an edge with a bounding plane C = 0, and the side coefficients decide (uncrossedEdgeSamples): the
  // samples there are written as met.
  for (int e = 0; e < 4; ++e)
    if ((planeEdges >> e) & 1)
      for (int i = 0; i < n; ++i) a[edgeIndex(e, i, 0)] = sign;
  return count;
}

struct CellResult {
  double central = 0;
  bool ok = true;
};

/// The central coefficient of a cell (configuration `config`): the fit clamped into the interval that the
/// cell lattice's samples allow, then the open faces' samples where they can be met with it, then the
/// staggered lattice where the first look suggests it (see below). Where no value meets the cell lattice,
/// the result is not ok and the coefficient is 0, or with `fallBackToLeastContradicted` the value the fewest
/// counting samples contradict (only for the cells still unresolved after the fallback rounds, as it
/// examines more samples). Where only the second look (the staggered lattice) finds no value, the result is
/// not ok and the coefficient is the one from before it.
CellResult fitCell(const CornerPatch& patch, std::uint8_t config, const CellReference& ref,
                   bool fallBackToLeastContradicted = false) {
  using Axis = CellAxis;
  constexpr int n = Axis::n;
  constexpr int kLattice = n * n * n;
  // Samples: the inset cell lattice, then the samples of each of the cell's faces that are not bounding
  // planes (no crossing on their edges: the cell across has no patch there or none that joins this one, so a
  // wrong sign anywhere on such a face is a hole; openFaceSamples). After them, where the cell lattice
  // suggests it (see below), the staggered lattice.
  using Staggered = StaggeredCellAxis;
  constexpr int kStaggered = Staggered::n * Staggered::n * Staggered::n;
  constexpr int kOpen = 6 * kOpenFaceSamples;
  std::array<double, kLattice + kOpen + kStaggered> r, value, basis;
  // Fit points lie on the lattice lines along the axis closest to the mean corner normal.
  Vec3 meanNormal = Vec3::Zero();
  for (int k = 0; k < patch.numCorners; ++k) meanNormal += patch.normal[k];
  int fitAxis = 0;
  meanNormal.cwiseAbs().maxCoeff(&fitAxis);
  const LinearTerms terms(patch);
  const PatchLines<Axis> lines(terms, fitAxis);
  referenceCellLattice<Axis>(ref, fitAxis, r.data());
  lines.lattice(value.data(), basis.data());
  // The open faces' samples, face after face (the first OpenFaceAxis::n^2 of each are its lattice).
  int count = kLattice, numOpen = 0;
  std::array<std::array<int, 2>, 6> open;  // face, first sample
  for (int f = 0; f < 6; ++f)
    if (!((patch.faceMask >> f) & 1)) {
      open[static_cast<std::size_t>(numOpen++)] = {f, count};
      count += openFaceSamples(terms, f, (config >> cube::faceVertex(f, 0)) & 1, &r[count], &value[count],
                               &basis[count]);
    }
  // The staggered lattice's patch lines and where its samples begin, while the second look below has them
  // (a pointer rather than an optional: the optional's storage, 2 KB, was zero-filled in every cell).
  const PatchLines<Staggered>* staggeredLines = nullptr;
  int staggeredBegin = -1;
  auto staggeredSample = [&](int i) {
    return staggeredBegin >= 0 && i >= staggeredBegin && i < staggeredBegin + kStaggered;
  };
  // Where the open faces cannot be met with the lattice, their lattice points where the reference agrees
  // with the corners take their place as reference samples (gatherAgreeing, below): `softOpen`, and per such
  // sample its face and index on the face's lattice.
  bool softOpen = false;
  std::array<std::array<int, 2>, 6 * OpenFaceAxis::n * OpenFaceAxis::n> faceOf;
  auto openPoint = [&](int i) {
    const auto [f, j] = faceOf[static_cast<std::size_t>(i - kLattice)];
    return faceLatticePoint<OpenFaceAxis>(f, j % OpenFaceAxis::n, j / OpenFaceAxis::n);
  };
  auto position = [&](int i) {
    if (i < kLattice) return lines.point(i);
    if (!staggeredSample(i)) return openPoint(i);  // softOpen
    return staggeredLines->point(i - staggeredBegin);
  };
  // Least-squares fit to the reference surface points between lattice neighbours along the fit axis (linear
  // interpolation of the reference), where the patch is evaluated exactly.
  double num = 0, den = 0;
  int fitCount = 0;
  // Sign changes along the lines as bits (few lines cross the surface: no branch per pair); line (p, q) is
  // the n bits from lines.index(0, p, q) on.
  std::array<std::uint64_t, (kLattice + 63) / 64> positive;
  for (int w = 0; w < (kLattice + 63) / 64; ++w)
    positive[static_cast<std::size_t>(w)] = positiveBits(r.data() + 64 * w, std::min(64, kLattice - 64 * w));
  for (int q = 0; q < n; ++q)
    for (int p = 0; p < n; ++p) {
      const int start = lines.index(0, p, q), word = start / 64, shift = start % 64;
      std::uint64_t line = positive[static_cast<std::size_t>(word)] >> shift;
      if (shift + n > 64) line |= positive[static_cast<std::size_t>(word + 1)] << (64 - shift);
      const auto signs = static_cast<unsigned>(line & ((1u << n) - 1));
      for (unsigned changes = (signs ^ (signs >> 1)) & ((1u << (n - 1)) - 1); changes;
           changes &= changes - 1) {
        const int i = __builtin_ctz(changes);
        const double r0 = r[static_cast<std::size_t>(lines.index(i, p, q))];
        const double r1 = r[static_cast<std::size_t>(lines.index(i + 1, p, q))];
        double b;
        const double v = lines.at(Axis::coord(i) + r0 / (r0 - r1) * Axis::step, p, q, b);
        num += v * b;
        den += b * b;
        ++fitCount;
      }
    }
  const double cCentre = centreSquares(patch.faceMask);  // patch.centralBasis((0.5, 0.5, 0.5))
  den += kRidge * cCentre * cCentre * std::max(1, fitCount);
  // Samples within the margin by the first-order estimate are left free, but where the clamped coefficient
  // gives one of them the wrong sign, the estimate is checked by Newton steps on the reference; a sample that
  // turns out farther than kVerifiedVoxels from the surface counts after all.
  auto far = [&](int i) {
    if (i >= kLattice && !staggeredSample(i)) {
      if (!softOpen) return true;  // an open-face sample counts always
      const auto [f, j] = faceOf[static_cast<std::size_t>(i - kLattice)];
      return farFromSurface(ref, r[static_cast<std::size_t>(i)],
                            faceGradient(ref, f, OpenFaceAxis::coord(j % OpenFaceAxis::n),
                                         OpenFaceAxis::coord(j / OpenFaceAxis::n)));
    }
    const Vec3 g = i < kLattice ? lines.gradient(r.data(), i)
                                : staggeredLines->gradient(r.data() + staggeredBegin, i - staggeredBegin);
    return farFromSurface(ref, r[static_cast<std::size_t>(i)], g);
  };
  const int lineAxes[3] = {fitAxis, cube::otherAxes(fitAxis)[0], cube::otherAxes(fitAxis)[1]};
  const LatticeLayout cellLayout = LatticeLayout::of<Axis>(3, lineAxes, ref.metric);
  auto confirmFar = [&](int i) {
    if (i >= kLattice && !staggeredSample(i))  // softOpen: Newton steps only
      return !referenceSurfaceWithin(ref, openPoint(i), r[static_cast<std::size_t>(i)], kVerifiedVoxels);
    const bool near = i < kLattice ? neighbourCrosses(r.data(), i, cellLayout, kVerifiedVoxels)
                                   : neighbourCrosses(r.data() + staggeredBegin, i - staggeredBegin,
                                                      LatticeLayout::of<Staggered>(3, lineAxes, ref.metric),
                                                      kVerifiedVoxels);
    return !near &&
           !referenceSurfaceWithin(ref, position(i), r[static_cast<std::size_t>(i)], kVerifiedVoxels);
  };
  const double fitted = fitCount > 0 ? -num / den : 0.0;
  // The open faces' lattice points where the reference agrees with the corners, as reference samples from
  // index kLattice on (over the open faces' own samples); returns the end of the samples.
  auto gatherAgreeing = [&] {
    constexpr int nf = OpenFaceAxis::n;
    int kept = kLattice;
    for (int k = 0; k < numOpen; ++k) {
      std::array<double, nf * nf> reference;
      referenceFaceLattice<OpenFaceAxis>(ref, open[static_cast<std::size_t>(k)][0], reference.data());
      for (int j = 0; j < nf * nf; ++j) {
        const int i = open[static_cast<std::size_t>(k)][1] + j;
        if ((reference[static_cast<std::size_t>(j)] > 0) != (r[static_cast<std::size_t>(i)] > 0)) continue;
        r[static_cast<std::size_t>(kept)] = reference[static_cast<std::size_t>(j)];
        value[static_cast<std::size_t>(kept)] = value[static_cast<std::size_t>(i)];
        basis[static_cast<std::size_t>(kept)] = basis[static_cast<std::size_t>(i)];
        faceOf[static_cast<std::size_t>(kept - kLattice)] = {open[static_cast<std::size_t>(k)][0], j};
        ++kept;
      }
    }
    softOpen = true;
    return kept;
  };
  // The lattice first. Where no value meets it, the cell is unresolved; the last fallback takes the value
  // that the fewest of its samples and the open faces' agreeing points contradict, nearest to 0 (better than
  // the fit there: Marschner-Lobb at N = 32 exact has 0 wrong-sign cells with 0, 96 with the fit).
  thread_local SignConstraintSolver solver, latticeOnly;
  solver.reset();
  const SignedCoefficient lattice =
      solver.solve(fitted, {r.data(), value.data(), basis.data(), kLattice}, far, confirmFar);
  if (!lattice.feasible) {
    if (!fallBackToLeastContradicted) return CellResult{0.0, false};
    const SignSamples agreeing{r.data(), value.data(), basis.data(), gatherAgreeing()};
    return CellResult{leastContradicted(0.0, agreeing, far, confirmFar), false};
  }
  // The open faces' samples join where the lattice's coefficient fails one of them. Where no value meets
  // them with the lattice (the reference crosses an open face or bulges towards it with sign structure the
  // cell's loops do not have, as on Marschner-Lobb, or the patch without the central term is too far off
  // there), the open faces' lattice points count only where the reference has the corners' sign too, and
  // only where they lie away from its surface, as the cell lattice's do. Where not even those can be met,
  // the lattice decides. Either way the patch may cross the face there, a hole (docs/method.md, "Holes");
  // failing the cell instead makes the fallback rounds blend normals, which spread failures (Marschner-Lobb
  // at N = 32 exact: 16 more unresolved cells, 144 blended isovertices and 0.3 degrees more normal error).
  // `used`: the samples the solver knows, from index 0; latticeOnly keeps it as it was after the lattice.
  SignedCoefficient sc = lattice;
  int used = kLattice;
  std::array<std::uint64_t, (kOpen + 63) / 64> failing;
  const bool openFails =
      count > kLattice && slackSweep({&r[kLattice], &value[kLattice], &basis[kLattice], count - kLattice},
                                     lattice.value, failing.data()) > 0;
  if (openFails) {
    latticeOnly = solver;
    sc = solver.solve(fitted, {r.data(), value.data(), basis.data(), count}, far, confirmFar);
    used = count;
    if (!sc.feasible) {
      solver = latticeOnly;
      used = gatherAgreeing();
      sc = solver.solve(fitted, {r.data(), value.data(), basis.data(), used}, far, confirmFar);
    }
    if (!sc.feasible) {
      solver = latticeOnly;
      sc = lattice;
      used = kLattice;
    }
  }
  // A second look, between the lattice points: where the clamping found kStaggeredTrigger or more samples on
  // the wrong side that lie near the surface, the patch and the reference part ways inside the cell, and a
  // wrong sign farther out can hide between the lattice points. The staggered lattice (with the cell
  // lattice, a body-centred one) joins the samples; where no value meets it with the open faces' samples,
  // it is tried with the lattice alone, as above. If no coefficient meets the lattices, the cell is
  // unresolved, so that the fallback rounds blend its normals; it keeps the coefficient it had before the
  // second look meanwhile, and at the end if it stays unresolved.
  if (solver.confirmedNear() >= kStaggeredTrigger) {
    const PatchLines<Staggered> staggered(terms, fitAxis);
    staggeredLines = &staggered;
    staggeredBegin = used;
    referenceCellLattice<Staggered>(ref, fitAxis, r.data() + staggeredBegin);
    staggeredLines->lattice(value.data() + staggeredBegin, basis.data() + staggeredBegin);
    const SignedCoefficient first = sc;
    sc = solver.solve(fitted, {r.data(), value.data(), basis.data(), used + kStaggered}, far, confirmFar);
    if (!sc.feasible && used > kLattice) {
      std::copy_n(r.data() + staggeredBegin, kStaggered, r.data() + kLattice);
      std::copy_n(value.data() + staggeredBegin, kStaggered, value.data() + kLattice);
      std::copy_n(basis.data() + staggeredBegin, kStaggered, basis.data() + kLattice);
      staggeredBegin = kLattice;
      sc = latticeOnly.solve(fitted, {r.data(), value.data(), basis.data(), kLattice + kStaggered}, far,
                             confirmFar);
    }
    staggeredLines = nullptr;  // `staggered` ends here; no sample is examined after it
    if (!sc.feasible) return CellResult{first.value, false};
  }
  return CellResult{sc.value, true};
}

/// Grid faces with crossings, each with its (one or two) cells, and per cell the index of each of its faces
/// in that table (-1: not a bounding plane).
struct FaceTable {
  std::vector<FaceEntry> faces;
  std::vector<std::array<std::int32_t, 6>> cellFaces;
  std::vector<std::uint8_t> ownedFaces;  ///< per cell, bit f: the cell is its face f's first cell
};

/// The first cell of a face (lowest index) computes it. Faces are listed as the cells meet them in grid
/// (raster) order: a cell's far face along an axis (side 1) is new, its near face (side 0) is the far face
/// of the cell below if that cell has it. The cells below along an axis come in raster order too, so one
/// cursor per axis finds them. Throws cip::Error if the cells are not in that order.
FaceTable buildFaceTable(const Model& model, const std::vector<CellLoops>& loops) {
  const std::size_t numCells = model.cells.size();
  const auto& dims = model.geometry.dims;
  const std::array<std::uint64_t, 3> step{1, static_cast<std::uint64_t>(dims[0]),
                                          static_cast<std::uint64_t>(dims[0] * dims[1])};
  auto key = [&](std::size_t c) {
    const auto& p = model.cells[c].index;
    return p[0] * step[0] + p[1] * step[1] + p[2] * step[2];
  };
  FaceTable table;
  std::vector<FaceEntry>& faces = table.faces;
  auto& cellFaces = table.cellFaces;
  table.ownedFaces.assign(numCells, 0);
  cellFaces.resize(numCells);
  for (auto& cf : cellFaces) cf.fill(-1);
  std::size_t bounding = 0;
  for (const CellLoops& l : loops) bounding += static_cast<std::size_t>(__builtin_popcount(l.faceMask));
  faces.reserve(bounding / 2 + numCells);
  std::array<std::size_t, 3> cursor{};
  for (std::size_t c = 0; c < numCells; ++c) {
    const std::uint64_t k = key(c);
    if (c > 0 && k <= key(c - 1))
      throw Error("fitModelPatches: cells must be in grid order (by z, y, x), each once");
    for (int f = 0; f < 6; ++f) {
      if (!((loops[c].faceMask >> f) & 1)) continue;
      const int axis = cube::faceAxis(f);
      if (cube::faceSide(f) == 0 && model.cells[c].index[axis] > 0) {
        const std::uint64_t below = k - step[axis];
        std::size_t& at = cursor[axis];
        while (at < c && key(at) < below) ++at;
        if (at < c && key(at) == below) {
          const std::int32_t i = cellFaces[at][f + 1];
          if (i >= 0) {
            FaceEntry& e = faces[static_cast<std::size_t>(i)];
            e.cell[1] = static_cast<std::uint32_t>(c);
            e.face[1] = static_cast<std::int8_t>(f);
            e.count = 2;
            cellFaces[c][f] = i;
            continue;
          }
        }
      }
      FaceEntry e;
      e.cell[0] = static_cast<std::uint32_t>(c);
      e.face[0] = static_cast<std::int8_t>(f);
      e.count = 1;
      cellFaces[c][f] = static_cast<std::int32_t>(faces.size());
      table.ownedFaces[c] = static_cast<std::uint8_t>(table.ownedFaces[c] | (1u << f));
      faces.push_back(e);
    }
  }
  return table;
}

}  // namespace

FittingStats fitModelPatches(Model& model, const std::vector<CellLoops>& loops,
                             const std::function<void(std::size_t, CellReference&)>& reference) {
  FittingStats stats;
  const std::size_t numCells = model.cells.size(), numVertices = model.vertices.size();
  if (loops.size() != numCells) throw Error("fitModelPatches: one CellLoops per cell expected");
  if (numCells == 0) return stats;
  // Gradient normal and edge axis of every isovertex (a byte each: most cells write each of theirs).
  std::vector<Vec3> baseNormal(numVertices);
  std::vector<std::uint8_t> edgeAxis(numVertices, 0);
  for (std::size_t v = 0; v < numVertices; ++v) baseNormal[v] = model.vertices[v].normal;
  for (std::size_t c = 0; c < numCells; ++c) {
    const ModelCell& cell = model.cells[c];
    for (int k = 0; k < cell.numCorners(); ++k)
      edgeAxis[model.corners[cell.firstCorner + k]] =
          static_cast<std::uint8_t>(cube::edgeAxis(loops[c].edges[k]));
  }
  // The edge direction of an isovertex, towards the positive vertex.
  auto edgeDirection = [&](std::size_t v) {
    const int axis = edgeAxis[v];
    return Vec3(Vec3::Unit(axis) * (baseNormal[v][axis] >= 0 ? 1.0 : -1.0));
  };
  FaceTable table = buildFaceTable(model, loops);
  const std::vector<FaceEntry>& faces = table.faces;
  const std::vector<std::array<std::int32_t, 6>>& cellFaces = table.cellFaces;

  std::vector<std::uint8_t> level(numVertices, 0), bump(numVertices, 0);
  std::vector<std::uint8_t> faceDirty(faces.size(), 1), cellDirty(numCells, 1);
  std::vector<std::uint8_t> faceOk(faces.size(), 1), cellOk(numCells, 1);
  // Per face, whether FaceResult::holeEdges has an edge on a face that is open in one of its cells (a cell
  // face without a crossing, which no patch continues): there the patch's zero set ends, a hole. Where both
  // cells have a bounding plane through the edge instead, their zero sets meet along it (a crease).
  std::vector<std::uint8_t> faceHole(faces.size(), 0);
  auto opensAHole = [&](std::size_t i, std::uint8_t holeEdges) {
    const FaceEntry& face = faces[i];
    for (int k = 0; k < 4; ++k) {
      if (!((holeEdges >> k) & 1)) continue;
      const auto both = cube::edgeFaces(cube::faceEdge(face.face[0], k));
      const int other = both[0] == face.face[0] ? both[1] : both[0];  // the same plane in both cells
      for (int s = 0; s < face.count; ++s)
        if (!((loops[face.cell[s]].faceMask >> other) & 1)) return true;
    }
    return false;
  };
  std::vector<double> faceCoefficient(faces.size(), 0.0);
  auto cellVertex = [&](std::size_t c, int k) { return model.corners[model.cells[c].firstCorner + k]; };
  const std::vector<std::uint8_t>& ownedFaces = table.ownedFaces;
  auto ownedDirtyFace = [&](std::size_t c, int f) {
    return ((ownedFaces[c] >> f) & 1) && faceDirty[static_cast<std::size_t>(cellFaces[c][f])];
  };
  // The round's cells, ascending: all of them first, then the cells of the faces touched by an isovertex
  // whose blend level changed (a dirty face's cells are both dirty, so its first cell fits it).
  std::vector<std::uint32_t> dirtyCells(numCells), changedVertices;
  for (std::size_t c = 0; c < numCells; ++c) dirtyCells[c] = static_cast<std::uint32_t>(c);
  std::vector<std::uint8_t> vertexChanged;  // flags of changedVertices while the next round's cells are found
  std::vector<CellReference> blockReference(std::min(numCells, kBlockCells));
  // Cells without a sign-correct central coefficient or with a face without a sign-correct side coefficient.
  // Failures are few: the flags are scanned, not every cell's faces.
  auto unresolvedCells = [&] {
    std::vector<std::uint32_t> out;
    for (std::size_t c = 0; c < numCells; ++c)
      if (!cellOk[c]) out.push_back(static_cast<std::uint32_t>(c));
    for (std::size_t i = 0; i < faces.size(); ++i)
      if (!faceOk[i])
        for (int s = 0; s < faces[i].count; ++s) out.push_back(faces[i].cell[s]);
    std::sort(out.begin(), out.end());
    out.erase(std::unique(out.begin(), out.end()), out.end());
    return out;
  };
  // Whether one of `cells` gets sign-correct side coefficients on all its faces and a sign-correct central
  // coefficient when fitted alone with the current normals, exactly as a round would fit it (each face by its
  // first cell). The model is not changed.
  auto someCellResolves = [&](const std::vector<std::uint32_t>& cells) {
    std::atomic<bool> found{false};
    tbb::parallel_for(std::size_t(0), cells.size(), [&](std::size_t j) {
      if (found.load(std::memory_order_relaxed)) return;
      const std::size_t c = cells[j];
      CornerPatch patch = model.patch(c, loops[c]);
      CellReference ref, firstRef;
      reference(c, ref);
      for (int f = 0; f < 6; ++f) {
        const std::int32_t i = cellFaces[c][f];
        if (i < 0) continue;
        const FaceEntry& face = faces[static_cast<std::size_t>(i)];
        const std::size_t first = face.cell[0];
        if (first != c) reference(first, firstRef);
        const FaceResult fr =
            first == c ? fitFace(patch, model.cells[c].config, model.cells[c].pairing03, face.face[0], ref)
                       : fitFace(model.patch(first, loops[first]), model.cells[first].config,
                                 model.cells[first].pairing03, face.face[0], firstRef);
        if (!fr.ok) return;
        patch.faceCoefficient[static_cast<std::size_t>(f)] = fr.coefficient;
      }
      patch.central = 0;
      if (fitCell(patch, model.cells[c].config, ref).ok) found.store(true, std::memory_order_relaxed);
    });
    return found.load();
  };
  std::size_t bestUnresolved = 0;
  // What a round overwrites, to undo it: per dirty cell its coefficients and result, per refitted face its
  // result.
  struct SavedCell {
    double central;
    std::array<double, 6> faceCoefficient;
    std::uint8_t ok;
  };
  struct SavedFace {
    std::size_t index;
    double coefficient;
    std::uint8_t ok, hole;
  };
  std::vector<SavedCell> savedCells;
  std::vector<SavedFace> savedFaces;
  auto setNormal = [&](std::size_t v) {
    double beta = kBlend[level[v]];
    const Vec3 edge = edgeDirection(v);
    Vec3 n = (1 - beta) * baseNormal[v] + beta * edge;
    model.vertices[v].normal = n.norm() > 1e-12 ? Vec3(n.normalized()) : edge;
  };
  // A face's fit recorded (by its first cell), then copied to both its cells; a cell's central coefficient
  // fitted with the side coefficients it has. The rounds and the local blends below fit alike.
  auto recordFace = [&](std::size_t i, const FaceResult& fr) {
    faceCoefficient[i] = fr.coefficient;
    faceOk[i] = fr.ok;
    faceHole[i] = opensAHole(i, fr.holeEdges);
  };
  auto shareFace = [&](std::size_t i) {
    const FaceEntry& face = faces[i];
    for (int s = 0; s < face.count; ++s)
      model.cells[face.cell[s]].faceCoefficient[face.face[s]] = faceCoefficient[i];
  };
  auto refitCell = [&](std::size_t c, const CellReference& ref) {
    model.cells[c].central = 0;
    const CellResult cr = fitCell(model.patch(c, loops[c]), model.cells[c].config, ref);
    model.cells[c].central = cr.central;
    cellOk[c] = cr.ok;
  };
  // Puts back what savedFaces and savedCells (one per cell of `cells`) hold.
  auto restoreSaved = [&](const std::vector<std::uint32_t>& cells) {
    for (std::size_t j = 0; j < cells.size(); ++j) {
      ModelCell& cell = model.cells[cells[j]];
      cell.central = savedCells[j].central;
      cell.faceCoefficient = savedCells[j].faceCoefficient;
      cellOk[cells[j]] = savedCells[j].ok;
    }
    for (const SavedFace& saved : savedFaces) {
      faceCoefficient[saved.index] = saved.coefficient;
      faceOk[saved.index] = saved.ok;
      faceHole[saved.index] = saved.hole;
    }
  };
  for (int round = 0;; ++round) {
    stats.rounds = round + 1;
    if (round > 0) {
      savedCells.clear();
      savedFaces.clear();
      for (std::uint32_t c : dirtyCells) {
        savedCells.push_back({model.cells[c].central, model.cells[c].faceCoefficient, cellOk[c]});
        for (int f = 0; f < 6; ++f)
          if (ownedDirtyFace(c, f)) {
            const auto i = static_cast<std::size_t>(cellFaces[c][f]);
            savedFaces.push_back({i, faceCoefficient[i], faceOk[i], faceHole[i]});
          }
      }
    }
    if (round == 0)
      tbb::parallel_for(std::size_t(0), numVertices, setNormal);
    else
      for (std::uint32_t v : changedVertices) setNormal(v);
    // Cells in blocks of index order. A face is fitted by its first cell (the lowest index), so when a
    // block's cells are fitted, every face they touch has been fitted in this block or an earlier one, and
    // each cell's reference is built once per round for its faces and itself.
    for (std::size_t b0 = 0; b0 < dirtyCells.size(); b0 += kBlockCells) {
      const std::size_t b1 = std::min(dirtyCells.size(), b0 + kBlockCells);
      tbb::parallel_for(
          tbb::blocked_range<std::size_t>(b0, b1, 32), [&](const tbb::blocked_range<std::size_t>& r) {
            for (std::size_t j = r.begin(); j != r.end(); ++j) {
              const std::size_t c = dirtyCells[j];
              CellReference& ref = blockReference[j - b0];
              reference(c, ref);
              unsigned fits = 0;  // the faces this cell fits now
              for (int f = 0; f < 6; ++f) fits |= unsigned{ownedDirtyFace(c, f)} << f;
              if (!fits) continue;
              const CornerPatch patch = model.patch(c, loops[c]);
              for (int f = 0; f < 6; ++f) {
                if (!((fits >> f) & 1)) continue;
                const auto i = static_cast<std::size_t>(cellFaces[c][f]);
                recordFace(i, fitFace(patch, model.cells[c].config, model.cells[c].pairing03, f, ref));
              }
            }
          });
      for (std::size_t j = b0; j < b1; ++j)
        for (int f = 0; f < 6; ++f) {
          const std::size_t c = dirtyCells[j];
          if (ownedDirtyFace(c, f)) shareFace(static_cast<std::size_t>(cellFaces[c][f]));
        }
      tbb::parallel_for(tbb::blocked_range<std::size_t>(b0, b1, 32),
                        [&](const tbb::blocked_range<std::size_t>& r) {
                          for (std::size_t j = r.begin(); j != r.end(); ++j)
                            refitCell(dirtyCells[j], blockReference[j - b0]);
                        });
    }
    // A fallback round that does not reduce the unresolved cells is undone, and the rounds end: blending
    // normals cannot make a cell follow sign structure its loops do not have (a field with detail inside
    // cells), and there it only spreads failures to the neighbours (Marschner-Lobb at N = 32, exact: 160
    // unresolved cells after the first round, 280 after ten).
    const std::size_t unresolved = unresolvedCells().size();
    if (round > 0 && unresolved >= bestUnresolved) {
      restoreSaved(dirtyCells);
      for (std::uint32_t v : changedVertices) {
        --level[v];
        setNormal(v);
      }
      stats.lastRoundUndone = true;
      break;
    }
    bestUnresolved = unresolved;
    // Isovertices of failed faces and cells move one blend level towards the edge direction. Only this
    // round's faces and cells can bump one: a failure left from an earlier round that was not refitted has
    // all its isovertices at the last level.
    changedVertices.clear();
    auto mark = [&](std::size_t c, std::uint16_t edgeMask) {
      const ModelCell& cell = model.cells[c];
      for (int k = 0; k < cell.numCorners(); ++k) {
        if (!((edgeMask >> loops[c].edges[k]) & 1)) continue;
        const std::uint32_t v = cellVertex(c, k);
        if (level[v] < kMaxLevel && !bump[v]) {
          bump[v] = 1;
          changedVertices.push_back(v);
        }
      }
    };
    for (std::uint32_t c : dirtyCells) {
      for (int f = 0; f < 6; ++f) {
        if (!ownedDirtyFace(c, f) || faceOk[static_cast<std::size_t>(cellFaces[c][f])]) continue;
        std::uint16_t mask = 0;
        for (int k = 0; k < 4; ++k) mask = static_cast<std::uint16_t>(mask | (1u << cube::faceEdge(f, k)));
        mark(c, mask);
      }
      if (!cellOk[c]) mark(c, 0xFFF);
    }
    if (changedVertices.empty()) break;
    for (std::uint32_t v : changedVertices) {
      ++level[v];
      bump[v] = 0;
      setNormal(v);
    }
    // The next round can lower the count of unresolved cells only if one of them resolves, and what a round
    // gives a cell depends on its own isovertices alone. If none resolves when fitted alone, the round would
    // be undone: end here with the same result, without refitting the cells around them.
    if (!someCellResolves(unresolvedCells())) {
      for (std::uint32_t v : changedVertices) {
        --level[v];
        setNormal(v);
      }
      stats.rounds = round + 2;
      stats.lastRoundUndone = true;
      break;
    }
    // Next round: the cells of changed isovertices (found by a pass over the corners; there are few rounds),
    // all their faces, and the other cells of those faces.
    if (dirtyCells.size() == numCells) {
      std::fill(cellDirty.begin(), cellDirty.end(), 0);
      std::fill(faceDirty.begin(), faceDirty.end(), 0);
    } else {
      for (std::uint32_t c : dirtyCells) {
        cellDirty[c] = 0;
        for (int f = 0; f < 6; ++f)
          if (cellFaces[c][f] >= 0) faceDirty[static_cast<std::size_t>(cellFaces[c][f])] = 0;
      }
    }
    dirtyCells.clear();
    vertexChanged.resize(numVertices, 0);
    for (std::uint32_t v : changedVertices) vertexChanged[v] = 1;
    for (std::size_t c = 0; c < numCells; ++c)
      for (int k = 0; k < model.cells[c].numCorners(); ++k)
        if (vertexChanged[cellVertex(c, k)]) {
          cellDirty[c] = 1;
          dirtyCells.push_back(static_cast<std::uint32_t>(c));
          break;
        }
    for (std::uint32_t v : changedVertices) vertexChanged[v] = 0;
    const std::size_t touched = dirtyCells.size();
    for (std::size_t j = 0; j < touched; ++j)
      for (int f = 0; f < 6; ++f) {
        const std::int32_t i = cellFaces[dirtyCells[j]][f];
        if (i < 0) continue;
        faceDirty[static_cast<std::size_t>(i)] = 1;
        const FaceEntry& face = faces[static_cast<std::size_t>(i)];
        for (int s = 0; s < face.count; ++s)
          if (!cellDirty[face.cell[s]]) {
            cellDirty[face.cell[s]] = 1;
            dirtyCells.push_back(face.cell[s]);
          }
      }
    std::sort(dirtyCells.begin(), dirtyCells.end());
  }
  // Holes the rounds leave: faces whose uncrossed edges their side coefficient cannot keep at the vertices'
  // sign together with the face lattice, where the reference keeps that sign, next to an open face
  // (faceHole). The corner planes of the face's isovertices stand in the way, so they move towards the edge
  // direction one level at a time, here alone: the faces and cells around them are fitted again, and the
  // blend is kept at the first level where the hole closes and no face or cell around it fails or gets a hole
  // it did not have; otherwise it is undone. As failures, holes would spread to the neighbours through the
  // rounds (docs/method.md, step 7). One hole at a time, in index order, so the model does not depend on the
  // number of threads.
  std::vector<std::uint32_t> holes;
  for (std::size_t i = 0; i < faces.size(); ++i)
    if (faceHole[i] && faceOk[i]) holes.push_back(static_cast<std::uint32_t>(i));
  stats.holes = holes.size();
  if (!holes.empty()) {
    // The cells of each isovertex (at most 4), as offsets into one array.
    std::vector<std::uint32_t> cellsOfVertex, firstCellOf(numVertices + 1, 0);
    for (std::size_t c = 0; c < numCells; ++c)
      for (int k = 0; k < model.cells[c].numCorners(); ++k) ++firstCellOf[cellVertex(c, k) + 1];
    std::partial_sum(firstCellOf.begin(), firstCellOf.end(), firstCellOf.begin());
    cellsOfVertex.resize(firstCellOf[numVertices]);
    {
      std::vector<std::uint32_t> next(firstCellOf.begin(), firstCellOf.end() - 1);
      for (std::size_t c = 0; c < numCells; ++c)
        for (int k = 0; k < model.cells[c].numCorners(); ++k)
          cellsOfVertex[next[cellVertex(c, k)]++] = static_cast<std::uint32_t>(c);
    }
    std::vector<std::uint32_t> vertices, regionCells, regionFaces;
    std::vector<std::uint8_t> startLevel;  // of `vertices`
    CellReference ref;
    for (std::uint32_t target : holes) {
      if (!faceHole[target]) continue;  // closed by an earlier blend
      // The isovertices on the face's edges, from the face's first cell.
      const std::size_t owner = faces[target].cell[0];
      std::uint16_t edgeMask = 0;
      for (int k = 0; k < 4; ++k)
        edgeMask = static_cast<std::uint16_t>(edgeMask | (1u << cube::faceEdge(faces[target].face[0], k)));
      vertices.clear();
      for (int k = 0; k < model.cells[owner].numCorners(); ++k)
        if ((edgeMask >> loops[owner].edges[k]) & 1) vertices.push_back(cellVertex(owner, k));
      // The faces of the cells around them and all those faces' cells, as a round would fit them.
      regionCells.clear();
      regionFaces.clear();
      for (std::uint32_t v : vertices)
        for (std::uint32_t j = firstCellOf[v]; j < firstCellOf[v + 1]; ++j)
          for (int f = 0; f < 6; ++f)
            if (cellFaces[cellsOfVertex[j]][f] >= 0)
              regionFaces.push_back(static_cast<std::uint32_t>(cellFaces[cellsOfVertex[j]][f]));
      std::sort(regionFaces.begin(), regionFaces.end());
      regionFaces.erase(std::unique(regionFaces.begin(), regionFaces.end()), regionFaces.end());
      for (std::uint32_t i : regionFaces)
        for (int s = 0; s < faces[i].count; ++s) regionCells.push_back(faces[i].cell[s]);
      std::sort(regionCells.begin(), regionCells.end());
      regionCells.erase(std::unique(regionCells.begin(), regionCells.end()), regionCells.end());
      savedFaces.clear();
      savedCells.clear();
      for (std::uint32_t i : regionFaces)
        savedFaces.push_back({i, faceCoefficient[i], faceOk[i], faceHole[i]});
      for (std::uint32_t c : regionCells)
        savedCells.push_back({model.cells[c].central, model.cells[c].faceCoefficient, cellOk[c]});
      startLevel.clear();
      for (std::uint32_t v : vertices) startLevel.push_back(level[v]);
      bool closed = false;
      for (;;) {
        bool moved = false;
        for (std::uint32_t v : vertices)
          if (level[v] < kMaxLevel) {
            ++level[v];
            setNormal(v);
            moved = true;
          }
        if (!moved) break;
        for (std::uint32_t i : regionFaces) {
          const std::size_t c = faces[i].cell[0];
          reference(c, ref);
          recordFace(i, fitFace(model.patch(c, loops[c]), model.cells[c].config, model.cells[c].pairing03,
                                faces[i].face[0], ref));
          shareFace(i);
        }
        for (std::uint32_t c : regionCells) {
          reference(c, ref);
          refitCell(c, ref);
        }
        bool worse = false;
        for (const SavedFace& saved : savedFaces)
          worse |= (saved.ok && !faceOk[saved.index]) || (!saved.hole && faceHole[saved.index]);
        for (std::size_t j = 0; j < regionCells.size(); ++j)
          worse |= savedCells[j].ok && !cellOk[regionCells[j]];
        if (worse) break;
        if (!faceHole[target]) {
          closed = true;
          break;
        }
      }
      if (closed) {
        ++stats.holesClosed;
        continue;
      }
      for (std::size_t j = 0; j < vertices.size(); ++j) {
        level[vertices[j]] = startLevel[j];
        setNormal(vertices[j]);
      }
      restoreSaved(regionCells);
    }
  }
  // Faces left without a sign-correct side coefficient take the one the fewest counting samples contradict
  // (nearest to the fit) instead of the fit, and their cells' central coefficients are fitted again. Then
  // cells left without a sign-correct central coefficient take the one the fewest counting samples
  // contradict (nearest to 0) instead of 0.
  std::vector<std::uint32_t> failedFaces;
  for (std::size_t i = 0; i < faces.size(); ++i)
    if (!faceOk[i]) failedFaces.push_back(static_cast<std::uint32_t>(i));
  tbb::parallel_for(std::size_t(0), failedFaces.size(), [&](std::size_t j) {
    const FaceEntry& face = faces[failedFaces[j]];
    const std::size_t c = face.cell[0];
    CellReference ref;
    reference(c, ref);
    faceCoefficient[failedFaces[j]] = fitFace(model.patch(c, loops[c]), model.cells[c].config,
                                              model.cells[c].pairing03, face.face[0], ref, true)
                                          .coefficient;
  });
  std::vector<std::uint8_t> refit(numCells, 0);
  for (std::uint32_t i : failedFaces) {
    const FaceEntry& face = faces[i];
    for (int s = 0; s < face.count; ++s) {
      model.cells[face.cell[s]].faceCoefficient[face.face[s]] = faceCoefficient[i];
      refit[face.cell[s]] = 1;
    }
  }
  std::vector<std::uint32_t> lastCells;
  for (std::size_t c = 0; c < numCells; ++c)
    if (!cellOk[c] || refit[c]) lastCells.push_back(static_cast<std::uint32_t>(c));
  tbb::parallel_for(std::size_t(0), lastCells.size(), [&](std::size_t j) {
    const std::size_t c = lastCells[j];
    model.cells[c].central = 0;
    CellReference ref;
    reference(c, ref);
    const CellResult cr = fitCell(model.patch(c, loops[c]), model.cells[c].config, ref, true);
    model.cells[c].central = cr.central;
    cellOk[c] = cr.ok;
  });
  for (std::size_t v = 0; v < numVertices; ++v) {
    stats.blendedVertices += level[v] > 0;
    ++stats.levelCount[level[v]];
  }
  for (auto ok : faceOk) stats.failedFaces += !ok;
  for (auto ok : cellOk) stats.failedCells += !ok;
  stats.unresolvedCells = unresolvedCells();
  return stats;
}

}  // namespace cip
