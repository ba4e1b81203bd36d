// Hostile and degenerate inputs through the command line tools: clear errors, non-zero exits, and outputs
// that are either complete or untouched. (Parser-level cases live beside each reader's tests and in
// tests/fuzz.)
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
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
