// The analytic test fields: gradients against their values, and lattice evaluation against point evaluation.
#include "cip/volume/analytic_field.h"

#include <gtest/gtest.h>

#include <array>
#include <vector>

using namespace cip;

namespace {

/// Points spread over [-1, 1]^3, away from the fields' singular sets (origin, torus axis).
std::vector<Vec3> probePoints() {
  std::vector<Vec3> points;
  for (int i = 0; i < 64; ++i)
    points.emplace_back(-0.93 + 0.0291 * i, 0.87 - 0.0237 * ((i * 7) % 64), -0.71 + 0.0219 * ((i * 13) % 64));
  return points;
}

}  // namespace

TEST(AnalyticField, GradientsMatchCentralDifferences) {
  const double h = 1e-6;
  for (const std::string& name : analyticFieldNames()) {
    auto field = makeAnalyticField(name);
    ASSERT_NE(field, nullptr) << name;
    for (const Vec3& p : probePoints()) {
      const Vec3 g = field->gradient(p);
      for (int axis = 0; axis < 3; ++axis) {
        const Vec3 e = h * Vec3::Unit(axis);
        const double difference = (field->value(p + e) - field->value(p - e)) / (2 * h);
        EXPECT_NEAR(g[axis], difference, 1e-5 * (1 + g.norm())) << name << " at " << p.transpose();
      }
    }
  }
}

TEST(AnalyticField, LatticeValuesEqualPointValues) {
  // Irregular coordinates, counts and strides (the fitted construction uses both orders and face lattices
  // with a single coordinate and stride 0 on one axis).
  const std::vector<double> x{-0.97, -0.41, 0.05, 0.33, 0.86}, y{-0.62, -0.11, 0.28, 0.93},
      z{-0.88, 0.14, 0.57};
  const std::array<std::array<int, 3>, 3> counts{{{5, 4, 3}, {5, 4, 1}, {1, 4, 3}}};
  for (const std::string& name : analyticFieldNames()) {
    auto field = makeAnalyticField(name);
    for (const auto& count : counts) {
      // z fastest, then x, then y: not the natural order, to catch swapped strides.
      const std::array<int, 3> stride{count[2], count[2] * count[0], count[2] == 1 ? 0 : 1};
      std::vector<double> out(static_cast<std::size_t>(count[0] * count[1] * count[2]), -12345.0);
      field->valuesOnLattice(x.data(), y.data(), z.data(), count, stride, out.data());
      for (int d = 0; d < count[2]; ++d)
        for (int b = 0; b < count[1]; ++b)
          for (int a = 0; a < count[0]; ++a) {
            const double expected =
                field->value(Vec3(x[static_cast<std::size_t>(a)], y[static_cast<std::size_t>(b)],
                                  z[static_cast<std::size_t>(d)]));
            EXPECT_DOUBLE_EQ(out[static_cast<std::size_t>(a * stride[0] + b * stride[1] + d * stride[2])],
                             expected)
                << name << " at lattice point " << a << ' ' << b << ' ' << d;
          }
    }
  }
}

TEST(AnalyticField, MarschnerLobbRippleFrequencyCountsTheRipples) {
  // The ripple's phase f_M cos(pi r / 2) runs from 6 cycles on the z-axis to 0 at r = 1: the frequency
  // integrated along any radius over [0, 1] is 6 cycles, whatever the height and direction.
  for (const Vec3& direction : {Vec3(1, 0, 0), Vec3(0.6, -0.8, 0)})
    for (double z : {-0.5, 0.3}) {
      constexpr int kSteps = 2000;
      double cycles = 0;
      for (int i = 0; i < kSteps; ++i) {
        const double r = (i + 0.5) / kSteps;
        cycles += marschnerLobbRippleFrequency(r * direction + Vec3(0, 0, z)) / kSteps;
      }
      EXPECT_NEAR(cycles, 6.0, 1e-6) << "z " << z;
    }
  EXPECT_EQ(marschnerLobbRippleFrequency(Vec3(0, 0, 0.4)), 0.0);
  EXPECT_NEAR(marschnerLobbRippleFrequency(Vec3(0, -1, 0)), 6 * 3.14159265358979323846 / 2, 1e-12);
}
