// NIfTI-1 reader and writer: round trips through .nii and .nii.gz (with scl_slope/scl_inter), hand-made
// headers in both byte orders, origin from qform/sform, and the error paths.
#include "cip/readers/nifti_reader.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>
#include <limits>

#include "cip/readers/nrrd_reader.h"
#include "cip/readers/volume_reader.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;
using test::sharedData;

/// A NIfTI-1 header built field by field, in either byte order.
struct HeaderBuilder {
  unsigned char bytes[352] = {};
  bool big = false;

  template <typename T>
  void put(std::size_t offset, T value) {
    unsigned char b[sizeof(T)];
    std::memcpy(b, &value, sizeof(T));
    if (big != (hostEndian() == Endian::Big)) std::reverse(b, b + sizeof(T));
    std::memcpy(bytes + offset, b, sizeof(T));
  }
  HeaderBuilder(bool bigEndian, std::int16_t datatype, std::int16_t bitpix, std::array<std::int16_t, 3> dims)
      : big(bigEndian) {
    put<std::int32_t>(0, 348);
    put<std::int16_t>(40, 3);
    for (int a = 0; a < 3; ++a) put<std::int16_t>(42 + 2 * a, dims[a]);
    for (int a = 3; a < 7; ++a) put<std::int16_t>(42 + 2 * a, 1);
    put<std::int16_t>(70, datatype);
    put<std::int16_t>(72, bitpix);
    for (int a = 0; a < 8; ++a) put<float>(76 + 4 * a, 1.0f);
    put<float>(108, 352.0f);
    std::memcpy(bytes + 344, "n+1\0", 4);
  }
  std::string str() const { return std::string(reinterpret_cast<const char*>(bytes), sizeof bytes); }
};

DenseGrid smallGrid() {
  DenseGrid g;
  g.allocate({5, 4, 3});
  for (int k = 0; k < 3; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 5; ++i) g.at(i, j, k) = 10 * i - 3 * j + 0.5 * k;
  g.geometry.spacing = Vec3(0.5, 1.25, 2.0);
  g.geometry.origin = Vec3(-3.5, 4.0, 100.25);
  return g;
}

TEST(NiftiReader, RoundTripPlainAndGzip) {
  test::ScratchDir dir;
  DenseGrid nucleon = readNrrd(sharedData("nucleon.nhdr"));
  for (const char* name : {"n.nii", "n.nii.gz"}) {
    std::string path = dir.file(name);
    writeNifti(path, nucleon);
    DenseGrid g = readNifti(path);
    EXPECT_EQ(g.geometry.dims, nucleon.geometry.dims);
    EXPECT_EQ(g.values, nucleon.values) << name;
    EXPECT_EQ(g.geometry.spacing, Vec3::Ones());
    EXPECT_NE(g.description.find("float32"), std::string::npos);
  }
  // Compressed output really is gzip.
  std::string gz = test::readAll(dir.file("n.nii.gz"));
  ASSERT_GE(gz.size(), 2u);
  EXPECT_EQ(static_cast<unsigned char>(gz[0]), 0x1f);
  EXPECT_LT(gz.size(), 41u * 41 * 41 * 4);
  EXPECT_EQ(test::readAll(dir.file("n.nii")).size(), 352u + 41 * 41 * 41 * 4);
}

TEST(NiftiReader, ScaleSlopeAndGeometry) {
  test::ScratchDir dir;
  DenseGrid src = smallGrid();
  NiftiWriteOptions opt;
  opt.sclSlope = 0.5;
  opt.sclInter = -20;
  for (const char* name : {"s.nii", "s.nii.gz"}) {
    std::string path = dir.file(name);
    writeNifti(path, src, opt);
    NiftiHeader h = readNiftiHeader(path);
    EXPECT_EQ(h.slope, 0.5);
    EXPECT_EQ(h.inter, -20);
    EXPECT_EQ(h.type, SampleType::Float32);
    EXPECT_EQ(h.dataOffset, 352u);
    DenseGrid g = readNifti(path);
    ASSERT_EQ(g.values.size(), src.values.size());
    for (std::size_t n = 0; n < src.values.size(); ++n) EXPECT_NEAR(g.values[n], src.values[n], 1e-5) << n;
    for (int a = 0; a < 3; ++a) {
      EXPECT_FLOAT_EQ(static_cast<float>(g.geometry.spacing[a]), static_cast<float>(src.geometry.spacing[a]));
      EXPECT_FLOAT_EQ(static_cast<float>(g.geometry.origin[a]), static_cast<float>(src.geometry.origin[a]));
    }
  }
}

