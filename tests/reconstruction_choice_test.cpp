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
#include "support/model_bytes.h"
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
    const auto automatic = test::modelBytes(model);
    EXPECT_EQ(stats.reconstruction, expected) << name;
    EXPECT_EQ(model.reconstruction, expected) << name;  // recorded in the model (file) too
    EXPECT_EQ(stats.sampling.cells, estimateSampling(g, o.isovalue).cells) << name;
    EXPECT_NEAR(stats.sampling.wavelength, estimateSampling(g, o.isovalue).wavelength, 1e-9) << name;
    o.reconstruction = expected;
    EXPECT_EQ(automatic, test::modelBytes(buildModel(g, o))) << name;
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

namespace {

/// The effective wavelength from its definition in reconstruction_choice.h, computed here another way (the
/// differences from binomial weights, the cells by their samples' signs): R = sum (D6 s)^2 / sum (D4 s)^2
/// over the lowest corners of crossed cells, along each axis whose 7 samples centred there lie in the grid,
/// and L = pi / asin(R^(1/4) / 2), or 2 (the grid's Nyquist limit) from R = 16 on.
double wavelengthByDefinition(const DenseGrid& g, double isovalue) {
  const auto& d = g.geometry.dims;
  auto difference = [&](int order, std::array<std::int64_t, 3> p, int axis) {
    double sum = 0, binomial = 1;  // C(order, k)
    for (int k = 0; k <= order; ++k) {
      std::array<std::int64_t, 3> q = p;
      q[static_cast<std::size_t>(axis)] += order / 2 - k;
      sum += (k % 2 ? -binomial : binomial) * g.at(q[0], q[1], q[2]);
      binomial = binomial * (order - k) / (k + 1);
    }
    return sum;
  };
  double fourth = 0, sixth = 0;
  for (std::int64_t k = 0; k + 1 < d[2]; ++k)
    for (std::int64_t j = 0; j + 1 < d[1]; ++j)
      for (std::int64_t i = 0; i + 1 < d[0]; ++i) {
        int above = 0;
        for (int v = 0; v < 8; ++v) above += g.at(i + (v & 1), j + ((v >> 1) & 1), k + (v >> 2)) > isovalue;
        if (above == 0 || above == 8) continue;
        const std::array<std::int64_t, 3> p{i, j, k};
        for (int axis = 0; axis < 3; ++axis) {
          if (p[static_cast<std::size_t>(axis)] < 3 || p[static_cast<std::size_t>(axis)] + 3 >= d[axis])
            continue;
          fourth += std::pow(difference(4, p, axis), 2);
          sixth += std::pow(difference(6, p, axis), 2);
        }
      }
  const double x = std::pow(sixth / fourth, 0.25) / 2;
  return x >= 1 ? 2.0 : M_PI / std::asin(x);
}

}  // namespace

// What auto picks on the data of docs/method.md: central8 on the smooth sampled fields (Marschner-Lobb from
// N = 56 on), monotone on the aliased Marschner-Lobb at N = 32 and on every real volume (CT steps, a
// narrow-band level set). Each estimate is the one its definition gives, computed here another way; the
// differences cancel the samples' size by up to ~1e4 on these data (smooth fields: D4 ~ (2 pi / L)^4 of the
// amplitude), so the two computations round apart by ~1e-12 of R, and of L; 1e-9 leaves a wide margin and
// still sees any change of the measure. Where the field allows, the value is derived: the gyroid is one sine
// of period 1 along every axis (sin(2 pi x) cos(2 pi y) + ... ), for which R is exactly (2 sin(pi / L))^4
// with L = N / 2 samples; Marschner-Lobb's ripple cos(2 pi f_M cos(pi r / 2)) has local frequency at most
// f_M pi / 2 cycles per unit (at r = 1), a wavelength of at least N / (f_M pi) samples, 3.4 at N = 64 (the
// estimate, a weighted mean of the local (2 sin(pi / L))^4, is at least that), so central8.
TEST(SamplingEstimate, ChoicesOnTheMeasuredData) {
  struct Field {
    const char* name;
    int n;
    Reconstruction kind;
  };
  for (const Field& f :
       {Field{"marschner-lobb", 64, Reconstruction::Central8},
        Field{"marschner-lobb", 32, Reconstruction::Monotone}, Field{"torus", 32, Reconstruction::Central8},
        Field{"gyroid", 32, Reconstruction::Central8}}) {
    auto field = makeAnalyticField(f.name);
    const DenseGrid g = sampleField(*field, f.n, f.name);
    const SamplingEstimate e = estimateSampling(g, field->defaultIsovalue());
    EXPECT_NEAR(e.wavelength, wavelengthByDefinition(g, field->defaultIsovalue()), 1e-9 * e.wavelength)
        << f.name << " " << f.n;
    EXPECT_EQ(chooseReconstruction(e), f.kind) << f.name << " " << f.n;
  }
  const auto gyroid = makeAnalyticField("gyroid");
  EXPECT_NEAR(estimateSampling(sampleField(*gyroid, 32, "gyroid"), 0).wavelength, 16.0, 1e-9 * 16);
  const auto ml = makeAnalyticField("marschner-lobb");
  EXPECT_GT(estimateSampling(sampleField(*ml, 64, "marschner-lobb"), 0.5).wavelength, 64 / (6 * M_PI));
  EXPECT_GT(64 / (6 * M_PI), kCentral8Wavelength);

  struct Volume {
    const char* file;
    double iso;
  };
  for (const Volume& v : {Volume{"headsq.nhdr", 1150}, Volume{"headsq.nhdr", 500}, Volume{"tooth.nhdr", 120},
                          Volume{"nucleon.nhdr", 128}, Volume{"vdb/sphere.vdb", 0}}) {
    VolumeReadOptions o;
    o.brickCells = 1 << 20;  // one brick: the whole volume
    const SparseVolume volume = readVolume(test::sharedData(v.file), o);
    const DenseGrid& g = *volume.bricks[0].grid;
    const SamplingEstimate e = estimateSampling(g, v.iso);
    EXPECT_NEAR(e.wavelength, wavelengthByDefinition(g, v.iso), 1e-9 * e.wavelength)
        << v.file << " " << v.iso;
    EXPECT_EQ(chooseReconstruction(e), Reconstruction::Monotone) << v.file;
  }
}
