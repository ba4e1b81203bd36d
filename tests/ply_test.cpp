// PLY writing and reading: round trips in all three encodings, hand-written files with extra properties,
// elements and polygons, and rejection of truncated, corrupt and oversized input.
#include "cip/mesh/ply.h"

#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <string>

#include "cip/core/error.h"
#include "support/scratch_dir.h"

using namespace cip;

namespace {

TriangleMesh tetrahedron() {
  TriangleMesh m;
  m.positions = {Vec3(0, 0, 0), Vec3(1.5, 0, 0), Vec3(0, 2.25, 0), Vec3(0, 0, -3.125)};
  m.normals = {Vec3(-1, -1, 1).normalized(), Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, -1)};
  m.triangles = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  return m;
}

std::vector<std::uint8_t> bytesOf(const std::string& s) {
  return std::vector<std::uint8_t>(s.begin(), s.end());
}

TriangleMesh parse(const std::vector<std::uint8_t>& b) {
  return parsePly(b.data(), b.size(), "test.ply");
}
TriangleMesh parse(const std::string& s) {
  return parse(bytesOf(s));
}

void expectSameMesh(const TriangleMesh& a, const TriangleMesh& b, bool normals) {
  ASSERT_EQ(a.positions.size(), b.positions.size());
  for (std::size_t i = 0; i < a.positions.size(); ++i) {
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(static_cast<float>(a.positions[i][k]), static_cast<float>(b.positions[i][k]));
    }
  }
  if (normals) {
    ASSERT_EQ(a.normals.size(), b.normals.size());
    for (std::size_t i = 0; i < a.normals.size(); ++i) {
      for (int k = 0; k < 3; ++k)
        EXPECT_EQ(static_cast<float>(a.normals[i][k]), static_cast<float>(b.normals[i][k]));
    }
  } else {
    EXPECT_TRUE(b.normals.empty());
  }
  EXPECT_EQ(a.triangles, b.triangles);
}

template <typename T>
void putBig(std::vector<std::uint8_t>& out, T v) {
  std::uint8_t b[sizeof(T)];
  std::memcpy(b, &v, sizeof v);
  for (std::size_t i = 0; i < sizeof(T); ++i)
    out.push_back(b[sizeof(T) - 1 - i]);  // assumes a little-endian host
}

template <typename T>
void putLittle(std::vector<std::uint8_t>& out, T v) {
  std::uint8_t b[sizeof(T)];
  std::memcpy(b, &v, sizeof v);
  out.insert(out.end(), b, b + sizeof(T));
}

}  // namespace

TEST(Ply, RoundTripThroughFileBinaryLittleEndian) {
  TriangleMesh m = tetrahedron();
  test::ScratchDir dir;
  std::string path = dir.file("roundtrip.ply");
  std::size_t bytes = writePly(m, path, {});
  EXPECT_GT(bytes, 0u);
  TriangleMesh r = readPly(path);
  expectSameMesh(m, r, true);
  EXPECT_TRUE(analyseTopology(r).closedAndOriented());
  std::remove(path.c_str());
}

TEST(Ply, RoundTripAllEncodings) {
  TriangleMesh m = tetrahedron();
  m.positions[1] = Vec3(0.1, -1e-7, 12345.678);  // values that need all float digits
  for (PlyFormat f : {PlyFormat::BinaryLittleEndian, PlyFormat::BinaryBigEndian, PlyFormat::Ascii}) {
    for (bool normals : {true, false}) {
      PlyWriteOptions o;
      o.format = f;
      o.normals = normals;
      o.comment = "two\nlines";
      auto bytes = encodePly(m, o);
      SCOPED_TRACE(static_cast<int>(f));
      expectSameMesh(m, parse(bytes), normals);
    }
  }
}

TEST(Ply, EmptyMesh) {
  TriangleMesh m;
  TriangleMesh r = parse(encodePly(m));
  EXPECT_TRUE(r.positions.empty());
  EXPECT_TRUE(r.triangles.empty());
}

