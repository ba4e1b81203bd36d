// Slab reader: every slab of slices of raw, NRRD (raw, gzip, bzip2; attached and detached; one frame of a
// 4-D series) and NIfTI (plain, gzip, scaled) files holds the values the whole-volume reader gives there, in
// any order of reading; files read whole say why; short data fails naming the file and the position.
#include "cip/readers/slab_reader.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>

#include "cip/readers/nifti_reader.h"
#include "support/volume_blocks.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;
using test::sharedData;

/// Reads `path` in slabs of `thickness` slices, forwards and then backwards, and expects each slab to be
/// the whole-volume reader's slices, placed where they are in the volume.
void expectSlabsMatchWhole(const std::string& path, const VolumeReadOptions& options,
                           std::int64_t thickness) {
  SCOPED_TRACE(path + " in slabs of " + std::to_string(thickness));
  SparseVolume volume = readVolume(path, options);
  const DenseGrid& whole = *volume.dense();
  const DenseVolumeProbe probe = probeDenseVolume(path, options);
  ASSERT_TRUE(probe.layout.has_value()) << probe.whyNot;
  EXPECT_EQ(probe.layout->geometry.dims, whole.geometry.dims);
  EXPECT_EQ(probe.layout->description, whole.description);
  SlabReader reader(*probe.layout);
  const auto& d = whole.geometry.dims;
  const std::int64_t slice = d[0] * d[1];
  std::vector<std::int64_t> starts;
  for (std::int64_t z0 = 0; z0 < d[2]; z0 += thickness) starts.push_back(z0);
  std::vector<std::int64_t> order = starts;
  order.insert(order.end(), starts.rbegin(), starts.rend());
  for (std::int64_t z0 : order) {
    const std::int64_t z1 = std::min(d[2], z0 + thickness);
    const DenseGrid slab = reader.read(z0, z1);
    ASSERT_EQ(slab.geometry.dims, (std::array<std::int64_t, 3>{d[0], d[1], z1 - z0}));
    const std::vector<double> expected(whole.values.begin() + z0 * slice, whole.values.begin() + z1 * slice);
    ASSERT_EQ(slab.values, expected) << "slices " << z0 << ".." << z1;
    EXPECT_EQ(slab.geometry.spacing, whole.geometry.spacing);
    EXPECT_EQ(slab.geometry.direction, whole.geometry.direction);
    const Vec3 at =
        whole.geometry.origin +
        whole.geometry.direction * whole.geometry.spacing.cwiseProduct(Vec3(0, 0, static_cast<double>(z0)));
    EXPECT_NEAR((slab.geometry.origin - at).norm(), 0, 1e-9);
  }
}

TEST(SlabReader, BundledGzipNrrd) {
  for (std::int64_t t : {1, 5, 48}) expectSlabsMatchWhole(test::sourceFile("data/blobs.nrrd"), {}, t);
}

TEST(SlabReader, SharedVolumes) {
  for (const char* name : {"tooth.nhdr", "headsq.nhdr", "nucleon.nhdr"}) {
    if (!std::filesystem::exists(sharedData(name))) GTEST_SKIP() << sharedData(name) << " is missing";
    for (std::int64_t t : {1, 7}) expectSlabsMatchWhole(sharedData(name), {}, t);
  }
}

TEST(SlabReader, RawWithOffsetBigEndian) {
  test::ScratchDir dir;
  std::string bytes = "HEADER";
  for (int n = 0; n < 5 * 4 * 9; ++n) {
    const int v = n * 37 - 900;
    bytes += static_cast<char>((v >> 8) & 0xff);
    bytes += static_cast<char>(v & 0xff);
  }
  test::writeAll(dir.file("v.bin"), bytes);
  VolumeReadOptions options;
  options.raw = RawFormat{{5, 4, 9}, SampleType::Int16, Endian::Big, Vec3(1, 2, 3), Vec3(4, 5, 6), 6};
  for (std::int64_t t : {1, 2, 4}) expectSlabsMatchWhole(dir.file("v.bin"), options, t);
}

