// The fallbacks of the fitted construction (patch_fitting.h) on inputs where they run, as the fitting stats
// show: blend rounds that are kept, a round that is undone, cells left with the coefficient the fewest
// samples contradict, faces without a sign-correct coefficient, and holes closed by local blends. Where they
// run, the patches still join exactly (measureContinuity) and the model is byte-identical for 1, 2 and 7
// threads.
#include <gtest/gtest.h>

#include "cip/measure/continuity_check.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/volume/analytic_field.h"
#include "support/join_tolerances.h"
#include "support/model_bytes.h"
#include "support/random_volume.h"
#include "support/volume_blocks.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

/// Builds the model with 1, 2 and 7 threads, expects the same bytes and the same stats from each, and the
/// patches to join; returns the stats.
FittingStats expectJoinedAndThreadIndependent(const DenseGrid& grid, BuildOptions o) {
  FittingStats stats;
  o.fittingStats = &stats;
  o.threads = 1;
  const Model model = buildModel(grid, o);
  const std::vector<std::uint8_t> bytes = test::modelBytes(model);
  const FittingStats one = stats;
  for (int threads : {2, 7}) {
    o.threads = threads;
    EXPECT_EQ(test::modelBytes(buildModel(grid, o)), bytes) << threads << " threads";
    EXPECT_EQ(stats.rounds, one.rounds) << threads << " threads";
    EXPECT_EQ(stats.blendedVertices, one.blendedVertices) << threads << " threads";
    EXPECT_EQ(stats.unresolvedCells, one.unresolvedCells) << threads << " threads";
    EXPECT_EQ(stats.holesClosed, one.holesClosed) << threads << " threads";
  }
  const ContinuityStats s = measureContinuity(model, 8);
  EXPECT_GT(s.curvePoints, 1000);
  EXPECT_LT(s.maxGap, test::kJoinGap);
  EXPECT_LT(s.maxAngle, test::kJoinAngle);
  EXPECT_EQ(s.signDisagreements, 0);
  return one;
}

BuildOptions exact(const AnalyticField& field) {
  BuildOptions o;
  o.isovalue = field.defaultIsovalue();
  o.normals = NormalMode::Exact;
  o.exactField = &field;
  return o;
}

}  // namespace

// CT bone (headsq at 1150, a 16^3 block): two blend rounds kept, the third undone, four cells left with the
// fewest-violation central coefficient, and a hole closed by a local blend; the reference is the samples'
// monotone interpolant, named, so that the build runs at 1150 itself (Auto, which picks monotone here too,
// builds integer samples 1/64 of a level higher, and then no hole is left to close).
TEST(FittingFallbacks, CtBoneBlock) {
  const DenseGrid block =
      test::crop(test::readVolumeDense(test::sharedData("headsq.nhdr")), {24, 16, 64}, {16, 16, 16});
  BuildOptions o;
  o.isovalue = 1150;
  o.reconstruction = Reconstruction::Monotone;
  const FittingStats s = expectJoinedAndThreadIndependent(block, o);
  EXPECT_EQ(s.reconstruction, Reconstruction::Monotone);
  EXPECT_GE(s.rounds, 3);
  EXPECT_TRUE(s.lastRoundUndone);
  EXPECT_GT(s.blendedVertices, 0u);
  EXPECT_GT(s.failedCells, 0u);
  EXPECT_GT(s.unresolvedCells.size(), 0u);
  EXPECT_GT(s.holes, 0u);
  EXPECT_EQ(s.holesClosed, s.holes);
}

// Marschner-Lobb at N = 28 with exact normals: a blend round kept (hundreds of isovertices blended), the next
// undone, and cells and faces without a sign-correct coefficient.
TEST(FittingFallbacks, MarschnerLobbExactN28) {
  const auto field = makeAnalyticField("marschner-lobb");
  const FittingStats s =
      expectJoinedAndThreadIndependent(sampleField(*field, 28, field->name()), exact(*field));
  EXPECT_GE(s.rounds, 3);
  EXPECT_TRUE(s.lastRoundUndone);
  EXPECT_GT(s.blendedVertices, 0u);
  EXPECT_GT(s.failedCells, 0u);
  EXPECT_GT(s.failedFaces, 0u);
  EXPECT_GT(s.unresolvedCells.size(), 0u);
}

// Marschner-Lobb at N = 16 with exact normals: the only blend round is undone, and the holes left are all
// closed by local blends (the only blended isovertices).
TEST(FittingFallbacks, MarschnerLobbExactN16) {
  const auto field = makeAnalyticField("marschner-lobb");
  const FittingStats s =
      expectJoinedAndThreadIndependent(sampleField(*field, 16, field->name()), exact(*field));
  EXPECT_TRUE(s.lastRoundUndone);
  EXPECT_GT(s.holes, 0u);
  EXPECT_EQ(s.holesClosed, s.holes);
  EXPECT_GT(s.blendedVertices, 0u);
  EXPECT_GT(s.failedFaces, 0u);
}

// Random samples (9^3, monotone reference): a blend round that resolves every cell is kept, and a hole is
// closed.
TEST(FittingFallbacks, RandomSamples) {
  BuildOptions o;
  o.reconstruction = Reconstruction::Monotone;
  const FittingStats s = expectJoinedAndThreadIndependent(test::randomVolume(9, 4), o);
  EXPECT_EQ(s.rounds, 2);
  EXPECT_FALSE(s.lastRoundUndone);
  EXPECT_GT(s.blendedVertices, 0u);
  EXPECT_TRUE(s.unresolvedCells.empty());
  EXPECT_GT(s.holes, 0u);
  EXPECT_EQ(s.holesClosed, s.holes);
}
