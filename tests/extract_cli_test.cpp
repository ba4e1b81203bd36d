// The extract command's run statistics (--stats-json), its report of the fitted construction's fallback, its
// choice of reference reconstruction, the meshes it writes (--mc-mesh, --patch-mesh, --subdiv), its
// independence of --threads, its choice of an OpenVDB grid (--grid), its storage check (--check-storage) and
// its count of holes (--check-holes).
// Each test in a folder of its own.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "cip/measure/surface_fidelity.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/mesh/patch_mesh.h"
#include "cip/mesh/ply.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/readers/vdb_reader.h"
#include "cip/readers/volume_reader.h"
#include "cip/volume/analytic_field.h"
#include "support/command_line.h"
#include "support/sanitized_build.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

const std::string kExtract = std::string(CIP_BINARY_DIR) + "/extract/extract";

/// The model the library builds from an analytic field sampled as extract samples it (fitted, gradient
/// normals), with the given reconstruction.
Model libraryModel(const std::string& name, int n, Reconstruction reconstruction) {
  auto field = makeAnalyticField(name);
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  o.reconstruction = reconstruction;
  return buildModel(sampleField(*field, n, name), o);
}

/// The model's numbers as the file stores them, without the header's record of the reconstruction and the
/// source text: equal for two models exactly when their isovertices, cells and coefficients are.
std::vector<std::uint8_t> numbersOf(Model m) {
  m.reconstruction.reset();
  m.source.clear();
  return serializeModel(m);
}

/// The file extract writes for `built` if `read` (a model read from that file) is its model: `built` with the
/// header's description and reconstruction of `read`, serialised. A model read back and written again is the
/// same model but not always the same bytes (two codes can decode to the same number: docs/model-format.md),
/// so files are compared as written.
std::string fileOf(Model built, const Model& read) {
  built.source = read.source;
  built.reconstruction = read.reconstruction;
  const std::vector<std::uint8_t> bytes = serializeModel(built);
  return std::string(bytes.begin(), bytes.end());
}

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

