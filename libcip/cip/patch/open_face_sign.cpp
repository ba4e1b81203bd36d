#include "cip/patch/open_face_sign.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "cip/core/vector_clones.h"
#include "cip/patch/fit_lattice.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

using fit_lattice::pattern;
using fit_lattice::squares;

/// The screen's lattice on a face: kScreen points 1/(kScreen - 1) apart along each face axis, border
/// included.
constexpr int kScreen = 9;
/// Room for the largest lattice summed on the stack; larger ones use the heap.
constexpr int kStackPoints = kOpenFaceLattice * kOpenFaceLattice;

/// The face's corners' sign (they share it on an open face).
bool positiveCorners(std::uint8_t config, int f) {
  return (config >> cube::faceVertex(f, 0)) & 1;
}

/// value[a + n b] += su[a] (p[b] + q[b] t[a]): the terms of one pattern along u over the lattice.
CIP_VECTOR_CLONES void addPattern(const double* __restrict p, const double* __restrict q,
                                  const double* __restrict t, const double* __restrict su, int n,
                                  double* __restrict value) {
  for (int b = 0; b < n; ++b) {
    const double pb = p[b], qb = q[b];
    double* __restrict row = value + n * b;
    for (int a = 0; a < n; ++a) row[a] += su[a] * (pb + qb * t[a]);
  }
}

/// A patch on one face, summed per pair of the patterns of squared face planes along the face's two axes
/// (u = axis + 1, v = axis + 2, mod 3): a term c S(x) prod B_h^2 is on the face c' (A + B u + C v) U(u) V(v),
/// where c' holds the squares across the face's own axis (constant on it) and U, V the squares along u and v.
/// Each pair's sums are taken once, then spread over the lattice: separable products.
class FaceSums {
 public:
  /// `terms` and `numTerms` as patch.terms() gives them.
  FaceSums(const CornerPatch& patch, const std::array<PatchTerm, CornerPatch::kMaxTerms>& terms, int numTerms,
           int f)
      : axis_(cube::faceAxis(f)) {
    const double side = cube::faceSide(f);
    const int u = (axis_ + 1) % 3, v = (axis_ + 2) % 3;
    for (int i = 0; i < numTerms; ++i) {
      const PatchTerm& term = terms[static_cast<std::size_t>(i)];
      const double c = term.coefficient * squares(pattern(term.faceSquares, axis_), side);
      if (c == 0) continue;
      const int pair = 4 * pattern(term.faceSquares, u) + pattern(term.faceSquares, v);
      Sum& s = sum_[static_cast<std::size_t>(pair)];
      if (!((pairs_ >> pair) & 1)) s = Sum{};
      pairs_ |= 1u << pair;
      if (term.corner < 0) {
        s.a += c;
        s.magnitude += std::abs(c);
        continue;
      }
      const Vec3& n = patch.normal[static_cast<std::size_t>(term.corner)];
      const Vec3& q = patch.point[static_cast<std::size_t>(term.corner)];
      const double a = n[axis_] * (side - q[axis_]) - n[u] * q[u] - n[v] * q[v];
      s.a += c * a;
      s.b += c * n[u];
      s.c += c * n[v];
      // |c S| on the face, u and v in [0, 1]: the bound of the rounding of these sums.
      s.magnitude += std::abs(c) * (std::abs(n[axis_] * (side - q[axis_])) + std::abs(n[u] * q[u]) +
                                    std::abs(n[v] * q[v]) + std::abs(n[u]) + std::abs(n[v]));
    }
  }

  /// The patch's value at the points (t[a], t[b]) of the face (index a + n b); sq[m] holds the squares of
  /// pattern m at t (1, t^2, (1-t)^2, their product).
  void lattice(const double* t, const double* const* sq, int n, double* __restrict value) const {
    std::fill(value, value + n * n, 0.0);
    // Per pattern mu along u: p(v) = sum over mv of sv(v) (A + C v) and q(v) = sum of sv(v) B, then
    // value += su(u) (p(v) + q(v) u), one pass over the lattice per pattern instead of per pair.
    double pStack[kOpenFaceLattice], qStack[kOpenFaceLattice];
    std::vector<double> heap;
    double *p = pStack, *q = qStack;
    if (n > kOpenFaceLattice) {
      heap.resize(static_cast<std::size_t>(2 * n));
      p = heap.data();
      q = p + n;
    }
    for (int mu = 0; mu < 4; ++mu) {
      const unsigned mine = (pairs_ >> (4 * mu)) & 15u;
      if (!mine) continue;
      std::fill(p, p + n, 0.0);
      std::fill(q, q + n, 0.0);
      for (unsigned rest = mine; rest; rest &= rest - 1) {
        const int mv = __builtin_ctz(rest);
        const Sum& s = sum_[static_cast<std::size_t>(4 * mu + mv)];
        const double* sv = sq[mv];
        for (int b = 0; b < n; ++b) {
          p[b] += sv[b] * (s.a + s.c * t[b]);
          q[b] += sv[b] * s.b;
        }
      }
      addPattern(p, q, t, sq[mu], n, value);
    }
  }

  /// A bound on the magnitudes of the terms summed at any point of the face (the squares are at most 1 on
  /// it), which bounds the rounding of any way of summing them.
  double magnitude() const {
    double m = 0;
    for (unsigned rest = pairs_; rest; rest &= rest - 1)
      m += sum_[static_cast<std::size_t>(__builtin_ctz(rest))].magnitude;
    return m;
  }

