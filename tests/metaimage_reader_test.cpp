// MetaImage reader: files written by VTK's vtkMetaImageWriter and hand-written ones read back by
// vtkMetaImageReader (both ITK's MetaIO; tests/support/vtk_metaimage_files.py), TransformMatrix in ITK's
// column-after-column order with rotations and flips, 4-D frames, slice lists and patterns, and the errors.
#include "cip/readers/metaimage_reader.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>
#include <limits>

#include "cip/readers/volume_reader.h"
#include "support/python_truth.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;

/// Little-endian bytes of int16 samples.
std::string int16Bytes(const std::vector<std::int16_t>& values, bool big = false) {
  std::string out;
  for (std::int16_t v : values) {
    auto u = static_cast<std::uint16_t>(v);
    char b[2] = {static_cast<char>(u & 0xff), static_cast<char>(u >> 8)};
    if (big) std::swap(b[0], b[1]);
    out.append(b, 2);
  }
  return out;
}

std::vector<std::int16_t> ramp(std::size_t n, int scale = 7) {
  std::vector<std::int16_t> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = static_cast<std::int16_t>(static_cast<int>(i) * scale - 100);
  return v;
}

std::vector<double> asDoubles(const std::vector<std::int16_t>& v) {
  return {v.begin(), v.end()};
}

std::string numbers(const Mat3& m) {  // column after column, as ITK writes TransformMatrix
  std::ostringstream s;
  s.precision(17);
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) s << (c || r ? " " : "") << m(r, c);
  return s.str();
}

TEST(MetaImageReader, VtkFilesAndVtkReadings) {
  test::ScratchDir dir;
  auto cases = test::runTruthScript(test::sourceFile("tests/support/vtk_metaimage_files.py"), dir.path());
  if (!cases) GTEST_SKIP() << "python3-vtk9 is not installed";
  ASSERT_GE(cases->size(), 10u);
  for (const auto& c : *cases) {
    SCOPED_TRACE(c.path);
    DenseGrid g = readMetaImage(c.path);
    EXPECT_EQ(g.geometry.dims, c.dims);
    EXPECT_EQ(g.geometry.space, WorldSpace::LPS);
    test::expectSamePlacement(g.geometry, c.affine, c.path);
    EXPECT_EQ(g.values, test::readTruthSamples(c.truth));
    EXPECT_EQ(volumeFormatOf(c.path), VolumeFormat::MetaImage);
  }
}

TEST(MetaImageReader, TransformMatrixListsTheAxisDirections) {
  test::ScratchDir dir;
  // A rotation with a flipped axis: the header lists its columns, the direction of index axes 0, 1, 2.
  Mat3 d = (Eigen::AngleAxisd(0.7, Vec3(1, -2, 0.5).normalized()) * Eigen::AngleAxisd(-1.9, Vec3::UnitZ()))
               .toRotationMatrix();
  d.col(1) *= -1;
  const std::vector<std::int16_t> values = ramp(4 * 3 * 2);
  const std::string path = dir.file("turned.mha");
  test::writeAll(path,
                 "ObjectType = Image\nNDims = 3\nDimSize = 4 3 2\nElementType = MET_SHORT\n"
                 "ElementSpacing = 0.5 2 3.5\nOffset = 10 -20 30\nTransformMatrix = " +
                     numbers(d) + "\nAnatomicalOrientation = RAI\nElementDataFile = LOCAL\n" +
                     int16Bytes(values));
  DenseGrid g = readMetaImage(path);
  EXPECT_LT((g.geometry.direction - d).cwiseAbs().maxCoeff(), 1e-15);
  EXPECT_LT((g.geometry.spacing - Vec3(0.5, 2, 3.5)).norm(), 1e-14);
  EXPECT_EQ(g.geometry.origin, Vec3(10, -20, 30));
  EXPECT_EQ(g.geometry.space, WorldSpace::LPS);
  EXPECT_EQ(g.values, asDoubles(values));
  EXPECT_LT(g.geometry.direction.determinant(), 0);

  // By hand: TransformMatrix = 0 1 0  -1 0 0  0 0 1 sends index axis 0 along world +y, axis 1 along -x.
  test::writeAll(path,
                 "NDims = 3\nDimSize = 4 3 2\nElementType = MET_SHORT\nElementSpacing = 2 3 4\n"
                 "Origin = 1 2 3\nRotation = 0 1 0 -1 0 0 0 0 1\nElementDataFile = LOCAL\n" +
                     int16Bytes(values));
  g = readMetaImage(path);
  const Vec3 world =
      g.geometry.origin + g.geometry.direction * g.geometry.spacing.cwiseProduct(Vec3(1, 1, 1));
  EXPECT_LT((world - Vec3(1 - 3, 2 + 2, 3 + 4)).norm(), 1e-12);
  SparseVolume v = readVolume(path);
  EXPECT_NE(describeVolume(v).find("axes (0 1 0) (-1 0 0) (0 0 1), LPS"), std::string::npos)
      << describeVolume(v);
}

