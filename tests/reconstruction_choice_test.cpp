// Reconstruction::Auto: the spectral estimate of the samples near the surface, and the choice it makes.
#include "cip/reference/reconstruction_choice.h"

#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>

#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/readers/volume_reader.h"
#include "cip/volume/analytic_field.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

DenseGrid sampled(std::int64_t n, const std::function<double(double, double, double)>& f) {
  DenseGrid g;
  g.allocate({n, n, n});
  for (std::int64_t k = 0; k < n; ++k)
    for (std::int64_t j = 0; j < n; ++j)
      for (std::int64_t i = 0; i < n; ++i)
        g.at(i, j, k) = f(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k));
  return g;
}

}  // namespace

// Samples of a sine of wavelength L along x: the estimate is L, whatever the isovalue.
TEST(SamplingEstimate, IsTheWavelengthOfASine) {
  for (double L : {2.5, 3.0, 4.0, 6.0, 12.0}) {
    const DenseGrid g =
        sampled(24, [&](double x, double, double) { return std::sin(2 * M_PI * x / L + 0.3); });
    for (double iso : {0.0, 0.4}) {
      const SamplingEstimate e = estimateSampling(g, iso);
      EXPECT_GT(e.cells, 100);
      EXPECT_NEAR(e.wavelength, L, 1e-6 * L) << "L " << L << " iso " << iso;
    }
  }
  // The same sine along y and z (the axes are summed alike).
  const DenseGrid y = sampled(24, [](double, double yy, double) { return std::sin(2 * M_PI * yy / 5); });
  EXPECT_NEAR(estimateSampling(y, 0.2).wavelength, 5.0, 5e-6);
  const DenseGrid z = sampled(24, [](double, double, double zz) { return std::sin(2 * M_PI * zz / 5); });
  EXPECT_NEAR(estimateSampling(z, 0.2).wavelength, 5.0, 5e-6);
}

// Cubic data have no finest scale (their fourth differences vanish to rounding): infinite wavelength,
// Central8 (which reproduces them). Steps, sharp or spread over a voxel or so, are short: Monotone. A step
// spread over several voxels is smooth at the grid's scale: Central8.
TEST(SamplingEstimate, CubicsAreSmoothStepsAreNot) {
  const DenseGrid cubic = sampled(16, [](double x, double y, double z) {
    return 1000 + 0.01 * x * x * x - 0.2 * x * y + 0.03 * z * z * y - 7 * z;
  });
  SamplingEstimate e = estimateSampling(cubic, 1000 - 40);
  ASSERT_GT(e.cells, 0);
  EXPECT_EQ(e.wavelength, std::numeric_limits<double>::infinity());
  EXPECT_EQ(chooseReconstruction(e), Reconstruction::Central8);

  for (double width : {0.01, 0.5, 0.8, 3.0}) {
    const DenseGrid step = sampled(16, [&](double x, double y, double) {
      return 100 * std::tanh((x + 0.3 * y - 8.2) / width);  // CT-like: bone next to soft tissue
    });
    e = estimateSampling(step, 10);
    ASSERT_GT(e.cells, 0);
    EXPECT_EQ(chooseReconstruction(e), width < 1 ? Reconstruction::Monotone : Reconstruction::Central8)
        << width << ": " << e.wavelength;
  }
  // Nothing crossed: nothing measured, and the safe choice.
  e = estimateSampling(cubic, 1e9);
  EXPECT_EQ(e.cells, 0);
  EXPECT_EQ(chooseReconstruction(e), Reconstruction::Monotone);
}

// A non-finite sample leaves out only the differences that reach it.
TEST(SamplingEstimate, NonFiniteSamplesAreLeftOut) {
  DenseGrid g = sampled(20, [](double x, double, double) { return std::sin(2 * M_PI * x / 6); });
  const double clean = estimateSampling(g, 0.1).wavelength;
  g.at(3, 5, 5) = std::numeric_limits<double>::quiet_NaN();
  g.at(12, 7, 9) = std::numeric_limits<double>::infinity();
  const SamplingEstimate e = estimateSampling(g, 0.1);
  EXPECT_TRUE(std::isfinite(e.sixthToFourth));
  EXPECT_NEAR(e.wavelength, clean, 1e-9);
}

