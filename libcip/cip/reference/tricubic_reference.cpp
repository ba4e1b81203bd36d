#include "cip/reference/tricubic_reference.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include "cip/core/error.h"
#include "cip/core/vector_clones.h"
#include "cip/reference/isovertex.h"
#include "cip/reference/point_hermite.h"
#include "cip/topology/cube_topology.h"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace cip {

namespace {

/// Throws for Reconstruction::Auto, which only buildModel resolves.
void requireResolved(Reconstruction kind) {
  if (kind == Reconstruction::Auto) throw Error("the reference needs a resolved reconstruction, not auto");
}

/// The x and y contractions of CellReference::valueAndGradient for the sampled reference: per z Hermite
/// index k, plane[k], planeDx[k] and planeDy[k] as the scalar loop there computes them.
void contractXY(const double* hermite, const double (&w)[3][4], const double (&d)[3][4], double* plane,
                double* planeDx, double* planeDy) {
  for (int k = 0; k < 4; ++k) {
    plane[k] = planeDx[k] = planeDy[k] = 0;
    for (int j = 0; j < 4; ++j) {
      const double* row = &hermite[4 * (j + 4 * k)];
      const double v = w[0][0] * row[0] + w[0][1] * row[1] + w[0][2] * row[2] + w[0][3] * row[3];
      const double dx = d[0][0] * row[0] + d[0][1] * row[1] + d[0][2] * row[2] + d[0][3] * row[3];
      plane[k] += w[1][j] * v;
      planeDx[k] += w[1][j] * dx;
      planeDy[k] += d[1][j] * v;
    }
  }
}

#if defined(CIP_HAS_AVX2_KERNELS)
/// contractXY with the four k in the lanes of a vector (the same operations in the same order, no fused
/// multiply-add, so the same bits): the Newton steps of the sign checks spend most of their time here.
CIP_AVX2_KERNEL void contractXYAvx2(const double* hermite, const double (&w)[3][4], const double (&d)[3][4],
                                    double* plane, double* planeDx, double* planeDy) {
  __m256d p = _mm256_setzero_pd(), px = p, py = p;
  for (int j = 0; j < 4; ++j) {
    // Rows (j, k) for k = 0..3, transposed so that c[i] holds element i of each row, lane k.
    const __m256d r0 = _mm256_loadu_pd(hermite + 4 * j), r1 = _mm256_loadu_pd(hermite + 4 * j + 16),
                  r2 = _mm256_loadu_pd(hermite + 4 * j + 32), r3 = _mm256_loadu_pd(hermite + 4 * j + 48);
    const __m256d t0 = _mm256_unpacklo_pd(r0, r1), t1 = _mm256_unpackhi_pd(r0, r1),
                  t2 = _mm256_unpacklo_pd(r2, r3), t3 = _mm256_unpackhi_pd(r2, r3);
    const __m256d c[4] = {_mm256_permute2f128_pd(t0, t2, 0x20), _mm256_permute2f128_pd(t1, t3, 0x20),
                          _mm256_permute2f128_pd(t0, t2, 0x31), _mm256_permute2f128_pd(t1, t3, 0x31)};
    __m256d v = _mm256_mul_pd(_mm256_set1_pd(w[0][0]), c[0]);
    __m256d dx = _mm256_mul_pd(_mm256_set1_pd(d[0][0]), c[0]);
    for (int i = 1; i < 4; ++i) {
      v = _mm256_add_pd(v, _mm256_mul_pd(_mm256_set1_pd(w[0][i]), c[i]));
      dx = _mm256_add_pd(dx, _mm256_mul_pd(_mm256_set1_pd(d[0][i]), c[i]));
    }
    p = _mm256_add_pd(p, _mm256_mul_pd(_mm256_set1_pd(w[1][j]), v));
    px = _mm256_add_pd(px, _mm256_mul_pd(_mm256_set1_pd(w[1][j]), dx));
    py = _mm256_add_pd(py, _mm256_mul_pd(_mm256_set1_pd(d[1][j]), v));
  }
  _mm256_storeu_pd(plane, p);
  _mm256_storeu_pd(planeDx, px);
  _mm256_storeu_pd(planeDy, py);
}
#endif

}  // namespace

void hermiteWeights(double t, double* w, double* d) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = 2 * t3 - 3 * t2 + 1;
  w[1] = t3 - 2 * t2 + t;
  w[2] = -2 * t3 + 3 * t2;
  w[3] = t3 - t2;
  if (d) {
    d[0] = 6 * t2 - 6 * t;
    d[1] = 3 * t2 - 4 * t + 1;
    d[2] = -6 * t2 + 6 * t;
    d[3] = 3 * t2 - 2 * t;
  }
}