TEST(MetaImageReader, FramesOfAFourDimensionalImage) {
  test::ScratchDir dir;
  const std::vector<std::int16_t> values = ramp(3 * 2 * 2 * 4, 3);
  for (bool compressed : {false, true}) {
    const std::string path = dir.file(compressed ? "series_z.mha" : "series.mha");
    std::string data = int16Bytes(values, true);
    if (compressed) data = test::gzipBytes(data);
    test::writeAll(
        path, std::string("ObjectType = Image\nNDims = 4\nDimSize = 3 2 2 4\nElementType = MET_SHORT\n") +
                  "ElementSpacing = 1 2 3 0.5\nOffset = 5 6 7 0\n"
                  "TransformMatrix = 0 0 1 0  0 1 0 0  -1 0 0 0  0 0 0 1\nBinaryDataByteOrderMSB = True\n" +
                  (compressed ? "CompressedData = True\n" : "") + "ElementDataFile = LOCAL\n" + data);
    for (int frame = 0; frame < 4; ++frame) {
      DenseGrid g = readMetaImage(path, DenseGrid::defaultMaxBytes(), frame);
      EXPECT_EQ(g.values, asDoubles({values.begin() + 12 * frame, values.begin() + 12 * (frame + 1)}));
      Mat3 expected;
      expected << 0, 0, -1, 0, 1, 0, 1, 0, 0;  // columns (0 0 1), (0 1 0), (-1 0 0)
      EXPECT_EQ(g.geometry.direction, expected);
      EXPECT_EQ(g.geometry.spacing, Vec3(1, 2, 3));
      EXPECT_EQ(g.geometry.origin, Vec3(5, 6, 7));
      EXPECT_NE(g.description.find("frame " + std::to_string(frame) + " of 4"), std::string::npos);
    }
    expectError([&] { readMetaImage(path); }, {path, "4 frames", "--frame 0..3"});
    expectError([&] { readMetaImage(path, DenseGrid::defaultMaxBytes(), 4); },
                {path, "frame 4 is out of range"});
  }
}

TEST(MetaImageReader, SliceListsAndPatterns) {
  test::ScratchDir dir;
  const std::vector<std::int16_t> values = ramp(5 * 4 * 3);
  const std::string head = "ObjectType = Image\nNDims = 3\nDimSize = 5 4 3\nElementType = MET_SHORT\n";
  for (int k = 0; k < 3; ++k) {
    std::string slice = int16Bytes({values.begin() + 20 * k, values.begin() + 20 * (k + 1)});
    test::writeAll(dir.file("s" + std::to_string(k) + ".raw"), slice);
    test::writeAll(dir.file("img" + std::string(k == 0 ? "005" : k == 1 ? "007" : "009") + ".raw"), slice);
    test::writeAll(dir.file("z" + std::to_string(k + 1) + ".zraw"), test::gzipBytes(slice));
  }
  test::writeAll(dir.file("list.mhd"),
                 head + "ElementDataFile = LIST\ns0.raw\n\ns1.raw\n" + dir.file("s2.raw") + "\n");
  test::writeAll(dir.file("pattern.mhd"), head + "ElementDataFile = img%03d.raw 5 9 2\n");
  test::writeAll(dir.file("zpattern.mhd"), head + "CompressedData = True\nElementDataFile = z%d.zraw\n");
  for (const char* name : {"list.mhd", "pattern.mhd", "zpattern.mhd"}) {
    SCOPED_TRACE(name);
    EXPECT_EQ(readMetaImage(dir.file(name)).values, asDoubles(values));
  }
  // The bytes on disk count every slice file.
  EXPECT_EQ(volumeFileBytes(dir.file("list.mhd")), test::readAll(dir.file("list.mhd")).size() + 3 * 40);

  test::writeAll(dir.file("short_list.mhd"), head + "ElementDataFile = LIST\ns0.raw\ns1.raw\n");
  expectError([&] { readMetaImage(dir.file("short_list.mhd")); },
              {"short_list.mhd", "needs 3 file names", "lists 2"});
  test::writeAll(dir.file("bad_pattern.mhd"), head + "ElementDataFile = img%s%d.raw\n");
  expectError([&] { readMetaImage(dir.file("bad_pattern.mhd")); }, {"bad_pattern.mhd", "integer conversion"});
  test::writeAll(dir.file("far_pattern.mhd"), head + "ElementDataFile = img%03d.raw 5 7 2\n");
  expectError([&] { readMetaImage(dir.file("far_pattern.mhd")); },
              {"far_pattern.mhd", "does not name 3 files"});
  test::writeAll(dir.file("missing.mhd"), head + "ElementDataFile = img%03d.raw 1\n");
  expectError([&] { readMetaImage(dir.file("missing.mhd")); }, {"img001.raw", "cannot open"});
  std::remove(dir.file("s1.raw").c_str());
  test::writeAll(dir.file("s1.raw"), std::string(39, '\0'));
  expectError([&] { readMetaImage(dir.file("list.mhd")); }, {"s1.raw", "1 bytes short"});
}

