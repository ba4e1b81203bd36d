// NRRD placement and frames: headers written here with rotated, flipped and sheared `space directions`, every
// `space`, `spacings` without a space, and 4-D volumes with the frame axis first or last. The truth is the
// header's own numbers: grid point ijk must sit at `space origin` + sum_a ijk[a] * (direction vector a), and
// origin + direction * (spacing . ijk) of the geometry must equal it. teem's `unu` (teem-apps), when
// installed, writes the same placements as an independent writer.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <sstream>

#include "cip/readers/nrrd_reader.h"
#include "cip/readers/volume_reader.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::expectError;

std::string vec(const Vec3& v) {
  std::ostringstream s;
  s.precision(17);
  s << "(" << v[0] << "," << v[1] << "," << v[2] << ")";
  return s.str();
}

/// A uint8 volume of `dims` with value i + 7j + 31k (mod 256), raw.
std::string ramp(const std::array<std::int64_t, 3>& dims, int frame = 0) {
  std::string bytes;
  for (std::int64_t k = 0; k < dims[2]; ++k)
    for (std::int64_t j = 0; j < dims[1]; ++j)
      for (std::int64_t i = 0; i < dims[0]; ++i)
        bytes += static_cast<char>((i + 7 * j + 31 * k + 50 * frame) & 0xff);
  return bytes;
}

/// Every grid point's world position against origin + columns * ijk.
void expectPlacement(const GridGeometry& g, const Vec3& origin, const Mat3& columns) {
  for (std::int64_t k = 0; k < g.dims[2]; ++k)
    for (std::int64_t j = 0; j < g.dims[1]; ++j)
      for (std::int64_t i = 0; i < g.dims[0]; ++i) {
        const Vec3 ijk(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k));
        const Vec3 expected =
            origin + ijk[0] * columns.col(0) + ijk[1] * columns.col(1) + ijk[2] * columns.col(2);
        const Vec3 world = g.origin + g.direction * g.spacing.cwiseProduct(ijk);
        ASSERT_LT((world - expected).norm(), 1e-9 * (1 + expected.norm())) << i << " " << j << " " << k;
      }
  for (int a = 0; a < 3; ++a) {
    EXPECT_NEAR(g.direction.col(a).norm(), 1, 1e-12);
    EXPECT_GT(g.spacing[a], 0);
  }
}

void expectRamp(const DenseGrid& g, int frame = 0) {
  const std::string bytes = ramp(g.geometry.dims, frame);
  ASSERT_EQ(g.values.size(), bytes.size());
  for (std::size_t n = 0; n < bytes.size(); ++n)
    ASSERT_EQ(g.values[n], static_cast<unsigned char>(bytes[n])) << n;
}

struct Placement {
  const char* name;
  Mat3 columns;  ///< index-to-world columns as written in `space directions`
};

std::vector<Placement> placements() {
  Mat3 rotated = Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()).toRotationMatrix() *
                 Vec3(0.5, 1.5, 2.0).asDiagonal();
  Mat3 flipped;
  flipped << -0.9, 0, 0, 0, 1.1, 0, 0, 0, -2.5;  // columns (-0.9,0,0) (0,1.1,0) (0,0,-2.5)
  Mat3 permuted;
  permuted << 0, 0, 1.2, 0.8, 0, 0, 0, -0.6, 0;  // index x runs along world y, y along -z, z along x
  Mat3 sheared;
  sheared << 1, 0, 0.3, 0, 1, -0.4, 0, 0, 2;  // gantry-tilt like: the slice step leans
  return {{"rotated", rotated}, {"flipped", flipped}, {"permuted", permuted}, {"sheared", sheared}};
}

TEST(NrrdPlacement, SpaceDirectionsRotatedFlippedSheared) {
  test::ScratchDir dir;
  const Vec3 origin(-12.5, 7.25, 101);
  const std::array<std::int64_t, 3> dims{4, 3, 5};
  for (const auto& p : placements()) {
    const std::string header =
        "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 4 3 5\nspace: LPS\n"
        "space directions: " +
        vec(p.columns.col(0)) + " " + vec(p.columns.col(1)) + " " + vec(p.columns.col(2)) +
        "\nspace origin: " + vec(origin) + "\nencoding: raw\n\n";
    test::writeAll(dir.file("p.nrrd"), header + ramp(dims));
    const DenseGrid g = readNrrd(dir.file("p.nrrd"));
    SCOPED_TRACE(p.name);
    expectPlacement(g.geometry, origin, p.columns);
    EXPECT_NEAR(g.geometry.direction.determinant(),
                p.columns.determinant() / p.columns.colwise().norm().prod(), 1e-12);
    EXPECT_EQ(g.geometry.space, WorldSpace::LPS);
    expectRamp(g);
  }
}