// --reconstruction reaches the build: each file holds the library's model for the reconstruction asked for,
// number for number, and says which it followed; the stats file records it. On the torus at N = 32 `auto`
// picks central8, and monotone's numbers differ from it, so a flag that did not reach the build (or reached
// only the header) fails. An unknown name, or a build that has no reference of the samples, is refused.
TEST(ExtractCli, ReconstructionChoosesTheReference) {
  test::ScratchDir dir;
  const Model autoModel = libraryModel("torus", 32, Reconstruction::Auto);
  const Model monotoneModel = libraryModel("torus", 32, Reconstruction::Monotone);
  const Model central8Model = libraryModel("torus", 32, Reconstruction::Central8);
  ASSERT_EQ(autoModel.reconstruction, Reconstruction::Central8);
  ASSERT_TRUE(numbersOf(autoModel) == numbersOf(central8Model));
  ASSERT_TRUE(numbersOf(monotoneModel) != numbersOf(central8Model));  // the comparisons below tell them apart
  for (const char* kind : {"monotone", "central8", "auto"}) {
    SCOPED_TRACE(kind);
    const std::string model = dir.file(std::string(kind) + ".cip"),
                      json = dir.file(std::string(kind) + ".json");
    auto r = test::run(kExtract + " torus --resolution 32 --reconstruction " + kind + " -o " + model +
                       " --stats-json " + json);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_EQ(r.err.find("too steep"), std::string::npos) << r.err;  // smooth data
    const bool automatic = std::string(kind) == "auto";
    EXPECT_EQ(r.err.find("reference:") != std::string::npos, automatic)
        << r.err;  // said only when auto chose
    const Model& expected = std::string(kind) == "monotone" ? monotoneModel : central8Model;
    const Model written = readModel(model);
    EXPECT_EQ(written.reconstruction, expected.reconstruction);  // recorded in the file
    EXPECT_TRUE(fileOf(expected, written) == test::slurp(model));
    const std::string text = test::slurp(json);
    EXPECT_NE(text.find("\"reconstruction\": \"" + std::string(kind) + "\""), std::string::npos) << text;
    EXPECT_NE(text.find(std::string("\"reconstruction\": \"") + toString(*expected.reconstruction) + "\""),
              std::string::npos)
        << text;
  }

  // A sparse volume: the bricks keep the 4 points the central8 reference reads around their cells, so the
  // model is the one of the whole volume read as a single brick.
  const std::string sphere = test::sharedData("vdb/sphere.vdb"), vdbModel = dir.file("v.cip");
  auto r = test::run(kExtract + " " + sphere + " --reconstruction central8 -q -o " + vdbModel);
  ASSERT_EQ(r.status, 0) << r.err;
  VolumeReadOptions whole;
  whole.brickCells = 1 << 20;
  whole.apron = referenceReach(Reconstruction::Central8);
  const SparseVolume v = readVolume(sphere, whole);
  ASSERT_EQ(v.bricks.size(), 1u);
  BuildOptions o;
  o.isovalue = 0;
  o.reconstruction = Reconstruction::Central8;
  const Model single = buildModel(v.geometry, v.bricks, o, "");
  const Model bricked = readModel(vdbModel);
  ASSERT_EQ(bricked.cells.size(), single.cells.size());
  EXPECT_TRUE(fileOf(single, bricked) == test::slurp(vdbModel));

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

/// The file holds exactly `mesh` as cip writes PLY (binary, float coordinates and normals); the reader takes
/// it back with its counts.
void expectPlyOf(const std::string& file, const TriangleMesh& mesh, const std::string& what) {
  const std::vector<std::uint8_t> bytes = encodePly(mesh);
  EXPECT_TRUE(test::slurp(file) == std::string(bytes.begin(), bytes.end())) << what;
  const TriangleMesh read = readPly(file);
  EXPECT_EQ(read.positions.size(), mesh.positions.size()) << what;
  EXPECT_EQ(read.normals.size(), mesh.normals.size()) << what;
  EXPECT_EQ(read.triangles, mesh.triangles) << what;
}

// --mc-mesh and --patch-mesh write the library's meshes of the model written (marching cubes on its cells and
// isovertices; the patch surface with --subdiv samples per cell edge), as PLY files the reader takes back;
// both are closed, oriented spheres (Euler characteristic 2), and the stats list their sizes.
TEST(ExtractCli, MeshesAreTheModelsAndClosed) {
  test::ScratchDir dir;
  const std::string model = dir.file("s.cip"), mc = dir.file("mc.ply"), patch = dir.file("patch.ply"),
                    json = dir.file("s.json");
  auto r = test::run(kExtract + " sphere --resolution 12 --normals exact -q -o " + model + " --mc-mesh " +
                     mc + " --patch-mesh " + patch + " --subdiv 3 --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  const Model m = readModel(model);
  MarchingCubesOptions mo;
  mo.recordCells = false;
  expectPlyOf(mc, marchingCubes(m, mo), "marching cubes");
  expectPlyOf(patch, patchMesh(m, 3), "patch mesh");
  const TriangleMesh mcRead = readPly(mc), patchRead = readPly(patch);
  for (const TriangleMesh* mesh : {&mcRead, &patchRead}) {
    const MeshTopology topology = analyseTopology(*mesh);
    EXPECT_TRUE(topology.closedAndOriented()) << topology.describe();
    EXPECT_EQ(topology.eulerCharacteristic, 2) << topology.describe();
    EXPECT_EQ(topology.components, 1u) << topology.describe();
  }
  const std::string text = test::slurp(json);
  for (const std::string& file : {model, mc, patch})
    EXPECT_NE(text.find("\"" + file + "\": " + std::to_string(std::filesystem::file_size(file))),
              std::string::npos)
        << file << "\n"
        << text;
  // --subdiv reaches the patch mesh: 3 samples per cell edge give fewer triangles than the default 4.
  r = test::run(kExtract + " sphere --resolution 12 --normals exact -q -o " + model + " --patch-mesh " +
                patch);
  ASSERT_EQ(r.status, 0) << r.err;
  expectPlyOf(patch, patchMesh(m, 4), "patch mesh, default subdivision");
  const TriangleMesh finer = readPly(patch);
  EXPECT_GT(finer.triangles.size(), patchRead.triangles.size());
}

// The model and both meshes are the same bytes on one thread and on two (the model, marching cubes and the
// patch mesh each split their work over the threads given).
TEST(ExtractCli, ThreadCountChangesNoByte) {
  test::ScratchDir dir;
  std::vector<std::string> outputs[2];
  for (int threads : {1, 2}) {
    const std::string t = std::to_string(threads);
    const std::string model = dir.file("m" + t + ".cip"), mc = dir.file("mc" + t + ".ply"),
                      patch = dir.file("p" + t + ".ply");
    auto r = test::run(kExtract + " gyroid --resolution 20 -q --threads " + t + " -o " + model +
                       " --mc-mesh " + mc + " --patch-mesh " + patch);
    ASSERT_EQ(r.status, 0) << r.err;
    for (const std::string& file : {model, mc, patch}) outputs[threads - 1].push_back(test::slurp(file));
  }
  ASSERT_GT(outputs[0][0].size(), 1000u);
  for (std::size_t k = 0; k < outputs[0].size(); ++k) EXPECT_TRUE(outputs[0][k] == outputs[1][k]) << k;
  // A thread count out of range is refused, not taken as "all".
  auto r = test::run(kExtract + " gyroid --resolution 8 --threads -1 -o " + dir.file("x.cip"));
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find("--threads"), std::string::npos) << r.err;
}

// --grid picks the OpenVDB grid by name: the smoke volume's `density` gives the same model as the default
// (its first float grid), the stats name it; a name the file does not have is an error that lists the grids
// the file has (as listVdbGrids reads them), and no model is written.
TEST(ExtractCli, GridSelectsTheVdbGrid) {
  test::ScratchDir dir;
  const std::string smoke = test::sharedData("vdb/smoke.vdb"), named = dir.file("named.cip"),
                    first = dir.file("first.cip"), json = dir.file("s.json");
  const std::vector<VdbGridInfo> grids = listVdbGrids(smoke);
  ASSERT_EQ(grids.size(), 1u);
  ASSERT_EQ(grids[0].name, "density");
  // At 4 under the sanitizers: the densest 2,950 cells (81,500 at 0.5, whose file took most of the time).
  const std::string common =
      std::string(test::kSanitizedBuild ? " --iso 4" : " --iso 0.5") + " --method paper -q -o ";
  auto r = test::run(kExtract + " " + smoke + " --grid density" + common + named + " --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  r = test::run(kExtract + " " + smoke + common + first);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_GT(readModel(named).cells.size(), 1000u);
  EXPECT_TRUE(test::slurp(named) == test::slurp(first));
  EXPECT_NE(test::slurp(json).find("grid density"), std::string::npos) << test::slurp(json);

  const std::string missing = dir.file("missing.cip");
  r = test::run(kExtract + " " + smoke + " --grid temperature" + common + missing);
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("no grid named 'temperature'"), std::string::npos) << r.err;
  for (const VdbGridInfo& g : grids)
    EXPECT_NE(r.err.find("'" + g.name + "' (" + g.valueType + ")"), std::string::npos) << r.err;
  EXPECT_EQ(r.err.find('\n'), r.err.size() - 1) << "one line: " << r.err;
  EXPECT_FALSE(std::filesystem::exists(missing));
}

/// A MetaImage file (float64, inline) holding the given frames of one grid's dims; a 4-D image for several.
void writeMetaImage(const std::string& path, const std::vector<DenseGrid>& frames) {
  const auto& d = frames[0].geometry.dims;
  std::string text = "ObjectType = Image\nNDims = " + std::string(frames.size() > 1 ? "4" : "3") +
                     "\nDimSize = " + std::to_string(d[0]) + " " + std::to_string(d[1]) + " " +
                     std::to_string(d[2]) + (frames.size() > 1 ? " " + std::to_string(frames.size()) : "") +
                     "\nElementType = MET_DOUBLE\nElementDataFile = LOCAL\n";
  for (const DenseGrid& g : frames)
    text.append(reinterpret_cast<const char*>(g.values.data()), g.values.size() * sizeof(double));
  test::writeAll(path, text);
}

// --frame picks one volume of a 4-D series: the model is the one of a 3-D file holding that volume alone. A
// series read without --frame, or with a frame it does not have, is a one-line error and no output.
TEST(ExtractCli, FrameSelectsTheVolumeOfASeries) {
  test::ScratchDir dir;
  const DenseGrid sphere = sampleField(*makeAnalyticField("sphere"), 12, "sphere");
  const DenseGrid torus = sampleField(*makeAnalyticField("torus"), 12, "torus");
  const std::string series = dir.file("series.mha"), single = dir.file("torus.mha");
  writeMetaImage(series, {sphere, torus});
  writeMetaImage(single, {torus});
  const std::string common = " --iso 0 --method paper -q -o ";
  for (const char* frame : {"0", "1"}) {
    auto r = test::run(kExtract + " " + series + " --frame " + frame + common +
                       dir.file(std::string(frame) + ".cip"));
    ASSERT_EQ(r.status, 0) << r.err;
  }
  auto r = test::run(kExtract + " " + single + common + dir.file("single.cip"));
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(numbersOf(readModel(dir.file("1.cip"))), numbersOf(readModel(dir.file("single.cip"))));
  EXPECT_NE(numbersOf(readModel(dir.file("0.cip"))), numbersOf(readModel(dir.file("1.cip"))));
  EXPECT_NE(readModel(dir.file("1.cip")).source.find("frame 1 of 2"), std::string::npos);

  for (const std::string& args : {std::string(""), std::string(" --frame 2")}) {
    const std::string out = dir.file("bad.cip");
    r = test::run(kExtract + " " + series + args + common + out);
    EXPECT_EQ(r.status, 1) << args;
    EXPECT_EQ(r.err.rfind("extract: error: " + series + ": ", 0), 0u) << r.err;
    EXPECT_NE(r.err.find(args.empty() ? "holds 2 frames" : "frame 2 is out of range"), std::string::npos)
        << r.err;
    EXPECT_EQ(r.err.find('\n'), r.err.size() - 1) << "one line: " << r.err;
    EXPECT_FALSE(std::filesystem::exists(out));
  }
  r = test::run(kExtract + " " + series + " --frame -1" + common + dir.file("neg.cip"));
  EXPECT_NE(r.status, 0);
}

// --check-storage measures the written model against the built one and reports it on standard error and under
// "storage" in the stats file, keys added beside the others: within the format's bounds for format 2 (the
// default), exactly 0 for the lossless format 1; without the flag neither appears, and --quiet keeps the line
// off standard error.
TEST(ExtractCli, CheckStorageReportsHowFarTheStoredSurfaceMoves) {
  test::ScratchDir dir;
  const std::string json = dir.file("stats.json");
  const std::string common =
      kExtract + " sphere --resolution 16 -o " + dir.file("s.cip") + " --stats-json " + json;
  test::CommandResult r = test::run(common + " --check-storage --model-version 1");
  ASSERT_EQ(r.status, 0) << r.err;
  std::string text = test::slurp(json);
  for (const char* key : {"\"storage\": {", "\"max_distance_voxels\": 0.0", "\"mean_distance_voxels\": 0.0",
                          "\"max_normal_degrees\": 0.0", "\"one_sided_hits\": 0", "\"format_version\": 1",
                          "\"check_storage\": ", "\"non_empty_cells\": "})
    EXPECT_NE(text.find(key), std::string::npos) << key << "\n" << text;
  EXPECT_NE(r.err.find("storage: the stored surface moves by at most 0 voxel"), std::string::npos) << r.err;
  r = test::run(common + " --check-storage");
  ASSERT_EQ(r.status, 0) << r.err;
  const nlohmann::json stats = nlohmann::json::parse(test::slurp(json));
  EXPECT_EQ(stats["model"]["format_version"], 2);
  const double moved = stats["storage"]["max_distance_voxels"];
  EXPECT_GT(moved, 0.0);
  EXPECT_LE(moved, 0.01);
  r = test::run(common + " --check-storage --quiet");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err.find("storage:"), std::string::npos) << r.err;
  r = test::run(common);
  ASSERT_EQ(r.status, 0) << r.err;
  text = test::slurp(json);
  EXPECT_EQ(text.find("\"storage\""), std::string::npos) << text;
  EXPECT_EQ(r.err.find("storage:"), std::string::npos) << r.err;
}