 private:
  struct Sum {
    double a = 0, b = 0, c = 0, magnitude = 0;
  };
  int axis_;
  unsigned pairs_ = 0;
  std::array<Sum, 16> sum_;  ///< valid for the pairs in pairs_
};

/// The squares of the four patterns at coordinates t (sq[m] points into `storage`, 4 n values), for lattices
/// whose size is known only at run time (LatticeSquares holds them for fixed ones).
void patternSquares(const double* t, int n, double* storage, const double* sq[4]) {
  for (int m = 0; m < 4; ++m) {
    sq[m] = storage + m * n;
    for (int i = 0; i < n; ++i) storage[m * n + i] = squares(m, t[i]);
  }
}

/// The screen's axis: kScreen points 1/(kScreen - 1) apart, border included.
struct ScreenAxis {
  static constexpr int n = kScreen;
  static constexpr double coord(int i) { return static_cast<double>(i) / (kScreen - 1); }
};

}  // namespace

bool openFaceLeaks(const CornerPatch& patch, std::uint8_t config, int f, int lattice) {
  const int n = std::max(2, lattice);
  const bool positive = positiveCorners(config, f);
  const double sign = positive ? 1.0 : -1.0;
  std::vector<double> t(static_cast<std::size_t>(n)), squares(static_cast<std::size_t>(4 * n));
  for (int a = 0; a < n; ++a) t[static_cast<std::size_t>(a)] = static_cast<double>(a) / (n - 1);
  const double* sq[4];
  patternSquares(t.data(), n, squares.data(), sq);
  std::array<double, kStackPoints> stack;
  std::vector<double> heap;
  double* value = stack.data();
  if (n * n > kStackPoints) {
    heap.resize(static_cast<std::size_t>(n * n));
    value = heap.data();
  }
  std::array<PatchTerm, CornerPatch::kMaxTerms> terms;
  const int numTerms = patch.terms(terms);
  const FaceSums sums(patch, terms, numTerms, f);
  sums.lattice(t.data(), sq, n, value);
  // The separable sums round differently from CornerPatch::value, whose sign is the verdict: a point whose
  // sum keeps the corners' sign by far more than any rounding of the terms' magnitudes keeps it in value()
  // too; every other point is evaluated.
  const double margin = 1e-12 * sums.magnitude();
  const int axis = cube::faceAxis(f);
  Vec3 local;
  local[axis] = cube::faceSide(f);
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) {
      if (sign * value[a + n * b] > margin) continue;
      local[(axis + 1) % 3] = t[static_cast<std::size_t>(a)];
      local[(axis + 2) % 3] = t[static_cast<std::size_t>(b)];
      const double v = patch.value(local);
      if (v != 0 && (v > 0) != positive) return true;
    }
  return false;
}

unsigned openFacesNearOtherSign(const CornerPatch& patch, std::uint8_t config, double inside, double border) {
  const fit_lattice::LatticeSquares<ScreenAxis>& screen = fit_lattice::LatticeSquares<ScreenAxis>::get();
  const double* sq[4] = {screen.sq[0], screen.sq[1], screen.sq[2], screen.sq[3]};
  const unsigned open = ~static_cast<unsigned>(patch.faceMask) & 63u;
  if (!open) return 0;
  std::array<PatchTerm, CornerPatch::kMaxTerms> terms;
  const int numTerms = patch.terms(terms);
  unsigned near = 0;
  for (unsigned rest = open; rest; rest &= rest - 1) {
    const int f = __builtin_ctz(rest);
    alignas(32) std::array<double, kScreen * kScreen> value;
    FaceSums(patch, terms, numTerms, f).lattice(screen.t, sq, kScreen, value.data());
    const double sign = positiveCorners(config, f) ? 1.0 : -1.0;
    constexpr int last = kScreen - 1;
    double lowInside = std::numeric_limits<double>::infinity(), highInside = 0;
    for (int b = 1; b < last; ++b)
      for (int a = 1; a < last; ++a) {
        const double x = value[static_cast<std::size_t>(a + kScreen * b)];
        lowInside = std::min(lowInside, sign * x);
        highInside = std::max(highInside, std::abs(x));
      }
    // The border: its edges without the face's corners; at the corners (samples, where the patch need not
    // have their sign) only a value of the other sign, since the patch comes close to 0 there wherever the
    // surface passes near a sample, and is 0 where two bounding planes meet.
    double lowBorder = std::numeric_limits<double>::infinity(), high = highInside;
    bool cornerTurned = false;
    auto onBorder = [&](int a, int b) {
      const double x = value[static_cast<std::size_t>(a + kScreen * b)];
      lowBorder = std::min(lowBorder, sign * x);
      high = std::max(high, std::abs(x));
    };
    for (int i = 1; i < last; ++i) {
      onBorder(i, 0);
      onBorder(i, last);
      onBorder(0, i);
      onBorder(last, i);
    }
    for (int k = 0; k < 4; ++k) {
      const double x = value[static_cast<std::size_t>((k & 1) * last + kScreen * (k >> 1) * last)];
      high = std::max(high, std::abs(x));
      cornerTurned = cornerTurned || sign * x < 0;
    }
    if (!(lowInside > inside * highInside) || !(lowBorder > border * high) || cornerTurned) near |= 1u << f;
  }
  return near;
}

}  // namespace cip
