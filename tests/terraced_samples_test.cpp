// Terraced samples (mask_reference.h, TwoValuedSamples; build_passes.h, terraceRaise): integer samples that
// climb by about a level per voxel, so that many next to the surface equal an integer isovalue. Which data
// count as terraces, that bricks which overlap count every grid edge once, and that Auto builds such data at
// the isovalue raised by 1/64 of a level: one fitting round, no hole, the cells and sides of the samples at
// the isovalue, and a surface as close to the shape the samples were made from as the plain build's.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>

#include "cip/mesh/patch_mesh.h"
#include "cip/model/build_passes.h"
#include "cip/model/model_builder.h"
#include "cip/model/patch_fitting.h"
#include "cip/reference/mask_reference.h"
#include "support/corner_sides.h"

using namespace cip;

namespace {

const Vec3 kCentre(16.3, 15.6, 17.2);
constexpr double kRadius = 11.4;

/// A ball's signed distance times `slope` around the level 128, as `round` makes it: rounded to integers
/// (8-bit data) or not.
DenseGrid slopedBall(std::int64_t n, double slope, bool round = true) {
  DenseGrid g;
  g.allocate({n, n, n});
  for (std::int64_t k = 0; k < n; ++k)
    for (std::int64_t j = 0; j < n; ++j)
      for (std::int64_t i = 0; i < n; ++i) {
        const Vec3 x(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k));
        const double v = 128 + slope * (kRadius - (x - kCentre).norm());
        g.at(i, j, k) = round ? std::clamp(std::round(v), 0.0, 255.0) : v;
      }
  return g;
}

/// Slices z0 .. z1 - 1 of `g` as a grid of their own.
DenseGrid slices(const DenseGrid& g, std::int64_t z0, std::int64_t z1) {
  const auto& d = g.geometry.dims;
  DenseGrid out;
  out.allocate({d[0], d[1], z1 - z0});
  for (std::int64_t k = z0; k < z1; ++k)
    for (std::int64_t j = 0; j < d[1]; ++j)
      for (std::int64_t i = 0; i < d[0]; ++i) out.at(i, j, k - z0) = g.at(i, j, k);
  return out;
}

}  // namespace

TEST(TerracedSamples, AreIntegersThatStepByALevelOrTwo) {
  build::TwoValuedVerdict gentle, steep, unrounded, between;
  const TwoValuedSamples t = detectTwoValued(slopedBall(34, 1.3), 128);
  EXPECT_TRUE(t.integral);
  EXPECT_FALSE(t.twoValued);
  EXPECT_GT(t.crossedEdges, 50);  // every eighth slice
  EXPECT_GT(2 * t.terraceEdges, t.crossedEdges);
  gentle.add(t);
  EXPECT_TRUE(gentle.terraced());
  EXPECT_EQ(build::terraceRaise(gentle), build::kTerraceRaise);
  // CT-like steps of tens of levels, samples that are not integers, an isovalue no sample can equal.
  steep.add(detectTwoValued(slopedBall(34, 30), 128));
  EXPECT_FALSE(steep.terraced());
  unrounded.add(detectTwoValued(slopedBall(34, 1.3, false), 128));
  EXPECT_FALSE(unrounded.terraced());
  EXPECT_TRUE(unrounded.decided());
  const TwoValuedSamples half = detectTwoValued(slopedBall(34, 1.3), 127.5);
  EXPECT_EQ(half.crossedEdges, 0);
  between.add(half);
  EXPECT_EQ(build::terraceRaise(between), 0.0);
  // An infinite sample is no integer: a counted slice of them (z = 16, a multiple of the stride) ends it.
  DenseGrid infinite = slopedBall(34, 1.3);
  for (std::int64_t j = 0; j < 34; ++j)
    for (std::int64_t i = 0; i < 34; ++i) infinite.at(i, j, 16) = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(detectTwoValued(infinite, 128).integral);
}

// Two slabs that overlap by three slices, each counting its own slices as a streamed build's slabs do: the
// counts add up to the whole grid's.
TEST(TerracedSamples, OverlappingBricksCountEveryEdgeOnce) {
  const DenseGrid whole = slopedBall(34, 1.3);
  const TwoValuedSamples all = detectTwoValued(whole, 128, TerraceCount{{0, 0, 0}, {33, 33, 33}, 0});
  std::int64_t crossed = 0, terrace = 0;
  for (const auto& [z0, z1, own0, own1] :
       {std::array<std::int64_t, 4>{0, 20, 0, 17}, std::array<std::int64_t, 4>{14, 34, 3, 19}}) {
    const TwoValuedSamples part =
        detectTwoValued(slices(whole, z0, z1), 128, TerraceCount{{0, 0, own0}, {33, 33, own1}, z0});
    crossed += part.crossedEdges;
    terrace += part.terraceEdges;
  }
  EXPECT_GT(all.crossedEdges, 50);
  EXPECT_EQ(crossed, all.crossedEdges);
  EXPECT_EQ(terrace, all.terraceEdges);
}

TEST(TerracedSamples, AutoRaisesTheIsovalueKeepingCellsAndSides) {
  const DenseGrid g = slopedBall(34, 1.3);
  BuildOptions options;
  options.isovalue = 128;
  FittingStats raisedStats, plainStats;
  options.fittingStats = &raisedStats;
  const Model raised = buildModel(g, options);
  EXPECT_EQ(raisedStats.isovalueRaise, build::kTerraceRaise);
  EXPECT_EQ(raised.isovalue, 128 + build::kTerraceRaise);
  EXPECT_EQ(raisedStats.rounds, 1);
  EXPECT_EQ(raisedStats.holes, 0u);
  EXPECT_TRUE(raisedStats.unresolvedCells.empty());
  // The reference asked for by name is built at the isovalue as given.
  options.reconstruction = Reconstruction::Monotone;
  options.fittingStats = &plainStats;
  const Model plain = buildModel(g, options);
  EXPECT_EQ(plainStats.isovalueRaise, 0.0);
  EXPECT_EQ(plain.isovalue, 128.0);
  // That build follows interpolants that are zero on plateaus: this data makes it fall back (3 rounds, about
  // 1,000 blended isovertices and 30 holes), so the test keeps exercising what the raise avoids.
  EXPECT_GT(plainStats.rounds, 1);
  // The same cells and configurations: no sample lies between the two isovalues.
  ASSERT_EQ(raised.cells.size(), plain.cells.size());
  ASSERT_GT(raised.cells.size(), 1000u);
  for (std::size_t c = 0; c < raised.cells.size(); ++c) {
    ASSERT_EQ(raised.cells[c].index, plain.cells[c].index);
    ASSERT_EQ(raised.cells[c].config, plain.cells[c].config);
  }
  // Every cell corner on its sample's side of 128.
  EXPECT_EQ(test::wrongSideCorners(raised, g, 128), 0);
  // As close to the ball as the plain build (the samples place it to about half a level, 0.6 voxel).
  auto meanDistance = [](const Model& m) {
    const TriangleMesh mesh = patchMesh(m, 3);
    double sum = 0;
    for (const Vec3& p : mesh.positions) sum += std::abs((p - kCentre).norm() - kRadius);
    return sum / static_cast<double>(mesh.positions.size());
  };
  const double raisedDistance = meanDistance(raised), plainDistance = meanDistance(plain);
  EXPECT_LT(raisedDistance, 0.4);
  EXPECT_LT(raisedDistance, 1.1 * plainDistance);
}
