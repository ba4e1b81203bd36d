// NIfTI files against nibabel, an independent reader: nibabel's own test files (anatomical.nii, example4d,
// NIfTI-2, header-only .hdr) and files written by nibabel with rotated, flipped (qfac -1), sheared,
// sform-only, qform-only, scaled, 4-D, NIfTI-2, big-endian and .hdr/.img forms
// (tests/support/nibabel_files.py). For each, nibabel's img.affine applied to indices equals cip's origin +
// direction * (spacing * index) to 1e-9 and the samples equal nibabel's get_fdata(). Skipped when
// python3-nibabel is not installed.
#include <gtest/gtest.h>

#include <cmath>
#include <set>

#include "cip/readers/metaimage_reader.h"
#include "cip/readers/nifti_reader.h"
#include "cip/readers/volume_reader.h"
#include "support/python_truth.h"
#include "support/volume_files.h"

namespace cip {
namespace {

TEST(NiftiNibabel, PlacementAndSamplesEqualNibabels) {
  test::ScratchDir dir;
  auto cases = test::runTruthScript(test::sourceFile("tests/support/nibabel_files.py"), dir.path());
  if (!cases) GTEST_SKIP() << "python3-nibabel is not installed";
  std::set<std::string> kinds;
  std::size_t withData = 0;
  for (const auto& c : *cases) {
    SCOPED_TRACE(c.path + " frame " + std::to_string(c.frame));
    kinds.insert(c.kind);
    if (c.truth == "-") {
      // A header shipped without its .img: the placement alone.
      NiftiHeader h = readNiftiHeader(c.path);
      EXPECT_EQ(h.geometry.dims, c.dims);
      EXPECT_EQ(h.geometry.space, WorldSpace::RAS);
      test::expectSamePlacement(h.geometry, c.affine, c.path);
      continue;
    }
    DenseGrid g = c.kind == "lps" ? readMetaImage(c.path, DenseGrid::defaultMaxBytes(), c.frame)
                                  : readNifti(c.path, DenseGrid::defaultMaxBytes(), c.frame);
    EXPECT_EQ(g.geometry.dims, c.dims);
    test::expectSamePlacement(g.geometry, c.affine, c.path);
    const WorldSpace space = c.kind == "affine" ? WorldSpace::RAS
                             : c.kind == "lps"  ? WorldSpace::LPS
                                                : WorldSpace::Unspecified;
    EXPECT_EQ(g.geometry.space, space);
    const std::vector<double> truth = test::readTruthSamples(c.truth);
    ASSERT_EQ(g.values.size(), truth.size());
    std::size_t wrong = 0;
    for (std::size_t n = 0; n < truth.size(); ++n)
      if (!(std::abs(g.values[n] - truth[n]) <= 1e-9 * (1 + std::abs(truth[n]))) &&
          !(std::isnan(g.values[n]) && std::isnan(truth[n])))
        ++wrong;
    EXPECT_EQ(wrong, 0u) << "samples differ from nibabel's get_fdata()";
    ++withData;
    // The dispatcher picks the same reader from the name and passes the frame.
    VolumeReadOptions options;
    options.frame = c.frame;
    EXPECT_EQ(readVolume(c.path, options).geometry.direction, g.geometry.direction);
  }
  EXPECT_EQ(kinds, (std::set<std::string>{"affine", "pixdim", "lps"}));
  EXPECT_GE(withData, 25u);
}

TEST(NiftiNibabel, FourDimensionalFilesNeedAFrame) {
  test::ScratchDir dir;
  auto cases = test::runTruthScript(test::sourceFile("tests/support/nibabel_files.py"), dir.path());
  if (!cases) GTEST_SKIP() << "python3-nibabel is not installed";
  for (const auto& c : *cases) {
    if (c.frame < 0) continue;
    test::expectError([&] { readNifti(c.path); }, {c.path, "frames", "--frame"});
    test::expectError([&] { readNifti(c.path, DenseGrid::defaultMaxBytes(), 1000); },
                      {c.path, "frame 1000 is out of range"});
  }
}

}  // namespace
}  // namespace cip