double CellReference::value(const Vec3& local) const {
  if (field) return field->value(geometry->indexToWorld(origin + local)) - isovalue;
  double wx[4], wy[4], wz[4];
  hermiteWeights(local.x(), wx, nullptr);
  hermiteWeights(local.y(), wy, nullptr);
  hermiteWeights(local.z(), wz, nullptr);
  double sum = 0;
  for (int k = 0; k < 4; ++k) {
    double plane = 0;
    for (int j = 0; j < 4; ++j) {
      const double* row = &hermite[static_cast<std::size_t>(4 * (j + 4 * k))];
      plane += wy[j] * (wx[0] * row[0] + wx[1] * row[1] + wx[2] * row[2] + wx[3] * row[3]);
    }
    sum += wz[k] * plane;
  }
  return sum - isovalue;
}

Vec3 CellReference::gradient(const Vec3& local) const {
  Vec3 g;
  valueAndGradient(local, g);
  return g;
}

double CellReference::valueAndGradient(const Vec3& local, Vec3& gradient) const {
  if (field) {
    const Vec3 world = geometry->indexToWorld(origin + local);
    gradient = field->gradient(world).cwiseProduct(geometry->spacing);
    return field->value(world) - isovalue;
  }
  // Contracted one axis at a time: x gives values and x-derivatives per (y, z) Hermite index, y and z follow.
  double w[3][4], d[3][4];
  for (int a = 0; a < 3; ++a) hermiteWeights(local[a], w[a], d[a]);
  double plane[4], planeDx[4], planeDy[4];
#if defined(CIP_HAS_AVX2_KERNELS)
  if (hasAvx2())
    contractXYAvx2(hermite.data(), w, d, plane, planeDx, planeDy);
  else
#endif
    contractXY(hermite.data(), w, d, plane, planeDx, planeDy);
  double value = 0;
  gradient = Vec3::Zero();
  for (int k = 0; k < 4; ++k) {
    value += w[2][k] * plane[k];
    gradient.x() += w[2][k] * planeDx[k];
    gradient.y() += w[2][k] * planeDy[k];
    gradient.z() += d[2][k] * plane[k];
  }
  return value - isovalue;
}

CellReference tricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell,
                                double isovalue, Reconstruction kind) {
  CellReference ref;
  setTricubicReference(grid, cell, isovalue, ref, kind);
  return ref;
}

void setTricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell, double isovalue,
                          CellReference& ref, Reconstruction kind) {
  ref.field = nullptr;
  ref.geometry = nullptr;
  ref.origin = Vec3::Zero();
  ref.isovalue = isovalue;
  ref.metric = Vec3::Ones();
  std::array<std::array<int, 3>, 8> at;  // hermiteInBox refuses Auto
  std::array<PointHermite, 8> data;
  std::array<const PointHermite*, 8> corners;
  for (int v = 0; v < 8; ++v) {
    at[static_cast<std::size_t>(v)] = cube::vertexCoords(v);
    corners[static_cast<std::size_t>(v)] = &data[static_cast<std::size_t>(v)];
  }
  hermiteInBox(grid, kind, cell, {2, 2, 2}, at.data(), at.size(), data.data());
  cellHermite(corners, ref.hermite);
}

TricubicInterpolant::TricubicInterpolant(const DenseGrid& grid, Reconstruction kind)
    : grid_(grid), kind_(kind) {
  requireResolved(kind);
  static std::atomic<std::uint64_t> next{1};
  id_ = next++;
}

const CellReference& TricubicInterpolant::at(const Vec3& world, Vec3& local) const {
  const Vec3 index = grid_.geometry.worldToIndex(world);
  std::array<std::int64_t, 3> cell;
  for (int a = 0; a < 3; ++a) {
    const std::int64_t cells = std::max<std::int64_t>(1, grid_.geometry.dims[a] - 1);
    const double lower = std::floor(index[a]);
    cell[a] = std::isfinite(lower)
                  ? std::clamp<std::int64_t>(
                        static_cast<std::int64_t>(std::clamp(lower, -1.0, static_cast<double>(cells))), 0,
                        cells - 1)
                  : 0;
    local[a] = index[a] - static_cast<double>(cell[a]);
  }
  struct LastCell {
    std::uint64_t owner = 0;
    std::array<std::int64_t, 3> cell{};
    CellReference ref;
  };
  thread_local LastCell last;
  if (last.owner != id_ || last.cell != cell) {
    setTricubicReference(grid_, cell, 0.0, last.ref, kind_);
    last.owner = id_;
    last.cell = cell;
  }
  return last.ref;
}

