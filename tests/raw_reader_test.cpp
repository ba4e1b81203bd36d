// Raw volume reader: the shared test volumes read as raw files, every sample type in both byte orders, and
// the error paths (wrong sizes, bad dims, overflow, memory limit, missing file).
#include "cip/readers/raw_reader.h"

#include <gtest/gtest.h>

#include <cstring>

#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;
using test::sharedData;

TEST(RawReader, ToothMatchesFileBytes) {
  std::string path = sharedData("tooth_103x94x161_uint8.raw");
  RawFormat f;
  f.dims = {103, 94, 161};
  f.type = SampleType::UInt8;
  f.origin = Vec3(-51.5, -47, -80.5);
  DenseGrid g = readRaw(path, f);
  EXPECT_EQ(g.geometry.dims, f.dims);
  EXPECT_EQ(g.geometry.origin, f.origin);
  EXPECT_EQ(g.geometry.spacing, Vec3::Ones());
  std::string bytes = test::readAll(path);
  ASSERT_EQ(bytes.size(), g.values.size());
  for (std::int64_t n :
       {std::int64_t(0), std::int64_t(12345), std::int64_t(777777), std::int64_t(bytes.size() - 1)}) {
    EXPECT_EQ(g.values[n], static_cast<unsigned char>(bytes[n])) << n;
  }
  // (i,j,k) addressing, x fastest.
  std::int64_t i = 50, j = 40, k = 80;
  EXPECT_EQ(g.at(i, j, k), static_cast<unsigned char>(bytes[i + 103 * (j + 94 * k)]));
  unsigned char lo = 255, hi = 0;
  for (char c : bytes) {
    lo = std::min(lo, static_cast<unsigned char>(c));
    hi = std::max(hi, static_cast<unsigned char>(c));
  }
  EXPECT_EQ(g.range().first, lo);
  EXPECT_EQ(g.range().second, hi);
  EXPECT_NE(g.description.find("tooth"), std::string::npos);
}

TEST(RawReader, HeadsqInt16LittleEndian) {
  std::string path = sharedData("headsq_64x64x93_int16.raw");
  RawFormat f;
  f.dims = {64, 64, 93};
  f.type = parseSampleType("int16");
  f.spacing = Vec3(3.2, 3.2, 1.5);
  DenseGrid g = readRaw(path, f);
  std::string bytes = test::readAll(path);
  for (std::int64_t n :
       {std::int64_t(0), std::int64_t(64 * 64 * 46 + 64 * 32 + 32), std::int64_t(64 * 64 * 93 - 1)}) {
    std::int16_t v = static_cast<std::int16_t>(static_cast<unsigned char>(bytes[2 * n]) |
                                               (static_cast<unsigned char>(bytes[2 * n + 1]) << 8));
    EXPECT_EQ(g.values[n], v) << n;
  }
  EXPECT_EQ(g.geometry.spacing, Vec3(3.2, 3.2, 1.5));
  EXPECT_GT(g.range().second, 1000);  // bone
}

TEST(RawReader, NucleonWithWrongDimsNamesSizes) {
  std::string path = sharedData("nucleon_41x41x41_uint8.raw");
  RawFormat f;
  f.dims = {41, 41, 40};
  expectError([&] { readRaw(path, f); }, {path, "68921", "67240", "1681 bytes too many"});
  f.dims = {41, 41, 42};
  expectError([&] { readRaw(path, f); }, {path, "68921", "70602", "bytes short"});
  f.dims = {41, 41, 41};
  f.type = SampleType::UInt16;
  expectError([&] { readRaw(path, f); }, {path, "137842", "uint16"});
}

/// Writes `values` as `type` in `endian` order and reads them back.
template <typename T>
void roundTrip(SampleType type, Endian endian, const std::vector<T>& values, std::uint64_t offset = 0) {
  test::ScratchDir dir;
  std::string bytes(offset, 'H');
  for (T v : values) {
    char b[sizeof(T)];
    std::memcpy(b, &v, sizeof(T));
    if (endian != hostEndian()) std::reverse(b, b + sizeof(T));
    bytes.append(b, sizeof(T));
  }
  std::string path = dir.file("v.raw");
  test::writeAll(path, bytes);
  RawFormat f;
  f.dims = {static_cast<std::int64_t>(values.size()), 1, 1};
  f.type = type;
  f.endian = endian;
  f.offset = offset;
  DenseGrid g = readRaw(path, f);
  ASSERT_EQ(g.values.size(), values.size());
  for (std::size_t n = 0; n < values.size(); ++n) {
    if (std::isnan(static_cast<double>(values[n]))) {
      EXPECT_TRUE(std::isnan(g.values[n]));
    } else {
      EXPECT_EQ(g.values[n], static_cast<double>(values[n]))
          << toString(type) << " " << toString(endian) << " " << n;
    }
  }
}

