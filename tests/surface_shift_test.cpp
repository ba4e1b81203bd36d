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

// surfaceShiftExceeds is surfaceShiftEstimate's verdict against a threshold, whatever the change and the
// threshold: thresholds around each cell's own estimate, and changes of one coefficient and of all of them.
TEST(SurfaceShift, ExceedsGivesTheEstimatesVerdict) {
  for (const PatchMethod method : {PatchMethod::Paper, PatchMethod::Fitted}) {
    const Model m = test::fieldModel("gyroid", 12, method);
    int over = 0, under = 0;
    for (std::size_t c = 0; c < m.cells.size(); ++c) {
      const CornerPatch p = m.patch(c);
      CornerPatch changed = p;
      for (int f = 0; f < 6; ++f)
        if ((p.faceMask >> f) & 1)
          changed.faceCoefficient[static_cast<std::size_t>(f)] += (c % 3 == 0 ? 1e-3 : 1e-5) * (f + 1);
      changed.central += c % 2 ? 1e-4 : 0.0;
      const double estimate = surfaceShiftEstimate(p, changed);
      for (const double t : {estimate * 0.5, estimate * 0.999, estimate * 1.001, estimate * 2, 0.002, 1e-6}) {
        if (!(t > 0)) continue;
        const bool exceeds = surfaceShiftExceeds(p, changed, t);
        EXPECT_EQ(exceeds, estimate > t) << "cell " << c << " threshold " << t << " estimate " << estimate;
        over += exceeds;
        under += !exceeds;
      }
    }
    EXPECT_GT(over, 100);
    EXPECT_GT(under, 100);
  }
}
