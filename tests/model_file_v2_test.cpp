// Model file version 2 (model_file_v2.h): what it keeps exactly, what it quantises and by how much, that the
// stored model does not depend on how it is chunked or on threads, that writing a stored model gives the same
// file, and that damage is found and reported with the chunk it is in. (How far the stored surface moves is
// stored_model_test.cpp.)
#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <zlib.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>

#include "cip/core/error.h"
#include "cip/measure/model_displacement.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/volume_reader.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "support/field_model.h"
#include "support/random_volume.h"
#include "support/sanitized_build.h"
#include "support/volume_blocks.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

using test::fieldModel;

std::vector<std::uint8_t> withBrick(const Model& m, int brick) {
  ModelFileOptions o;
  o.v2 = ModelFileV2Options::forMethod(m.method);
  o.v2->brick = brick;
  return serializeModel(m, o);
}

// Offsets of the version 2 header (docs/model-format.md).
std::size_t directoryOffset(const Model& m) {
  return 8 + 4 + 24 + 24 + 24 + 8 + 4 + 4 + m.source.size() + 4 + 4 + 16 + 16;
}
constexpr std::size_t kEntryBytes = 36;

std::uint32_t chunkCount(const std::vector<std::uint8_t>& b, const Model& m) {
  std::uint64_t n;
  std::memcpy(&n, b.data() + directoryOffset(m) - 8, 8);
  return static_cast<std::uint32_t>(n);
}

// Re-seals the header checksum so that the structural checks are what must catch a change.
void resealHeader(std::vector<std::uint8_t>& b, const Model& m) {
  const std::size_t end = directoryOffset(m) + chunkCount(b, m) * kEntryBytes;
  const auto c = static_cast<std::uint32_t>(crc32(0L, b.data(), static_cast<uInt>(end)));
  std::memcpy(b.data() + end, &c, 4);
}

std::string parseError(const std::vector<std::uint8_t>& b) {
  try {
    parseModel(b.data(), b.size(), "test.cip");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

void expectSamePatches(const Model& a, const Model& b) {
  ASSERT_EQ(a.cells.size(), b.cells.size());
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0, 1);
  for (std::size_t c = 0; c < a.cells.size(); ++c) {
    ASSERT_EQ(a.cells[c].index, b.cells[c].index);
    const CornerPatch pa = a.patch(c), pb = b.patch(c);
    for (int s = 0; s < 3; ++s) {
      const Vec3 x(u(rng), u(rng), u(rng));
      ASSERT_EQ(pa.value(x), pb.value(x)) << "cell " << c;
    }
  }
}

// Everything the file stores is the same, bit for bit.
void expectSameModel(const Model& a, const Model& b) {
  ASSERT_EQ(a.cells.size(), b.cells.size());
  ASSERT_EQ(a.vertices.size(), b.vertices.size());
  EXPECT_EQ(a.corners, b.corners);
  for (std::size_t c = 0; c < a.cells.size(); ++c) {
    EXPECT_EQ(a.cells[c].index, b.cells[c].index);
    EXPECT_EQ(a.cells[c].config, b.cells[c].config);
    EXPECT_EQ(a.cells[c].numLoops, b.cells[c].numLoops);
    EXPECT_EQ(a.cells[c].loopSize, b.cells[c].loopSize);
    EXPECT_EQ(a.cells[c].pairing03, b.cells[c].pairing03);
    EXPECT_EQ(a.cells[c].firstCorner, b.cells[c].firstCorner);
    EXPECT_EQ(a.cells[c].faceCoefficient, b.cells[c].faceCoefficient);
    EXPECT_EQ(a.cells[c].central, b.cells[c].central);
  }
  for (std::size_t v = 0; v < a.vertices.size(); ++v) {
    EXPECT_EQ(a.vertices[v].position, b.vertices[v].position);
    EXPECT_EQ(a.vertices[v].normal, b.vertices[v].normal);
    EXPECT_EQ(a.vertices[v].weight, b.vertices[v].weight);
  }
}

std::vector<std::uint8_t> fileBytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::vector<std::uint8_t>(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
}

}  // namespace

