// surfaceShiftEstimate (patch/surface_shift.h): the first-order shift of a cell's surface under a change of
// its patch, which the model writer uses to find the cells that need refined vertices.
#include "cip/patch/surface_shift.h"

#include <gtest/gtest.h>

#include "support/field_model.h"

using namespace cip;

// No change, no shift (to rounding); a side coefficient changed by e shifts by e D_f / |grad I| to first
// order, so twice the change gives twice the estimate, and the estimate of a small change is within the
// cell's scale.
TEST(SurfaceShift, ZeroForTheSamePatchAndLinearInTheChange) {
  const Model m = test::fieldModel("gyroid", 12, PatchMethod::Paper);
  int changed = 0;
  for (std::size_t c = 0; c < m.cells.size(); ++c) {
    const CornerPatch p = m.patch(c);
    EXPECT_LE(surfaceShiftEstimate(p, p), 1e-12);  // value() and valueAndGradient() round differently
    int f = 0;
    while (f < 6 && !((p.faceMask >> f) & 1)) ++f;
    ASSERT_LT(f, 6);
    CornerPatch once = p, twice = p;
    once.faceCoefficient[static_cast<std::size_t>(f)] += 1e-4;
    twice.faceCoefficient[static_cast<std::size_t>(f)] += 2e-4;
    const double a = surfaceShiftEstimate(p, once), b = surfaceShiftEstimate(p, twice);
    EXPECT_NEAR(b, 2 * a, 1e-6 * b + 1e-12);
    EXPECT_LT(a, 0.05);
    changed += a > 0;
  }
  EXPECT_GT(changed,
            static_cast<int>(m.cells.size()) / 2);  // most cells have lattice points near the surface
}