TEST(MetaImageReader, Errors) {
  test::ScratchDir dir;
  const std::string path = dir.file("e.mha");
  const std::string data = int16Bytes(ramp(8));
  auto expectBad = [&](const std::string& header, const std::string& body, std::vector<std::string> parts) {
    test::writeAll(path, header + body);
    parts.push_back(path);
    expectError([&] { readMetaImage(path); }, parts);
  };
  const std::string dims = "NDims = 3\nDimSize = 2 2 2\nElementType = MET_SHORT\n";
  expectBad(dims, "", {"no ElementDataFile"});
  expectBad("\x01\x02garbage", "", {"not a MetaImage header", "line 1"});
  expectBad("NDims = 2\nDimSize = 2 2\nElementType = MET_SHORT\nElementDataFile = LOCAL\n", data,
            {"NDims is 2"});
  expectBad("NDims = 3\nDimSize = 2 2\nElementType = MET_SHORT\nElementDataFile = LOCAL\n", data,
            {"DimSize has 2 numbers"});
  expectBad("NDims = 3\nDimSize = 2 0 2\nElementType = MET_SHORT\nElementDataFile = LOCAL\n", data,
            {"DimSize 0"});
  expectBad("NDims = 3\nDimSize = 2 2 2\nElementType = MET_LONG_LONG\nElementDataFile = LOCAL\n", data,
            {"MET_LONG_LONG", "not supported"});
  expectBad("ObjectType = Mesh\n" + dims + "ElementDataFile = LOCAL\n", data, {"ObjectType", "Mesh"});
  expectBad(dims + "ElementNumberOfChannels = 3\nElementDataFile = LOCAL\n", data,
            {"ElementNumberOfChannels"});
  expectBad(dims + "BinaryData = False\nElementDataFile = LOCAL\n", data, {"ASCII"});
  expectBad(dims + "TransformMatrix = 1 0 0 0 1 0 1 0 0\nElementDataFile = LOCAL\n", data, {"singular"});
  expectBad(dims + "TransformMatrix = 1 0 0 0 1 0 0 0 nan\nElementDataFile = LOCAL\n", data,
            {"TransformMatrix"});
  expectBad(dims + "TransformMatrix = 1 0 0 0 1 0\nElementDataFile = LOCAL\n", data,
            {"6 numbers, expected 9"});
  expectBad(dims + "ElementSpacing = 1 -1 1\nElementDataFile = LOCAL\n", data, {"ElementSpacing"});
  expectBad(dims + "Offset = 1 inf 0\nElementDataFile = LOCAL\n", data, {"Offset", "finite"});
  expectBad(dims + "ElementDataFile = LOCAL\n", data.substr(3), {"3 bytes short"});
  expectBad(dims + "ElementDataFile = LOCAL\n", data + "xy", {"2 bytes longer"});
  expectBad(dims + "ElementDataFile = nothere.raw\n", "", {"nothere.raw", "cannot open"});
  expectBad(dims + "CompressedData = True\nHeaderSize = -1\nElementDataFile = LOCAL\n", test::gzipBytes(data),
            {"CompressedDataSize"});
  std::string corrupt = test::gzipBytes(data);
  for (std::size_t n = 10; n < corrupt.size(); ++n) corrupt[n] = static_cast<char>(corrupt[n] ^ 0x33);
  expectBad(dims + "CompressedData = True\nElementDataFile = LOCAL\n", corrupt, {});
  expectBad(dims + "CompressedData = True\nElementDataFile = LOCAL\n", test::gzipBytes(data + "more"),
            {"continues past"});
  // Absurd sizes are refused before anything is allocated.
  expectBad("NDims = 3\nDimSize = 100000 100000 100000\nElementType = MET_DOUBLE\nElementDataFile = LOCAL\n",
            data, {"100000x100000x100000"});
  expectBad(
      "NDims = 4\nDimSize = 2 2 2 4611686018427387904\nElementType = MET_SHORT\nElementDataFile = LOCAL\n",
      data, {"frames"});
  expectBad("NDims = 3\nDimSize = 2 2 9223372036854775807\nElementType = MET_SHORT\nElementDataFile = LIST\n",
            "", {"LIST"});
  expectError([&] { readMetaImage(dir.file("none.mha")); }, {"none.mha", "cannot open"});
}

}  // namespace
}  // namespace cip
