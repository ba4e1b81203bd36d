// Model file: round trip, rejection of damaged files, identical bytes for any thread count.
#include "cip/model/model_file.h"

#include <gtest/gtest.h>
#include <zlib.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>

#include "cip/core/error.h"
#include "cip/model/model_builder.h"
#include "cip/volume/analytic_field.h"
#include "support/random_volume.h"
#include "support/scratch_dir.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

const ModelFileOptions kVersion1{1, {}};

Model sampleModel() {
  DenseGrid g = test::randomVolume(8, 42);
  BuildOptions o;
  o.central = CentralRule::Interior;
  return buildModel(g, o);
}

void expectParseError(const std::vector<std::uint8_t>& bytes, const std::string& fragment) {
  try {
    parseModel(bytes.data(), bytes.size(), "test.cip");
    FAIL() << "accepted a damaged file (expected '" << fragment << "')";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
  }
}

// Re-seal a modified file with a correct checksum so that structural validation is what must catch it.
void reseal(std::vector<std::uint8_t>& bytes) {
  std::uint32_t c = static_cast<std::uint32_t>(crc32(0L, bytes.data(), static_cast<uInt>(bytes.size() - 4)));
  std::memcpy(bytes.data() + bytes.size() - 4, &c, 4);
}

// Byte offset of the three counts (vertex, cell, corner) in the header.
std::size_t countsOffset(const Model& m) {
  return 8 + 4 + 24 + 24 + 24 + 8 + 4 + 4 + m.source.size();
}

}  // namespace

// Version 1 stores every number: a model comes back bit for bit.
TEST(ModelFile, RoundTripIsIdentical) {
  Model m = sampleModel();
  ASSERT_GT(m.cells.size(), 100u);
  test::ScratchDir dir;
  std::string path = dir.file("roundtrip.cip");
  std::size_t written = writeModel(m, path, kVersion1);
  EXPECT_EQ(written, std::filesystem::file_size(path));
  Model r = readModel(path);
  EXPECT_EQ(serializeModel(r, kVersion1), serializeModel(m, kVersion1));
  EXPECT_EQ(r.geometry.dims, m.geometry.dims);
  EXPECT_EQ(r.source, m.source);
  ASSERT_TRUE(m.reconstruction.has_value());  // the default build follows a reference of the samples
  EXPECT_EQ(r.reconstruction, m.reconstruction);
  ASSERT_EQ(r.cells.size(), m.cells.size());
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  for (std::size_t c = 0; c < m.cells.size(); c += 7) {
    CornerPatch a = m.patch(c), b = r.patch(c);
    for (int s = 0; s < 5; ++s) {
      Vec3 x(u(rng), u(rng), u(rng));
      EXPECT_EQ(a.value(x), b.value(x));  // bit-identical evaluation
    }
  }
  std::filesystem::remove(path);
}

// What a reader can know from the header alone (raycast's memory estimate): the counts of the decoded tables,
// for both versions and the paper and fitted methods; version 2's corner count is the 4-cells-per-edge bound.
TEST(ModelFile, TableCountsFromTheHeaderMatchTheDecodedModel) {
  DenseGrid blobs = test::randomVolume(12, 7);
  BuildOptions paper;
  paper.method = PatchMethod::Paper;
  for (const Model& built : {sampleModel(), buildModel(blobs, {}), buildModel(blobs, paper)}) {
    for (const ModelFileOptions& options : {ModelFileOptions{}, kVersion1}) {
      const std::vector<std::uint8_t> bytes = serializeModel(built, options);
      const ModelTableCounts n = modelTableCounts(bytes.data(), bytes.size(), "counts.cip");
      const Model m = parseModel(bytes.data(), bytes.size());
      EXPECT_EQ(n.version, options.version);
      EXPECT_EQ(n.cells, m.cells.size());
      EXPECT_EQ(n.vertices, m.vertices.size());
      if (options.version == 1) {
        EXPECT_TRUE(n.cornersExact);
        EXPECT_EQ(n.corners, m.corners.size());
      } else {
        EXPECT_FALSE(n.cornersExact);
        EXPECT_GE(n.corners, m.corners.size());
        EXPECT_EQ(n.corners, 4 * m.vertices.size());
      }
      EXPECT_GE(n.tableBytes(), m.cells.size() * sizeof(ModelCell) + m.vertices.size() * sizeof(IsoVertex) +
                                    m.corners.size() * sizeof(std::uint32_t));
      // A damaged header is an error, as for parseModel.
      std::vector<std::uint8_t> bad = bytes;
      bad[9] ^= 0x40;  // the version
      EXPECT_THROW(modelTableCounts(bad.data(), bad.size(), "bad.cip"), Error);
      EXPECT_THROW(modelTableCounts(bytes.data(), 20, "cut.cip"), Error);
    }
  }
}

