// The zero mask of a patch (patch_bounds.h): every zero of a real patch lies in a marked sub-box, an unmarked
// sub-box holds values of one strict sign, and searching a ray only over the stretch of marked sub-boxes
// finds the same first crossing as searching the whole cell, for rays of every kind through every cell.
#include "cip/ray/patch_bounds.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "cip/model/model_builder.h"
#include "cip/ray/ray_patch.h"
#include "cip/volume/analytic_field.h"
#include "support/field_model.h"
#include "support/sanitized_build.h"

using namespace cip;

namespace {

Model sampledModel(const std::string& field, int n, NormalMode normals = NormalMode::Exact) {
  return test::fieldModel(field, n, normals);
}

/// Models of several shapes and both kinds of normals; `all` adds the larger ones.
std::vector<Model> models(bool all) {
  std::vector<Model> out;
  out.push_back(sampledModel("sphere", 8));
  out.push_back(sampledModel("torus", 12));
  out.push_back(sampledModel("gyroid", 12, NormalMode::Gradient));
  if (all) {
    out.push_back(sampledModel("sphere", 16));
    out.push_back(sampledModel("gyroid", 16));
  }
  return out;
}

constexpr int kN = kZeroMaskDivisions;

/// Whether point x (cell-local) lies in a marked sub-box enlarged by `pad`.
bool inMarkedSubBox(std::uint64_t mask, const Vec3& x, double pad) {
  for (int b = 0; b < kN * kN * kN; ++b) {
    if (!((mask >> b) & 1)) continue;
    const int index[3] = {b % kN, (b / kN) % kN, b / (kN * kN)};
    bool inside = true;
    for (int a = 0; a < 3; ++a)
      inside = inside && x[a] >= static_cast<double>(index[a]) / kN - pad &&
               x[a] <= static_cast<double>(index[a] + 1) / kN + pad;
    if (inside) return true;
  }
  return false;
}

}  // namespace

// Dense samples of every cell's patch: sign changes between neighbouring samples are refined to a zero by
// bisection, and every zero must lie in a marked sub-box; every sample of an unmarked sub-box has the sign of
// the sub-box's centre (no zero inside). The marks must also cull: on average fewer than three quarters of
// the sub-boxes on these coarse grids (about a third on sphere.vdb's 67,736 cells).
TEST(PatchZeroMask, MarksEveryZeroAndUnmarkedSubBoxesHaveOneSign) {
  // Per axis over the cell, so 4 per sub-box (2 under the sanitizers, where the samples are most of the
  // time).
  constexpr int kSamples = test::kSanitizedBuild ? 8 : 16;
  for (const Model& model : models(false)) {
    std::int64_t zeros = 0, marked = 0;
    for (std::size_t c = 0; c < model.cells.size(); ++c) {
      const CornerPatch patch = model.patch(c);
      const std::uint64_t mask = patchZeroMask(patch);
      marked += __builtin_popcountll(mask);
      auto at = [&](int i, int j, int k) -> Vec3 { return Vec3(i, j, k) / kSamples; };
      for (int k = 0; k <= kSamples; ++k)
        for (int j = 0; j <= kSamples; ++j)
          for (int i = 0; i <= kSamples; ++i) {
            const Vec3 x = at(i, j, k);
            const double v = patch.value(x);
            if (v == 0) {
              ++zeros;
              ASSERT_TRUE(inMarkedSubBox(mask, x, 0)) << "cell " << c << " zero at " << x.transpose();
              continue;
            }
            for (int a = 0; a < 3; ++a) {
              Vec3 y = x;
              y[a] += 1.0 / kSamples;
              if (y[a] > 1) continue;
              const double w = patch.value(y);
              if (w == 0 || (w < 0) == (v < 0)) continue;
              Vec3 lo = x, hi = y;
              for (int it = 0; it < 60; ++it) {
                const Vec3 m = 0.5 * (lo + hi);
                ((patch.value(m) < 0) == (v < 0) ? lo : hi) = m;
              }
              ++zeros;
              ASSERT_TRUE(inMarkedSubBox(mask, 0.5 * (lo + hi), 1e-12))
                  << "cell " << c << " zero at " << (0.5 * (lo + hi)).transpose();
            }
          }
      for (int b = 0; b < kN * kN * kN; ++b) {
        if ((mask >> b) & 1) continue;
        const Vec3 lo = Vec3(b % kN, (b / kN) % kN, b / (kN * kN)) * (1.0 / kN);
        const double centre = patch.value(lo + Vec3::Constant(0.5 / kN));
        ASSERT_NE(centre, 0);
        for (int k = 0; k <= 5; ++k)
          for (int j = 0; j <= 5; ++j)
            for (int i = 0; i <= 5; ++i) {
              const double v = patch.value(lo + Vec3(i, j, k) / (5.0 * kN));
              ASSERT_TRUE(v != 0 && (v < 0) == (centre < 0)) << "cell " << c << " sub-box " << b;
            }
      }
    }
    EXPECT_GT(zeros, 0);
    const double meanMarked = static_cast<double>(marked) / static_cast<double>(model.cells.size());
    std::printf("%zu cells: %.1f of 64 sub-boxes marked on average\n", model.cells.size(), meanMarked);
    EXPECT_LT(meanMarked, 48);
  }
}