TEST(NiftiReader, HandMadeHeadersBothByteOrders) {
  test::ScratchDir dir;
  for (bool big : {false, true}) {
    HeaderBuilder h(big, 4, 16, {3, 2, 1});  // int16
    h.put<float>(80, -2.0f);                 // pixdim[1] negative: spacing is its absolute value
    h.put<float>(84, 3.0f);
    h.put<float>(88, 4.0f);
    h.put<std::int16_t>(252, 0);  // no qform: placement from the sform
    h.put<std::int16_t>(254, 2);
    h.put<float>(280, 2.0f);
    h.put<float>(296 + 4, 3.0f);
    h.put<float>(312 + 8, 4.0f);
    h.put<float>(280 + 12, 7.0f);
    h.put<float>(296 + 12, 8.0f);
    h.put<float>(312 + 12, 9.0f);
    std::string data;
    for (std::int16_t v : {std::int16_t(-300), std::int16_t(1), std::int16_t(2), std::int16_t(32767),
                           std::int16_t(-32768), std::int16_t(5)}) {
      auto u = static_cast<std::uint16_t>(v);
      char b[2] = {static_cast<char>(u & 0xff), static_cast<char>(u >> 8)};
      if (big) std::swap(b[0], b[1]);
      data.append(b, 2);
    }
    std::string path = dir.file(big ? "big.nii" : "little.nii");
    test::writeAll(path, h.str() + data);
    NiftiHeader hdr = readNiftiHeader(path);
    EXPECT_EQ(hdr.endian, big ? Endian::Big : Endian::Little);
    DenseGrid g = readNifti(path);
    EXPECT_EQ(g.geometry.dims, (std::array<std::int64_t, 3>{3, 2, 1}));
    EXPECT_EQ(g.values, (std::vector<double>{-300, 1, 2, 32767, -32768, 5}));
    EXPECT_EQ(g.geometry.spacing, Vec3(2, 3, 4));
    EXPECT_EQ(g.geometry.origin, Vec3(7, 8, 9));
    EXPECT_EQ(g.geometry.space, WorldSpace::RAS);
    // With a qform as well, the sform still wins; without the sform, the qform places the grid.
    h.put<std::int16_t>(252, 1);
    h.put<float>(268, -1.0f);
    h.put<float>(272, -2.0f);
    h.put<float>(276, -3.0f);
    test::writeAll(path, h.str() + data);
    EXPECT_EQ(readNifti(path).geometry.origin, Vec3(7, 8, 9));
    h.put<std::int16_t>(254, 0);
    test::writeAll(path, h.str() + data);
    EXPECT_EQ(readNifti(path).geometry.origin, Vec3(-1, -2, -3));
    EXPECT_EQ(readNifti(path).geometry.spacing, Vec3(2, 3, 4));
    EXPECT_TRUE(readNifti(path).geometry.axisAligned());
    // 4-D with a single time point, and scaling with slope 0 (ignored).
    h.put<std::int16_t>(40, 4);
    h.put<float>(116, 100.0f);
    test::writeAll(path, h.str() + data);
    EXPECT_EQ(readNifti(path).values[0], -300);
  }
}

