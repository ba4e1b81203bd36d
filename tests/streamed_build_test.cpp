// Streamed builds: the model built slab by slab from a file (readers/slab_reader.h, model/streamed_build.h)
// is the whole-volume build's byte for byte — on the bundled and shared volumes, for the fitted and paper
// methods, the Auto, monotone, central8 and mask references and a label map, with slabs of one cell and a
// few (many slabs), for 1 and 2 threads — and the extract command's --stream gives the same file, fails
// cleanly on a file cut short, and leaves no output behind.
#include "cip/model/streamed_build.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <vector>

#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/readers/slab_reader.h"
#include "support/command_line.h"
#include "support/model_bytes.h"
#include "support/sanitized_build.h"
#include "support/volume_files.h"

namespace cip {
namespace {

const std::string kExtract = std::string(CIP_BINARY_DIR) + "/extract/extract";

/// The model of `path` built slab by slab, `slabCells` cells per slab, serialised.
std::vector<std::uint8_t> streamedBytes(const std::string& path, const BuildOptions& options,
                                        std::int64_t slabCells, StreamStats* stats = nullptr) {
  const DenseVolumeProbe probe = probeDenseVolume(path);
  EXPECT_TRUE(probe.layout.has_value()) << probe.whyNot;
  SlabReader reader(*probe.layout);
  StreamOptions stream;
  stream.slabCells = slabCells;
  const Model m = buildModelStreamed(
      probe.layout->geometry,
      [&](std::int64_t z0, std::int64_t z1, double* out) { reader.readInto(z0, z1, out); }, options,
      probe.layout->description, stream, stats);
  return test::modelBytes(m);
}

/// Expects the streamed model of `path` to be the whole-volume model, byte for byte, for slabs of the given
/// thicknesses and 1 and 2 threads (2 only under the sanitizers, support/sanitized_build.h); returns the
/// whole model's cell count.
std::size_t expectStreamedEqualsWhole(const std::string& path, BuildOptions options,
                                      const std::vector<std::int64_t>& slabCells) {
  SparseVolume volume = readVolume(path);
  std::size_t cells = 0;
  for (int threads : test::kSanitizedBuild ? std::vector<int>{2} : std::vector<int>{1, 2}) {
    options.threads = threads;
    const Model whole = buildModel(*volume.dense(), options);
    cells = whole.cells.size();
    const std::vector<std::uint8_t> expected = test::modelBytes(whole);
    for (std::int64_t slab : slabCells) {
      StreamStats stats;
      EXPECT_EQ(streamedBytes(path, options, slab, &stats), expected)
          << path << ": slabs of " << slab << " cells, " << threads << " threads";
      const std::int64_t nz = volume.geometry.dims[2] - 1;
      EXPECT_EQ(stats.slabs, (nz + stats.slabCells - 1) / stats.slabCells);
      if (slab > 0) {
        EXPECT_EQ(stats.slabCells, std::min(slab, nz));
      }
    }
  }
  return cells;
}

BuildOptions optionsFor(double iso, PatchMethod method, Reconstruction reconstruction) {
  BuildOptions o;
  o.isovalue = iso;
  o.method = method;
  o.reconstruction = reconstruction;
  return o;
}

TEST(StreamedBuild, BundledBlobsEveryReference) {
  const std::string blobs = test::sourceFile("data/blobs.nrrd");
  for (Reconstruction r :
       {Reconstruction::Auto, Reconstruction::Monotone, Reconstruction::Central8, Reconstruction::Mask}) {
    // Under the sanitizers the references other than Auto take slabs of one cell only (the most slabs, and
    // the halo of their reach spanning several); Auto still takes the thicker and the chosen ones.
    const std::vector<std::int64_t> slabs = test::kSanitizedBuild && r != Reconstruction::Auto
                                                ? std::vector<std::int64_t>{1}
                                                : std::vector<std::int64_t>{1, 5, 0};
    EXPECT_GT(expectStreamedEqualsWhole(blobs, optionsFor(128, PatchMethod::Fitted, r), slabs), 500u);
  }
  EXPECT_GT(
      expectStreamedEqualsWhole(blobs, optionsFor(128, PatchMethod::Paper, Reconstruction::Auto), {1, 6}),
      500u);
}

TEST(StreamedBuild, SharedVolumes) {
  struct Case {
    const char* name;
    double iso;
  };
  // The sanitizer run takes the same paths on the smallest of them (support/sanitized_build.h).
  const std::vector<Case> cases =
      test::kSanitizedBuild
          ? std::vector<Case>{{"nucleon.nhdr", 128}}
          : std::vector<Case>{{"tooth.nhdr", 120}, {"headsq.nhdr", 500}, {"nucleon.nhdr", 128}};
  for (const Case& c : cases) {
    const std::string path = test::sharedData(c.name);
    if (!std::filesystem::exists(path)) GTEST_SKIP() << path << " is missing";
    EXPECT_GT(expectStreamedEqualsWhole(path, optionsFor(c.iso, PatchMethod::Fitted, Reconstruction::Auto),
                                        {4, 17}),
              500u);
    EXPECT_GT(
        expectStreamedEqualsWhole(path, optionsFor(c.iso, PatchMethod::Paper, Reconstruction::Auto), {3}),
        500u);
  }
  const std::string headsq = test::sharedData("headsq.nhdr");
  if (test::kSanitizedBuild) return;
  expectStreamedEqualsWhole(headsq, optionsFor(1150, PatchMethod::Fitted, Reconstruction::Monotone), {2});
}

/// A label map of three labels touching each other and the border, as a gzip NRRD.
std::string writeLabelMap(const test::ScratchDir& dir) {
  std::string bytes;
  const int n = 30;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const double x = i - 14.5, y = j - 13.0, z = k - 15.2;
        int label = 0;
        if (x * x + y * y + z * z < 100) label = x > 1.5 ? 2 : 1;
        if (std::abs(z + 9) < 3 && std::abs(x) < 12) label = 3;
        bytes += static_cast<char>(label);
      }
  const std::string path = dir.file("labels.nrrd");
  test::writeAll(path, "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 30 30 30\nencoding: gzip\n\n" +
                           test::gzipBytes(bytes));
  return path;
}

TEST(StreamedBuild, LabelMapAndDetectedMask) {
  test::ScratchDir dir;
  const std::string labels = writeLabelMap(dir);
  // Each label takes the same path; under the sanitizers label 3 alone, which touches the other two and the
  // volume's border.
  for (std::int64_t label :
       test::kSanitizedBuild ? std::vector<std::int64_t>{3} : std::vector<std::int64_t>{1, 2, 3}) {
    BuildOptions o;
    o.label = label;
    EXPECT_GT(expectStreamedEqualsWhole(labels, o, {1, 4}), 100u) << "label " << label;
  }
  // A mask (values 0 and 1) that Auto detects as two-valued: built as the mask's field.
  BuildOptions o = optionsFor(0.5, PatchMethod::Fitted, Reconstruction::Auto);
  FittingStats stats;
  o.fittingStats = &stats;
  test::writeAll(
      dir.file("mask.nrrd"), "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 30 30 30\nencoding: raw\n\n" + [] {
        std::string b;
        for (int n = 0; n < 27000; ++n) {
          const int i = n % 30 - 15, j = n / 30 % 30 - 14, k = n / 900 - 16;
          b += static_cast<char>(i * i + 2 * j * j + k * k < 120 ? 1 : 0);
        }
        return b;
      }());
  expectStreamedEqualsWhole(dir.file("mask.nrrd"), o, {2});
  EXPECT_EQ(stats.reconstruction, Reconstruction::Mask);
}

// Integer samples that climb by a level per voxel (terraces, build_passes.h): Auto raises the isovalue from
// the slabs' own counts as the whole volume does, and the models are the same.
TEST(StreamedBuild, TerracedSamples) {
  test::ScratchDir dir;
  test::writeAll(
      dir.file("terraces.nrrd"),
      "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 30 30 30\nencoding: raw\n\n" + [] {
        std::string b;
        for (int n = 0; n < 27000; ++n) {
          const double i = n % 30 - 14.6, j = n / 30 % 30 - 15.3, k = n / 900 - 14.8;
          b += static_cast<char>(std::lround(128 + 1.3 * (10.2 - std::sqrt(i * i + j * j + k * k))));
        }
        return b;
      }());
  BuildOptions o = optionsFor(128, PatchMethod::Fitted, Reconstruction::Auto);
  FittingStats stats;
  o.fittingStats = &stats;
  expectStreamedEqualsWhole(dir.file("terraces.nrrd"), o, {1, 4});
  EXPECT_EQ(stats.isovalueRaise, 1.0 / 64);
}

TEST(StreamedBuild, ExtractStreamGivesTheSameFile) {
  test::ScratchDir dir;
  const std::string blobs = test::sourceFile("data/blobs.nrrd");
  const std::string base = kExtract + " " + blobs + " --iso 128 -q";
  ASSERT_EQ(test::run(base + " --stream off -o " + dir.file("whole.cip")).status, 0);
  const test::CommandResult r = test::run(base + " --stream on --slab-cells 3 -o " + dir.file("slabs.cip") +
                                          " --stats-json " + dir.file("s.json"));
  ASSERT_EQ(r.status, 0) << r.err;
  EXPECT_EQ(test::slurp(dir.file("whole.cip")), test::slurp(dir.file("slabs.cip")));
  const auto stats = nlohmann::json::parse(test::slurp(dir.file("s.json")));
  EXPECT_TRUE(stats["stream"]["streamed"].get<bool>());
  EXPECT_EQ(stats["stream"]["slab_cells"].get<int>(), 3);
  EXPECT_EQ(stats["stream"]["slabs"].get<int>(), 16);  // 47 cells along z
  EXPECT_GT(stats["peak_rss_bytes"].get<double>(), 0);
  // A label of a label map, and --labels, streamed.
  const std::string labels = writeLabelMap(dir);
  for (const char* mode : {"off", "on"})
    ASSERT_EQ(test::run(kExtract + " " + labels + " -q --labels --stream " + mode + " --slab-cells 2 -o " +
                        dir.file(std::string(mode) + ".cip"))
                  .status,
              0);
  for (int label : {1, 2, 3})
    EXPECT_EQ(test::slurp(dir.file("off-label" + std::to_string(label) + ".cip")),
              test::slurp(dir.file("on-label" + std::to_string(label) + ".cip")))
        << "label " << label;
  // What cannot be streamed says why when asked for.
  // (The sanitizer run samples the sphere at N = 16 instead of the default 64: the check is that it runs.)
  const test::CommandResult ascii = test::run(kExtract + " sphere --stream on -o " + dir.file("x.cip") +
                                              (test::kSanitizedBuild ? " --resolution 16" : ""));
  EXPECT_EQ(ascii.status, 0) << "analytic fields are sampled, never read: --stream does not apply";
}

TEST(StreamedBuild, TruncatedFileFailsWithoutOutput) {
  test::ScratchDir dir;
  std::string bytes(40 * 40 * 40, '\0');
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    const double i = double(n % 40) - 20, j = double(n / 40 % 40) - 20, k = double(n / 1600) - 20;
    bytes[n] = static_cast<char>(std::min(255.0, 4 * std::sqrt(i * i + j * j + k * k)));
  }
  const std::string gz = test::gzipBytes(bytes);
  test::writeAll(dir.file("cut.nrrd"),
                 "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 40 40 40\nencoding: gzip\n\n" +
                     gz.substr(0, gz.size() * 2 / 3));
  const std::string out = dir.file("m.cip");
  const test::CommandResult r =
      test::run(kExtract + " " + dir.file("cut.nrrd") + " --iso 60 --stream on --slab-cells 4 -q -o " + out);
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find(dir.file("cut.nrrd")), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("truncated"), std::string::npos) << r.err;
  EXPECT_FALSE(std::filesystem::exists(out));
  // A raw file shorter than its dims say is refused before any slab is read, naming the shortfall.
  test::writeAll(dir.file("short.raw"), bytes.substr(0, bytes.size() - 100));
  const test::CommandResult raw =
      test::run(kExtract + " " + dir.file("short.raw") +
                " --dims 40,40,40 --type uint8 --iso 60 --stream on -q -o " + out);
  EXPECT_NE(raw.status, 0);
  EXPECT_NE(raw.err.find("100 bytes short"), std::string::npos) << raw.err;
  EXPECT_FALSE(std::filesystem::exists(out));
}