TEST(Ply, AsciiWithExtraPropertiesElementsAndPolygons) {
  const std::string text =
      "ply\r\n"
      "format ascii 1.0\r\n"
      "comment made by hand\r\n"
      "obj_info anything\r\n"
      "element material 1\r\n"
      "property list uchar float weights\r\n"
      "property int id\r\n"
      "element vertex 5\r\n"
      "property double x\r\n"
      "property uchar red\r\n"
      "property double y\r\n"
      "property list int short junk\r\n"
      "property double z\r\n"
      "element face 2\r\n"
      "property uchar flags\r\n"
      "property list uchar uint vertex_index\r\n"
      "property float quality\r\n"
      "end_header\r\n"
      "2 0.5 0.25 7\r\n"
      "0 255 0 0 0\n"
      "1 1 0 2 -3 4 0\n"
      "1 2 1 0 0\n"
      "0 3 1 1 1 0\n"
      "0.5 4 0.5 0 2\n"
      "9 4 0 1 2 3 1.5\n"
      "0 3 0 3 4 -2e-3\n";
  TriangleMesh m = parse(text);
  ASSERT_EQ(m.positions.size(), 5u);
  EXPECT_TRUE(m.normals.empty());
  EXPECT_EQ(m.positions[1], Vec3(1, 0, 0));
  EXPECT_EQ(m.positions[4], Vec3(0.5, 0.5, 2));
  ASSERT_EQ(m.triangles.size(), 3u);  // quad fanned into two, plus one triangle
  EXPECT_EQ(m.triangles[0], (std::array<std::uint32_t, 3>{0, 1, 2}));
  EXPECT_EQ(m.triangles[1], (std::array<std::uint32_t, 3>{0, 2, 3}));
  EXPECT_EQ(m.triangles[2], (std::array<std::uint32_t, 3>{0, 3, 4}));
}

TEST(Ply, BinaryBigEndianDoubleWithNormalsAndUintCounts) {
  std::string header =
      "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
      "property double z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty ushort extra\n"
      "element face 1\nproperty list uint int vertex_indices\nend_header\n";
  auto b = bytesOf(header);
  for (int v = 0; v < 3; ++v) {
    putBig<double>(b, v == 1 ? 1.0 : 0.0);
    putBig<double>(b, v == 2 ? 1.0 : 0.0);
    putBig<double>(b, 0.125 * v);
    putBig<float>(b, 0.0f);
    putBig<float>(b, 0.0f);
    putBig<float>(b, 1.0f);
    putBig<std::uint16_t>(b, 0xBEEF);
  }
  putBig<std::uint32_t>(b, 3);
  for (std::int32_t i : {2, 1, 0}) putBig<std::int32_t>(b, i);
  TriangleMesh m = parse(b);
  ASSERT_EQ(m.positions.size(), 3u);
  EXPECT_EQ(m.positions[2], Vec3(0, 1, 0.25));
  ASSERT_TRUE(m.hasNormals());
  EXPECT_EQ(m.normals[1], Vec3(0, 0, 1));
  ASSERT_EQ(m.triangles.size(), 1u);
  EXPECT_EQ(m.triangles[0], (std::array<std::uint32_t, 3>{2, 1, 0}));
}

TEST(Ply, EveryTruncationIsRejected) {
  for (PlyFormat f : {PlyFormat::BinaryLittleEndian, PlyFormat::Ascii}) {
    PlyWriteOptions o;
    o.format = f;
    auto full = encodePly(tetrahedron(), o);
    // The ASCII body may lose its final newline and still be complete; everything shorter must fail.
    std::size_t complete = f == PlyFormat::Ascii ? full.size() - 1 : full.size();
    for (std::size_t n = 0; n < complete; ++n) {
      EXPECT_THROW(parsePly(full.data(), n, "cut.ply"), Error)
          << "format " << static_cast<int>(f) << " length " << n;
    }
    EXPECT_NO_THROW(parsePly(full.data(), complete, "cut.ply"));
  }
}