TEST(NiftiReader, OtherTypes) {
  test::ScratchDir dir;
  struct Case {
    std::int16_t code, bits;
    std::string bytes;
    double first;
  } cases[] = {{2, 8, std::string("\xff", 1), 255},
               {256, 8, std::string("\xff", 1), -1},
               {512, 16, std::string("\xff\xff", 2), 65535},
               {8, 32, std::string("\xfe\xff\xff\xff", 4), -2},
               {768, 32, std::string("\xfe\xff\xff\xff", 4), 4294967294.0},
               {64, 64, std::string("\0\0\0\0\0\0\xf0\x3f", 8), 1.0}};
  for (const auto& c : cases) {
    HeaderBuilder h(false, c.code, c.bits, {1, 1, 1});
    test::writeAll(dir.file("t.nii"), h.str() + c.bytes);
    EXPECT_EQ(readNifti(dir.file("t.nii")).values[0], c.first) << c.code;
  }
}

TEST(NiftiReader, Errors) {
  test::ScratchDir dir;
  std::string path = dir.file("e.nii");
  auto expectBad = [&](const HeaderBuilder& h, const std::string& data, std::vector<std::string> parts) {
    test::writeAll(path, h.str() + data);
    parts.push_back(path);
    expectError([&] { readNifti(path); }, parts);
  };
  const std::string four(4, '\0');
  {
    HeaderBuilder h(false, 16, 32, {1, 1, 1});
    h.put<std::int32_t>(0, 349);
    expectBad(h, four, {"sizeof_hdr is 349"});
  }
  {
    HeaderBuilder h(false, 16, 32, {1, 1, 1});
    std::memcpy(h.bytes + 344, "ni1\0", 4);
    expectBad(h, four, {"ni1"});
    std::memcpy(h.bytes + 344, "abc\0", 4);
    expectBad(h, four, {"magic"});
  }
  {
    HeaderBuilder h(false, 16, 32, {1, 1, 1});
    h.put<float>(108, 4000.0f);
    expectBad(h, four, {"data offset 4000 is beyond the end of the file"});
    h.put<float>(108, 100.0f);
    expectBad(h, four, {"vox_offset"});
  }
  {
    HeaderBuilder h(false, 16, 32, {2, 2, 2});
    expectBad(h, four, {"28 bytes short"});
    expectBad(h, std::string(40, '\0'), {"8 bytes longer"});
  }
  {
    HeaderBuilder h(false, 128, 24, {1, 1, 1});
    expectBad(h, std::string(3, '\0'), {"datatype 128", "rgb24"});
  }
  {
    HeaderBuilder h(false, 16, 16, {1, 1, 1});
    expectBad(h, four, {"bitpix"});
  }
  {
    HeaderBuilder h(false, 16, 32, {1, 1, 1});
    h.put<std::int16_t>(40, 4);
    h.put<std::int16_t>(48, 2);
    expectBad(h, four + four, {"2 frames", "--frame"});
    h.put<std::int16_t>(40, 2);
    expectBad(h, four, {"dim[0] is 2"});
  }
  {
    HeaderBuilder h(false, 16, 32, {1, 0, 1});
    expectBad(h, "", {"dim[2] is 0"});
  }
  {
    HeaderBuilder h(false, 16, 32, {1, 1, 1});
    h.put<float>(84, 0.0f);
    expectBad(h, four, {"pixdim[2]"});
    h.put<float>(84, std::numeric_limits<float>::infinity());
    expectBad(h, four, {"pixdim[2]"});
  }
  {
    // dims 32767^3 float64: valid for NIfTI, but far over the memory limit; must fail before allocating.
    HeaderBuilder h(false, 64, 64, {32767, 32767, 32767});
    expectBad(h, four, {"MiB", "32767x32767x32767"});
  }
  test::writeAll(path, "tiny");
  expectError([&] { readNifti(path); }, {path, "too small"});
  expectError([&] { readNifti(dir.file("missing.nii")); }, {"missing.nii", "cannot open"});

  // Compressed: truncated, corrupt, and longer than declared.
  DenseGrid g = smallGrid();
  writeNifti(dir.file("g.nii.gz"), g);
  std::string gz = test::readAll(dir.file("g.nii.gz"));
  test::writeAll(dir.file("cut.nii.gz"), gz.substr(0, gz.size() - 30));
  expectError([&] { readNifti(dir.file("cut.nii.gz")); }, {"cut.nii.gz"});
  std::string corrupt = gz;
  for (std::size_t n = 20; n < 60 && n < corrupt.size(); ++n)
    corrupt[n] = static_cast<char>(corrupt[n] ^ 0x5a);
  test::writeAll(dir.file("bad.nii.gz"), corrupt);
  expectError([&] { readNifti(dir.file("bad.nii.gz")); }, {"bad.nii.gz"});
  std::string plain = test::readAll([&] {
    writeNifti(dir.file("g.nii"), g);
    return dir.file("g.nii");
  }());
  test::writeAll(dir.file("long.nii.gz"), test::gzipBytes(plain + std::string(1 << 20, 'x')));
  expectError([&] { readNifti(dir.file("long.nii.gz")); },
              {"long.nii.gz", "continues past its declared size"});
}