TEST(StreamedBuild, StreamOnRefusesWhatItCannotStream) {
  test::ScratchDir dir;
  test::writeAll(dir.file("a.nrrd"),
                 "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: ascii\n\n0 0 0 0 9 9 9 9\n");
  const test::CommandResult r =
      test::run(kExtract + " " + dir.file("a.nrrd") + " --iso 1 --stream on -q -o " + dir.file("m.cip"));
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.err.find("ascii"), std::string::npos) << r.err;
  EXPECT_EQ(test::run(kExtract + " " + dir.file("a.nrrd") + " --iso 1 -q -o " + dir.file("m.cip")).status, 0);
  EXPECT_NE(whyNotStreamed([] {
              BuildOptions o;
              o.method = PatchMethod::Paper;
              o.central = CentralRule::Interior;
              return o;
            }()),
            "");
}

// A budget that holds two slices: slabs still own at least half as many cells as their halo has slices, so
// that they do not recompute the reference on the halo and move the shared slices for every cell; the
// model is the whole volume's.
TEST(StreamedBuild, WideSlicesKeepSlabsAsThickAsHalfTheirHalo) {
  const std::string path = test::sourceFile("data/blobs.nrrd");  // 48^3, central8: a halo of 4 slices
  const DenseVolumeProbe probe = probeDenseVolume(path);
  ASSERT_TRUE(probe.layout.has_value()) << probe.whyNot;
  SlabReader reader(*probe.layout);
  StreamOptions stream;
  stream.slabBytes = 2 * 48 * 48 * sizeof(double);
  StreamStats stats;
  BuildOptions options;
  options.isovalue = 128;
  const Model m = buildModelStreamed(
      probe.layout->geometry,
      [&](std::int64_t z0, std::int64_t z1, double* out) { reader.readInto(z0, z1, out); }, options,
      probe.layout->description, stream, &stats);
  EXPECT_EQ(stats.halo, 4);
  EXPECT_EQ(stats.slabCells, 4);  // (2 * 4 + 1) / 2
  EXPECT_EQ(test::modelBytes(m), test::modelBytes(buildModel(*readVolume(path).dense(), options)));
}

