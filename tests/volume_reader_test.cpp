// Format dispatch: every format through readVolume, the raw fallback, descriptions for statistics.
#include "cip/readers/volume_reader.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/nifti_reader.h"
#include "cip/readers/nrrd_reader.h"
#include "support/model_bytes.h"
#include "support/scratch_dir.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;
using test::sharedData;

TEST(VolumeReader, FormatFromName) {
  EXPECT_EQ(volumeFormatOf("a/b.nrrd"), VolumeFormat::Nrrd);
  EXPECT_EQ(volumeFormatOf("B.NHDR"), VolumeFormat::Nrrd);
  EXPECT_EQ(volumeFormatOf("x.nii"), VolumeFormat::Nifti);
  EXPECT_EQ(volumeFormatOf("x.nii.gz"), VolumeFormat::Nifti);
  EXPECT_EQ(volumeFormatOf("x.vdb"), VolumeFormat::Vdb);
  for (const char* name : {"x.hdr", "X.IMG", "x.hdr.gz", "x.img.gz"})
    EXPECT_EQ(volumeFormatOf(name), VolumeFormat::Nifti);
  EXPECT_EQ(volumeFormatOf("x.mha"), VolumeFormat::MetaImage);
  EXPECT_EQ(volumeFormatOf("x.MHD"), VolumeFormat::MetaImage);
  EXPECT_EQ(volumeFormatOf("x.raw"), VolumeFormat::Raw);
  EXPECT_EQ(volumeFormatOf("x.gz"), VolumeFormat::Raw);
  EXPECT_EQ(volumeFormatOf("IM0001.DCM"), VolumeFormat::Dicom);
  test::ScratchDir dir;
  EXPECT_EQ(volumeFormatOf(dir.path()), VolumeFormat::Dicom);  // a folder is a DICOM series
  EXPECT_EQ(volumeFormatOf(dir.file("missing")), VolumeFormat::Raw);
}

TEST(VolumeReader, FileBytesCountDetachedData) {
  test::ScratchDir dir;
  auto write = [&](const std::string& name, const std::string& text) {
    std::ofstream(dir.file(name), std::ios::binary) << text;
    return dir.file(name);
  };
  const std::string data = write("d.raw", std::string(1000, 'x'));
  const std::string header =
      "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 10 10 10\nencoding: raw\ndata file: d.raw\n";
  const std::string nhdr = write("v.nhdr", header);
  EXPECT_EQ(volumeFileBytes(nhdr), header.size() + 1000);
  EXPECT_EQ(volumeFileBytes(data), 1000u);
  // A header naming a missing data file, or no header at all, counts as its own bytes; no file as nothing.
  const std::string dangling = write("w.nhdr",
                                     "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 10 10 10\n"
                                     "encoding: raw\ndata file: gone.raw\n");
  EXPECT_EQ(volumeFileBytes(dangling), std::filesystem::file_size(dangling));
  const std::string garbage = write("g.nhdr", "not a header");
  EXPECT_EQ(volumeFileBytes(garbage), 12u);
  EXPECT_EQ(volumeFileBytes(dir.file("none.nrrd")), 0u);
  // A folder (DICOM series) counts the files in it.
  std::filesystem::create_directory(dir.file("series"));
  write("series/a.dcm", std::string(300, 'a'));
  write("series/b.dcm", std::string(200, 'b'));
  EXPECT_EQ(volumeFileBytes(dir.file("series")), 500u);
}