TEST(SlabReader, CompressedNrrdAndFrames) {
  test::ScratchDir dir;
  std::string data;
  for (int n = 0; n < 2 * 6 * 5 * 7; ++n) data += static_cast<char>((n * 13) & 0xff);
  const std::string head = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 6 5 7\n";
  const std::string frame1 = data.substr(6 * 5 * 7);
  test::writeAll(dir.file("b.nrrd"), head + "encoding: bzip2\n\n" + test::bzip2Bytes(frame1));
  test::writeAll(dir.file("g.raw.gz"), test::gzipBytes("xyz" + frame1));
  test::writeAll(dir.file("g.nhdr"), head + "encoding: gzip\nbyte skip: 3\ndata file: g.raw.gz\n");
  // Frames stored one after the other (the last axis): frame 1 of 2, plain and compressed.
  const std::string head4 =
      "NRRD0004\ntype: uint8\ndimension: 4\nsizes: 6 5 7 2\nkinds: space space space list\n";
  test::writeAll(dir.file("f.nrrd"), head4 + "encoding: raw\n\n" + data);
  test::writeAll(dir.file("fg.nrrd"), head4 + "encoding: gzip\n\n" + test::gzipBytes(data));
  VolumeReadOptions second;
  second.frame = 1;
  for (std::int64_t t : {1, 3}) {
    expectSlabsMatchWhole(dir.file("b.nrrd"), {}, t);
    expectSlabsMatchWhole(dir.file("g.nhdr"), {}, t);
    expectSlabsMatchWhole(dir.file("f.nrrd"), second, t);
    expectSlabsMatchWhole(dir.file("fg.nrrd"), second, t);
  }
}

TEST(SlabReader, NiftiPlainGzipAndScaled) {
  test::ScratchDir dir;
  DenseGrid grid;
  grid.allocate({7, 3, 6});
  grid.geometry.spacing = Vec3(0.5, 1, 2);
  for (std::size_t n = 0; n < grid.values.size(); ++n) grid.values[n] = static_cast<double>(n) * 0.75 - 20;
  writeNifti(dir.file("v.nii"), grid);
  writeNifti(dir.file("v.nii.gz"), grid);
  writeNifti(dir.file("s.nii"), grid, {0.25, -3});
  for (std::int64_t t : {1, 4})
    for (const char* name : {"v.nii", "v.nii.gz", "s.nii"}) expectSlabsMatchWhole(dir.file(name), {}, t);
}

TEST(SlabReader, FilesReadWholeSayWhy) {
  test::ScratchDir dir;
  test::writeAll(dir.file("a.nrrd"),
                 "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 1 1\nencoding: ascii\n\n1 2\n");
  const DenseVolumeProbe ascii = probeDenseVolume(dir.file("a.nrrd"));
  EXPECT_FALSE(ascii.layout.has_value());
  EXPECT_NE(ascii.whyNot.find("ascii"), std::string::npos);
  const DenseVolumeProbe raw = probeDenseVolume(dir.file("v.bin"));
  EXPECT_FALSE(raw.layout.has_value());
  EXPECT_FALSE(raw.whyNot.empty());
  // What the whole reader rejects, the probe rejects with the same kind of message.
  test::writeAll(dir.file("short.nrrd"),
                 "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n123");
  expectError([&] { probeDenseVolume(dir.file("short.nrrd")); }, {dir.file("short.nrrd"), "short"});
}

TEST(SlabReader, ShortDataNamesFileAndPosition) {
  test::ScratchDir dir;
  const std::string data(8 * 8 * 8, '\x40');
  const std::string head = "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 8 8 8\nencoding: gzip\n\n";
  const std::string gz = test::gzipBytes(data);
  test::writeAll(dir.file("cut.nrrd"), head + gz.substr(0, gz.size() / 2));
  const DenseVolumeProbe probe = probeDenseVolume(dir.file("cut.nrrd"));
  ASSERT_TRUE(probe.layout.has_value());
  SlabReader reader(*probe.layout);
  expectError([&] { reader.read(0, 8); }, {dir.file("cut.nrrd"), "truncated"});
  // Plain data cut after the probe: the slab that meets the end says where the data ends.
  test::writeAll(dir.file("p.raw"), data);
  VolumeReadOptions options;
  options.raw = RawFormat{{8, 8, 8}, SampleType::UInt8, Endian::Little, Vec3::Ones(), Vec3::Zero(), 0};
  const DenseVolumeProbe plain = probeDenseVolume(dir.file("p.raw"), options);
  ASSERT_TRUE(plain.layout.has_value());
  SlabReader cut(*plain.layout);
  std::filesystem::resize_file(dir.file("p.raw"), 8 * 8 * 5 + 3);
  EXPECT_EQ(cut.read(0, 5).values, std::vector<double>(8 * 8 * 5, 64.0));
  expectError([&] { cut.read(5, 8); }, {dir.file("p.raw"), "data ends after 323 of 512 bytes"});
  expectError([&] { cut.read(3, 9); }, {"slices [3, 9)"});
}

}  // namespace
}  // namespace cip