// The renderer's use: the first crossing found over the stretch of marked sub-boxes is the one found over the
// whole cell, for random rays, rays along the axes, and rays exactly in the sub-box and cell planes.
TEST(ClipRayToZeroMask, SearchingTheMarkedStretchFindsTheSameFirstCrossing) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0, 1), dir(-1, 1);
  std::uniform_int_distribution<int> plane(0, kN);
  RootSearchOptions options;
  options.crossingsOnly = true;
  for (const Model& model : models(true)) {
    int rays = 0, hits = 0, culled = 0;
    for (std::size_t c = 0; c < model.cells.size(); ++c) {
      const CornerPatch patch = model.patch(c);
      const std::uint64_t mask = patchZeroMask(patch);
      for (int r = 0; r < 40; ++r) {
        Vec3 d(dir(rng), dir(rng), dir(rng));
        Vec3 through(u(rng), u(rng), u(rng));
        if (r % 4 == 1) {  // along an axis
          d = Vec3::Zero();
          d[r % 3] = r % 8 < 4 ? 1 : -1;
        }
        if (r % 4 == 2) {  // in a sub-box plane (or a cell face) of one or two axes
          d[r % 3] = 0;
          through[r % 3] = static_cast<double>(plane(rng)) / kN;
          if (r % 8 == 2) {
            d[(r + 1) % 3] = 0;
            through[(r + 1) % 3] = static_cast<double>(plane(rng)) / kN;
          }
        }
        if (d.norm() < 0.1) continue;
        d.normalize();
        const Vec3 o = through - 2.0 * d;
        double t0, t1, s0, s1;
        if (!clipRayToCell(o, d, 0, 10, t0, t1)) continue;
        ++rays;
        const auto whole = intersectRayPatch(patch, o, d, 0, 10, options);
        const bool crosses = clipRayToZeroMask(o, d, t0, t1, mask, s0, s1);
        if (!crosses) {
          ++culled;
          ASSERT_FALSE(whole) << "cell " << c << " ray " << r << ": a crossing at " << whole->t
                              << " in the culled cell";
          continue;
        }
        EXPECT_GE(s0, t0);
        EXPECT_LE(s1, t1);
        const auto part = intersectRayPatch(patch, o, d, s0, s1, options);
        ASSERT_EQ(static_cast<bool>(whole), static_cast<bool>(part)) << "cell " << c << " ray " << r;
        if (!whole) continue;
        ++hits;
        EXPECT_NEAR(whole->t, part->t, 1e-12) << "cell " << c << " ray " << r;
      }
    }
    std::printf("%d rays, %d with a crossing, %d culled by the mask\n", rays, hits, culled);
    EXPECT_GT(hits, rays / 10);
    EXPECT_GT(culled, rays / 20);
  }
}

TEST(ClipRayToZeroMask, StretchOfMarkedSubBoxes) {
  double s0, s1;
  // All marked: the whole interval.
  ASSERT_TRUE(clipRayToZeroMask(Vec3(-1, 0.5, 0.5), Vec3(1, 0, 0), 1, 2, ~std::uint64_t{0}, s0, s1));
  EXPECT_EQ(s0, 1);
  EXPECT_EQ(s1, 2);
  // Only sub-box (2, 2, 2): a ray along x at y = z = 0.6 crosses it for x in [0.5, 0.75] (padded).
  const std::uint64_t one = std::uint64_t{1} << (2 + 4 * 2 + 16 * 2);
  ASSERT_TRUE(clipRayToZeroMask(Vec3(-1, 0.6, 0.6), Vec3(1, 0, 0), 1, 2, one, s0, s1));
  EXPECT_NEAR(s0, 1.5, 1e-8);
  EXPECT_NEAR(s1, 1.75, 1e-8);
  // The same ray at y = 0.2 misses it; a zero direction component outside the slab misses too.
  EXPECT_FALSE(clipRayToZeroMask(Vec3(-1, 0.2, 0.6), Vec3(1, 0, 0), 1, 2, one, s0, s1));
  // On the sub-box's face y = 0.5 (within the pad): crosses.
  EXPECT_TRUE(clipRayToZeroMask(Vec3(-1, 0.5, 0.6), Vec3(1, 0, 0), 1, 2, one, s0, s1));
  EXPECT_FALSE(clipRayToZeroMask(Vec3(-1, 0.6, 0.6), Vec3(1, 0, 0), 1, 2, 0, s0, s1));
  // The box of the marks.
  Vec3 lo, hi;
  ASSERT_TRUE(zeroMaskBox(one | 1, lo, hi));
  EXPECT_EQ(lo, Vec3(0, 0, 0));
  EXPECT_EQ(hi, Vec3(0.75, 0.75, 0.75));
  EXPECT_FALSE(zeroMaskBox(0, lo, hi));
}