// The cells, their configurations, loops and corners are kept exactly; each vertex stays on its edge within
// half a quantisation step (9 bits: 1/1022 of the edge), normals within a fraction of a degree, and the
// coefficients within their steps.
TEST(ModelFileV2, KeepsTopologyAndQuantisesWithinItsSteps) {
  for (PatchMethod method : {PatchMethod::Fitted, PatchMethod::Paper}) {
    SCOPED_TRACE(toString(method));
    const Model m = fieldModel("torus", 24, method);
    const Model s = storedModel(m);
    ASSERT_EQ(s.cells.size(), m.cells.size());
    ASSERT_EQ(s.corners.size(), m.corners.size());
    ASSERT_EQ(s.vertices.size(), m.vertices.size());
    double worstPosition = 0, worstNearEnds = 0, worstDegrees = 0, worstSide = 0;
    int movedOntoGridPoints = 0;
    for (std::size_t c = 0; c < m.cells.size(); ++c) {
      const ModelCell &a = m.cells[c], &b = s.cells[c];
      ASSERT_EQ(a.index, b.index);
      ASSERT_EQ(a.config, b.config);
      ASSERT_EQ(m.loops(c).edges, s.loops(c).edges);
      for (int k = 0; k < a.numCorners(); ++k) {
        const IsoVertex& va = m.vertices[m.corners[a.firstCorner + k]];
        const IsoVertex& vb = s.vertices[s.corners[b.firstCorner + k]];
        // Crossings within half a step of a grid point are kept off it (one step from it) ...
        const double toPoint = (va.position - va.position.array().round().matrix()).norm();
        (toPoint < 0.5 / 511 ? worstNearEnds : worstPosition) =
            std::max(toPoint < 0.5 / 511 ? worstNearEnds : worstPosition, (va.position - vb.position).norm());
        const auto onGridPoint = [](const Vec3& x) { return x == x.array().round().matrix(); };
        movedOntoGridPoints += onGridPoint(vb.position) && !onGridPoint(va.position);
        worstDegrees =
            std::max(worstDegrees, std::acos(std::min(1.0, va.normal.dot(vb.normal))) * 180 / M_PI);
        EXPECT_EQ(vb.weight, 1.0);
      }
      // Fitted: step 0.002 up to 64 steps, then 6 bits of mantissa: half a step or 1/128 of the value.
      for (int f = 0; f < 6; ++f)
        worstSide = std::max(worstSide, std::abs(a.faceCoefficient[f] - b.faceCoefficient[f]) /
                                            (0.001 + std::abs(a.faceCoefficient[f]) / 128));
    }
    EXPECT_GT(worstPosition, 0);  // it does quantise ...
    EXPECT_LE(worstPosition, 0.5 / 511 + 1e-12);
    EXPECT_LE(worstNearEnds, 1.0 / 511 + 1e-12);
    EXPECT_EQ(movedOntoGridPoints, 0);  // ... so that no corner plane passes through an open face's corner
    EXPECT_LE(worstDegrees, 0.25);
    if (method == PatchMethod::Fitted) {
      EXPECT_LE(worstSide, 1.0 + 1e-9);
    }
  }
}

