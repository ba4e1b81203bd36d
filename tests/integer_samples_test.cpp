// Integer samples at an integer isovalue (mask_reference.h, TwoValuedSamples; build_passes.h, integerRaise).
// Which data count, that bricks which overlap count every grid edge once, and that Auto builds such data at
// the isovalue raised by 1/64 of a level. On terraces (integer samples that climb by about a level per voxel,
// so that many next to the surface equal the isovalue): one fitting round, no hole, the cells and sides of
// the samples at the isovalue, and a surface as close to the shape the samples were made from as the plain
// build's. On the bundled blobs: isovertices next to samples at the isovalue keep the uncrossed grid edges
// from them clear, and fewer cells leak than without the raise.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>

#include "cip/measure/surface_fidelity.h"
#include "cip/mesh/patch_mesh.h"
#include "cip/model/build_passes.h"
#include "cip/model/model_builder.h"
#include "cip/model/patch_fitting.h"
#include "cip/reference/mask_reference.h"
#include "support/corner_sides.h"
#include "support/volume_blocks.h"
#include "support/volume_files.h"

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

TEST(IntegerSamples, AreCountedAtAnIntegerIsovalue) {
  build::TwoValuedVerdict gentle, steep, unrounded, between;
  const TwoValuedSamples t = detectTwoValued(slopedBall(34, 1.3), 128);
  EXPECT_TRUE(t.integral);
  EXPECT_FALSE(t.twoValued);
  EXPECT_GT(t.crossedEdges, 50);  // every eighth slice
  gentle.add(t);
  EXPECT_TRUE(gentle.integerSamples());
  EXPECT_EQ(build::integerRaise(gentle, 128), build::kIntegerRaise);
  // CT-like steps of tens of levels are integer samples too.
  steep.add(detectTwoValued(slopedBall(34, 30), 128));
  EXPECT_TRUE(steep.integerSamples());
  EXPECT_EQ(build::integerRaise(steep, 128), build::kIntegerRaise);
  // An isovalue so large that 1/64 changes no bit of it is not raised.
  EXPECT_EQ(build::integerRaise(steep, 0x1p60), 0.0);
  // Samples that are not integers, an isovalue no sample can equal.
  unrounded.add(detectTwoValued(slopedBall(34, 1.3, false), 128));
  EXPECT_FALSE(unrounded.integerSamples());
  EXPECT_TRUE(unrounded.decided());
  EXPECT_EQ(build::integerRaise(unrounded, 128), 0.0);
  const TwoValuedSamples half = detectTwoValued(slopedBall(34, 1.3), 127.5);
  EXPECT_EQ(half.crossedEdges, 0);
  between.add(half);
  EXPECT_EQ(build::integerRaise(between, 127.5), 0.0);
  // An infinite sample is no integer: a counted slice of them (z = 16, a multiple of the stride) ends it.
  DenseGrid infinite = slopedBall(34, 1.3);
  for (std::int64_t j = 0; j < 34; ++j)
    for (std::int64_t i = 0; i < 34; ++i) infinite.at(i, j, 16) = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(detectTwoValued(infinite, 128).integral);
}

// Two slabs that overlap by three slices, each counting its own slices as a streamed build's slabs do: the
// counts add up to the whole grid's.
TEST(IntegerSamples, OverlappingBricksCountEveryEdgeOnce) {
  const DenseGrid whole = slopedBall(34, 1.3);
  const TwoValuedSamples all = detectTwoValued(whole, 128, CountedEdges{{0, 0, 0}, {33, 33, 33}, 0});
  std::int64_t crossed = 0;
  for (const auto& [z0, z1, own0, own1] :
       {std::array<std::int64_t, 4>{0, 20, 0, 17}, std::array<std::int64_t, 4>{14, 34, 3, 19}}) {
    const TwoValuedSamples part =
        detectTwoValued(slices(whole, z0, z1), 128, CountedEdges{{0, 0, own0}, {33, 33, own1}, z0});
    crossed += part.crossedEdges;
  }
  EXPECT_GT(all.crossedEdges, 50);
  EXPECT_EQ(crossed, all.crossedEdges);
}

TEST(IntegerSamples, AutoRaisesTheIsovalueKeepingCellsAndSides) {
  const DenseGrid g = slopedBall(34, 1.3);
  BuildOptions options;
  options.isovalue = 128;
  FittingStats raisedStats, plainStats;
  options.fittingStats = &raisedStats;
  const Model raised = buildModel(g, options);
  EXPECT_EQ(raisedStats.isovalueRaise, build::kIntegerRaise);
  EXPECT_EQ(raised.isovalue, 128 + build::kIntegerRaise);
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

// On the bundled blobs (8-bit, 107 samples at the isovalue 128): the raised build's isovertices next to those
// samples are treated as on their grid points, so that no corner plane tilts towards the other sign along a
// grid edge from the sample that the surface does not cross; without that (the same isovalue given by hand)
// the patches cross open faces next to them in many more cells, with it in no more than at 128 itself.
TEST(IntegerSamples, IsoverticesNextToSamplesAtTheIsovalueKeepUncrossedEdgesClear) {
  const DenseGrid g = test::readVolumeDense(test::sourceFile("data/blobs.nrrd"));
  BuildOptions options;
  options.isovalue = 128;
  FittingStats stats;
  options.fittingStats = &stats;
  const Model raised = buildModel(g, options);
  ASSERT_EQ(stats.isovalueRaise, build::kIntegerRaise);
  ASSERT_EQ(stats.reconstruction, Reconstruction::Central8);
  // Every isovertex within 1/64 voxel of a sample at 128: its normal does not point along an uncrossed grid
  // edge from that sample (both ends at or below 128: the plane must not rise towards them).
  const auto& d = g.geometry.dims;
  int near = 0;
  for (const IsoVertex& v : raised.vertices) {
    const Vec3 q = v.position.array().round().matrix();
    if ((v.position - q).norm() > build::kIntegerRaise) continue;
    const std::array<std::int64_t, 3> p{static_cast<std::int64_t>(q[0]), static_cast<std::int64_t>(q[1]),
                                        static_cast<std::int64_t>(q[2])};
    if (g.at(p[0], p[1], p[2]) != 128) continue;
    ++near;
    int axis = 0;
    for (int a = 0; a < 3; ++a)
      if (v.position[a] != q[a]) axis = a;
    for (int other = 0; other < 3; ++other) {
      if (other == axis) continue;
      for (int step : {-1, 1}) {
        auto n = p;
        n[other] += step;
        if (n[other] < 0 || n[other] >= d[other] || g.at(n[0], n[1], n[2]) > 128) continue;
        EXPECT_LE(v.normal[other] * step, 0.0) << "isovertex at " << v.position.transpose();
      }
    }
  }
  EXPECT_GT(near, 50);
  // The same raise without it, and the build at 128 itself (a reconstruction named: no raise).
  options.fittingStats = nullptr;
  options.isovalue = 128 + build::kIntegerRaise;
  const Model byHand = buildModel(g, options);
  options.isovalue = 128;
  options.reconstruction = Reconstruction::Central8;
  const Model plain = buildModel(g, options);
  const std::int64_t leaks = countOpenFaceLeaks(raised);
  EXPECT_LE(leaks, countOpenFaceLeaks(plain));
  EXPECT_LT(4 * leaks, countOpenFaceLeaks(byHand));
}
