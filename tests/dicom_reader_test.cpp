// DICOM series reader: series written here slice by slice (support/dicom_files.h, independent of GDCM) with
// an oblique orientation, a gantry-tilt shear, shuffled file names and a rescale; the placement is checked
// against the DICOM formula position_k + i * PixelSpacing[1] * row + j * PixelSpacing[0] * column, and the
// values against the stored pixels; pydicom reads the same series (also RLE-compressed) independently. Then
// the hostile series.
#include "cip/readers/dicom_reader.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <numeric>
#include <random>
#include <sstream>

#include "cip/readers/volume_reader.h"
#include "support/dicom_files.h"
#include "support/volume_files.h"

namespace cip {
namespace {

using test::dicomNumber;
using test::DicomSlice;
using test::DicomWriter;
using test::expectError;

/// The stored pixel of column i, row j on slice k.
std::int16_t stored(int i, int j, int k) {
  return static_cast<std::int16_t>(37 * i - 11 * j + 300 * k - 500);
}

/// A series of `count` slices: slice k at origin + k * step, pixels stored(i, j, k).
struct Series {
  std::array<double, 6> orientation{1, 0, 0, 0, 1, 0};
  std::array<double, 3> origin{0, 0, 0};
  Vec3 step{0, 0, 1};
  std::array<double, 2> pixelSpacing{0.7, 0.45};
  int rows = 4, columns = 5, count = 6;
  double slope = 1, intercept = 0;