// The stored model is the same for any brick size and thread count (chunks only split the file), and writing
// a stored model gives its file again, so reading and rewriting a file never drifts.
TEST(ModelFileV2, StoredModelIsIndependentOfChunkingAndThreadsAndRewritesIdentically) {
  for (PatchMethod method : {PatchMethod::Fitted, PatchMethod::Paper}) {
    SCOPED_TRACE(toString(method));
    const Model m = fieldModel("gyroid", 26, method);
    const std::vector<std::uint8_t> big = withBrick(m, 64), small = withBrick(m, 8);
    EXPECT_GT(chunkCount(small, m), 8u);
    EXPECT_EQ(chunkCount(big, m), 1u);
    const Model a = parseModel(big.data(), big.size()), b = parseModel(small.data(), small.size());
    expectSamePatches(a, b);
    {
      tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
      EXPECT_EQ(withBrick(m, 8), small);
      // Chunks are decoded in parallel; one thread decodes the same model, bit for bit.
      expectSameModel(parseModel(small.data(), small.size()), b);
    }
    if (method == PatchMethod::Fitted) {
      EXPECT_EQ(withBrick(a, 64), big);
    } else {
      const std::vector<std::uint8_t> again = withBrick(a, 64);
      expectSamePatches(a, parseModel(again.data(), again.size()));
      expectSameModel(a, parseModel(again.data(), again.size()));
    }
  }
}

// A model written with refinements: the model a file of it at brick size 64 decodes to, and at 16, have the
// same patches, and each survives being written again bit for bit.
void expectRewritesToTheSameModel(const Model& m, const std::vector<std::uint8_t>& bytes) {
  const Model a = parseModel(bytes.data(), bytes.size());
  const std::vector<std::uint8_t> again = withBrick(a, 64);
  expectSameModel(a, parseModel(again.data(), again.size()));
  // Bricks order the vertices differently; the patches are the same, and so is a rewrite.
  const std::vector<std::uint8_t> small = withBrick(m, 16);
  const Model b = parseModel(small.data(), small.size());
  expectSamePatches(a, b);
  const std::vector<std::uint8_t> smallAgain = withBrick(b, 16);
  expectSameModel(b, parseModel(smallAgain.data(), smallAgain.size()));
}

std::size_t streamBytes(const std::vector<std::uint8_t>& file, const std::string& name) {
  for (const auto& [n, bytes] : modelFileV2Streams(file))
    if (n == name) return bytes;
  ADD_FAILURE() << "no stream " << name;
  return 0;
}

// A paper model of CT data keeps refined vertices where its rule is ill-conditioned or its cells amplify
// rounding (flag bit 3; no full-precision vertices), and the stored model survives being written again bit
// for bit (refined vertices are recognised by their values), at any brick size and thread count.
TEST(ModelFileV2, PaperModelOfCtDataRefinesVerticesAndRewritesToTheSameModel) {
  BuildOptions o;
  o.isovalue = 1150;
  o.method = PatchMethod::Paper;
  const Model m = buildModel(test::readVolumeDense(test::sharedData("headsq.nhdr")), o);
  const std::vector<std::uint8_t> bytes = withBrick(m, 64);
  constexpr std::size_t kFlags = 8 + 4 + 24 + 24 + 24 + 8 + 3;  // magic, version, grid, isovalue, 3 bytes
  EXPECT_EQ(bytes[kFlags] & 8, 8);                              // bit 3: refined vertices
  EXPECT_GT(streamBytes(bytes, "refined vertices"), 1000u);
  EXPECT_LE(streamBytes(bytes, "full-precision vertices"), chunkCount(bytes, m));  // a count of 0 each
  expectRewritesToTheSameModel(m, bytes);
  tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
  EXPECT_EQ(withBrick(m, 64), bytes);
}