double TricubicInterpolant::value(const Vec3& world) const {
  Vec3 local;
  const CellReference& ref = at(world, local);
  return ref.value(local);
}

Vec3 TricubicInterpolant::gradient(const Vec3& world) const {
  Vec3 local;
  const CellReference& ref = at(world, local);
  return ref.gradient(local).cwiseQuotient(grid_.geometry.spacing);
}

double cubicEdgeVertex(const DenseGrid& grid, const std::array<std::int64_t, 3>& point, int axis,
                       double isovalue, Vec3& normal, Reconstruction kind) {
  std::array<int, 3> size{1, 1, 1};  // hermiteInBox refuses Auto
  size[axis] = 2;
  std::array<std::array<int, 3>, 2> at{};
  at[1][static_cast<std::size_t>(axis)] = 1;
  std::array<PointHermite, 2> ends;
  hermiteInBox(grid, kind, point, size, at.data(), at.size(), ends.data());
  return cubicEdgeVertex(ends[0], ends[1], axis, isovalue, normal);
}

double cubicEdgeVertex(const PointHermite& start, const PointHermite& end, int axis, double isovalue,
                       Vec3& normal) {
  // The edge's data from its ends': along it, (value, slope) at both ends; across it along each other axis,
  // (slope, mixed derivative with the edge axis) at both ends.
  const int along = 1 << axis;
  // The reference along the edge: a cubic Hermite segment, in powers of t (one variable on [0, 1] with
  // coefficients of the size of the data: no cancellation to fear), evaluated by Horner.
  const double v0 = start[0] - isovalue, d0 = start[along], v1 = end[0] - isovalue, d1 = end[along];
  const double k0 = v0, k1 = d0, k2 = -3 * v0 - 2 * d0 + 3 * v1 - d1, k3 = 2 * v0 + d0 - 2 * v1 + d1;
  auto cubic = [&](double t) { return ((k3 * t + k2) * t + k1) * t + k0; };
  auto slope = [&](double t) { return (3 * k3 * t + 2 * k2) * t + k1; };
  const double tLinear = linearCrossing(v0, v1, 0.0);
  // All sign changes on [0,1] (16 brackets; the segment is monotone, so there is one), each refined by Newton
  // steps kept inside the bracket (bisection when a step leaves it); keep the root nearest the linear
  // crossing. The end values bracket the isovalue, so there is at least one.
  constexpr int kBrackets = 16;
  double best = tLinear, bestGap = std::numeric_limits<double>::infinity();
  double t0 = 0, c0 = v0;
  for (int b = 1; b <= kBrackets; ++b) {
    const double t1 = static_cast<double>(b) / kBrackets, c1 = b == kBrackets ? v1 : cubic(t1);
    if ((c0 > 0) != (c1 > 0)) {
      double lo = t0, hi = t1, fLo = c0, t = 0.5 * (t0 + t1);
      for (int it = 0; it < 60 && hi - lo > 0x1p-50; ++it) {
        const double ft = cubic(t);
        if (ft == 0) break;
        if ((ft > 0) == (fLo > 0)) {
          lo = t;
          fLo = ft;
        } else {
          hi = t;
        }
        const double d = slope(t), next = d != 0 ? t - ft / d : 0.5 * (lo + hi);
        if (std::abs(next - t) < 0x1p-50) {  // converged (the step may sit on a bracket end)
          t = std::clamp(next, lo, hi);
          break;
        }
        t = next > lo && next < hi ? next : 0.5 * (lo + hi);
      }
      if (std::abs(t - tLinear) < bestGap) {
        bestGap = std::abs(t - tLinear);
        best = t;
      }
    }
    t0 = t1;
    c0 = c1;
  }
  // The gradient there, as CellReference::gradient computes it on the edge: along the edge the cubic's
  // derivative, across it the Hermite segment of the cross slopes and mixed derivatives.
  double w[4], dw[4];
  hermiteWeights(best, w, dw);
  Vec3 gradient;
  gradient[axis] = dw[0] * start[0] + dw[1] * d0 + dw[2] * end[0] + dw[3] * d1;
  for (int other : cube::otherAxes(axis)) {
    const int across = 1 << other;
    gradient[other] =
        w[0] * start[across] + w[1] * start[across | along] + w[2] * end[across] + w[3] * end[across | along];
  }
  const Vec3 towardsPositive = Vec3::Unit(axis) * (v1 > 0 ? 1.0 : -1.0);
  normal = orientCornerNormal(gradient, towardsPositive);
  return best;
}

}  // namespace cip