  DicomSlice slice(int k) const {
    DicomSlice s;
    s.orientation = orientation;
    for (int a = 0; a < 3; ++a) s.position[a] = origin[a] + k * step[a];
    s.pixelSpacing = pixelSpacing;
    s.rows = rows;
    s.columns = columns;
    s.slope = slope;
    s.intercept = intercept;
    s.instance = k + 1;
    for (int j = 0; j < rows; ++j)
      for (int i = 0; i < columns; ++i) s.pixels.push_back(stored(i, j, k));
    return s;
  }
  /// Writes the slices under names in a shuffled order ("img<n>.dcm"); returns the file of each slice.
  std::vector<std::string> write(const test::ScratchDir& dir, unsigned seed = 7) const {
    std::vector<int> names(static_cast<std::size_t>(count));
    std::iota(names.begin(), names.end(), 100);
    std::shuffle(names.begin(), names.end(), std::mt19937(seed));
    std::vector<std::string> files;
    for (int k = 0; k < count; ++k) {
      files.push_back(dir.file("img" + std::to_string(names[static_cast<std::size_t>(k)]) + ".dcm"));
      DicomWriter::write(files.back(), slice(k));
    }
    return files;
  }
};

/// Unit row and column cosines of a rotation by the given angles (radians) about x, y and z.
std::array<double, 6> obliqueOrientation(double ax, double ay, double az) {
  Mat3 r = (Eigen::AngleAxisd(az, Vec3::UnitZ()) * Eigen::AngleAxisd(ay, Vec3::UnitY()) *
            Eigen::AngleAxisd(ax, Vec3::UnitX()))
               .toRotationMatrix();
  return {r(0, 0), r(1, 0), r(2, 0), r(0, 1), r(1, 1), r(2, 1)};
}

/// Every grid point's world position (origin + direction * (spacing . ijk)) against the DICOM formula for
/// the positions as written, and every value against the stored pixel rescaled.
void expectSeries(const DenseGrid& g, const Series& s) {
  ASSERT_EQ(g.geometry.dims, (std::array<std::int64_t, 3>{s.columns, s.rows, s.count}));
  EXPECT_EQ(g.geometry.space, WorldSpace::LPS);
  Vec3 row, column;
  for (int a = 0; a < 3; ++a) {
    row[a] = dicomNumber(s.orientation[a]);
    column[a] = dicomNumber(s.orientation[a + 3]);
  }
  const double di = dicomNumber(s.pixelSpacing[1]), dj = dicomNumber(s.pixelSpacing[0]);
  for (int k = 0; k < s.count; ++k) {
    const DicomSlice slice = s.slice(k);
    const Vec3 position(dicomNumber(slice.position[0]), dicomNumber(slice.position[1]),
                        dicomNumber(slice.position[2]));
    for (int j = 0; j < s.rows; ++j)
      for (int i = 0; i < s.columns; ++i) {
        const Vec3 expected = position + i * di * row + j * dj * column;
        const Vec3 ijk(i, j, k);
        const Vec3 world = g.geometry.origin + g.geometry.direction * g.geometry.spacing.cwiseProduct(ijk);
        EXPECT_LT((world - expected).norm(), 1e-6) << i << " " << j << " " << k;
        EXPECT_NEAR(g.at(i, j, k), stored(i, j, k) * dicomNumber(s.slope) + dicomNumber(s.intercept), 1e-9);
      }
  }
}

TEST(DicomReader, ObliqueShuffledRescaledSeries) {
  test::ScratchDir dir;
  Series s;
  s.orientation = obliqueOrientation(0.3, -0.5, 1.1);
  s.origin = {-120.25, 33.5, 410.75};
  const Vec3 row(s.orientation[0], s.orientation[1], s.orientation[2]);
  const Vec3 column(s.orientation[3], s.orientation[4], s.orientation[5]);
  s.step = 1.25 * row.cross(column);
  s.slope = 0.5;
  s.intercept = -1024;
  s.write(dir);
  const DenseGrid g = readDicom(dir.path());
  expectSeries(g, s);
  EXPECT_NEAR(g.geometry.spacing[2], 1.25, 1e-6);
  EXPECT_NEAR(std::abs(g.geometry.direction.determinant()), 1, 1e-6);
  EXPECT_NE(g.description.find("DICOM int16 5x4x6"), std::string::npos) << g.description;
}

TEST(DicomReader, GantryTiltIsAShear) {
  test::ScratchDir dir;
  Series s;
  s.origin = {10, -20, 30};
  s.step = Vec3(0, 0.4, 2.0);  // the slices move along y too: the third axis is not the normal
  s.write(dir, 3);
  const DenseGrid g = readDicom(dir.path());
  expectSeries(g, s);
  EXPECT_GT(std::abs(g.geometry.direction.col(2).dot(Vec3::UnitY())), 0.1);
}

TEST(DicomReader, ReversedSliceOrderAndReadVolume) {
  // Positions decreasing with the instance number: the reader sorts along the normal, so the first slice
  // is the one with the smallest position along it.
  test::ScratchDir dir;
  Series s;
  s.origin = {0, 0, 50};
  s.step = Vec3(0, 0, -2.5);
  s.write(dir);
  const DenseGrid g = readDicom(dir.path());
  EXPECT_NEAR(g.geometry.origin.z(), 50 - 2.5 * (s.count - 1), 1e-9);
  EXPECT_NEAR(g.geometry.spacing.z(), 2.5, 1e-9);
  // Slice 0 of the grid holds the pixels of the last slice written.
  EXPECT_EQ(g.at(1, 2, 0), stored(1, 2, s.count - 1));
  EXPECT_EQ(volumeFormatOf(dir.path()), VolumeFormat::Dicom);
  const SparseVolume v = readVolume(dir.path());
  EXPECT_EQ(v.dense()->values, g.values);
  EXPECT_EQ(v.geometry.direction, g.geometry.direction);
}

TEST(DicomReader, SeveralSeriesTakeTheLargest) {
  test::ScratchDir dir;
  Series big;
  big.write(dir);
  DicomSlice other = big.slice(0);
  other.series = "1.2.826.0.1.3680043.2.1125.77";
  other.orientation = {0, 1, 0, 0, 0, -1};  // a localizer of another orientation
  DicomWriter::write(dir.file("localizer.dcm"), other);
  const DenseGrid g = readDicom(dir.path());
  expectSeries(g, big);
  EXPECT_NE(g.description.find("largest of 2 series"), std::string::npos) << g.description;
}

TEST(DicomReader, SingleSliceFileAndSkippedOtherFiles) {
  test::ScratchDir dir;
  Series s;
  s.count = 1;
  const auto files = s.write(dir);
  test::writeAll(dir.file("README.txt"), "not an image\n");
  expectSeries(readDicom(dir.path()), s);
  expectSeries(readDicom(files[0]), s);
  EXPECT_EQ(volumeFormatOf(files[0]), VolumeFormat::Dicom);
}

TEST(DicomReader, HostileSeries) {
  {
    test::ScratchDir dir;
    Series s;
    s.count = 8;
    auto files = s.write(dir);
    std::filesystem::remove(files[4]);
    expectError([&] { readDicom(dir.path()); }, {dir.path(), "irregular slice spacing", "missing slice"});
  }
  {
    test::ScratchDir dir;
    Series s;
    s.write(dir);
    Series wide = s;
    wide.columns = 6;
    DicomWriter::write(dir.file("wide.dcm"), wide.slice(s.count));
    expectError([&] { readDicom(dir.path()); }, {dir.path(), "mixed sizes", "wide.dcm"});
  }
  {
    test::ScratchDir dir;
    Series s;
    s.write(dir);
    Series turned = s;
    turned.orientation = obliqueOrientation(0.01, 0, 0);
    DicomWriter::write(dir.file("turned.dcm"), turned.slice(s.count));
    expectError([&] { readDicom(dir.path()); }, {dir.path(), "mixed orientations", "turned.dcm"});
  }
  {
    test::ScratchDir dir;
    Series s;
    s.write(dir);
    DicomWriter::write(dir.file("twin.dcm"), s.slice(2));
    expectError([&] { readDicom(dir.path()); }, {dir.path(), "same position"});
  }
  {
    test::ScratchDir dir;
    expectError([&] { readDicom(dir.path()); }, {dir.path(), "no DICOM image file"});
    test::writeAll(dir.file("notes.txt"), "hello\n");
    expectError([&] { readDicom(dir.path()); }, {dir.path(), "no DICOM image file", "1 files"});
    expectError([&] { readDicom(dir.file("notes.txt")); }, {"notes.txt", "not a DICOM image file"});
    expectError([&] { readDicom(dir.file("missing.dcm")); }, {"missing.dcm", "cannot open"});
  }
  {
    test::ScratchDir dir;
    Series s;
    const std::string bytes = DicomWriter::file(s.slice(0));
    test::writeAll(dir.file("cut.dcm"), bytes.substr(0, 200));
    expectError([&] { readDicom(dir.path()); }, {"cut.dcm"});
    test::writeAll(dir.file("cut.dcm"), bytes.substr(0, bytes.size() - 10));
    expectError([&] { readDicom(dir.path()); }, {"cut.dcm"});
  }
}

/// pydicom (Debian's python3-pydicom), an independent reader: for each file of the folder, sorted along the
/// normal, the world position of every pixel by the standard's formula and its rescaled value, one
/// "x y z value" line per pixel, row by row. With "rle" it first rewrites every file RLE-compressed.
const char* kPydicomScript = R"(
import glob, sys
import numpy as np
import pydicom
from pydicom.uid import RLELossless
files = glob.glob(sys.argv[1] + "/*.dcm")
if sys.argv[2] == "rle":
    for f in files:
        ds = pydicom.dcmread(f)
        ds.compress(RLELossless)
        ds.save_as(f)
slices = [pydicom.dcmread(f) for f in files]
r = np.array([float(v) for v in slices[0].ImageOrientationPatient[:3]])
c = np.array([float(v) for v in slices[0].ImageOrientationPatient[3:]])
n = np.cross(r, c)
slices.sort(key=lambda s: float(np.dot(n, [float(v) for v in s.ImagePositionPatient])))
for s in slices:
    p = np.array([float(v) for v in s.ImagePositionPatient])
    dj, di = (float(v) for v in s.PixelSpacing)
    values = s.pixel_array * float(s.RescaleSlope) + float(s.RescaleIntercept)
    for j in range(s.Rows):
        for i in range(s.Columns):
            x = p + i * di * r + j * dj * c
            print("%.17g %.17g %.17g %.17g" % (x[0], x[1], x[2], values[j, i]))
)";

TEST(DicomReader, AgreesWithPydicomUncompressedAndRle) {
  if (std::system("/usr/bin/python3 -c 'import pydicom' >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "python3-pydicom is not installed";
  }
  Series s;
  s.orientation = obliqueOrientation(-0.4, 0.9, 0.2);
  s.origin = {5.5, -300.125, 12};
  s.step = Vec3(0.1, -0.2, 3.0);
  s.slope = 2.5;
  s.intercept = 7;
  for (const std::string mode : {"plain", "rle"}) {
    SCOPED_TRACE(mode);
    test::ScratchDir dir;
    std::filesystem::create_directory(dir.file("series"));
    for (int k = 0; k < s.count; ++k)
      DicomWriter::write(dir.file("series/s" + std::to_string((k * 5) % s.count) + ".dcm"), s.slice(k));
    test::writeAll(dir.file("read.py"), kPydicomScript);
    const std::string out = dir.file("pydicom.txt");
    ASSERT_EQ(std::system(("/usr/bin/python3 " + dir.file("read.py") + " " + dir.file("series") + " " + mode +
                           " > " + out)
                              .c_str()),
              0);
    const bool rle =
        test::readAll(dir.file("series/s0.dcm")).find("1.2.840.10008.1.2.5") != std::string::npos;
    EXPECT_EQ(rle, mode == "rle");  // the files really are compressed (RLE Lossless transfer syntax)
    std::istringstream lines(test::readAll(out));
    const DenseGrid g = readDicom(dir.file("series"));
    int seen = 0;
    for (int k = 0; k < s.count; ++k)
      for (int j = 0; j < s.rows; ++j)
        for (int i = 0; i < s.columns; ++i) {
          Vec3 x;
          double value = 0;
          ASSERT_TRUE(lines >> x[0] >> x[1] >> x[2] >> value);
          const Vec3 world =
              g.geometry.origin + g.geometry.direction * g.geometry.spacing.cwiseProduct(Vec3(i, j, k));
          EXPECT_LT((world - x).norm(), 1e-6) << i << " " << j << " " << k;
          EXPECT_NEAR(g.at(i, j, k), value, 1e-9);
          EXPECT_NEAR(value, stored(i, j, k) * 2.5 + 7, 1e-9);
          ++seen;
        }
    EXPECT_EQ(seen, s.columns * s.rows * s.count);
  }
}

/// Runs the reader on `path`; returns "" on success, else the error, which must start with the path.
std::string outcome(const std::string& path) {
  try {
    readDicom(path);
    return "";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()).rfind(path, 0), 0u) << e.what();
    return e.what();
  }
}

TEST(DicomReader, TruncatedAndCorruptFilesFailCleanly) {
  // GDCM aborts on some malformed files; the reader checks the file's structure first. Every truncation of a
  // slice and a thousand random byte changes end in success or a cip::Error, never a crash.
  test::ScratchDir dir;
  Series s;
  const std::string bytes = DicomWriter::file(s.slice(0));
  const std::string file = dir.file("x.dcm");
  int errors = 0;
  for (std::size_t cut = 0; cut < bytes.size(); ++cut) {
    test::writeAll(file, bytes.substr(0, cut));
    errors += !outcome(file).empty();
  }
  EXPECT_EQ(errors, static_cast<int>(bytes.size()));  // no truncated file reads as a volume
  std::mt19937 random(11);
  for (int n = 0; n < 1000; ++n) {
    std::string changed = bytes;
    for (int c = 0; c < 3; ++c)
      changed[128 + random() % (bytes.size() - 128)] = static_cast<char>(random() & 0xff);
    test::writeAll(file, changed);
    outcome(file);
  }
}

}  // namespace
}  // namespace cip
