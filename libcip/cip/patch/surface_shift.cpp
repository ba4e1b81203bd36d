#include "cip/patch/surface_shift.h"

#include <algorithm>
#include <cmath>

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
  return forLatticePoints([&](const Vec3& x) {
    const double v = built.value(x), s = stored.value(x);
    // With |v| <= step g (the point counts) and |s - v| / g > threshold, |v| threshold < |s - v| step.
    // value() and valueAndGradient() round differently: the margin covers that, so no point that could count
    // is skipped, and those that are evaluated get the estimate's own test.
    const double change = std::abs(s - v) + 1e-9 * (std::abs(v) + std::abs(s));
    if (std::abs(v) * threshold > change * kStep) return false;
    return shiftAt(built, stored, x) > threshold;
  });
}

}  // namespace cip
