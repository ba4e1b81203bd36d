// Format dispatch: every format through readVolume, the raw fallback, descriptions for statistics.
#include "cip/readers/volume_reader.h"

#include <gtest/gtest.h>

#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/nifti_reader.h"
#include "cip/readers/nrrd_reader.h"
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
  EXPECT_EQ(volumeFormatOf("x.raw"), VolumeFormat::Raw);
  EXPECT_EQ(volumeFormatOf("x.gz"), VolumeFormat::Raw);
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
  EXPECT_EQ(serializeModel(buildModel(v.geometry, v.bricks, opt, v.description)),
            serializeModel(buildModel(g, opt)));
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