/// The world position cip gives index `ijk`.
Vec3 worldOf(const GridGeometry& g, const Vec3& ijk) {
  return g.origin + g.direction * g.spacing.cwiseProduct(ijk);
}

TEST(NiftiReader, QformQuaternionAndQfac) {
  test::ScratchDir dir;
  const Eigen::Quaterniond q(Eigen::AngleAxisd(1.2, Vec3(0.3, -1, 0.4).normalized()));
  const Mat3 rotation = q.toRotationMatrix();
  for (double qfac : {1.0, -1.0, 0.0}) {
    HeaderBuilder h(false, 2, 8, {2, 2, 2});
    h.put<std::int16_t>(252, 1);
    h.put<float>(76, static_cast<float>(qfac));
    h.put<float>(80, 0.5f);
    h.put<float>(84, 1.5f);
    h.put<float>(88, 2.5f);
    const double sign = q.w() < 0 ? -1 : 1;  // the file stores the quaternion with a >= 0
    h.put<float>(256, static_cast<float>(sign * q.x()));
    h.put<float>(260, static_cast<float>(sign * q.y()));
    h.put<float>(264, static_cast<float>(sign * q.z()));
    h.put<float>(268, 10.0f);
    h.put<float>(272, -20.0f);
    h.put<float>(276, 30.0f);
    const std::string path = dir.file("q.nii");
    test::writeAll(path, h.str() + std::string(8, '\x01'));
    DenseGrid g = readNifti(path);
    // qfac -1 flips the third index axis; 0 counts as 1.
    const Mat3 expected = rotation * Vec3(1, 1, qfac == -1 ? -1 : 1).asDiagonal();
    EXPECT_LT((g.geometry.direction - expected).cwiseAbs().maxCoeff(), 1e-6) << qfac;
    EXPECT_LT((g.geometry.spacing - Vec3(0.5, 1.5, 2.5)).norm(), 1e-6);
    const Vec3 ijk(1, 1, 1);
    const Vec3 truth = Vec3(10, -20, 30) + expected * Vec3(0.5, 1.5, 2.5).cwiseProduct(ijk);
    EXPECT_LT((worldOf(g.geometry, ijk) - truth).norm(), 1e-5);
    EXPECT_EQ(readNiftiHeader(path).placement, NiftiPlacement::Qform);
  }
}