TEST(NrrdPlacement, SpaceNames) {
  const struct {
    const char* name;
    WorldSpace space;
  } cases[] = {{"right-anterior-superior", WorldSpace::RAS}, {"RAS", WorldSpace::RAS},
               {"left-anterior-superior", WorldSpace::LAS},  {"LAS", WorldSpace::LAS},
               {"left-posterior-superior", WorldSpace::LPS}, {"LPS", WorldSpace::LPS},
               {"scanner-xyz", WorldSpace::Unspecified},     {"3D-right-handed", WorldSpace::Unspecified},
               {"3D-left-handed", WorldSpace::Unspecified},  {"my-own-frame", WorldSpace::Unspecified}};
  const std::string head = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: x\n";
  for (const auto& c : cases) {
    const NrrdHeader h =
        parseNrrdHeader(head + "space: " + c.name + "\nspace directions: (0,2,0) (1,0,0) (0,0,1)\n");
    EXPECT_EQ(h.space, c.space) << c.name;
    EXPECT_EQ(h.spacing, Vec3(2, 1, 1));
  }
  EXPECT_EQ(parseNrrdHeader(head + "space dimension: 3\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n").space,
            WorldSpace::Unspecified);
  expectError([&] { parseNrrdHeader(head + "space: RAST\n"); }, {"line 7", "RAST", "4 dimensions"});
  expectError([&] { parseNrrdHeader(head + "space: scanner-xyz-time\n"); }, {"4 dimensions"});
  expectError([&] { parseNrrdHeader(head + "space dimension: 2\n"); }, {"space dimension 2"});
}

TEST(NrrdPlacement, SpacingsWithoutSpaceAreAxisAligned) {
  NrrdHeader h = parseNrrdHeader(
      "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nspacings: 0.5 -2 nan\nencoding: raw\ndata file: "
      "x\n");
  EXPECT_EQ(h.spacing, Vec3(0.5, 2, 1));
  Mat3 flip = Vec3(1, -1, 1).asDiagonal();
  EXPECT_EQ(h.direction, flip);
  EXPECT_EQ(h.origin, Vec3::Zero());
  EXPECT_EQ(h.space, WorldSpace::Unspecified);
}

TEST(NrrdPlacement, HostileDirections) {
  const std::string head = "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 2 2 2\nencoding: raw\ndata file: x\n";
  auto bad = [&](const std::string& dirs, std::vector<std::string> parts) {
    expectError([&] { parseNrrdHeader(head + "space directions: " + dirs + "\n"); }, parts);
  };
  bad("(1,0,0) (2,0,0) (0,0,1)", {"line 7", "space directions", "singular"});
  bad("(1,1,0) (0,1,1) (1,2,1)", {"line 7", "singular"});
  bad("(1,0,0) (0,0,0) (0,0,1)", {"line 7", "axis 1"});
  bad("(1,0,0) (0,nan,0) (0,0,1)", {"line 7", "not finite"});
  bad("(1,0,0) (0,inf,0) (0,0,1)", {"line 7", "not finite"});
  bad("(1,0,0) (0,1,0) (1,1,1e-8)", {"line 7", "singular"});
  bad("(1,0,0) none (0,0,1)", {"spatial axis 1 is 'none'"});
  expectError([&] { parseNrrdHeader(head + "space origin: (0,nan,0)\n"); }, {"space origin", "finite"});
}

/// A 4-D header and its data: `frames` ramps of dims 3x2x4, the frame axis first or last.
std::string fourD(bool framesFirst, int frames, const std::string& axisInfo) {
  const std::array<std::int64_t, 3> dims{3, 2, 4};
  std::string sizes = framesFirst ? std::to_string(frames) + " 3 2 4" : "3 2 4 " + std::to_string(frames);
  std::string data;
  if (framesFirst) {
    std::vector<std::string> f;
    for (int t = 0; t < frames; ++t) f.push_back(ramp(dims, t));
    for (std::size_t n = 0; n < f[0].size(); ++n)
      for (int t = 0; t < frames; ++t) data += f[static_cast<std::size_t>(t)][n];
  } else {
    for (int t = 0; t < frames; ++t) data += ramp(dims, t);
  }
  return "NRRD0005\ntype: uchar\ndimension: 4\nsizes: " + sizes + "\n" + axisInfo + "encoding: raw\n\n" +
         data;
}