TEST(ModelFile, TruncatedFilesAreRejected) {
  for (const ModelFileOptions& options : {ModelFileOptions{}, kVersion1}) {
    std::vector<std::uint8_t> bytes = serializeModel(sampleModel(), options);
    for (std::size_t len = 0; len < bytes.size(); len += 1 + len / 16) {
      std::vector<std::uint8_t> cut(bytes.begin(), bytes.begin() + static_cast<std::ptrdiff_t>(len));
      EXPECT_THROW(parseModel(cut.data(), cut.size(), "cut.cip"), Error) << "length " << len;
    }
    std::vector<std::uint8_t> longer = bytes;
    longer.push_back(0);
    EXPECT_THROW(parseModel(longer.data(), longer.size()), Error);
  }
}

TEST(ModelFile, CorruptedBytesAreRejected) {
  for (const ModelFileOptions& options : {ModelFileOptions{}, kVersion1}) {
    std::vector<std::uint8_t> bytes = serializeModel(sampleModel(), options);
    std::mt19937 rng(9);
    for (int trial = 0; trial < 300; ++trial) {
      std::vector<std::uint8_t> bad = bytes;
      std::size_t at = rng() % bad.size();
      bad[at] = static_cast<std::uint8_t>(bad[at] ^ (1u << (rng() % 8)));
      EXPECT_THROW(parseModel(bad.data(), bad.size()), Error) << "byte " << at;
    }
  }
}

TEST(ModelFile, OutOfRangeFieldsAreRejectedEvenWithAValidChecksum) {
  Model m = sampleModel();
  const std::vector<std::uint8_t> good = serializeModel(m, kVersion1);
  auto patched = [&](std::size_t offset, const void* value, std::size_t n) {
    std::vector<std::uint8_t> b = good;
    std::memcpy(b.data() + offset, value, n);
    reseal(b);
    return b;
  };
  const std::size_t counts = countsOffset(m);
  std::uint64_t huge = ~std::uint64_t(0) / 3;
  expectParseError(patched(counts, &huge, 8), "vertex count");
  expectParseError(patched(counts + 8, &huge, 8), "cell count");
  expectParseError(patched(counts + 16, &huge, 8), "corner count");
  std::int64_t badDim = -5;
  expectParseError(patched(12, &badDim, 8), "grid dimension");
  std::uint32_t version = 99;
  expectParseError(patched(8, &version, 4), "version 99");
  const std::size_t reconstructionOffset = 12 + 24 + 24 + 24 + 8 + 2;
  std::uint8_t unknownReconstruction = 3;
  expectParseError(patched(reconstructionOffset, &unknownReconstruction, 1), "unknown reconstruction 3");
  // 0: none recorded, as in files written before the field; 1 monotone; 2 central8.
  const std::optional<Reconstruction> expected[] = {std::nullopt, Reconstruction::Monotone,
                                                    Reconstruction::Central8};
  for (std::uint8_t stored = 0; stored < 3; ++stored) {
    const std::vector<std::uint8_t> b = patched(reconstructionOffset, &stored, 1);
    EXPECT_EQ(parseModel(b.data(), b.size()).reconstruction, expected[stored]);
  }
  double nan = std::nan("");
  expectParseError(patched(12 + 24 + 24, &nan, 8), "spacing");
  // First cell: its index, configuration and first corner index.
  const std::size_t firstCell = counts + 24 + m.vertices.size() * 56;
  std::uint32_t outside = 1000;
  expectParseError(patched(firstCell, &outside, 4), "outside the grid");
  std::uint8_t empty = 0;
  expectParseError(patched(firstCell + 12, &empty, 1), "empty configuration");
  std::uint8_t loops = 4;
  expectParseError(patched(firstCell + 14, &loops, 1), "loops do not match");
  std::uint32_t badVertex = static_cast<std::uint32_t>(m.vertices.size());
  expectParseError(patched(firstCell + 19, &badVertex, 4), "out of range");
  std::uint32_t wrongVertex = m.corners[1] != m.corners[0] ? m.corners[1] : m.corners[2];
  expectParseError(patched(firstCell + 19, &wrongVertex, 4), "not on its edge");
  expectParseError(std::vector<std::uint8_t>{'n', 'o', 't', ' ', 'a', ' ', 'm', 'o', 'd', 'e', 'l'}, "magic");
}