// Without a measure or a mesh of the stored surface, extract does not read its file back: the statistics'
// model block (counts, loops, reconstruction) and the world box, which the file keeps as built, are the same
// as when it does, and are those of the file read back.
TEST(ExtractCli, StatsWithoutReadingTheModelBackDescribeTheFile) {
  test::ScratchDir dir;
  const std::string plain = dir.file("plain.json"), readBack = dir.file("back.json"),
                    model = dir.file("b.cip");
  const std::string common = kExtract + " " + test::sourceFile("data/blobs.nrrd") + " --iso 128 -o " + model;
  test::CommandResult r = test::run(common + " --stats-json " + plain);
  ASSERT_EQ(r.status, 0) << r.err;
  r = test::run(common + " --check-holes --stats-json " + readBack);
  ASSERT_EQ(r.status, 0) << r.err;
  const nlohmann::json a = nlohmann::json::parse(test::slurp(plain));
  const nlohmann::json b = nlohmann::json::parse(test::slurp(readBack));
  EXPECT_EQ(a["seconds"]["read_back_model"], 0.0);
  EXPECT_GT(b["seconds"]["read_back_model"].get<double>(), 0.0);
  EXPECT_EQ(a["model"], b["model"]);
  EXPECT_EQ(a["world"], b["world"]);
  EXPECT_EQ(a["fitting"], b["fitting"]);
  const Model stored = readModel(model);
  EXPECT_EQ(a["model"]["non_empty_cells"], stored.cells.size());
  EXPECT_EQ(a["model"]["isovertices"], stored.vertices.size());
  EXPECT_EQ(a["model"]["corners"], stored.corners.size());
}

