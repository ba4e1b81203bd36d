#include "cip/ray/patch_bounds.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include "cip/core/vector_clones.h"

namespace cip {

namespace {

constexpr int kN = kZeroMaskDivisions;
constexpr double kH = 1.0 / kN;
/// Absolute widening of every factor's range: covers the rounding of a ray polynomial's factors (a few ulps
/// of numbers of order 1) many times over.
constexpr double kWiden = 1e-12;
/// The bound of the sum must exclude [-margin, margin], margin = kMargin * (sum of the terms' magnitude
/// bounds): far above the rounding of a factored evaluation (RayPolynomial::roundingBound, ~1e-14 of it).
constexpr double kMargin = 1e-12;

static_assert(kN * kN * kN <= 64, "the mask is one 64-bit word");
static_assert(kN == 4, "one vector of four doubles holds the sub-boxes along x");

/// Four doubles: the four sub-boxes along x.
struct Lanes {
  std::array<double, kN> v;
  double& operator[](int i) { return v[i]; }
  double operator[](int i) const { return v[i]; }
};

/// lo += min(a q0, a q1) and hi += max(b q0, b q1) in each lane, a = c - r, b = c + r, c = x + shift, q0 =
/// qx0 yzLo, q1 = qx1 yzHi: the range of (c +- r) [q0, q1] added to [lo, hi].
inline void accumulate(const Lanes& x, double shift, double r, const Lanes& qx0, double yzLo,
                       const Lanes& qx1, double yzHi, Lanes& lo, Lanes& hi) {
#if defined(__SSE2__)
  const __m128d s = _mm_set1_pd(shift), rr = _mm_set1_pd(r), y0 = _mm_set1_pd(yzLo), y1 = _mm_set1_pd(yzHi);
  for (int h = 0; h < kN; h += 2) {
    const __m128d c = _mm_add_pd(_mm_loadu_pd(&x.v[h]), s);
    const __m128d a = _mm_sub_pd(c, rr), b = _mm_add_pd(c, rr);
    const __m128d q0 = _mm_mul_pd(_mm_loadu_pd(&qx0.v[h]), y0), q1 = _mm_mul_pd(_mm_loadu_pd(&qx1.v[h]), y1);
    const __m128d l = _mm_min_pd(_mm_mul_pd(a, q0), _mm_mul_pd(a, q1));
    const __m128d u = _mm_max_pd(_mm_mul_pd(b, q0), _mm_mul_pd(b, q1));
    _mm_storeu_pd(&lo.v[h], _mm_add_pd(_mm_loadu_pd(&lo.v[h]), l));
    _mm_storeu_pd(&hi.v[h], _mm_add_pd(_mm_loadu_pd(&hi.v[h]), u));
  }
#else
  for (int i = 0; i < kN; ++i) {
    const double c = x[i] + shift, a = c - r, b = c + r, q0 = qx0[i] * yzLo, q1 = qx1[i] * yzHi;
    lo[i] += std::min(a * q0, a * q1);
    hi[i] += std::max(b * q0, b * q1);
  }
#endif
}

/// One group of terms of patchZeroMask: L at the sub-box centres split per axis (L = constant + x[i] + y[j] +
/// z[k]), its half-range over a sub-box (radius), and per axis the range [q0, q1] of the squared face planes
/// on each slab; the four sub-boxes along x are one vector.
struct MaskTerm {
  Lanes x, qx0, qx1;
  std::array<double, kN> y, z, qy0, qy1, qz0, qz1;
  double constant, radius;
};

#if defined(CIP_HAS_AVX2_KERNELS)
/// The bound of every row of four sub-boxes, as the SSE2 loop of patchZeroMask computes it (the same
/// operations in the same order, four lanes at once): the marked sub-boxes (the bound reaches [-margin,
/// margin]) and those proven positive.
CIP_AVX2_KERNEL void maskRowsAvx2(const MaskTerm* terms, int ng, double margin, std::uint64_t& mask,
                                  std::uint64_t& positive) {
  const __m256d m = _mm256_set1_pd(margin), negM = _mm256_set1_pd(-margin);
  for (int k = 0; k < kN; ++k)
    for (int j = 0; j < kN; ++j) {
      __m256d lo = _mm256_setzero_pd(), hi = _mm256_setzero_pd();
      for (int g = 0; g < ng; ++g) {
        const MaskTerm& t = terms[g];
        const __m256d s = _mm256_set1_pd(t.constant + t.y[j] + t.z[k]), r = _mm256_set1_pd(t.radius);
        const __m256d y0 = _mm256_set1_pd(t.qy0[j] * t.qz0[k]), y1 = _mm256_set1_pd(t.qy1[j] * t.qz1[k]);
        const __m256d c = _mm256_add_pd(_mm256_loadu_pd(t.x.v.data()), s);
        const __m256d a = _mm256_sub_pd(c, r), b = _mm256_add_pd(c, r);
        const __m256d q0 = _mm256_mul_pd(_mm256_loadu_pd(t.qx0.v.data()), y0);
        const __m256d q1 = _mm256_mul_pd(_mm256_loadu_pd(t.qx1.v.data()), y1);
        lo = _mm256_add_pd(lo, _mm256_min_pd(_mm256_mul_pd(a, q0), _mm256_mul_pd(a, q1)));
        hi = _mm256_add_pd(hi, _mm256_max_pd(_mm256_mul_pd(b, q0), _mm256_mul_pd(b, q1)));
      }
      const int shift = kN * j + kN * kN * k;
      const auto marked = static_cast<unsigned>(_mm256_movemask_pd(
          _mm256_and_pd(_mm256_cmp_pd(lo, m, _CMP_LE_OQ), _mm256_cmp_pd(hi, negM, _CMP_GE_OQ))));
      const auto above = static_cast<unsigned>(_mm256_movemask_pd(_mm256_cmp_pd(lo, m, _CMP_GT_OQ)));
      mask |= std::uint64_t{marked} << shift;
      positive |= std::uint64_t{above & ~marked} << shift;
    }
}
#endif

}  // namespace

std::uint64_t patchZeroMask(const CornerPatch& patch, std::uint64_t* positive) {
  if (positive) *positive = 0;
  std::array<PatchTerm, CornerPatch::kMaxTerms> ts;
  const int nt = patch.terms(ts);
  if (nt == 0) return ~std::uint64_t{0};  // the zero polynomial vanishes everywhere

  // Terms with the same squared face planes are one term L(x) prod B_h^2 with L linear (the sum of their
  // coefficients times corner planes): I = sum_m L_m(x) Q_m(x). The range of a linear function on a box is
  // exact, so grouping also tightens the bound.
  struct Group {
    std::uint8_t faces;
    Vec3 gradient;  // of L
    double constant;
  };
  std::array<Group, CornerPatch::kMaxTerms> groups;
  int ng = 0;
  for (int t = 0; t < nt; ++t) {
    int g = 0;
    while (g < ng && groups[g].faces != ts[t].faceSquares) ++g;
    if (g == ng) groups[ng++] = Group{ts[t].faceSquares, Vec3::Zero(), 0.0};
    const double c = ts[t].coefficient;
    if (ts[t].corner >= 0) {
      const Vec3& n = patch.normal[ts[t].corner];
      groups[g].gradient += c * n;
      groups[g].constant -= c * n.dot(patch.point[ts[t].corner]);
    } else {
      groups[g].constant += c;
    }
  }

  // Squared face planes B_f^2 on each slab [i h - pad, (i + 1) h + pad] of the face's axis.
  std::array<std::array<double, kN>, 6> sqLo, sqHi;
  for (int f = 0; f < 6; ++f)
    for (int i = 0; i < kN; ++i) {
      double lo = i * kH - kZeroMaskPad, hi = (i + 1) * kH + kZeroMaskPad;
      if (f & 1) std::tie(lo, hi) = std::pair(1.0 - hi, 1.0 - lo);
      lo -= kWiden;
      hi += kWiden;
      sqHi[f][i] = std::max(lo * lo, hi * hi);
      sqLo[f][i] = lo > 0 ? lo * lo : (hi < 0 ? hi * hi : 0.0);
    }

  // Per group: L at the sub-box centres split per axis (L = constant + x[i] + y[j] + z[k]), its half-range
  // over a sub-box, and per axis the range of the squared face planes on each slab; the four sub-boxes along
  // x are one vector. `size` bounds sum |L_m| Q_m on the cell; the margin is relative to it.
  std::array<MaskTerm, CornerPatch::kMaxTerms> terms;
  double size = 0;
  for (int g = 0; g < ng; ++g) {
    MaskTerm& term = terms[g];
    const Group& group = groups[g];
    const double g1 = group.gradient.cwiseAbs().sum();
    term.constant = group.constant;
    term.radius = g1 * (0.5 * kH + kZeroMaskPad) + kWiden * (std::abs(group.constant) + 4 * g1);
    std::array<std::array<double, kN>, 3> centre, q0, q1;
    double qMax = 1;
    for (int a = 0; a < 3; ++a) {
      double axisMax = 0;
      for (int i = 0; i < kN; ++i) {
        centre[a][i] = group.gradient[a] * ((i + 0.5) * kH);
        double lo = 1, hi = 1;
        for (int f = 2 * a; f < 2 * a + 2; ++f)
          if ((group.faces >> f) & 1) {
            lo *= sqLo[f][i];
            hi *= sqHi[f][i];
          }
        q0[a][i] = lo;
        q1[a][i] = hi;
        axisMax = std::max(axisMax, hi);
      }
      qMax *= axisMax;
    }
    for (int i = 0; i < kN; ++i) {
      term.x[i] = centre[0][i];
      term.qx0[i] = q0[0][i];
      term.qx1[i] = q1[0][i];
    }
    term.y = centre[1];
    term.z = centre[2];
    term.qy0 = q0[1];
    term.qy1 = q1[1];
    term.qz0 = q0[2];
    term.qz1 = q1[2];
    size += (std::abs(group.constant) + 2 * g1) * qMax;
  }
  const double margin = kMargin * size;

  std::uint64_t mask = 0, positives = 0;
#if defined(CIP_HAS_AVX2_KERNELS)
  if (hasAvx2()) {
    maskRowsAvx2(terms.data(), ng, margin, mask, positives);
    if (positive) *positive = positives;
    return mask;
  }
#endif
  for (int k = 0; k < kN; ++k)
    for (int j = 0; j < kN; ++j) {
      Lanes lo{}, hi{};
      for (int g = 0; g < ng; ++g) {
        const MaskTerm& term = terms[g];
        accumulate(term.x, term.constant + term.y[j] + term.z[k], term.radius, term.qx0,
                   term.qy0[j] * term.qz0[k], term.qx1, term.qy1[j] * term.qz1[k], lo, hi);
      }
      for (int i = 0; i < kN; ++i)
        if (lo[i] <= margin && hi[i] >= -margin)
          mask |= std::uint64_t{1} << (i + kN * j + kN * kN * k);
        else if (lo[i] > margin)
          positives |= std::uint64_t{1} << (i + kN * j + kN * kN * k);
    }
  if (positive) *positive = positives;
  return mask;
}

bool zeroMaskBox(std::uint64_t mask, Vec3& lo, Vec3& hi) {
  if (mask == 0) return false;
  std::array<int, 3> first{kN, kN, kN}, last{-1, -1, -1};
  for (int b = 0; b < kN * kN * kN; ++b) {
    if (!((mask >> b) & 1)) continue;
    const std::array<int, 3> idx{b % kN, (b / kN) % kN, b / (kN * kN)};
    for (int a = 0; a < 3; ++a) {
      first[a] = std::min(first[a], idx[a]);
      last[a] = std::max(last[a], idx[a]);
    }
  }
  for (int a = 0; a < 3; ++a) {
    lo[a] = first[a] * kH;
    hi[a] = (last[a] + 1) * kH;
  }
  return true;
}

bool clipRayToZeroMask(const Vec3& origin, const Vec3& direction, double t0, double t1, std::uint64_t mask,
                       double& s0, double& s1, double pad) {
  if (mask == 0 || !(t0 <= t1)) return false;
  // The ray's interval in each slab of each axis, within [t0, t1] (empty: lo > hi).
  std::array<std::array<double, kN>, 3> lo, hi;
  for (int a = 0; a < 3; ++a) {
    const double o = origin[a], d = direction[a];
    if (d == 0) {
      for (int i = 0; i < kN; ++i) {
        const bool inside = o >= i * kH - pad && o <= (i + 1) * kH + pad;
        lo[a][i] = t0;
        hi[a][i] = inside ? t1 : -std::numeric_limits<double>::infinity();
      }
      continue;
    }
    const double inv = 1.0 / d;
    for (int i = 0; i < kN; ++i) {
      double ta = (i * kH - pad - o) * inv, tb = ((i + 1) * kH + pad - o) * inv;
      if (ta > tb) std::swap(ta, tb);
      lo[a][i] = std::max(t0, ta);
      hi[a][i] = std::min(t1, tb);
    }
  }
  double first = std::numeric_limits<double>::infinity(), last = -first;
  for (int k = 0; k < kN; ++k) {
    if (((mask >> (kN * kN * k)) & 0xFFFF) == 0 || !(lo[2][k] <= hi[2][k])) continue;
    for (int j = 0; j < kN; ++j) {
      const unsigned row = static_cast<unsigned>(mask >> (kN * kN * k + kN * j)) & 0xF;
      if (row == 0) continue;
      const double ljk = std::max(lo[2][k], lo[1][j]), hjk = std::min(hi[2][k], hi[1][j]);
      if (!(ljk <= hjk)) continue;
      for (int i = 0; i < kN; ++i) {
        if (!((row >> i) & 1)) continue;
        const double l = std::max(ljk, lo[0][i]), h = std::min(hjk, hi[0][i]);
        if (!(l <= h)) continue;
        first = std::min(first, l);
        last = std::max(last, h);
      }
    }
  }
  if (!(first <= last)) return false;
  s0 = first;
  s1 = last;
  return true;
}

}  // namespace cip