// Under-sampled data give fitted patches that amplify rounding: with the plain codes alone some cells of
// Marschner-Lobb at N = 64 moved by twice the storage bound (0.01 voxel, stored_model_test.cpp). The writer
// finds such cells (surface_shift.h) and stores their coefficients, and where that is not enough their
// corners, with finer codes (flag bits 3 and 4); the file grows by a few per cent, and the stored model
// survives being written again bit for bit at any brick size (refined coefficients are recognised by their
// values).
TEST(ModelFileV2, FittedCellsThatAmplifyRoundingKeepFinerCodes) {
  const Model m = fieldModel("marschner-lobb", 64, PatchMethod::Fitted);
  ModelFileOptions plainOptions;
  plainOptions.v2 = ModelFileV2Options::forMethod(m.method);
  plainOptions.v2->refineMovingCells = false;
  const std::vector<std::uint8_t> plainBytes = serializeModel(m, plainOptions), bytes = withBrick(m, 64);
  const Model plain = parseModel(plainBytes.data(), plainBytes.size()),
              stored = parseModel(bytes.data(), bytes.size());
  DisplacementOptions rays;
  rays.raysPerAxis = test::kSanitizedBuild ? 1 : 4;
  const double plainMax = measureModelDisplacement(m, plain, rays).distanceVoxels.max,
               storedMax = measureModelDisplacement(m, stored, rays).distanceVoxels.max;
  std::printf("plain codes: %zu bytes, distance max %.3g voxel; refined: %zu bytes, %.3g voxel\n",
              plainBytes.size(), plainMax, bytes.size(), storedMax);
  EXPECT_GT(plainMax, 0.01);
  EXPECT_LE(storedMax, 0.01);
  constexpr std::size_t kFlags = 8 + 4 + 24 + 24 + 24 + 8 + 3;
  EXPECT_EQ(bytes[kFlags] & 24, 24);  // bits 3 and 4: refined vertices and coefficients
  EXPECT_EQ(plainBytes[kFlags] & 24, 0);
  EXPECT_GT(streamBytes(bytes, "refined coefficients"), 100u);
  EXPECT_LT(static_cast<double>(bytes.size()), 1.1 * static_cast<double>(plainBytes.size()));
  expectRewritesToTheSameModel(m, bytes);
  // Refined coefficients follow the refined vertices' stream: a file that claims them without it is damaged.
  std::vector<std::uint8_t> damaged = bytes;
  damaged[kFlags] = static_cast<std::uint8_t>(damaged[kFlags] & ~8);
  resealHeader(damaged, m);
  EXPECT_NE(parseError(damaged).find("refined coefficients without refined vertices"), std::string::npos)
      << parseError(damaged);
}

// Files written before (tests/data/model-v2, whose README says how) decode to the models they decoded to when
// they were written, bit for bit: each is stored beside that model as version 1 (every number in full
// precision). Fitted and paper models, several chunks each.
TEST(ModelFileV2, StoredFilesDecodeAsWhenWritten) {
  for (const char* name : {"sphere-12-fitted", "torus-12-paper-interior", "marschner-lobb-12-edge"}) {
    SCOPED_TRACE(name);
    const std::string base = test::sourceFile(std::string("tests/data/model-v2/") + name);
    const std::vector<std::uint8_t> v2 = fileBytes(base + ".cip"), v1 = fileBytes(base + ".v1.cip");
    ASSERT_FALSE(v2.empty());
    ASSERT_FALSE(v1.empty());
    const Model decoded = parseModel(v2.data(), v2.size()), then = parseModel(v1.data(), v1.size());
    ASSERT_GT(decoded.cells.size(), 100u);
    EXPECT_EQ(decoded.method, then.method);
    EXPECT_EQ(decoded.isovalue, then.isovalue);
    expectSameModel(decoded, then);
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    expectSameModel(parseModel(v2.data(), v2.size()), then);
  }
}

