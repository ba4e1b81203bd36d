// NIfTI-1 reader and writer: round trips through .nii and .nii.gz (with scl_slope/scl_inter), hand-made
// headers in both byte orders, origin from qform/sform, and the error paths.
#include "cip/readers/nifti_reader.h"

#include <gtest/gtest.h>

#include <cstring>

#include "cip/readers/nrrd_reader.h"
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
    h.put<std::int16_t>(252, 0);  // no qform: origin from sform
    h.put<std::int16_t>(254, 2);
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
    // With a qform, its offsets win over the sform.
    h.put<std::int16_t>(252, 1);
    h.put<float>(268, -1.0f);
    h.put<float>(272, -2.0f);
    h.put<float>(276, -3.0f);
    test::writeAll(path, h.str() + data);
    EXPECT_EQ(readNifti(path).geometry.origin, Vec3(-1, -2, -3));
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
    expectBad(h, four + four, {"time points"});
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

TEST(NiftiWriter, RejectsUnwritableGrids) {
  test::ScratchDir dir;
  DenseGrid g;
  g.allocate({40000, 1, 1});
  expectError([&] { writeNifti(dir.file("w.nii"), g); }, {"32767"});
  expectError([&] { writeNifti("/nonexistent/dir/w.nii", smallGrid()); }, {"/nonexistent/dir/w.nii"});
}

}  // namespace
}  // namespace cip