// --check-holes lists the cells of the model as written whose patch leaks through an open face, as the
// library's measure finds them in the file read back; the bundled volume has a few (docs/method.md, "Holes"),
// the sphere none; without the flag the key is absent.
TEST(ExtractCli, CheckHolesListsTheLeakingCellsOfTheStoredModel) {
  test::ScratchDir dir;
  const std::string json = dir.file("stats.json"), model = dir.file("b.cip");
  test::CommandResult r = test::run(kExtract + " " + test::sourceFile("data/blobs.nrrd") + " --iso 128 -o " +
                                    model + " --check-holes --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  const Model stored = readModel(model);
  const std::vector<std::uint32_t> leaks = openFaceLeakCells(stored);
  EXPECT_GT(leaks.size(), 0u);
  const nlohmann::json stats = nlohmann::json::parse(test::slurp(json));
  ASSERT_TRUE(stats.contains("holes")) << stats.dump();
  EXPECT_EQ(stats["holes"]["open_face_leak_cells"], leaks.size());
  EXPECT_EQ(stats["holes"]["lattice"], 33);
  ASSERT_EQ(stats["holes"]["cells"].size(), leaks.size());
  for (std::size_t i = 0; i < leaks.size(); ++i) {
    const auto& index = stored.cells[leaks[i]].index;
    EXPECT_EQ(stats["holes"]["cells"][i], nlohmann::json({index[0], index[1], index[2]}));
  }
  EXPECT_NE(r.err.find("holes: " + std::to_string(leaks.size()) + " of "), std::string::npos) << r.err;

  r = test::run(kExtract + " sphere --resolution 16 -o " + model + " --check-holes --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(nlohmann::json::parse(test::slurp(json))["holes"]["open_face_leak_cells"], 0);
  r = test::run(kExtract + " sphere --resolution 16 -o " + model + " --stats-json " + json);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_FALSE(nlohmann::json::parse(test::slurp(json)).contains("holes"));
}

// A uint8 mask: auto takes the mask reference and says so; --labels writes one model per non-zero label,
// named after the output, each the library's model of that label; --label N one; bad label requests fail
// clearly.
TEST(ExtractCli, MasksAndLabelMaps) {
  test::ScratchDir dir;
  const std::int64_t n = 24;
  std::string bytes(static_cast<std::size_t>(n * n * n), '\0');
  DenseGrid labels;
  labels.allocate({n, n, n});
  for (std::int64_t k = 0; k < n; ++k)
    for (std::int64_t j = 0; j < n; ++j)
      for (std::int64_t i = 0; i < n; ++i) {
        const double x = static_cast<double>(i), y = static_cast<double>(j), z = static_cast<double>(k);
        const double r = std::hypot(x - 11.6, y - 12.3, z - 11.9);
        const int label = r < 8 ? (x + 0.4 * y < 15 ? 1 : 3) : 0;
        bytes[static_cast<std::size_t>(i + n * (j + n * k))] = static_cast<char>(label);
        labels.at(i, j, k) = label;
      }
  const std::string raw = dir.file("labels.raw");
  test::writeAll(raw, bytes);
  const std::string input = raw + " --dims 24,24,24 --type uint8";

  // Three values next to the surface at 0.5 (0, 1 and 3): not a mask for auto, but --reconstruction mask
  // takes the two sides of the isovalue as the two classes.
  auto r = test::run(kExtract + " " + input + " --iso 0.5 -o " + dir.file("auto.cip"));
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(r.err.find("reference: mask"), std::string::npos) << r.err;
  EXPECT_NE(readModel(dir.file("auto.cip")).reconstruction, Reconstruction::Mask);
  r = test::run(kExtract + " " + input + " --iso 0.5 --reconstruction mask -q -o " + dir.file("mask.cip"));
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(readModel(dir.file("mask.cip")).reconstruction, Reconstruction::Mask);
  // Two values (0 and 1): auto takes the mask reference and says so.
  for (char& c : bytes) c = c != 0;
  const std::string maskRaw = dir.file("mask.raw");
  test::writeAll(maskRaw, bytes);
  r = test::run(kExtract + " " + maskRaw + " --dims 24,24,24 --type uint8 --iso 0.5 -o " +
                dir.file("two.cip"));
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("reference: mask"), std::string::npos) << r.err;
  EXPECT_EQ(readModel(dir.file("two.cip")).reconstruction, Reconstruction::Mask);

  r = test::run(kExtract + " " + input + " --labels -q -o " + dir.file("out.cip") + " --patch-mesh " +
                dir.file("p.ply"));
  ASSERT_EQ(r.status, 0) << r.err;
  for (const int label : {1, 3}) {
    SCOPED_TRACE(label);
    const std::string name = dir.file("out-label" + std::to_string(label) + ".cip");
    const Model written = readModel(name);
    EXPECT_EQ(written.reconstruction, Reconstruction::Mask);
    BuildOptions o;
    o.label = label;
    const Model built = buildModel(labels, o);
    EXPECT_EQ(written.cells.size(), built.cells.size());
    EXPECT_TRUE(std::filesystem::exists(dir.file("p-label" + std::to_string(label) + ".ply")));
  }
  EXPECT_FALSE(std::filesystem::exists(dir.file("out-label2.cip")));  // no such label
  r = test::run(kExtract + " " + input + " --label 3 -q -o " + dir.file("three.cip"));
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(readModel(dir.file("three.cip")).cells.size(),
            readModel(dir.file("out-label3.cip")).cells.size());

  r = test::run(kExtract + " " + input + " --labels --label 3 -q -o " + dir.file("x.cip"));
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find("not both"), std::string::npos) << r.err;
  r = test::run(kExtract + " " + input + " --labels --method paper -q -o " + dir.file("x.cip"));
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find("applies to --method fitted"), std::string::npos) << r.err;
  r = test::run(kExtract + " sphere --resolution 16 --labels -q -o " + dir.file("x.cip"));
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find("label map (integer samples)"), std::string::npos) << r.err;
}

