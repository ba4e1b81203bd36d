#include "cip/patch/surface_shift.h"

#include <algorithm>
#include <array>
#include <cmath>

#include "cip/core/vector_clones.h"

namespace cip {

namespace {

constexpr int kPoints = 4;  // per axis
constexpr double kStep = 1.0 / (kPoints - 1);

/// Calls visit(x) at the lattice points of the estimate (faces included, cell edges left out) until it
/// returns true; returns whether one did.
template <class Visit>
bool forLatticePoints(const Visit& visit) {
  for (int k = 0; k < kPoints; ++k)
    for (int j = 0; j < kPoints; ++j)
      for (int i = 0; i < kPoints; ++i) {
        const int onFaces =
            (i == 0 || i == kPoints - 1) + (j == 0 || j == kPoints - 1) + (k == 0 || k == kPoints - 1);
        if (onFaces < 2 && visit(Vec3(i * kStep, j * kStep, k * kStep))) return true;
      }
  return false;
}

/// The first-order shift at x, or a negative number where x is not within a lattice step of the surface.
double shiftAt(const CornerPatch& built, const CornerPatch& stored, const Vec3& x) {
  const PatchDerivatives d = built.valueAndGradient(x);
  const double g = d.gradient.norm();
  if (!(g > 0) || !(std::abs(d.value) <= g * kStep)) return -1;
  return std::abs(stored.value(x) - d.value) / g;
}

/// The lattice of forLatticePoints, in its order (also as coordinate arrays), with the products of squared
/// face planes that a patch's terms multiply (CornerPatch: corner, side and central terms), per face mask and
/// point.
constexpr int kLatticePoints = 32;
struct Lattice {
  std::array<Vec3, kLatticePoints> x;
  std::array<std::array<double, kLatticePoints>, 3> coordinate;            ///< [axis][point]
  alignas(32) std::array<std::array<double, kLatticePoints>, 64> product;  ///< [mask][point]
};

const Lattice& lattice() {
  static const Lattice table = [] {
    Lattice t{};
    int n = 0;
    forLatticePoints([&](const Vec3& x) {
      t.x[static_cast<std::size_t>(n++)] = x;
      return false;
    });
    for (std::size_t p = 0; p < kLatticePoints; ++p)
      for (int a = 0; a < 3; ++a) t.coordinate[static_cast<std::size_t>(a)][p] = t.x[p][a];
    for (unsigned mask = 0; mask < 64; ++mask)
      for (std::size_t p = 0; p < kLatticePoints; ++p) {
        double r = 1;
        for (int f = 0; f < 6; ++f)
          if ((mask >> f) & 1) {
            const double b = CornerPatch::facePlane(f, t.x[p]);
            r *= b * b;
          }
        t.product[mask][p] = r;
      }
    return t;
  }();
  return table;
}

/// value[p] += coefficient * t[p], magnitude[p] += |coefficient| t[p] over the lattice (a side or central
/// term).
CIP_VECTOR_CLONES void addTerm(double coefficient, const double* __restrict t, double* __restrict value,
                               double* __restrict magnitude) {
  const double bound = std::abs(coefficient);
  for (int p = 0; p < kLatticePoints; ++p) {
    value[p] += coefficient * t[p];
    magnitude[p] += bound * t[p];
  }
}

/// The same for a corner term, weight * S_c(x) * t[p], with |S_c| at most |n|_1 in the unit cell.
CIP_VECTOR_CLONES void addCornerTerm(double weight, const Vec3& n, const Vec3& q, const Lattice& L,
                                     const double* __restrict t, double* __restrict value,
                                     double* __restrict magnitude) {
  const double nx = n[0], ny = n[1], nz = n[2], qx = q[0], qy = q[1], qz = q[2];
  const double bound = std::abs(weight) * (std::abs(nx) + std::abs(ny) + std::abs(nz));
  const double *__restrict x = L.coordinate[0].data(), *__restrict y = L.coordinate[1].data(),
                           *__restrict z = L.coordinate[2].data();
  for (int p = 0; p < kLatticePoints; ++p) {
    const double plane = nx * (x[p] - qx) + ny * (y[p] - qy) + nz * (z[p] - qz);
    value[p] += weight * plane * t[p];
    magnitude[p] += bound * t[p];
  }
}

/// The patch's value at every lattice point, and a bound on the magnitudes of the terms summed there, which
/// bounds the rounding of any way of summing them.
void latticeValues(const Lattice& L, const CornerPatch& patch, std::array<double, kLatticePoints>& value,
                   std::array<double, kLatticePoints>& magnitude) {
  value.fill(0.0);
  magnitude.fill(0.0);
  std::array<PatchTerm, CornerPatch::kMaxTerms> terms;
  const int n = patch.terms(terms);
  for (int i = 0; i < n; ++i) {
    const PatchTerm& term = terms[static_cast<std::size_t>(i)];
    const double* t = L.product[term.faceSquares].data();
    if (term.corner >= 0)
      addCornerTerm(term.coefficient, patch.normal[term.corner], patch.point[term.corner], L, t, value.data(),
                    magnitude.data());
    else
      addTerm(term.coefficient, t, value.data(), magnitude.data());
  }
}

}  // namespace

double surfaceShiftEstimate(const CornerPatch& built, const CornerPatch& stored) {
  double worst = 0;
  forLatticePoints([&](const Vec3& x) {
    worst = std::max(worst, shiftAt(built, stored, x));
    return false;
  });
  return worst;
}

bool surfaceShiftExceeds(const CornerPatch& built, const CornerPatch& stored, double threshold) {
  // Both patches' values at every lattice point, from the tabulated face products (most cells are
  // evaluated whole: they do not move). With |v| <= step g (the point counts) and |s - v| / g > threshold,
  // |v| threshold < |s - v| step. These values round differently from valueAndGradient(), which the
  // estimate's own test uses: the margin covers far more than that (a few units of rounding of the terms'
  // magnitudes), so no point that could count is skipped, and those evaluated get the estimate's test.
  const Lattice& L = lattice();
  alignas(32) std::array<double, kLatticePoints> v, s, vMagnitude, sMagnitude;
  latticeValues(L, built, v, vMagnitude);
  latticeValues(L, stored, s, sMagnitude);
  for (int p = 0; p < kLatticePoints; ++p) {
    const double change = std::abs(s[p] - v[p]) + 1e-9 * (std::abs(v[p]) + std::abs(s[p])) +
                          1e-12 * (vMagnitude[p] + sMagnitude[p]);
    if (std::abs(v[p]) * threshold > change * kStep) continue;
    if (shiftAt(built, stored, L.x[p]) > threshold) return true;
  }
  return false;
}

}  // namespace cip