// A model of a sparse volume (an OpenVDB level set read as bricks; cells outside them left out) survives
// serialise -> parse -> serialise -> parse bit for bit, fitted and paper, whole and in bricks of 16 cells,
// and its file is the same for one thread and two.
TEST(ModelFileV2, SparseVolumeModelsRoundTripBitForBit) {
  const std::string path = test::sharedData("vdb/sphere.vdb");
  if (!std::filesystem::exists(path)) GTEST_SKIP() << path << " is not there";
  const SparseVolume v = readVolume(path);
  // Under the sanitizers the bricks of one octant of the grid only: an eighth of the sphere, still with the
  // grid's other cells left out around it.
  std::vector<GridBrick> bricks;
  for (const GridBrick& b : v.bricks)
    if (!test::kSanitizedBuild || std::max({b.offset[0], b.offset[1], b.offset[2]}) < v.geometry.dims[0] / 2)
      bricks.push_back(b);
  for (PatchMethod method : {PatchMethod::Fitted, PatchMethod::Paper}) {
    SCOPED_TRACE(toString(method));
    BuildOptions o;
    o.isovalue = 0;
    o.method = method;
    const Model built = buildModel(v.geometry, bricks, o, "sphere");
    ASSERT_GT(built.cells.size(), 1000u);
    for (int brick : test::kSanitizedBuild ? std::vector<int>{16} : std::vector<int>{64, 16}) {
      SCOPED_TRACE(brick);
      const std::vector<std::uint8_t> file = withBrick(built, brick);
      const Model a = parseModel(file.data(), file.size());
      ASSERT_EQ(a.cells.size(), built.cells.size());
      const std::vector<std::uint8_t> again = withBrick(a, brick);
      const Model b = parseModel(again.data(), again.size());
      if (method == PatchMethod::Fitted) {
        EXPECT_EQ(again, file);
        expectSameModel(a, b);
      } else {
        expectSamePatches(a, b);
      }
      tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
      EXPECT_EQ(withBrick(built, brick), file);
      expectSameModel(parseModel(file.data(), file.size()), a);
    }
  }
}

// Cells the model leaves out although their signs say crossed (here: next to non-finite samples skipped with
// --skip-nonfinite) are listed as exceptions and stay out.
TEST(ModelFileV2, CellsLeftOutStayOut) {
  DenseGrid g = test::randomVolume(10, 7);
  g.at(4, 5, 5) = std::numeric_limits<double>::quiet_NaN();
  g.at(7, 2, 3) = std::numeric_limits<double>::infinity();
  BuildOptions o;
  o.skipNonFinite = true;
  const Model m = buildModel(g, o);
  const Model s = storedModel(m);
  ASSERT_EQ(s.cells.size(), m.cells.size());
  for (std::size_t c = 0; c < m.cells.size(); ++c) EXPECT_EQ(s.cells[c].index, m.cells[c].index);
  EXPECT_EQ(s.vertices.size(), m.vertices.size());
}

