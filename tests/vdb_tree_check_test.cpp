// The walk over a VDB grid's tree that checks its stored sizes before OpenVDB reads it: it must accept every
// way OpenVDB stores a valid tree (compression, mask compression, half floats, inactive-value variants,
// several root children, streams without grid offsets where it passes over other grids) and turn corrupt
// sizes into errors instead of OpenVDB's huge allocations and buffer overflows.
#include "cip/readers/vdb_tree_check.h"

#include <gtest/gtest.h>
#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>

#include <cstring>
#include <fstream>
#include <iostream>
#include <sstream>

#include "cip/core/error.h"
#include "cip/readers/vdb_reader.h"
#include "support/sanitized_build.h"
#include "support/volume_files.h"

// OpenVDB leaks a node when it gives up on some corrupt trees (docs/reliability.md); that is not cip's to
// fix, so the corruption sweep keeps its allocations out of leak checking.
// (tests/CMakeLists.txt defines CIP_LEAK_SANITIZER itself in the sanitizer build, where this file is not
// instrumented but linked with the sanitizers.)
#if defined(CIP_LEAK_SANITIZER)
#elif defined(__SANITIZE_ADDRESS__)
#define CIP_LEAK_SANITIZER 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define CIP_LEAK_SANITIZER 1
#endif
#endif
#ifdef CIP_LEAK_SANITIZER
#include <sanitizer/lsan_interface.h>
#endif