// Auto in buildModel: the model is the one built with the reconstruction it chose, and the fitting stats say
// which and why. Marschner-Lobb at N = 32 aliases (Monotone); the torus at N = 32 is smooth (Central8).
TEST(SamplingEstimate, AutoBuildsWithTheChosenReconstruction) {
  for (auto [name, expected] : {std::pair{"marschner-lobb", Reconstruction::Monotone},
                                std::pair{"torus", Reconstruction::Central8}}) {
    auto field = makeAnalyticField(name);
    const DenseGrid g = sampleField(*field, 32, name);
    BuildOptions o;
    o.isovalue = field->defaultIsovalue();
    ASSERT_EQ(o.reconstruction, Reconstruction::Auto);  // the default
    FittingStats stats;
    o.fittingStats = &stats;
    const Model model = buildModel(g, o);
    const auto automatic = serializeModel(model);
    EXPECT_EQ(stats.reconstruction, expected) << name;
    EXPECT_EQ(model.reconstruction, expected) << name;  // recorded in the model (file) too
    EXPECT_EQ(stats.sampling.cells, estimateSampling(g, o.isovalue).cells) << name;
    EXPECT_NEAR(stats.sampling.wavelength, estimateSampling(g, o.isovalue).wavelength, 1e-9) << name;
    o.reconstruction = expected;
    EXPECT_EQ(automatic, serializeModel(buildModel(g, o))) << name;
    EXPECT_EQ(stats.reconstruction, expected);
    EXPECT_EQ(stats.sampling.cells, 0);  // nothing estimated when the choice is given
    // No reference of the samples, none recorded: the paper's construction, and exact normals.
    o.method = PatchMethod::Paper;
    o.reconstruction = Reconstruction::Auto;
    EXPECT_FALSE(buildModel(g, o).reconstruction.has_value()) << name;
    o.method = PatchMethod::Fitted;
    o.normals = NormalMode::Exact;
    o.exactField = field.get();
    EXPECT_FALSE(buildModel(g, o).reconstruction.has_value()) << name;
  }
}

// What auto picks on the data of docs/method.md, with the margins documented there: central8 on the smooth
// sampled fields (Marschner-Lobb from N = 56 on), monotone on the aliased Marschner-Lobb at N = 32 and on
// every real volume (CT steps, a narrow-band level set). A change of the measure shows here first.
TEST(SamplingEstimate, ChoicesOnTheMeasuredData) {
  struct Field {
    const char* name;
    int n;
    double low, high;  // the documented wavelength, to 1 %
    Reconstruction kind;
  };
  for (const Field& f : {Field{"marschner-lobb", 64, 3.87, 3.95, Reconstruction::Central8},
                         Field{"marschner-lobb", 32, 2.42, 2.47, Reconstruction::Monotone},
                         Field{"torus", 32, 4.53, 4.63, Reconstruction::Central8},
                         Field{"gyroid", 32, 15.8, 16.2, Reconstruction::Central8}}) {
    auto field = makeAnalyticField(f.name);
    const SamplingEstimate e = estimateSampling(sampleField(*field, f.n, f.name), field->defaultIsovalue());
    EXPECT_GT(e.wavelength, f.low) << f.name << " " << f.n;
    EXPECT_LT(e.wavelength, f.high) << f.name << " " << f.n;
    EXPECT_EQ(chooseReconstruction(e), f.kind) << f.name << " " << f.n;
  }
  struct Volume {
    const char* file;
    double iso, low, high;
  };
  for (const Volume& v : {Volume{"headsq.nhdr", 1150, 2.67, 2.73}, Volume{"headsq.nhdr", 500, 2.69, 2.75},
                          Volume{"tooth.nhdr", 120, 2.76, 2.82}, Volume{"nucleon.nhdr", 128, 3.20, 3.28},
                          Volume{"vdb/sphere.vdb", 0, 1.99, 2.01}}) {
    VolumeReadOptions o;
    o.brickCells = 1 << 20;  // one brick: the whole volume
    const SparseVolume volume = readVolume(test::sharedData(v.file), o);
    const SamplingEstimate e = estimateSampling(*volume.bricks[0].grid, v.iso);
    EXPECT_GT(e.wavelength, v.low) << v.file << " " << v.iso;
    EXPECT_LT(e.wavelength, v.high) << v.file << " " << v.iso;
    EXPECT_EQ(chooseReconstruction(e), Reconstruction::Monotone) << v.file;
  }
}