// OpenVDB, GDCM and Open MPI are loaded only when a run needs them (core/module_loader.h): extract itself
// loads none of them, a volume in another format is read without their modules, and a VDB file or DICOM
// series whose module cannot be found is a clear error and no output.
TEST(ExtractCli, LargeLibrariesLoadOnlyWhenAFileNeedsThem) {
  test::ScratchDir dir;
  // What the dynamic linker loads for the program itself (LD_TRACE_LOADED_OBJECTS lists it, as ldd does).
  auto r = test::run("{ LD_TRACE_LOADED_OBJECTS=1 " + kExtract + " 1>&2; }");
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_NE(r.err.find("libtbb"), std::string::npos) << r.err;
  for (const char* library : {"libopenvdb", "libgdcm", "libmpi", "libboost"})
    EXPECT_EQ(r.err.find(library), std::string::npos) << library << " is loaded by extract itself:\n"
                                                      << r.err;

  const std::string empty = dir.file("no-modules");
  std::filesystem::create_directory(empty);
  const std::string without = "CIP_MODULE_DIR='" + empty + "' " + kExtract + " ";
  const std::string nucleon = test::sharedData("nucleon.nhdr"), plain = dir.file("plain.cip"),
                    alone = dir.file("alone.cip");
  r = test::run(kExtract + " " + nucleon + " --iso 128 -q -o " + plain);
  ASSERT_EQ(r.status, 0) << r.err;
  r = test::run(without + nucleon + " --iso 128 -q -o " + alone);
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_TRUE(test::slurp(plain) == test::slurp(alone));

  const std::string dicom = dir.file("slice.dcm");
  test::writeAll(dicom, std::string(128, '\0') + "DICM");
  for (const auto& [input, module] : {std::pair{test::sharedData("vdb/sphere.vdb"), "libcip_vdb.so"},
                                      std::pair{dicom, "libcip_dicom.so"}}) {
    const std::string out = dir.file("out.cip");
    r = test::run(without + input + " -q -o " + out);
    EXPECT_EQ(r.status, 1) << r.err;
    EXPECT_EQ(r.err.rfind("extract: error: " + input + ": ", 0), 0u) << r.err;
    for (const std::string& part :
         {std::string(module), empty + "/" + module + ": no such file", std::string("CIP_MODULE_DIR")})
      EXPECT_NE(r.err.find(part), std::string::npos) << part << " not in: " << r.err;
    EXPECT_FALSE(std::filesystem::exists(out));
  }
}