TEST(NiftiReader, QuaternionBeyondTheUnitBallIsRefused) {
  test::ScratchDir dir;
  const std::string path = dir.file("q.nii");
  HeaderBuilder h(false, 2, 8, {1, 1, 1});
  h.put<std::int16_t>(252, 1);
  h.put<float>(256, 0.6f);
  h.put<float>(260, 0.6f);
  h.put<float>(264, 0.6f);
  test::writeAll(path, h.str() + "x");
  expectError([&] { readNifti(path); }, {path, "quaternion", "not a rotation"});
  // Within nibabel's tolerance (3 float epsilons) b² + c² + d² may exceed 1: a is 0, a half turn about x.
  h.put<float>(256, std::nextafter(1.0f, 2.0f));
  h.put<float>(260, 0.0f);
  h.put<float>(264, 0.0f);
  test::writeAll(path, h.str() + "x");
  DenseGrid g = readNifti(path);
  EXPECT_LT((g.geometry.direction - Vec3(1, -1, -1).asDiagonal().toDenseMatrix()).cwiseAbs().maxCoeff(),
            1e-6);
  h.put<float>(256, std::numeric_limits<float>::quiet_NaN());
  test::writeAll(path, h.str() + "x");
  expectError([&] { readNifti(path); }, {path, "quaternion", "not finite"});
  // A zero pixdim makes the qform singular.
  h.put<float>(256, 0.0f);
  h.put<float>(84, 0.0f);
  test::writeAll(path, h.str() + "x");
  expectError([&] { readNifti(path); }, {path, "qform", "index axis 1"});
}

TEST(NiftiReader, BadSformsAreRefused) {
  test::ScratchDir dir;
  const std::string path = dir.file("s.nii");
  auto withSform = [&](const Mat3& m, const Vec3& origin) {
    HeaderBuilder h(false, 2, 8, {1, 1, 1});
    h.put<std::int16_t>(254, 1);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) h.put<float>(280 + 16 * r + 4 * c, static_cast<float>(m(r, c)));
      h.put<float>(280 + 16 * r + 12, static_cast<float>(origin[r]));
    }
    test::writeAll(path, h.str() + "x");
  };
  Mat3 m = Mat3::Identity();
  m(2, 2) = 0;  // index axis 2 goes nowhere
  withSform(m, Vec3::Zero());
  expectError([&] { readNifti(path); }, {path, "sform", "index axis 2 has no length"});
  m = Mat3::Identity();
  m.col(1) = Vec3(2, 0, 0);  // axes 0 and 1 parallel
  withSform(m, Vec3::Zero());
  expectError([&] { readNifti(path); }, {path, "sform", "singular"});
  m = Mat3::Identity();
  m(0, 1) = std::numeric_limits<double>::infinity();
  withSform(m, Vec3::Zero());
  expectError([&] { readNifti(path); }, {path, "sform", "not finite"});
  withSform(Mat3::Identity(), Vec3(0, std::numeric_limits<double>::quiet_NaN(), 0));
  expectError([&] { readNifti(path); }, {path, "sform", "origin is not finite"});
}

TEST(NiftiReader, FramesPairsAndDimensions) {
  test::ScratchDir dir;
  for (bool big : {false, true}) {
    HeaderBuilder h(big, 2, 8, {2, 1, 1});
    h.put<std::int16_t>(40, 4);
    h.put<std::int16_t>(48, 3);  // three frames of two samples
    const std::string data = "\x01\x02\x03\x04\x05\x06";
    const std::string path = dir.file("f.nii");
    test::writeAll(path, h.str() + data);
    for (int frame = 0; frame < 3; ++frame) {
      DenseGrid g = readNifti(path, DenseGrid::defaultMaxBytes(), frame);
      EXPECT_EQ(g.values, (std::vector<double>{2.0 * frame + 1, 2.0 * frame + 2}));
    }
    expectError([&] { readNifti(path); }, {path, "3 frames", "--frame 0..2"});
    expectError([&] { readNifti(path, DenseGrid::defaultMaxBytes(), 3); }, {path, "frame 3 is out of range"});
    // The same as a compressed file, and as a header/image pair (magic "ni1", data from byte 0 of the .img).
    test::writeAll(dir.file("f.nii.gz"), test::gzipBytes(h.str() + data));
    EXPECT_EQ(readNifti(dir.file("f.nii.gz"), DenseGrid::defaultMaxBytes(), 2).values,
              (std::vector<double>{5, 6}));
    std::memcpy(h.bytes + 344, "ni1\0", 4);
    h.put<float>(108, 0.0f);
    test::writeAll(dir.file("p.hdr"), h.str().substr(0, 348));
    test::writeAll(dir.file("p.img"), data);
    for (const char* name : {"p.hdr", "p.img"})
      EXPECT_EQ(readNifti(dir.file(name), DenseGrid::defaultMaxBytes(), 1).values,
                (std::vector<double>{3, 4}));
    EXPECT_EQ(volumeFileBytes(dir.file("p.img")), 348u + 6);
    std::remove(dir.file("p.img").c_str());
    expectError([&] { readNifti(dir.file("p.hdr"), DenseGrid::defaultMaxBytes(), 1); },
                {"p.img", "cannot open"});
    // Five dimensions with a real fifth extent are refused; trailing extents of 1 are not a fifth dimension.
    std::memcpy(h.bytes + 344, "n+1\0", 4);
    h.put<float>(108, 352.0f);
    h.put<std::int16_t>(40, 5);
    h.put<std::int16_t>(48, 1);
    h.put<std::int16_t>(50, 2);
    test::writeAll(path, h.str() + data.substr(0, 4));
    expectError([&] { readNifti(path); }, {path, "5 dimensions", "dim[5] is 2"});
    h.put<std::int16_t>(50, 1);
    test::writeAll(path, h.str() + data.substr(0, 2));
    EXPECT_EQ(readNifti(path).values, (std::vector<double>{1, 2}));
  }
}