// Version 1 files from before the header recorded the reconstruction (docs/model-format.md: that byte was
// half of a reserved u16, always 0, and reads as "none"). sphere4.cip and gyroid3.cip are seeds of the model
// fuzz corpus that the writer of that time wrote (`paper`, gradient normals). A `fitted` file of that time
// had the same layout with the byte 0 where today's has 1 or 2: fitted-torus8-before-reconstruction-byte.cip
// is `extract torus --resolution 8` with that byte set to 0 and the CRC-32 recomputed, as the older writer
// put it. Each must load as what it says, keep every byte through a round trip, and give patches that vanish
// at their corners' isovertices (every term of a cell's patch has a factor that is zero there).
TEST(ModelFile, ReadsVersion1FilesWrittenBeforeTheReconstructionByte) {
  struct OldFile {
    const char* name;
    PatchMethod method;
  };
  for (const OldFile& old :
       {OldFile{"sphere4.cip", PatchMethod::Paper}, OldFile{"gyroid3.cip", PatchMethod::Paper},
        OldFile{"fitted-torus8-before-reconstruction-byte.cip", PatchMethod::Fitted}}) {
    SCOPED_TRACE(old.name);
    const std::string text =
        test::readAll(test::sourceFile(std::string("tests/fuzz/corpus/model/") + old.name));
    const std::vector<std::uint8_t> bytes(text.begin(), text.end());
    ASSERT_GT(bytes.size(), 100u);
    std::uint32_t version = 0;
    std::memcpy(&version, &bytes[8], 4);
    EXPECT_EQ(version, 1u);
    EXPECT_EQ(bytes[94], 0);  // the reconstruction byte, reserved then
    EXPECT_EQ(bytes[95], 0);
    const Model m = parseModel(bytes.data(), bytes.size(), old.name);
    EXPECT_EQ(m.method, old.method);
    EXPECT_EQ(m.normalMode, NormalMode::Gradient);
    EXPECT_FALSE(m.reconstruction.has_value());  // not recorded, and not made up
    EXPECT_GT(m.cells.size(), 10u);
    EXPECT_TRUE(serializeModel(m, kVersion1) == bytes);
    double worst = 0;
    for (std::size_t c = 0; c < m.cells.size(); ++c) {
      const CornerPatch patch = m.patch(c);
      const ModelCell& cell = m.cells[c];
      for (int k = 0; k < cell.numCorners(); ++k) {
        const Vec3 local = m.vertices[m.corners[cell.firstCorner + k]].position - m.cellOrigin(c);
        worst = std::max(worst, std::abs(patch.value(local)));
      }
    }
    EXPECT_LT(worst, 1e-12);
  }
}

TEST(ModelFile, WriteIsAtomicAndFailureLeavesPreviousFile) {
  test::ScratchDir scratch;
  const std::string& dir = scratch.path();
  std::string path = dir + "/m.cip";
  { std::ofstream(path) << "previous contents"; }
  EXPECT_THROW(writeModel(sampleModel(), dir + "/missing-dir/m.cip"), Error);
  EXPECT_THROW(readModel(dir + "/does-not-exist.cip"), Error);
  EXPECT_THROW(readModel(path), Error);  // not a model: rejected, file untouched
  std::ifstream in(path);
  std::string s((std::istreambuf_iterator<char>(in)), {});
  EXPECT_EQ(s, "previous contents");
  writeModel(sampleModel(), path);
  std::size_t files = 0;
  for (auto& e : std::filesystem::directory_iterator(dir)) files += e.is_regular_file();
  EXPECT_EQ(files, 1u) << "no temporary file left behind";
}

TEST(ModelBuilder, IdenticalBytesForAnyThreadCount) {
  auto field = makeAnalyticField("gyroid");
  DenseGrid g = sampleField(*field, 20, "gyroid");
  for (NormalMode mode : {NormalMode::Gradient, NormalMode::Exact}) {
    std::vector<std::uint8_t> reference;
    for (int threads : {1, 2, 3, 8}) {
      BuildOptions o;
      o.normals = mode;
      o.exactField = field.get();
      o.central = CentralRule::Interior;
      o.threads = threads;
      std::vector<std::uint8_t> bytes = serializeModel(buildModel(g, o));
      if (reference.empty()) {
        reference = bytes;
      } else {
        EXPECT_EQ(bytes, reference) << threads << " threads";
      }
    }
  }
}

TEST(ModelBuilder, NonFiniteVoxelsAreRejectedOrSkipped) {
  DenseGrid g = test::randomVolume(6, 4);
  g.at(2, 3, 3) = std::nan("");
  EXPECT_THROW(buildModel(g, BuildOptions{}), Error);
  BuildOptions o;
  o.skipNonFinite = true;
  Model m = buildModel(g, o);
  for (const auto& c : m.cells) {
    bool touches = c.index[0] + 1 >= 2 && c.index[0] <= 2 && c.index[1] + 1 >= 3 && c.index[1] <= 3 &&
                   c.index[2] + 1 >= 3 && c.index[2] <= 3;
    EXPECT_FALSE(touches);
  }
  EXPECT_GT(m.cells.size(), 10u);
}
