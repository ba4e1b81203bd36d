// Hostile and degenerate inputs through the command line tools: clear errors, non-zero exits, and outputs
// that are either complete or untouched. (Parser-level cases live beside each reader's tests and in
// tests/fuzz.)
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
#include <tuple>
#include <vector>

#include "cip/model/model_file.h"
#include "support/command_line.h"

namespace fs = std::filesystem;
namespace test = cip::test;

using cip::test::CommandResult;
using cip::test::run;
using cip::test::slurp;

namespace {

const std::string kExtract = std::string(CIP_BINARY_DIR) + "/extract/extract";
const std::string kRaycast = std::string(CIP_BINARY_DIR) + "/raycast/raycast";

class HostileInput : public ::testing::Test {
 protected:
  void SetUp() override {
    scratch = std::make_unique<test::ScratchDir>();
    dir = scratch->path();
  }
  void TearDown() override { scratch.reset(); }
  fs::path file(const std::string& name, const std::string& contents) {
    fs::path p = dir / name;
    std::ofstream(p, std::ios::binary) << contents;
    return p;
  }
  // Only the given files exist in the folder: no temporary or partial output was left behind.
  void expectOnly(std::vector<std::string> names) {
    std::vector<std::string> present;
    for (auto& e : fs::directory_iterator(dir)) present.push_back(e.path().filename().string());
    std::sort(present.begin(), present.end());
    std::sort(names.begin(), names.end());
    EXPECT_EQ(present, names);
  }
  std::unique_ptr<test::ScratchDir> scratch;
  fs::path dir;
};

}  // namespace