namespace cip {
namespace {

/// While alive, allocations are not reported as leaks (under LeakSanitizer; nothing otherwise).
struct LeaksIgnored {
#ifdef CIP_LEAK_SANITIZER
  LeaksIgnored() {
    __lsan_disable();
  }
  ~LeaksIgnored() {
    __lsan_enable();
  }
#else
  LeaksIgnored() = default;
#endif
  LeaksIgnored(const LeaksIgnored&) = delete;
  LeaksIgnored& operator=(const LeaksIgnored&) = delete;
};

using test::expectError;

/// A grid whose tree has every kind of node OpenVDB stores differently: three root children (one at negative
/// coordinates), leaves whose inactive values are the background, its negative, one other value, two others
/// and many others (distinct cases under mask compression), and active and inactive tiles in internal nodes.
template <class GridT>
typename GridT::Ptr variedGrid(const std::string& name) {
  using V = typename GridT::ValueType;
  auto grid = GridT::create(V(3));
  grid->setName(name);
  auto& tree = grid->tree();
  for (int i = 0; i < 8; ++i) {
    tree.setValue(openvdb::Coord(i, 2 * i, 1), V(i) - V(2.5));            // leaf with background inactives
    tree.setValue(openvdb::Coord(-9000 + i, 4, 5), V(0.25) * V(i));       // another root child
    tree.setValue(openvdb::Coord(7000, i, -3), V(-1) - V(i));             // a third
    tree.setValueOff(openvdb::Coord(16 + i, 0, 0), V(-3));                // minus the background
    tree.setValueOff(openvdb::Coord(24 + i, 0, 0), V(7));                 // one other inactive value
    tree.setValueOff(openvdb::Coord(32 + i, 0, 0), i % 2 ? V(7) : V(8));  // two
    tree.setValueOff(openvdb::Coord(40 + i, 0, 0), V(10 + i));            // many
  }
  tree.setValue(openvdb::Coord(16, 1, 1), V(1));
  tree.setValue(openvdb::Coord(24, 1, 1), V(1));
  tree.setValue(openvdb::Coord(32, 1, 1), V(1));
  tree.setValue(openvdb::Coord(40, 1, 1), V(1));
  grid->fill(openvdb::CoordBBox(openvdb::Coord(128), openvdb::Coord(128 + 15)), V(2), true);  // active tiles
  grid->fill(openvdb::CoordBBox(openvdb::Coord(256), openvdb::Coord(256 + 7)), V(-5),
             false);  // inactive tile
  return grid;
}

void writeFile(const std::string& path, const openvdb::GridCPtrVec& grids, std::uint32_t compression) {
  openvdb::io::File file(path);
  file.setCompression(compression);
  file.write(grids);
}

void writeStream(const std::string& path, const openvdb::GridCPtrVec& grids, std::uint32_t compression) {
  std::ofstream out(path, std::ios::binary);
  openvdb::io::Stream stream(out);
  stream.setCompression(compression);
  stream.write(grids);
}

TEST(VdbTreeCheck, AcceptsEveryWayOpenVdbStoresATree) {
  openvdb::initialize();
  test::ScratchDir dir;
  using openvdb::io::COMPRESS_ACTIVE_MASK;
  using openvdb::io::COMPRESS_BLOSC;
  using openvdb::io::COMPRESS_NONE;
  using openvdb::io::COMPRESS_ZIP;
  const std::uint32_t compressions[] = {COMPRESS_NONE,  COMPRESS_ACTIVE_MASK,
                                        COMPRESS_ZIP,   COMPRESS_ZIP | COMPRESS_ACTIVE_MASK,
                                        COMPRESS_BLOSC, COMPRESS_BLOSC | COMPRESS_ACTIVE_MASK};
  // Grids that a stream without offsets makes the reader pass over: every value size the walk knows, saved at
  // full precision and as half floats.
  auto vectors = variedGrid<openvdb::Vec3SGrid>("vectors");
  auto halfVectors = variedGrid<openvdb::Vec3DGrid>("half vectors");
  halfVectors->setSaveFloatAsHalf(true);
  auto integers = variedGrid<openvdb::Int32Grid>("integers");
  auto longs = variedGrid<openvdb::Int64Grid>("longs");
  for (bool half : {false, true}) {
    auto target = variedGrid<openvdb::FloatGrid>("target");
    target->setSaveFloatAsHalf(half);
    auto wide = variedGrid<openvdb::DoubleGrid>("wide");
    wide->setSaveFloatAsHalf(half);
    std::vector<double> first;  // the target's samples, which every storage must reproduce
    for (std::uint32_t compression : compressions) {
      const std::string label = "compression " + std::to_string(compression) + (half ? ", half" : "");
      const std::string file = dir.file("f.vdb"), stream = dir.file("s.vdb");
      writeFile(file, {vectors, target, wide}, compression);
      writeStream(stream, {vectors, halfVectors, integers, longs, wide, target}, compression);
      for (const std::string& path : {file, stream}) {
        VdbReadOptions o;
        o.gridName = "target";
        o.brickCells = 8;
        SparseVolume v;
        ASSERT_NO_THROW(v = readVdb(path, o)) << label << " " << path;
        std::vector<double> samples;
        for (const DenseGrid& g : v.grids) samples.insert(samples.end(), g.values.begin(), g.values.end());
        if (first.empty()) first = samples;
        EXPECT_EQ(samples, first) << label << " " << path;
        o.gridName = "wide";
        EXPECT_NO_THROW(readVdb(path, o)) << label << " " << path;
      }
      EXPECT_EQ(listVdbGrids(stream).size(), 6u) << label;
    }
  }
}

TEST(VdbTreeCheck, RejectsCorruptTreesFoundByFuzzing) {
  // Found by fuzzing: an internal node's chunk marked as uncompressed with a size far larger than the node;
  // OpenVDB 10 read it into the node's buffer (heap overflow, then an abort in glibc).
  expectError(
      [&] {
        readVdb(test::sourceFile("tests/fuzz/regressions/vdb/openvdb-blosc-uncompressed-chunk-overflow.vdb"));
      },
      {"the values of an internal node at byte 75606", "stored size -2864576066649890121", "516 bytes",
       "corrupt"});
  // Also found by fuzzing: a root that lists the same child twice. OpenVDB replaces the first in its table
  // and leaks it (about 270 KB each); in the fuzzer's long-lived processes these leaks added up to its memory
  // limit.
  expectError(
      [&] { readVdb(test::sourceFile("tests/fuzz/regressions/vdb/openvdb-leak-repeated-root-child.vdb")); },
      {"a root child's origin at byte 17101 repeats an earlier child's"});
}

/// Problems of a volume a reader returned, as the builder would meet them: bricks that do not point at their
/// samples, sample counts that do not match the brick's dims, bricks outside the grid, cell ranges outside
/// the brick. Empty when the volume is sound.
std::string unsoundness(const SparseVolume& v) {
  if (v.bricks.empty() || v.bricks.size() != v.grids.size())
    return "brick and grid counts differ or are zero";
  for (std::size_t b = 0; b < v.bricks.size(); ++b) {
    const GridBrick& brick = v.bricks[b];
    const auto& dims = v.grids[b].geometry.dims;
    if (brick.grid != &v.grids[b]) return "brick " + std::to_string(b) + " does not point at its samples";
    if (v.grids[b].values.size() != static_cast<std::size_t>(dims[0] * dims[1] * dims[2]))
      return "brick " + std::to_string(b) + " has a sample count other than its dims";
    for (int a = 0; a < 3; ++a)
      if (dims[a] < 1 || brick.offset[a] < 0 || brick.offset[a] + dims[a] > v.geometry.dims[a] ||
          brick.cellBegin[a] < 0 || brick.cellBegin[a] > brick.cellEnd[a] || brick.cellEnd[a] > dims[a] - 1)
        return "brick " + std::to_string(b) + " lies outside the grid on axis " + std::to_string(a);
  }
  return "";
}

std::vector<double> samplesOf(const SparseVolume& v) {
  std::vector<double> out;
  for (const DenseGrid& g : v.grids) out.insert(out.end(), g.values.begin(), g.values.end());
  return out;
}

TEST(VdbTreeCheck, SingleByteCorruptionsGiveErrorsNotCrashes) {
  // Every byte of a small file (blosc and mask compression, OpenVDB's defaults) inverted in turn: each read
  // either gives a sound volume or fails with cip::Error (any other exception fails the test). Under the
  // sanitizers this also checks that nothing reads or writes out of bounds or asks for an absurd allocation
  // on the way. Where the fields lie is found from OpenVDB's format, not from the reader: the fields the
  // reader or OpenVDB must check are rejected at every byte, and values that only describe the file (its
  // memory and voxel counts) are read over, giving the original samples.
  openvdb::initialize();
  test::ScratchDir dir;
  auto grid = openvdb::FloatGrid::create(2.0f);
  grid->setName("g");
  for (int i = 0; i < 24; ++i)
    grid->tree().setValue(openvdb::Coord(i, i % 5, 3 * i % 7), 0.5f * static_cast<float>(i) - 3);
  grid->tree().setValueOff(openvdb::Coord(40, 0, 0), 5.0f);
  openvdb::io::File(dir.file("g.vdb")).write({grid});
  const std::string bytes = test::readAll(dir.file("g.vdb")), path = dir.file("c.vdb");
  const std::vector<double> original = samplesOf(readVdb(dir.file("g.vdb")));

  auto unique = [&](const std::string& what) {
    const std::size_t at = bytes.find(what);
    EXPECT_NE(at, std::string::npos) << what;
    EXPECT_EQ(bytes.find(what, at + 1), std::string::npos) << what;
    return at;
  };
  auto u32 = [](std::uint32_t v) { return std::string(reinterpret_cast<const char*>(&v), 4); };
  // A string is stored as its u32 length and its bytes; a metadata entry as name, type name, u32 value size
  // and value. The root of a one-buffer float tree starts with the buffer count 1, the background (2.0f), the
  // tile count 0 and the child count 1, then the child's origin (3 x i32) and the upper internal node's child
  // and value masks (4096 bytes each).
  struct Range {
    std::size_t begin, end;
    std::string what;
  };
  const std::size_t type = unique(u32(16) + "Tree_float_5_4_3"), map = unique(u32(15) + "UniformScaleMap");
  float background = 2.0f;
  const std::size_t root =
      unique(u32(1) + std::string(reinterpret_cast<const char*>(&background), 4) + u32(0) + u32(1));
  const std::vector<Range> mustReject = {
      {0, 8, "the magic number"},
      {type, type + 20, "the grid type name and its length"},
      {map, map + 19, "the transform's map type name and its length"},
      {root + 28, root + 28 + 2 * 4096, "the upper internal node's child and value masks"}};
  auto valueOf = [&](const std::string& name, const std::string& valueType) {
    const std::size_t at = unique(u32(static_cast<std::uint32_t>(name.size())) + name +
                                  u32(static_cast<std::uint32_t>(valueType.size())) + valueType) +
                           8 + name.size() + valueType.size();
    return Range{at + 4, at + 4 + 8, "the value of " + name};
  };
  const std::vector<Range> mustReadAsBefore = {valueOf("file_mem_bytes", "int64"),
                                               valueOf("file_voxel_count", "int64")};
  auto in = [](const std::vector<Range>& ranges, std::size_t i) -> const Range* {
    for (const Range& r : ranges)
      if (i >= r.begin && i < r.end) return &r;
    return nullptr;
  };

  // Under the sanitizers the upper node's masks (8192 of the file's bytes, each rejected like the next) are
  // inverted at every 16th byte and at each byte with a bit set; every other byte of the file still is.
  const Range& masks = mustReject.back();
  auto tried = [&](std::size_t i) {
    return !test::kSanitizedBuild || i < masks.begin || i >= masks.end || (i - masks.begin) % 16 == 0 ||
           bytes[i] != 0;
  };
  int read = 0, rejected = 0, treeErrors = 0;
  std::size_t mustRejectBytes = 0;
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    if (!tried(i)) continue;
    std::string corrupt = bytes;
    corrupt[i] = static_cast<char>(~corrupt[i]);
    test::writeAll(path, corrupt);
    const Range* reject = in(mustReject, i);
    const Range* keep = in(mustReadAsBefore, i);
    mustRejectBytes += reject != nullptr;
    try {
      [[maybe_unused]] LeaksIgnored ignored;
      const SparseVolume v = readVdb(path);
      ++read;
      EXPECT_EQ(unsoundness(v), "") << "byte " << i;
      EXPECT_EQ(reject, nullptr) << "byte " << i << " of " << (reject ? reject->what : "") << " read";
      if (keep) {
        EXPECT_TRUE(samplesOf(v) == original) << "byte " << i << " of " << keep->what;
      }
    } catch (const Error& e) {
      ++rejected;
      const std::string m = e.what();
      treeErrors += m.find("chunk") != std::string::npos || m.find("values of") != std::string::npos;
      EXPECT_EQ(keep, nullptr) << "byte " << i << " of " << (keep ? keep->what : "") << ": " << m;
    }
  }
  EXPECT_GE(rejected, static_cast<int>(mustRejectBytes));
  EXPECT_GT(read, 0);        // some bytes are data the checks cannot judge (values inside compressed chunks)
  EXPECT_GT(treeErrors, 0);  // some corruptions reach the tree's chunk sizes
  std::cout << bytes.size() << " bytes: " << read << " corrupt files read, " << rejected << " rejected ("
            << treeErrors << " at a chunk; " << mustRejectBytes
            << " bytes in fields that must be rejected)\n";
}

/// A tree of one leaf below one lower and one upper internal node, as OpenVDB stores it with the given
/// compression flags; the internal nodes' values are stored raw (a negative stored size when compressed), and
/// the leaf's buffer ends with `leafChunk` as given. Values take `valueBytes` (2 for half floats). A seekable
/// stream's leaf buffer omits the copy of the leaf's value mask.
std::string oneLeafTree(std::uint32_t compression, const std::string& leafChunk, int valueBytes = 4,
                        bool seekable = false) {
  std::ostringstream os;
  auto put = [&](auto v) { os.write(reinterpret_cast<const char*>(&v), sizeof v); };
  auto rawChunk = [&](std::int64_t bytes) {
    if (compression & (openvdb::io::COMPRESS_ZIP | openvdb::io::COMPRESS_BLOSC)) put(-bytes);
    os << std::string(static_cast<std::size_t>(bytes), '\0');
  };
  put(std::int32_t{1});                                  // buffer count
  put(0.0f);                                             // background
  put(std::uint32_t{0});                                 // tiles
  put(std::uint32_t{1});                                 // children
  for (int i = 0; i < 3; ++i) put(std::int32_t{-4096});  // the child's origin
  std::string upper(4096, '\0'), lower(512, '\0'), leaf(64, '\xff');
  upper[0] = lower[0] = 1;                 // one child each
  os << upper << std::string(4096, '\0');  // child and value masks
  put(std::int8_t{6});                     // all values stored
  rawChunk(32768 * valueBytes);
  os << lower << std::string(512, '\0');
  put(std::int8_t{6});
  rawChunk(4096 * valueBytes);
  os << leaf;                 // leaf topology: its value mask
  if (!seekable) os << leaf;  // leaf buffer: the mask again, the metadata byte, the values
  put(std::int8_t{6});
  os << leafChunk;
  return os.str();
}

std::string int64Bytes(std::int64_t v) {
  return std::string(reinterpret_cast<const char*>(&v), sizeof v);
}

/// A blosc chunk of `stored` bytes whose header claims `uncompressed` and `compressed` bytes.
std::string bloscChunk(std::int64_t stored, std::uint32_t uncompressed, std::uint32_t compressed) {
  std::string header(16, '\0');
  header[0] = 2;
  std::memcpy(&header[4], &uncompressed, 4);
  std::memcpy(&header[12], &compressed, 4);
  return int64Bytes(stored) + header + std::string(static_cast<std::size_t>(stored) - 16, '\0');
}

/// Walks `bytes` as a float tree; the walk must end where the tree does.
void walk(const std::string& bytes, std::uint32_t compression, std::uint32_t version = 224, bool half = false,
          bool seekable = false) {
  std::istringstream is(bytes);
  VdbTreeFormat f;
  f.fileVersion = version;
  f.compression = compression;
  f.valueBytes = 4;
  f.halfBytes = 2;
  f.fromHalf = half;
  f.seekable = seekable;
  checkVdbTree(is, static_cast<std::int64_t>(bytes.size()), f);
  EXPECT_EQ(static_cast<std::int64_t>(is.tellg()), static_cast<std::int64_t>(bytes.size()));
}

TEST(VdbTreeCheck, ChecksEachChunkAgainstItsNodeAndTheFile) {
  using openvdb::io::COMPRESS_BLOSC;
  using openvdb::io::COMPRESS_NONE;
  using openvdb::io::COMPRESS_ZIP;
  const std::string raw(2048, '\0');  // 512 floats
  EXPECT_NO_THROW(walk(oneLeafTree(COMPRESS_NONE, raw), COMPRESS_NONE));
  EXPECT_NO_THROW(walk(oneLeafTree(COMPRESS_NONE, raw.substr(1024), 2), COMPRESS_NONE, 224, /*half=*/true));
  EXPECT_NO_THROW(
      walk(oneLeafTree(COMPRESS_NONE, raw, 4, /*seekable=*/true), COMPRESS_NONE, 224, false, true));
  expectError([&] { walk(oneLeafTree(COMPRESS_NONE, raw.substr(1)), COMPRESS_NONE); },
              {"a leaf at byte", "needs 2048 bytes", "truncated or corrupt"});
  expectError([&] { walk(oneLeafTree(COMPRESS_NONE, raw), COMPRESS_NONE, 221); }, {"version 221", "222"});
  for (std::uint32_t compression : {COMPRESS_ZIP, COMPRESS_BLOSC}) {
    const std::string label = "compression " + std::to_string(compression);
    EXPECT_NO_THROW(walk(oneLeafTree(compression, int64Bytes(-2048) + raw), compression)) << label;
    // Marked uncompressed but larger than the leaf: OpenVDB 10 reads it into the leaf's buffer.
    expectError([&] { walk(oneLeafTree(compression, int64Bytes(-4096) + raw + raw), compression); },
                {"the values of a leaf at byte", "stored size -4096", "2048 bytes", "corrupt"});
    // A compressed size beyond the end of the file: OpenVDB allocates it before reading.
    expectError([&] { walk(oneLeafTree(compression, int64Bytes(std::int64_t{1} << 40) + raw), compression); },
                {"a compressed chunk at byte", "needs 1099511627776 bytes", "truncated or corrupt"});
  }
  EXPECT_NO_THROW(walk(oneLeafTree(COMPRESS_BLOSC, bloscChunk(40, 2048, 40)), COMPRESS_BLOSC));
  // Blosc reads as many bytes as its header says, past a shorter chunk.
  expectError([&] { walk(oneLeafTree(COMPRESS_BLOSC, bloscChunk(40, 2048, 4000)), COMPRESS_BLOSC); },
              {"a blosc chunk of 40 bytes whose header claims 4000 compressed and 2048 uncompressed"});
  expectError([&] { walk(oneLeafTree(COMPRESS_BLOSC, int64Bytes(8) + raw), COMPRESS_BLOSC); },
              {"shorter than its header"});
}

}  // namespace
}  // namespace cip