TEST(RawReader, EveryTypeBothByteOrders) {
  for (Endian e : {Endian::Little, Endian::Big}) {
    roundTrip<std::uint8_t>(SampleType::UInt8, e, {0, 1, 200, 255});
    roundTrip<std::int8_t>(SampleType::Int8, e, {-128, -1, 0, 127});
    roundTrip<std::uint16_t>(SampleType::UInt16, e, {0, 258, 65535});
    roundTrip<std::int16_t>(SampleType::Int16, e, {-32768, -2, 1000, 32767});
    roundTrip<std::uint32_t>(SampleType::UInt32, e, {0, 16909060u, 4294967295u});
    roundTrip<std::int32_t>(SampleType::Int32, e, {-2147483647 - 1, -5, 2147483647});
    roundTrip<float>(SampleType::Float32, e,
                     {-1.5f, 0.0f, 3.25e10f, std::numeric_limits<float>::infinity(),
                      std::numeric_limits<float>::quiet_NaN()});
    roundTrip<double>(SampleType::Float64, e, {-1e300, 0.1, 42.0, std::numeric_limits<double>::quiet_NaN()});
  }
  roundTrip<std::int16_t>(SampleType::Int16, Endian::Big, {-3, 7}, 5);  // with a 5-byte header skipped
}

TEST(RawReader, TypeNamesAndDims) {
  EXPECT_EQ(parseSampleType("uint8"), SampleType::UInt8);
  EXPECT_EQ(parseSampleType("unsigned char"), SampleType::UInt8);
  EXPECT_EQ(parseSampleType("uchar"), SampleType::UInt8);
  EXPECT_EQ(parseSampleType("short"), SampleType::Int16);
  EXPECT_EQ(parseSampleType("Unsigned  Short"), SampleType::UInt16);
  EXPECT_EQ(parseSampleType("int"), SampleType::Int32);
  EXPECT_EQ(parseSampleType("float"), SampleType::Float32);
  EXPECT_EQ(parseSampleType("double"), SampleType::Float64);
  EXPECT_EQ(parseSampleType("signed char"), SampleType::Int8);
  for (auto t : {SampleType::UInt8, SampleType::Int8, SampleType::UInt16, SampleType::Int16,
                 SampleType::UInt32, SampleType::Int32, SampleType::Float32, SampleType::Float64}) {
    EXPECT_EQ(parseSampleType(toString(t)), t);
  }
  expectError([] { parseSampleType("complex64"); }, {"unknown sample type 'complex64'", "float32"});
  expectError([] { parseEndian("middle"); }, {"middle"});
  EXPECT_EQ(parseDims("103x94x161"), (std::array<std::int64_t, 3>{103, 94, 161}));
  EXPECT_EQ(parseDims("1,2,3"), (std::array<std::int64_t, 3>{1, 2, 3}));
  expectError([] { parseDims("10x10"); }, {"10x10"});
  expectError([] { parseDims("10x0x4"); }, {"10x0x4"});
  expectError([] { parseDims("1x2x3x4"); }, {"1x2x3x4"});
}

TEST(RawReader, TruncatedFile) {
  test::ScratchDir dir;
  std::string path = dir.file("short.raw");
  test::writeAll(path, std::string(999, '\0'));
  RawFormat f;
  f.dims = {10, 10, 10};
  expectError([&] { readRaw(path, f); }, {path, "999", "1000", "1 bytes short"});
}

TEST(RawReader, DimsOverflowAndMemoryLimitFailBeforeAllocating) {
  test::ScratchDir dir;
  std::string path = dir.file("tiny.raw");
  test::writeAll(path, std::string(8, '\0'));
  RawFormat f;
  f.dims = {std::int64_t(1) << 40, std::int64_t(1) << 40, std::int64_t(1) << 40};
  expectError([&] { readRaw(path, f); }, {path, "overflow 64 bits"});
  f.dims = {std::int64_t(1) << 20, std::int64_t(1) << 20, std::int64_t(1) << 10};  // 8 PiB of doubles
  expectError([&] { readRaw(path, f); }, {path, "MiB", "1048576x1048576x1024"});
  f.dims = {-1, 2, 3};
  expectError([&] { readRaw(path, f); }, {path, "-1x2x3"});
  // A real file over a small limit.
  RawFormat n;
  n.dims = {41, 41, 41};
  expectError([&] { readRaw(sharedData("nucleon_41x41x41_uint8.raw"), n, 100000); }, {"nucleon", "MiB"});
}

TEST(RawReader, MissingFileAndBadSpacing) {
  RawFormat f;
  f.dims = {1, 1, 1};
  expectError([&] { readRaw("/nonexistent/volume.raw", f); }, {"/nonexistent/volume.raw", "cannot open"});
  f.spacing = Vec3(1, 0, 1);
  expectError([&] { readRaw(sharedData("nucleon_41x41x41_uint8.raw"), f); }, {"spacing"});
}

}  // namespace
}  // namespace cip
