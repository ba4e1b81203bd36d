#include "cip/patch/surface_shift.h"

#include <algorithm>
#include <cmath>

namespace cip {

double surfaceShiftEstimate(const CornerPatch& built, const CornerPatch& stored) {
  constexpr int kPoints = 4;  // per axis
  constexpr double kStep = 1.0 / (kPoints - 1);
  double worst = 0;
  for (int k = 0; k < kPoints; ++k)
    for (int j = 0; j < kPoints; ++j)
      for (int i = 0; i < kPoints; ++i) {
        const int onFaces =
            (i == 0 || i == kPoints - 1) + (j == 0 || j == kPoints - 1) + (k == 0 || k == kPoints - 1);
        if (onFaces >= 2) continue;
        const Vec3 x(i * kStep, j * kStep, k * kStep);
        const PatchDerivatives d = built.valueAndGradient(x);
        const double g = d.gradient.norm();
        if (!(g > 0) || !(std::abs(d.value) <= g * kStep)) continue;
        worst = std::max(worst, std::abs(stored.value(x) - d.value) / g);
      }
  return worst;
}

}  // namespace cip
