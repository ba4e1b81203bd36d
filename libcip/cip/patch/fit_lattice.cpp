#include "cip/patch/fit_lattice.h"

#include <cmath>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace cip::fit_lattice {

namespace {

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

}  // namespace

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

void analyticLattice(const CellReference& ref, const double* const coordinate[3],
                     const std::array<int, 3>& count, const std::array<int, 3>& stride, double* out) {
  ref.field->valuesOnLattice(coordinate[0], coordinate[1], coordinate[2], count, stride, out);
  for (int d = 0; d < count[2]; ++d)
    for (int b = 0; b < count[1]; ++b)
      for (int a = 0; a < count[0]; ++a) out[a * stride[0] + b * stride[1] + d * stride[2]] -= ref.isovalue;
}

Vec3 facePoint(int f, double u, double v) {
  const int axis = cube::faceAxis(f);
  const auto uv = cube::otherAxes(axis);
  Vec3 x;
  x[axis] = cube::faceSide(f);
  x[uv[0]] = u;
  x[uv[1]] = v;
  return x;
}

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

}  // namespace cip::fit_lattice