TEST(VolumeReader, NrrdAsOneBrick) {
  SparseVolume v = readVolume(sharedData("tooth.nhdr"));
  ASSERT_NE(v.dense(), nullptr);
  EXPECT_EQ(v.geometry.dims, (std::array<std::int64_t, 3>{103, 94, 161}));
  EXPECT_EQ(v.geometry.origin, Vec3(-51.5, -47, -80.5));
  EXPECT_FALSE(v.isLevelSet);
  std::string d = describeVolume(v);
  EXPECT_NE(d.find("NRRD uint8 103x94x161"), std::string::npos) << d;
  // Same model as the dense grid read directly.
  BuildOptions opt;
  opt.isovalue = 120;
  opt.threads = 2;
  DenseGrid g = readNrrd(sharedData("tooth.nhdr"));
  EXPECT_EQ(test::modelBytes(buildModel(v.geometry, v.bricks, opt, v.description)),
            test::modelBytes(buildModel(g, opt)));
}

TEST(VolumeReader, RawNeedsFormat) {
  const std::string path = sharedData("headsq_64x64x93_int16.raw");
  expectError([&] { readVolume(path); }, {path, "dims", "sample type"});
  VolumeReadOptions o;
  RawFormat f;
  f.dims = {64, 64, 93};
  f.type = SampleType::Int16;
  f.spacing = Vec3(3.2, 3.2, 1.5);
  o.raw = f;
  SparseVolume v = readVolume(path, o);
  ASSERT_NE(v.dense(), nullptr);
  EXPECT_EQ(v.dense()->values, readNrrd(sharedData("headsq.nhdr")).values);
  EXPECT_NE(describeVolume(v).find("raw int16 64x64x93"), std::string::npos) << describeVolume(v);
  // A known extension wins over a raw format.
  SparseVolume n = readVolume(sharedData("nucleon.nhdr"), o);
  EXPECT_EQ(n.geometry.dims, (std::array<std::int64_t, 3>{41, 41, 41}));
  // Except for a .img without the .hdr of a NIfTI pair beside it: raw data; with the .hdr, the pair.
  test::ScratchDir dir;
  const std::string img = dir.file("headsq.img");
  test::writeAll(img, test::readAll(path));
  EXPECT_EQ(readVolume(img, o).dense()->values, v.dense()->values);
  expectError([&] { readVolume(img); }, {img, "headsq.hdr", "cannot open"});
  test::writeAll(dir.file("headsq.hdr"), "not a header");
  expectError([&] { readVolume(img, o); }, {"headsq.hdr", "too small for a NIfTI header"});
}

TEST(VolumeReader, NiftiAndVdb) {
  test::ScratchDir dir;
  writeNifti(dir.file("n.nii.gz"), readNrrd(sharedData("nucleon.nhdr")));
  SparseVolume n = readVolume(dir.file("n.nii.gz"));
  ASSERT_NE(n.dense(), nullptr);
  EXPECT_NE(describeVolume(n).find("NIfTI float32 41x41x41"), std::string::npos);

  VolumeReadOptions o;
  o.vdbGrid = "ls_sphere";
  o.brickCells = 64;
  SparseVolume s = readVolume(sharedData("vdb/sphere.vdb"), o);
  EXPECT_TRUE(s.isLevelSet);
  EXPECT_EQ(s.dense(), nullptr);
  EXPECT_EQ(s.bricks.size(), 8u);  // 126 cells per axis in bricks of 64: 2x2x2, all touching the shell
  std::string d = describeVolume(s);
  EXPECT_NE(d.find("ls_sphere"), std::string::npos) << d;
  EXPECT_NE(d.find("127x127x127"), std::string::npos) << d;
  EXPECT_NE(d.find("8 bricks"), std::string::npos) << d;
  auto [lo, hi] = s.range();
  EXPECT_LT(lo, 0);
  EXPECT_GT(hi, 0);
}

TEST(VolumeReader, MemoryLimitAppliesToEveryFormat) {
  VolumeReadOptions o;
  o.maxBytes = 64 << 10;
  expectError([&] { readVolume(sharedData("nucleon.nhdr"), o); }, {"nucleon.nhdr", "MiB"});
  expectError([&] { readVolume(sharedData("vdb/smoke.vdb"), o); }, {"smoke.vdb", "MiB"});
}

}  // namespace
}  // namespace cip
