// The storage requirement of the model file: the surface a reader gets back moves by at most 0.01 voxel
// anywhere against the model that was built, and its normals by at most 1 degree (measured on rays by
// measureModelDisplacement: two-sided distance between the zero sets, and the angle between the normals at
// corresponding points). A lossless file measures 0; a quantising one must stay within the bounds on every
// model here: analytic fields with the default and with the paper's construction, the bundled volume and a CT
// head.
//
// Why 1 degree: a displacement of 0.01 voxel that changes across a cell tilts the surface by about
// atan(0.01 / 1 voxel) = 0.57 degree, so a codec within the distance bound with smooth errors stays well
// inside; noise-like errors over shorter spans tilt it more, and 1 degree is where that starts to matter for
// shading (a diffuse term changes by at most sin 1 deg = 1.7 % of the light), while still far above what
// quantised unit normals cost (16 bits per component: 0.002 degree).
#include <gtest/gtest.h>

#include <cstdio>
#include <string>
#include <vector>

#include "cip/measure/model_displacement.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/readers/volume_reader.h"
#include "cip/volume/analytic_field.h"
#include "support/volume_blocks.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

constexpr double kMaxDistanceVoxels = 0.01;
constexpr double kMaxNormalDegrees = 1.0;

struct Case {
  std::string name;
  Model model;
};

Model fieldModel(const std::string& field, int n, PatchMethod method) {
  const auto f = makeAnalyticField(field);
  BuildOptions o;
  o.isovalue = f->defaultIsovalue();
  o.method = method;
  return buildModel(sampleField(*f, n, field), o);
}

Model volumeModel(const DenseGrid& grid, double iso, PatchMethod method) {
  BuildOptions o;
  o.isovalue = iso;
  o.method = method;
  return buildModel(grid, o);
}

std::vector<Case> cases() {
  std::vector<Case> out;
  for (PatchMethod method : {PatchMethod::Fitted, PatchMethod::Paper}) {
    const std::string m = toString(method);
    out.push_back({"sphere-32-" + m, fieldModel("sphere", 32, method)});
    out.push_back({"torus-32-" + m, fieldModel("torus", 32, method)});
    out.push_back({"gyroid-24-" + m, fieldModel("gyroid", 24, method)});
  }
  const SparseVolume blobs = readVolume(test::sourceFile("data/blobs.nrrd"));
  out.push_back({"blobs-128", volumeModel(*blobs.dense(), 128, PatchMethod::Fitted)});
  out.push_back({"headsq-500", volumeModel(test::readVolumeDense(test::sharedData("headsq.nhdr")), 500,
                                           PatchMethod::Fitted)});
  return out;
}

}  // namespace

TEST(StoredModel, SurfaceMovesAtMostOneHundredthOfAVoxel) {
  for (const Case& c : cases()) {
    const std::vector<std::uint8_t> bytes = serializeModel(c.model);
    const Model stored = parseModel(bytes.data(), bytes.size(), c.name);
    const ModelDisplacement d = measureModelDisplacement(c.model, stored);
    std::printf(
        "%-18s %7zu cells %8zu bytes: distance max %.3g mean %.3g, normal max %.3g deg, %lld one-sided\n",
        c.name.c_str(), c.model.cells.size(), bytes.size(), d.distanceVoxels.max, d.distanceVoxels.mean,
        d.normalDegrees.max, static_cast<long long>(d.oneSidedHits()));
    EXPECT_EQ(d.cellsOnlyInReference, 0) << c.name;
    EXPECT_EQ(d.cellsOnlyInStored, 0) << c.name;
    EXPECT_TRUE(d.sameGeometry) << c.name;
    EXPECT_GT(d.distanceVoxels.count, c.model.cells.size()) << c.name;  // the surface was sampled
    EXPECT_LE(d.distanceVoxels.max, kMaxDistanceVoxels) << c.name;
    EXPECT_LE(d.normalDegrees.max, kMaxNormalDegrees) << c.name;
  }
}