TEST(NrrdFrames, FourDFrameAxisFirstOrLast) {
  test::ScratchDir dir;
  const Vec3 origin(1, 2, 3);
  Mat3 columns;
  columns << 0, 2, 0, 1.5, 0, 0, 0, 0, -1;
  const std::string dirsLast = "space: RAS\nspace directions: " + vec(columns.col(0)) + " " +
                               vec(columns.col(1)) + " " + vec(columns.col(2)) +
                               " none\nspace origin: " + vec(origin) + "\n";
  const std::string dirsFirst = "space: RAS\nspace directions: none " + vec(columns.col(0)) + " " +
                                vec(columns.col(1)) + " " + vec(columns.col(2)) +
                                "\nspace origin: " + vec(origin) + "\n";
  const struct {
    const char* name;
    bool first;
    std::string info;
  } cases[] = {{"time last by kinds", false, "kinds: domain domain domain time\n"},
               {"list first by kinds", true, "kinds: list domain domain domain\n"},
               {"none last", false, dirsLast},
               {"none first", true, dirsFirst}};
  for (const auto& c : cases) {
    SCOPED_TRACE(c.name);
    test::writeAll(dir.file("f.nrrd"), fourD(c.first, 5, c.info));
    for (int frame : {0, 3, 4}) {
      const DenseGrid g = readNrrd(dir.file("f.nrrd"), {DenseGrid::defaultMaxBytes(), frame});
      EXPECT_EQ(g.geometry.dims, (std::array<std::int64_t, 3>{3, 2, 4}));
      expectRamp(g, frame);
      if (c.info.find("space") != std::string::npos) {
        expectPlacement(g.geometry, origin, columns);
        EXPECT_EQ(g.geometry.space, WorldSpace::RAS);
      }
      EXPECT_NE(g.description.find("frame " + std::to_string(frame) + " of 5"), std::string::npos);
    }
    expectError([&] { readNrrd(dir.file("f.nrrd")); }, {"f.nrrd", "holds 5 frames", "0..4"});
    expectError(
        [&] {
          readNrrd(dir.file("f.nrrd"), {DenseGrid::defaultMaxBytes(), 5});
        },
        {"f.nrrd", "frame 5 is out of range", "5 frames"});
    VolumeReadOptions options;
    options.frame = 2;
    expectRamp(*readVolume(dir.file("f.nrrd"), options).dense(), 2);
  }
  // A 3-D volume holds one frame.
  test::writeAll(dir.file("3.nrrd"),
                 "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 3 2 4\nencoding: raw\n\n" + ramp({3, 2, 4}));
  expectRamp(readNrrd(dir.file("3.nrrd"), {DenseGrid::defaultMaxBytes(), 0}));
  expectError(
      [&] {
        readNrrd(dir.file("3.nrrd"), {DenseGrid::defaultMaxBytes(), 1});
      },
      {"3.nrrd", "frame 1 is out of range", "1 frame"});
}

TEST(NrrdFrames, AmbiguousFourD) {
  const std::string head = "NRRD0004\ntype: uchar\ndimension: 4\nsizes: 3 4 5 6\n";
  const std::string tail = "encoding: raw\ndata file: x\n";
  expectError([&] { parseNrrdHeader(head + tail); }, {"line 4", "3x4x5x6", "not spatial"});
  expectError([&] { parseNrrdHeader(head + "kinds: domain time domain domain\n" + tail); },
              {"line 5", "axis 1", "first or the last"});
  expectError([&] { parseNrrdHeader(head + "kinds: list domain domain time\n" + tail); },
              {"exactly one non-spatial axis", "gives 2"});
  NrrdHeader h = parseNrrdHeader("NRRD0004\ntype: uchar\ndimension: 4\nsizes: 3 4 5 1\n" + tail);
  EXPECT_EQ(h.dims, (std::array<std::int64_t, 3>{3, 4, 5}));
  EXPECT_EQ(h.frames, 1);
}

/// Runs a command; true on success.
bool run(const std::string& command) {
  return std::system((command + " >/dev/null 2>&1").c_str()) == 0;
}

TEST(NrrdPlacement, TeemWrittenFiles) {
  const std::string unu = "/usr/bin/teem-unu";
  if (!std::filesystem::exists(unu)) GTEST_SKIP() << "teem-apps (teem-unu) is not installed";
  test::ScratchDir dir;
  const std::array<std::int64_t, 3> dims{4, 3, 5};
  test::writeAll(dir.file("in.raw"), ramp(dims));
  const Vec3 origin(3.5, -8, 0.25);
  for (const auto& p : placements()) {
    SCOPED_TRACE(p.name);
    for (const char* encoding : {"raw", "gzip", "bzip2", "ascii", "hex"}) {
      SCOPED_TRACE(encoding);
      const std::string dirs =
          vec(p.columns.col(0)) + " " + vec(p.columns.col(1)) + " " + vec(p.columns.col(2));
      ASSERT_TRUE(run(unu + " make -i " + dir.file("in.raw") + " -t uchar -s 4 3 5 -e raw -spc RAS -orig '" +
                      vec(origin) + "' -dirs '" + dirs + "' -o " + dir.file("made.nrrd")));
      ASSERT_TRUE(run(unu + " save -f nrrd -e " + encoding + " -i " + dir.file("made.nrrd") + " -o " +
                      dir.file("t.nrrd")));
      const DenseGrid g = readNrrd(dir.file("t.nrrd"));
      expectPlacement(g.geometry, origin, p.columns);
      EXPECT_EQ(g.geometry.space, WorldSpace::RAS);
      expectRamp(g);
    }
  }
}

}  // namespace
}  // namespace cip
