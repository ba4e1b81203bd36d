// The reference of two-valued data (mask_reference.h): which data Auto takes it for, that every grid point
// keeps the mask's side (in the field and in the patches), how close it follows the shape the mask was made
// from, and that touching labels of a label map share their surface.
#include "cip/reference/mask_reference.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <functional>

#include "cip/measure/surface_fidelity.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/reference/reconstruction_choice.h"
#include "support/corner_sides.h"
#include "support/model_bytes.h"

using namespace cip;

namespace {

/// A field given by a function of the index coordinates (the grids below have spacing 1, origin 0).
class FunctionField : public ScalarField {
 public:
  explicit FunctionField(std::function<double(const Vec3&)> f) : f_(std::move(f)) {}
  double value(const Vec3& x) const override { return f_(x); }
  Vec3 gradient(const Vec3& x) const override {
    Vec3 g;
    for (int a = 0; a < 3; ++a) g[a] = (f_(x + 1e-6 * Vec3::Unit(a)) - f_(x - 1e-6 * Vec3::Unit(a))) / 2e-6;
    return g;
  }

 private:
  std::function<double(const Vec3&)> f_;
};

DenseGrid sampled(std::int64_t n, const std::function<double(const Vec3&)>& f) {
  DenseGrid g;
  g.allocate({n, n, n});
  for (std::int64_t k = 0; k < n; ++k)
    for (std::int64_t j = 0; j < n; ++j)
      for (std::int64_t i = 0; i < n; ++i)
        g.at(i, j, k) = f(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
  return g;
}

/// A mask with the values of a uint8 segmentation: 255 where `inside` is positive, else 0.
DenseGrid mask(std::int64_t n, const std::function<double(const Vec3&)>& inside) {
  return sampled(n, [&](const Vec3& x) { return inside(x) > 0 ? 255.0 : 0.0; });
}

std::function<double(const Vec3&)> ball(const Vec3& centre, double radius) {
  return [=](const Vec3& x) { return radius - (x - centre).norm(); };
}

std::function<double(const Vec3&)> torus(const Vec3& centre, double big, double small) {
  return [=](const Vec3& x) {
    const Vec3 q = x - centre;
    const double rho = std::hypot(q[0] * 0.8 + q[2] * 0.6, q[1]);  // axis tilted in the x-z plane
    const double along = -q[0] * 0.6 + q[2] * 0.8;
    return small - std::hypot(rho - big, along);
  };
}

/// A slab `thickness` voxels thick through `centre`, tilted.
std::function<double(const Vec3&)> plate(const Vec3& centre, double thickness) {
  const Vec3 n = Vec3(0.2, 0.3, 0.93).normalized();
  return [=](const Vec3& x) { return thickness / 2 - std::abs(n.dot(x - centre)); };
}

}  // namespace

TEST(TwoValuedSamples, AreMasksButNotContinuousData) {
  const Vec3 c(15.3, 14.6, 15.2);
  const TwoValuedSamples m = detectTwoValued(mask(32, ball(c, 9)), 127.5);
  EXPECT_TRUE(m.twoValued);
  EXPECT_EQ(m.below, 0.0);
  EXPECT_EQ(m.above, 255.0);
  EXPECT_GT(m.points, 1000);
  EXPECT_FALSE(detectTwoValued(sampled(32, ball(c, 9)), 0.0).twoValued);
  // Two values far from the surface but not next to it: not a mask.
  DenseGrid threeValued = mask(32, ball(c, 9));
  threeValued.at(16, 15, 24) = 128;  // next to the surface (radius 9 from the centre)
  EXPECT_FALSE(detectTwoValued(threeValued, 127.5).twoValued);
}

// Sphere, torus and a thin tilted plate (1 voxel): the field and the patches keep every grid point's side,
// and Auto takes the mask reference for such data.
TEST(MaskReference, KeepsEveryGridPointOnItsSide) {
  const Vec3 c(20.4, 19.7, 20.2);
  const std::function<double(const Vec3&)> shapes[] = {ball(c, 11), torus(c, 10, 3.5), plate(c, 1.0),
                                                       plate(c, 2.0)};
  for (const auto& shape : shapes) {
    const DenseGrid m = mask(41, shape);
    const DenseGrid field = smoothMask(m, 127.5);
    std::int64_t flipped = 0;
    for (std::size_t n = 0; n < m.values.size(); ++n)
      flipped += (m.values[n] > 127.5) != (field.values[n] > 127.5);
    EXPECT_EQ(flipped, 0);
    BuildOptions options;
    options.isovalue = 127.5;
    const Model model = buildModel(m, options);
    ASSERT_TRUE(model.reconstruction.has_value());
    EXPECT_EQ(*model.reconstruction, Reconstruction::Mask);
    EXPECT_GT(model.cells.size(), 500u);
    EXPECT_EQ(test::wrongSideCorners(model, m, 127.5), 0);
    // The file records it.
    const Model stored = parseModel(serializeModel(model).data(), serializeModel(model).size());
    EXPECT_EQ(stored.reconstruction, Reconstruction::Mask);
  }
}

// On a sphere mask the patches follow the sphere far more closely than those of the mask's samples as they
// are (the terraces), within 0.05 voxel and 2.5 degrees on average.
TEST(MaskReference, FollowsASphereBetterThanTheSamples) {
  const Vec3 c(17.35, 16.8, 17.1);
  const auto shape = ball(c, 10.5);
  const DenseGrid m = mask(35, shape);
  const FunctionField truth(shape);
  FidelityMeasures fidelity[2];
  for (int k = 0; k < 2; ++k) {
    BuildOptions options;
    options.isovalue = 127.5;
    options.reconstruction = k == 0 ? Reconstruction::Mask : Reconstruction::Monotone;
    const Model model = buildModel(m, options);
    fidelity[k] = measureFidelity(samplePatchSurface(model), truth, 0.0, 1.0, false);
  }
  EXPECT_LT(fidelity[0].distanceVoxels.mean, 0.05);
  EXPECT_LT(fidelity[0].normalDegrees.mean, 2.5);
  EXPECT_LT(fidelity[0].distanceVoxels.mean, 0.4 * fidelity[1].distanceVoxels.mean);
  EXPECT_LT(fidelity[0].normalDegrees.mean, 0.2 * fidelity[1].normalDegrees.mean);
  EXPECT_LT(fidelity[0].distanceVoxels.max, 0.5);
}

// Where the shape bends within a few voxels (a torus of tube radius 4, an ellipsoid 12 x 8 x 5 with tips of
// radius 2.1) the largest kernel alone moved the surface by 0.10-0.13 voxel on average (normals 3.3-6 degrees
// off); the smaller scales take over there (mask_reference.h), and the patches follow the shape as closely as
// on a large sphere.
TEST(MaskReference, FollowsThinPartsWithTheSmallerScales) {
  const Vec3 c(18.3, 17.6, 18.45);
  const Eigen::Matrix3d turn = (Eigen::AngleAxisd(0.7, Vec3(0.3, 0.8, 0.5).normalized()).toRotationMatrix());
  const std::function<double(const Vec3&)> ellipsoid = [&](const Vec3& x) {
    const Vec3 q = turn * (x - c);  // an approximate distance: enough to place the mask and the measure
    const Vec3 a(12, 8, 5);
    const double k0 = (q.array() / a.array()).matrix().norm(),
                 k1 = (q.array() / (a.array() * a.array())).matrix().norm();
    return -k0 * (k0 - 1) / std::max(k1, 1e-12);
  };
  const struct {
    const char* name;
    std::function<double(const Vec3&)> shape;
    double distance, degrees;
  } cases[] = {{"torus 10/4", torus(c, 10, 4), 0.065, 3.0}, {"ellipsoid 12x8x5", ellipsoid, 0.085, 4.5}};
  for (const auto& t : cases) {
    const DenseGrid m = mask(37, t.shape);
    BuildOptions options;
    options.isovalue = 127.5;
    const Model model = buildModel(m, options);
    const FidelityMeasures f =
        measureFidelity(samplePatchSurface(model), FunctionField(t.shape), 0.0, 1.0, false);
    std::printf("%s: %.4f voxel, %.2f degrees\n", t.name, f.distanceVoxels.mean, f.normalDegrees.mean);
    EXPECT_LT(f.distanceVoxels.mean, t.distance) << t.name;
    EXPECT_LT(f.normalDegrees.mean, t.degrees) << t.name;
    EXPECT_EQ(test::wrongSideCorners(model, m, 127.5), 0) << t.name;
  }
}

// Continuous data keep Auto's spectral choice: the model is the one the resolved reconstruction gives.
TEST(MaskReference, AutoKeepsTheChoiceOnContinuousData) {
  const DenseGrid g = sampled(28, ball(Vec3(13.2, 13.9, 14.1), 8.7));
  BuildOptions options;
  const Model automatic = buildModel(g, options);
  ASSERT_TRUE(automatic.reconstruction.has_value());
  const Reconstruction chosen = chooseReconstruction(estimateSampling(g, 0.0));
  EXPECT_EQ(*automatic.reconstruction, chosen);
  options.reconstruction = chosen;
  EXPECT_EQ(test::modelBytes(buildModel(g, options)), test::modelBytes(automatic));
}

// Two labels that fill the grid between them (a ball of label 1 in label 2): their models have the same
// cells with complementary signs, the same isovertices, and patches of opposite sign everywhere: one surface.
TEST(LabelMap, TouchingLabelsShareTheirSurface) {
  const auto inner = ball(Vec3(14.3, 15.2, 14.7), 8.6);
  const DenseGrid labels = sampled(30, [&](const Vec3& x) { return inner(x) > 0 ? 1.0 : 2.0; });
  Model models[2];
  for (int l = 0; l < 2; ++l) {
    BuildOptions options;
    options.label = l + 1;
    models[l] = buildModel(labels, options);
    ASSERT_TRUE(models[l].reconstruction.has_value());
    EXPECT_EQ(*models[l].reconstruction, Reconstruction::Mask);
    EXPECT_EQ(test::wrongSideCorners(
                  models[l], sampled(30, [&](const Vec3& x) { return (inner(x) > 0) == (l == 0); }), 0.5),
              0);
  }
  ASSERT_EQ(models[0].cells.size(), models[1].cells.size());
  ASSERT_GT(models[0].cells.size(), 500u);
  ASSERT_EQ(models[0].vertices.size(), models[1].vertices.size());
  for (std::size_t v = 0; v < models[0].vertices.size(); ++v)
    EXPECT_EQ(models[0].vertices[v].position, models[1].vertices[v].position);
  int disagree = 0;
  double largest = 0;
  for (std::size_t c = 0; c < models[0].cells.size(); ++c) {
    EXPECT_EQ(models[0].cells[c].config, static_cast<std::uint8_t>(~models[1].cells[c].config));
    const CornerPatch a = models[0].patch(c), b = models[1].patch(c);
    for (int s = 0; s < 27; ++s) {
      const Vec3 x(0.1 + 0.4 * (s % 3), 0.1 + 0.4 * ((s / 3) % 3), 0.1 + 0.4 * (s / 9));
      const double va = a.value(x), vb = b.value(x);
      largest = std::max(largest, std::abs(va + vb) / std::max(std::abs(va), 1e-300));
      if (va != 0 && (va > 0) == (vb > 0)) ++disagree;
    }
  }
  EXPECT_EQ(disagree, 0);
  EXPECT_LT(largest, 1e-9);
}

// The field, and so the model, does not depend on the number of threads.
TEST(MaskReference, ThreadCountChangesNoByte) {
  const DenseGrid m = mask(37, torus(Vec3(18.2, 17.7, 18.4), 10, 4));
  BuildOptions options;
  options.isovalue = 127.5;
  options.threads = 1;
  const std::vector<std::uint8_t> one = test::modelBytes(buildModel(m, options));
  options.threads = 2;
  EXPECT_EQ(test::modelBytes(buildModel(m, options)), one);
}