TEST_F(HostileInput, FailedExtractLeavesPreviousOutputUntouched) {
  fs::path out = file("model.cip", "previous model");
  fs::path raw = file("v.raw", std::string(100, '\1'));
  CommandResult r =
      run(kExtract + " " + raw.string() + " --dims 10,10,10 --type uint8 --iso 0.5 -o " + out.string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("expected 1000"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(out), "previous model");
  expectOnly({"model.cip", "v.raw"});
}

TEST_F(HostileInput, DimsOverflowingOrBeyondMemoryFailBeforeAllocating) {
  fs::path raw = file("v.raw", std::string(8, '\0'));
  CommandResult r =
      run(kExtract + " " + raw.string() + " --dims 4294967296,4294967296,4 --type uint8 --iso 1 -o " +
          (dir / "m.cip").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("overflow"), std::string::npos) << r.err;
  r = run(kExtract + " " + raw.string() + " --dims 100000,100000,1000 --type uint8 --iso 1 -o " +
          (dir / "m.cip").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("MiB"), std::string::npos) << r.err;
  expectOnly({"v.raw"});
}

TEST_F(HostileInput, NonFiniteVoxelsAreRejectedOrSkipped) {
  std::vector<float> v(4 * 4 * 4);
  for (std::size_t i = 0; i < v.size(); ++i) v[i] = (i % 3 == 0) ? 1.f : -1.f;
  v[21] = std::numeric_limits<float>::quiet_NaN();
  v[42] = std::numeric_limits<float>::infinity();
  fs::path raw = file("v.raw", std::string(reinterpret_cast<const char*>(v.data()), v.size() * 4));
  std::string common = kExtract + " " + raw.string() + " --dims 4,4,4 --type float32 --iso 0 -q -o ";
  CommandResult r = run(common + (dir / "a.cip").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("NaN or infinite"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "a.cip"));
  r = run(common + (dir / "b.cip").string() + " --skip-nonfinite");
  EXPECT_EQ(r.status, 0) << r.err;
  cip::Model m = cip::readModel((dir / "b.cip").string());
  EXPECT_GT(m.cells.size(), 0u);
}

/// A little-endian NIfTI header (version 1 or 2) of uint8 samples with the given dims and, for NIfTI-1, a
/// qform quaternion; data from byte 352 (NIfTI-1) or 544 (NIfTI-2).
std::string niftiHeader(int version, std::array<std::int64_t, 3> dims,
                        std::array<float, 3> quaternion = {0, 0, 0}) {
  std::string h(version == 1 ? 352 : 544, '\0');
  auto put = [&h](std::size_t at, auto v) { std::memcpy(&h[at], &v, sizeof v); };
  if (version == 1) {
    put(0, std::int32_t(348));
    put(40, std::int16_t(3));
    for (int a = 0; a < 3; ++a) put(42 + 2 * a, static_cast<std::int16_t>(dims[a]));
    put(70, std::int16_t(2));
    for (int a = 0; a < 4; ++a) put(76 + 4 * a, 1.0f);
    put(108, 352.0f);
    put(252, std::int16_t(1));
    for (int a = 0; a < 3; ++a) put(256 + 4 * a, quaternion[a]);
    std::memcpy(&h[344], "n+1", 4);
  } else {
    put(0, std::int32_t(540));
    std::memcpy(&h[4], "n+2\0\r\n\032\n", 8);
    put(12, std::int16_t(2));
    put(16, std::int64_t(3));
    for (int a = 0; a < 3; ++a) put(24 + 8 * a, dims[a]);
    for (int a = 0; a < 4; ++a) put(104 + 8 * a, 1.0);
    put(168, std::int64_t(544));
  }
  return h;
}

// Damaged or absurd NIfTI and MetaImage headers: a one-line error that starts with the file's path, exit
// status 1, no output, and nothing allocated for sizes the header merely claims.
TEST_F(HostileInput, DamagedMedicalHeaders) {
  const std::string mhaDims = "ObjectType = Image\nNDims = 3\nElementType = MET_UCHAR\n";
  const std::vector<std::tuple<std::string, std::string, std::string>> cases = {
      {"truncated.mha", mhaDims + "DimSize = 2 2 2\n", "no ElementDataFile"},
      {"cut_line.mha", mhaDims + "DimSize = 2 2 2\nElementSpa", "line 5 'ElementSpa' is not 'Key = Value'"},
      {"huge.mha", mhaDims + "DimSize = 1000000 1000000 1000000\nElementDataFile = LOCAL\n", "MiB"},
      {"frames.mha",
       "NDims = 4\nDimSize = 2 2 2 4611686018427387904\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n",
       "4611686018427387904 frames"},
      {"flat.mha",
       mhaDims + "DimSize = 2 2 2\nTransformMatrix = 1 0 0 0 1 0 0 0 0\nElementDataFile = LOCAL\n" +
           std::string(8, '\1'),
       "TransformMatrix"},
      {"files.mhd", mhaDims + "DimSize = 2 2 4611686018427387904\nElementDataFile = s%d.raw\n", "data files"},
      {"short.mha", mhaDims + "DimSize = 2 2 2\nElementDataFile = LOCAL\n" + std::string(5, '\1'),
       "3 bytes short"},
      {"quaternion.nii", niftiHeader(1, {2, 2, 2}, {0.8f, 0.8f, 0.1f}) + std::string(8, '\1'),
       "not a rotation"},
      {"huge2.nii", niftiHeader(2, {std::int64_t(1) << 40, std::int64_t(1) << 40, 4}) + std::string(8, '\1'),
       "overflow"},
      {"cut.nii", niftiHeader(1, {2, 2, 2}).substr(0, 200), "too small"},
      {"lonely.hdr",
       [] {
         std::string h = niftiHeader(1, {2, 2, 2}).substr(0, 348);
         h[345] = 'i';
         return h;
       }(),
       "lonely.img"},
  };
  std::vector<std::string> names;
  for (const auto& [name, contents, message] : cases) {
    fs::path input = file(name, contents);
    names.push_back(name);
    CommandResult r = run(kExtract + " " + input.string() + " --iso 0.5 -o " + (dir / "m.cip").string());
    EXPECT_EQ(r.status, 1) << name;
    EXPECT_EQ(r.err.rfind("extract: error: " + input.string() + ": ", 0), 0u) << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    EXPECT_EQ(r.err.find('\n'), r.err.size() - 1) << "one line: " << r.err;
  }
  expectOnly(names);
}

TEST_F(HostileInput, ZeroSizedAndOneVoxelThickVolumes) {
  fs::path empty = file("empty.raw", "");
  CommandResult r = run(kExtract + " " + empty.string() + " --dims 0,4,4 --type uint8 --iso 1 -o " +
                        (dir / "z.cip").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_FALSE(r.err.empty());
  EXPECT_FALSE(fs::exists(dir / "z.cip"));
  // One voxel thick: no cells, a valid empty model that reads back.
  fs::path slab = file("slab.raw", std::string(16, '\5'));
  r = run(kExtract + " " + slab.string() + " --dims 4,4,1 --type uint8 --iso 1 -q -o " +
          (dir / "s.cip").string());
  EXPECT_EQ(r.status, 0) << r.err;
  cip::Model m = cip::readModel((dir / "s.cip").string());
  EXPECT_EQ(m.cells.size(), 0u);
  EXPECT_EQ(m.geometry.dims[2], 1);
}

TEST_F(HostileInput, DamagedModelGivesClearRaycastErrorAndNoImage) {
  fs::path good = dir / "good.cip";
  CommandResult r = run(kExtract + " sphere --resolution 8 -q -o " + good.string());
  ASSERT_EQ(r.status, 0) << r.err;
  std::string bytes = slurp(good);
  bytes.resize(bytes.size() / 2);
  fs::path bad = file("bad.cip", bytes);
  fs::path image = file("image.exr", "previous image");
  r = run(kRaycast + " " + bad.string() + " -o " + image.string() + " --size 16x16 -q");
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("damaged model file"), std::string::npos) << r.err;
  EXPECT_EQ(slurp(image), "previous image");
  expectOnly({"good.cip", "bad.cip", "image.exr"});
}

TEST_F(HostileInput, UnknownInputsAndFlags) {
  CommandResult r = run(kExtract + " no-such-volume.nrrd -o " + (dir / "m.cip").string());
  EXPECT_EQ(r.status, 1);
  EXPECT_NE(r.err.find("no-such-volume.nrrd"), std::string::npos);
  r = run(kExtract + " sphere --normals sideways -o " + (dir / "m.cip").string());
  EXPECT_NE(r.status, 0);
  r = run(kRaycast + " " + (dir / "missing.cip").string() + " -o " + (dir / "i.exr").string());
  EXPECT_EQ(r.status, 1);
  expectOnly({});
}