TEST(NiftiWriter, WritesTheDirection) {
  test::ScratchDir dir;
  DenseGrid src = smallGrid();
  Mat3 rotation = Eigen::AngleAxisd(2.1, Vec3(1, 1, -0.5).normalized()).toRotationMatrix();
  Mat3 shear;
  shear << 1, 0.3, 0, 0, 1, 0.2, 0.1, 0, 1;
  for (const Mat3& columns :
       {rotation, Mat3(rotation * Vec3(1, -1, 1).asDiagonal()), Mat3(rotation * shear)}) {
    for (WorldSpace space : {WorldSpace::RAS, WorldSpace::LPS, WorldSpace::Unspecified}) {
      setAxes(src.geometry, columns * Vec3(0.5, 1.25, 2.0).asDiagonal(), "test");
      src.geometry.space = space;
      const std::string path = dir.file("w.nii");
      writeNifti(path, src);
      DenseGrid g = readNifti(path);
      NiftiHeader h = readNiftiHeader(path);
      EXPECT_EQ(h.sformCode, 1);
      const bool orthonormal = (columns.transpose() * columns - Mat3::Identity()).norm() < 1e-9;
      EXPECT_EQ(h.qformCode, orthonormal ? 1 : 0);
      EXPECT_EQ(g.geometry.space, WorldSpace::RAS);
      // LPS -> RAS negates x and y.
      const Vec3 flip = space == WorldSpace::LPS ? Vec3(-1, -1, 1) : Vec3(1, 1, 1);
      for (const Vec3& ijk : {Vec3(0, 0, 0), Vec3(4, 3, 2), Vec3(1, 2, 0)}) {
        const Vec3 expected = flip.cwiseProduct(worldOf(src.geometry, ijk));
        EXPECT_LT((worldOf(g.geometry, ijk) - expected).norm(), 1e-5);
      }
      // The qform alone, when written, places the grid the same way.
      if (h.qformCode == 1) {
        std::string bytes = test::readAll(path);
        bytes[254] = 0;
        test::writeAll(path, bytes);
        DenseGrid q = readNifti(path);
        EXPECT_LT((q.geometry.direction - g.geometry.direction).cwiseAbs().maxCoeff(), 1e-6);
      }
    }
  }
}

TEST(NiftiWriter, RejectsUnwritableGrids) {
  test::ScratchDir dir;
  DenseGrid g;
  g.allocate({40000, 1, 1});
  expectError([&] { writeNifti(dir.file("w.nii"), g); }, {"32767"});
  expectError([&] { writeNifti("/nonexistent/dir/w.nii", smallGrid()); }, {"/nonexistent/dir/w.nii"});
}

}  // namespace
}  // namespace cip