// Damage is found and says where: a flipped bit in a chunk names the chunk and its brick; in the header, the
// header checksum; counts and sizes that the file cannot back are refused before anything is allocated.
TEST(ModelFileV2, DamageIsReportedWithItsChunk) {
  const Model m = fieldModel("sphere", 30, PatchMethod::Fitted);
  const std::vector<std::uint8_t> good = withBrick(m, 8);
  const std::size_t dir = directoryOffset(m);
  const std::uint32_t chunks = chunkCount(good, m);
  ASSERT_GT(chunks, 3u);
  const std::size_t firstChunk = dir + chunks * kEntryBytes + 4;
  {
    std::vector<std::uint8_t> b = good;
    b[firstChunk + 20] ^= 4;
    const std::string e = parseError(b);
    EXPECT_NE(e.find("chunk 0 (brick "), std::string::npos) << e;
    EXPECT_NE(e.find(", cells from ("), std::string::npos) << e;
    EXPECT_NE(e.find("checksum mismatch"), std::string::npos) << e;
  }
  {
    std::vector<std::uint8_t> b = good;
    b[20] ^= 1;
    EXPECT_NE(parseError(b).find("header checksum mismatch"), std::string::npos) << parseError(b);
  }
  auto patched = [&](std::size_t offset, const void* value, std::size_t n) {
    std::vector<std::uint8_t> b = good;
    std::memcpy(b.data() + offset, value, n);
    resealHeader(b, m);
    return parseError(b);
  };
  const std::uint32_t huge = 0xFFFFFFF0u;
  EXPECT_NE(patched(dir + 12, &huge, 4).find("impossible counts"), std::string::npos);
  EXPECT_NE(patched(dir + 16, &huge, 4).find("impossible counts"), std::string::npos);
  const std::uint32_t one = 1;
  // A vertex count that the chunk's data contradict: its streams are too long for it.
  EXPECT_NE(patched(dir + 16, &one, 4).find("chunk 0 (brick "), std::string::npos)
      << patched(dir + 16, &one, 4);
  const std::uint64_t longChunk = ~std::uint64_t(0) / 2;
  EXPECT_NE(patched(dir + 24, &longChunk, 8).find("truncated"), std::string::npos);
  {  // checked before the header checksum, which a huge count cannot be sealed with
    std::vector<std::uint8_t> b = good;
    const std::uint64_t manyChunks = ~std::uint64_t(0) / 64;
    std::memcpy(b.data() + dir - 8, &manyChunks, 8);
    EXPECT_NE(parseError(b).find("chunk count"), std::string::npos) << parseError(b);
  }
  const std::uint32_t outside = 1000;
  EXPECT_NE(patched(dir, &outside, 4).find("outside the grid"), std::string::npos);
  // A stream that declares more bytes than its counts can need (the chunk's checksum re-sealed too).
  {
    std::vector<std::uint8_t> b = good;
    const std::uint32_t raw = 0x7FFFFFFF;
    std::memcpy(b.data() + firstChunk, &raw, 4);
    std::uint64_t bytes;
    std::memcpy(&bytes, b.data() + dir + 24, 8);
    const auto c = static_cast<std::uint32_t>(crc32(0L, b.data() + firstChunk, static_cast<uInt>(bytes)));
    std::memcpy(b.data() + dir + 32, &c, 4);
    resealHeader(b, m);
    const std::string e = parseError(b);
    EXPECT_NE(e.find("more than its counts can need"), std::string::npos) << e;
  }
  // A chunk left out (directory, cell count and checksums made consistent again): the cells of the bricks
  // below it lack the vertices and faces it owns, and the file is refused.
  {
    const std::size_t drop = chunks / 2, entries = dir, chunkStart = firstChunk;
    std::vector<std::uint8_t> b(good.begin(), good.begin() + static_cast<std::ptrdiff_t>(entries));
    std::uint64_t offset = chunkStart, dropOffset = 0, dropBytes = 0;
    std::uint32_t dropCells = 0;
    for (std::uint32_t i = 0; i < chunks; ++i) {
      const std::uint8_t* e = good.data() + dir + i * kEntryBytes;
      std::uint64_t bytes;
      std::memcpy(&bytes, e + 24, 8);
      if (i == drop) {
        std::memcpy(&dropCells, e + 12, 4);
        dropOffset = offset;
        dropBytes = bytes;
      } else {
        b.insert(b.end(), e, e + kEntryBytes);
      }
      offset += bytes;
    }
    ASSERT_GT(dropCells, 0u);
    std::uint64_t cells, count = chunks - 1;
    std::memcpy(&cells, b.data() + dir - 16, 8);
    cells -= dropCells;
    std::memcpy(b.data() + dir - 16, &cells, 8);
    std::memcpy(b.data() + dir - 8, &count, 8);
    const auto c = static_cast<std::uint32_t>(crc32(0L, b.data(), static_cast<uInt>(b.size())));
    b.insert(b.end(), reinterpret_cast<const std::uint8_t*>(&c),
             reinterpret_cast<const std::uint8_t*>(&c) + 4);
    b.insert(b.end(), good.begin() + static_cast<std::ptrdiff_t>(chunkStart),
             good.begin() + static_cast<std::ptrdiff_t>(dropOffset));
    b.insert(b.end(), good.begin() + static_cast<std::ptrdiff_t>(dropOffset + dropBytes), good.end());
    const std::string e = parseError(b);
    EXPECT_NE(e.find("damaged model file: a crossed"), std::string::npos) << e;
  }
  // Truncated anywhere: an error, never a crash.
  for (std::size_t len = 0; len < good.size(); len += 1 + len / 8) {
    const std::vector<std::uint8_t> cut(good.begin(), good.begin() + static_cast<std::ptrdiff_t>(len));
    EXPECT_FALSE(parseError(cut).empty()) << len;
  }
}