TEST(Ply, HugeCountsAreRejectedBeforeAllocation) {
  std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\nproperty float x\nproperty float "
      "y\n"
      "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
  auto b = bytesOf(header);
  b.resize(b.size() + 100, 0);
  try {
    parse(b);
    FAIL() << "accepted 1e12 vertices in 100 bytes";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("1000000000000"), std::string::npos) << e.what();
  }
  // A count beyond 64 bits is a header error.
  EXPECT_THROW(parse("ply\nformat ascii 1.0\nelement vertex 99999999999999999999999\nproperty float x\n"
                     "end_header\n"),
               Error);
  // Many faces over a few bytes.
  std::string faces =
      "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
      "property float z\nelement face 4000000000\nproperty list uchar int vertex_indices\nend_header\n";
  auto fb = bytesOf(faces);
  fb.resize(fb.size() + 64, 3);
  EXPECT_THROW(parse(fb), Error);
  // A list count larger than the data left.
  std::string list =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n";
  auto lb = bytesOf(list);
  for (int i = 0; i < 9; ++i) putLittle<float>(lb, 0.0f);
  putLittle<std::uint32_t>(lb, 0xFFFFFFF0u);
  for (int i = 0; i < 3; ++i) putLittle<std::int32_t>(lb, i);
  EXPECT_THROW(parse(lb), Error);
  // Too many vertices for 32-bit indices, even with enough bytes claimed: rejected by the byte count first.
  EXPECT_THROW(
      parse("ply\nformat ascii 1.0\nelement vertex 5000000000\nproperty float x\nproperty float y\n"
            "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"),
      Error);
}

TEST(Ply, BadIndicesAreRejected) {
  const std::string head =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n";
  EXPECT_NO_THROW(parse(head + "3 0 1 2\n"));
  EXPECT_THROW(parse(head + "3 0 1 3\n"), Error);
  EXPECT_THROW(parse(head + "3 0 -1 2\n"), Error);
  EXPECT_THROW(parse(head + "2 0 1\n"), Error);
  EXPECT_THROW(parse(head + "3 0 1 2.5\n"), Error);
  EXPECT_THROW(parse(head + "3 0 1 x\n"), Error);
  EXPECT_THROW(parse(head + "300 0 1 2\n"), Error);  // count out of uchar range
  // Binary, index past the end.
  std::string bin =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n";
  auto b = bytesOf(bin);
  for (int i = 0; i < 9; ++i) putLittle<float>(b, 0.0f);
  putLittle<std::uint8_t>(b, 3);
  for (std::uint32_t i : {0u, 1u, 4000000000u}) putLittle<std::uint32_t>(b, i);
  EXPECT_THROW(parse(b), Error);
}

TEST(Ply, CorruptHeadersAreRejected) {
  const std::string body =
      "element vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
      "element face 0\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n";
  EXPECT_NO_THROW(parse("ply\nformat ascii 1.0\n" + body));
  EXPECT_THROW(parse("plx\nformat ascii 1.0\n" + body), Error);
  EXPECT_THROW(parse("ply\nformat ebcdic 1.0\n" + body), Error);
  EXPECT_THROW(parse("ply\nformat ascii 2.0\n" + body), Error);
  EXPECT_THROW(parse("ply\n" + body), Error);  // no format line
  EXPECT_THROW(parse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\nend_header\n0\n"), Error);
  EXPECT_THROW(parse("ply\nformat ascii 1.0\nproperty float x\nend_header\n"), Error);
  EXPECT_THROW(parse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"), Error);  // no end_header
  EXPECT_THROW(
      parse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n0 0\n"),
      Error);  // no z
  EXPECT_THROW(parse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n0 0 0\n"),
               Error);  // no faces
  EXPECT_THROW(
      parse(
          "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
          "property float z\nelement face 0\nproperty list uchar float vertex_indices\nend_header\n0 0 0\n"),
      Error);  // float indices
  EXPECT_THROW(
      parse(
          "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
          "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n0 nan 0\n"),
      Error);  // non-finite coordinate
  EXPECT_THROW(parse(""), Error);
  EXPECT_THROW(readPly(testing::TempDir() + "/cip_no_such_file.ply"), Error);
}

TEST(Ply, RandomCorruptionNeverCrashes) {
  std::mt19937 rng(12345);
  for (PlyFormat f : {PlyFormat::BinaryLittleEndian, PlyFormat::Ascii}) {
    PlyWriteOptions o;
    o.format = f;
    const auto good = encodePly(tetrahedron(), o);
    for (int iter = 0; iter < 3000; ++iter) {
      auto b = good;
      int flips = 1 + static_cast<int>(rng() % 4);
      for (int k = 0; k < flips; ++k) b[rng() % b.size()] = static_cast<std::uint8_t>(rng());
      try {
        TriangleMesh m = parse(b);
        for (const auto& t : m.triangles)
          for (auto v : t) ASSERT_LT(v, m.positions.size());
      } catch (const Error&) {
      }
    }
  }
}
