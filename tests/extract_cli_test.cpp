// The extract command's run statistics (--stats-json), its report of the fitted construction's fallback, and
// its choice of reference reconstruction.
#include <gtest/gtest.h>

#include <string>

#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/readers/volume_reader.h"
#include "cip/volume/analytic_field.h"
#include "support/command_line.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

const std::string kExtract = std::string(CIP_BINARY_DIR) + "/extract/extract";

}  // namespace

// The fitted build's fallback counts reach the stats file and, when cells stay unresolved, standard error;
// they are those of the library's own build of the same volume.
TEST(ExtractCli, StatsReportTheFittedFallback) {
  test::ScratchDir dir;
  const std::string volume = test::sharedData("headsq.nhdr");
  BuildOptions o;
  o.isovalue = 1150;
  FittingStats expected;
  o.fittingStats = &expected;
  SparseVolume v = readVolume(volume);
  buildModel(*v.dense(), o);
  ASSERT_GT(expected.unresolvedCells.size(), 0u);

  const std::string json = dir.file("stats.json");
  test::CommandResult r =
      test::run(kExtract + " " + volume + " --iso 1150 -o " + dir.file("m.cip") + " --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  const std::string text = test::slurp(json);
  EXPECT_NE(text.find("\"unresolved_cells\": " + std::to_string(expected.unresolvedCells.size())),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("\"blended_isovertices\": " + std::to_string(expected.blendedVertices)),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("\"rounds\": " + std::to_string(expected.rounds)), std::string::npos) << text;
  ASSERT_GT(expected.holes, 0u);
  EXPECT_NE(text.find("\"edge_holes\": " + std::to_string(expected.holes)), std::string::npos) << text;
  EXPECT_NE(text.find("\"edge_holes_closed\": " + std::to_string(expected.holesClosed)), std::string::npos)
      << text;
  EXPECT_NE(text.find(std::string("\"last_round_undone\": ") + (expected.lastRoundUndone ? "true" : "false")),
            std::string::npos)
      << text;
  EXPECT_NE(r.err.find(std::to_string(expected.unresolvedCells.size()) + " cells have no coefficient"),
            std::string::npos)
      << r.err;
  EXPECT_EQ(r.err.find("too steep"), std::string::npos) << r.err;  // the hint is central8's alone
  // The default reconstruction is auto; it says what it chose (monotone: CT steps) and from what.
  ASSERT_EQ(expected.reconstruction, Reconstruction::Monotone);
  EXPECT_NE(text.find("\"reconstruction\": \"auto\""), std::string::npos) << text;
  EXPECT_NE(text.find("\"reconstruction\": \"monotone\""), std::string::npos) << text;
  EXPECT_NE(text.find("\"cells\": " + std::to_string(expected.sampling.cells)), std::string::npos) << text;
  EXPECT_NE(r.err.find("reference: monotone (samples near the surface: effective wavelength"),
            std::string::npos)
      << r.err;
  // central8 rings at the bone's steps: over 1 in 1000 cells unresolved, and extract says what to use.
  r = test::run(kExtract + " " + volume + " --iso 1150 --reconstruction central8 -o " + dir.file("c.cip"));
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("too steep for the central8 reconstruction"), std::string::npos) << r.err;

  // The paper construction has no fallback to report.
  r = test::run(kExtract + " " + volume + " --iso 1150 --method paper -o " + dir.file("p.cip") +
                " --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(test::slurp(json).find("\"fitting\""), std::string::npos);
  EXPECT_EQ(r.err.find("cells have no coefficient"), std::string::npos) << r.err;
}

// --reconstruction reaches the build (the model is the library's with that reconstruction, different from the
// default's) and the stats file; an unknown name, or a build that has no reference of the samples, is
// refused.
TEST(ExtractCli, ReconstructionChoosesTheReference) {
  test::ScratchDir dir;
  const std::string central8 = dir.file("c.cip"), monotone = dir.file("m.cip"), json = dir.file("s.json");
  auto r = test::run(kExtract + " torus --resolution 16 --reconstruction central8 -o " + central8 +
                     " --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err.find("too steep"), std::string::npos) << r.err;  // smooth data
  EXPECT_NE(test::slurp(json).find("\"reconstruction\": \"central8\""), std::string::npos);
  r = test::run(kExtract + " torus --resolution 16 --reconstruction monotone -o " + monotone);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err.find("reference:"), std::string::npos) << r.err;  // said only when auto chose
  EXPECT_NE(test::slurp(central8), test::slurp(monotone));

  auto field = makeAnalyticField("torus");
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  o.reconstruction = Reconstruction::Central8;
  const Model expected = buildModel(sampleField(*field, 16, "torus"), o);
  const Model written = readModel(central8);
  EXPECT_EQ(written.reconstruction, Reconstruction::Central8);  // recorded in the file
  EXPECT_EQ(readModel(monotone).reconstruction, Reconstruction::Monotone);
  ASSERT_EQ(written.cells.size(), expected.cells.size());
  for (std::size_t c = 0; c < expected.cells.size(); ++c)
    EXPECT_EQ(written.cells[c].central, expected.cells[c].central) << c;

  // A sparse volume: the bricks keep the 4 points the central8 reference reads around their cells, so the
  // model is the one of the whole volume read as a single brick.
  const std::string sphere = test::sharedData("vdb/sphere.vdb"), vdbModel = dir.file("v.cip");
  r = test::run(kExtract + " " + sphere + " --reconstruction central8 -q -o " + vdbModel);
  ASSERT_EQ(r.status, 0) << r.err;
  VolumeReadOptions whole;
  whole.brickCells = 1 << 20;
  whole.apron = referenceReach(Reconstruction::Central8);
  const SparseVolume v = readVolume(sphere, whole);
  ASSERT_EQ(v.bricks.size(), 1u);
  o.isovalue = 0;
  const Model single = buildModel(v.geometry, v.bricks, o, "");
  const Model bricked = readModel(vdbModel);
  ASSERT_EQ(bricked.cells.size(), single.cells.size());
  for (std::size_t c = 0; c < single.cells.size(); ++c)
    ASSERT_EQ(bricked.cells[c].central, single.cells[c].central) << c;

  r = test::run(kExtract + " torus --resolution 16 --reconstruction sinc -o " + dir.file("x.cip"));
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find("reconstruction"), std::string::npos) << r.err;
  // Where no reference of the samples is built, asking for one is an error rather than silently ignored.
  for (const char* other : {"--method paper", "--normals exact", "--normals edge"}) {
    r = test::run(kExtract + " torus --resolution 16 --reconstruction central8 " + other + " -o " +
                  dir.file("y.cip"));
    EXPECT_NE(r.status, 0) << other;
    EXPECT_NE(r.err.find("applies to --method fitted with --normals gradient"), std::string::npos) << r.err;
  }
}