// The range of the samples that extract warns with when the isovalue lies outside it: a streamed build sees
// each slice several times (the slabs' halos, two passes) and counts each once, but none less; NaN and
// infinite samples stay out of it. The whole read warns with the same range.
TEST(StreamedBuild, RangeWarningCoversEverySlice) {
  test::ScratchDir dir;
  constexpr int n = 12;
  std::vector<float> v(n * n * n);
  for (int i = 0; i < n * n * n; ++i) v[static_cast<std::size_t>(i)] = static_cast<float>(i % 97) * 0.5f;
  v.front() = -3.25f;                                          // the smallest, in the first slice
  v.back() = 77.5f;                                            // the largest, in the last
  v[5 * n * n + 7] = std::numeric_limits<float>::quiet_NaN();  // not finite: left out
  v[8 * n * n + 3] = std::numeric_limits<float>::infinity();   // likewise
  v[9 * n * n + 4] = -std::numeric_limits<float>::infinity();
  test::writeAll(dir.file("v.nrrd"),
                 "NRRD0004\ntype: float\ndimension: 3\nsizes: 12 12 12\nencoding: raw\n"
                 "endian: little\n\n" +
                     std::string(reinterpret_cast<const char*>(v.data()), v.size() * 4));
  for (const char* mode : {"on --slab-cells 2", "off"}) {
    const test::CommandResult r =
        test::run(kExtract + " " + dir.file("v.nrrd") + " --iso 100 --skip-nonfinite -q -o " +
                  dir.file("v.cip") + " --stream " + mode);
    ASSERT_EQ(r.status, 0) << r.err;
    EXPECT_NE(r.err.find("isovalue 100 is outside the data range [-3.25, 77.5]"), std::string::npos)
        << mode << ": " << r.err;
  }
}

}  // namespace
}  // namespace cip
