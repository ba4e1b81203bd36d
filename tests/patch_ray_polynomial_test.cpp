// The patch on a ray in its own form (patch_ray_polynomial.h) is the same polynomial as the general sum of
// products (rayPolynomial, ray_patch.h): the same values, derivatives and first crossings; its Bernstein
// coefficients describe it on the interval with their ends equal to its values bit for bit; and its interval
// bound never excludes a zero. Checked on every cell of real patch models, for random rays and rays along
// the axes and in the cell's faces.
#include "cip/ray/patch_ray_polynomial.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "cip/model/model_builder.h"
#include "cip/ray/ray_patch.h"
#include "cip/volume/analytic_field.h"
#include "support/field_model.h"

using namespace cip;

namespace {

std::vector<Model> models() {
  return {test::fieldModel("sphere", 8, NormalMode::Exact), test::fieldModel("torus", 12, NormalMode::Exact),
          test::fieldModel("gyroid", 12, NormalMode::Gradient),
          test::fieldModel("gyroid", 10, NormalMode::Exact)};
}

/// A ray through the cell: random, along an axis, or in a face plane of the cell.
void randomRay(std::mt19937_64& rng, int r, Vec3& origin, Vec3& direction) {
  std::uniform_real_distribution<double> u(0, 1), dir(-1, 1);
  Vec3 d(dir(rng), dir(rng), dir(rng)), through(u(rng), u(rng), u(rng));
  if (r % 4 == 1) {
    d = Vec3::Zero();
    d[r % 3] = r % 8 < 4 ? 1 : -1;
  } else if (r % 4 == 2) {
    d[r % 3] = 0;
    through[r % 3] = r % 8 < 4 ? 0.0 : 1.0;
  }
  if (d.norm() < 0.1) d = Vec3(0.3, -0.5, 0.8);
  direction = d.normalized();
  origin = through - 1.0 * direction;
}

/// The scaled Bernstein form c[0..n] at u in [0, 1], and the same sum of magnitudes (its rounding scale).
void bernsteinAt(const PatchRayPolynomial::Coefficients& c, int n, double u, double& value, double& scale) {
  value = 0;
  scale = 0;
  for (int k = 0; k <= n; ++k) {
    const double basis = std::pow(u, k) * std::pow(1 - u, n - k);
    value += c[static_cast<std::size_t>(k)] * basis;
    scale += std::abs(c[static_cast<std::size_t>(k)]) * basis;
  }
}

}  // namespace

TEST(PatchRayPolynomial, IsTheSamePolynomialAsTheSumOfProducts) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u01(0, 1);
  int rays = 0, excluded = 0, crossings = 0;
  for (const Model& model : models()) {
    for (std::size_t c = 0; c < model.cells.size(); ++c) {
      const CornerPatch patch = model.patch(c);
      for (int r = 0; r < 12; ++r) {
        Vec3 o, d;
        randomRay(rng, r, o, d);
        double t0 = 0, t1 = 0;
        if (!clipRayToCell(o, d, 0, 3, t0, t1)) continue;
        ++rays;
        const PatchRayPolynomial own(patch, o, d);
        const RayPolynomial sum = rayPolynomial(patch, o, d);
        ASSERT_GE(own.degree(), sum.degree());
        // Values and derivatives, within the rounding bounds of both evaluations.
        for (int k = 0; k <= 8; ++k) {
          const double t = t0 + (t1 - t0) * k / 8.0;
          double v = 0, dv = 0, bound = 0, vs = 0, ds = 0, bs = 0;
          own.valueDerivativeAndBound(t, v, dv, bound);
          sum.valueDerivativeAndBound(t, vs, ds, bs);
          ASSERT_EQ(v, own.value(t)) << "value() and valueDerivativeAndBound() differ in bits";
          ASSERT_NEAR(v, vs, bound + bs) << "cell " << c << " ray " << r << " t " << t;
          ASSERT_GT(bound, 0.5 * bs);  // the same rounding bound, to the degree it counts
          ASSERT_LT(bound, 2.0 * bs);
          ASSERT_NEAR(dv, ds, 1e-9 * (1 + std::abs(ds))) << "cell " << c << " ray " << r << " t " << t;
        }
        // Bernstein coefficients on a random sub-interval: ends bit for bit, the form equal to the values.
        const double a = t0 + (t1 - t0) * 0.5 * u01(rng), b = t1 - (t1 - t0) * 0.5 * u01(rng);
        PatchRayPolynomial::Coefficients coeff;
        const int n = own.scaledBernstein(a, b, coeff);
        ASSERT_EQ(n, own.degree());
        ASSERT_EQ(coeff[0], own.value(a));
        ASSERT_EQ(coeff[static_cast<std::size_t>(n)], own.value(b));
        for (double s : {0.1, 0.37, 0.5, 0.81}) {
          double form = 0, scale = 0;
          bernsteinAt(coeff, n, s, form, scale);
          ASSERT_NEAR(form, sum.value(a + s * (b - a)),
                      1e-12 * (scale + 1e-300) + sum.roundingBound(a + s * (b - a)))
              << "cell " << c << " ray " << r;
        }
        // The interval bound never excludes a zero: where it excludes one, the values keep one sign.
        if (own.excludesZero(a, b)) {
          ++excluded;
          const double first = sum.value(a);
          for (int k = 0; k <= 64; ++k) {
            const double value = sum.value(a + (b - a) * k / 64.0);
            ASSERT_NE(value, 0.0);
            ASSERT_EQ(value > 0, first > 0) << "cell " << c << " ray " << r;
          }
        }
        // The same first crossing.
        const auto mine = firstCrossing(own, t0, t1), theirs = firstCrossing(sum, t0, t1);
        ASSERT_EQ(static_cast<bool>(mine), static_cast<bool>(theirs)) << "cell " << c << " ray " << r;
        if (mine) {
          ++crossings;
          EXPECT_NEAR(mine->t, theirs->t, 1e-9) << "cell " << c << " ray " << r;
        }
      }
    }
  }
  std::printf("%d rays, %d with a crossing, %d excluded by the interval bound\n", rays, crossings, excluded);
  EXPECT_GT(crossings, rays / 10);
  EXPECT_GT(excluded, rays / 10);
}
