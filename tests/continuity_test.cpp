// Continuity between neighbouring cells and exact reproduction of linear fields, on whole models.
#include <gtest/gtest.h>

#include <cstdio>
#include <string>
#include <tuple>

#include "cip/measure/continuity_check.h"
#include "cip/model/model_builder.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "support/join_tolerances.h"
#include "support/random_volume.h"

using namespace cip;

// Tolerances: rounding only (support/join_tolerances.h derives them).
using test::kJoinAngle;
using test::kJoinGap;
// Sample lines per face axis: 14 gives thousands of boundary-curve points per volume while keeping the
// sanitizer build's run short.
constexpr int kFaceSamples = 14;

// Every normal mode with every coefficient construction (PatchMethod).
using ModeAndMethod = std::tuple<NormalMode, PatchMethod>;
std::string modeAndMethodName(const ::testing::TestParamInfo<ModeAndMethod>& param) {
  return std::string(toString(std::get<0>(param.param))) + "_" + toString(std::get<1>(param.param));
}

/// Grid faces between two cells of the volume with a crossed edge (their four samples not all on one side of
/// the isovalue), counted from the samples: the face pairs measureContinuity should compare.
int facesWithACrossing(const DenseGrid& g, double isovalue) {
  const auto& d = g.geometry.dims;
  int faces = 0;
  for (int axis = 0; axis < 3; ++axis) {
    const auto uv = cube::otherAxes(axis);
    std::array<std::int64_t, 3> p{};
    // The face at p[axis] between cells p[axis] - 1 and p[axis], its lowest point p.
    for (p[axis] = 1; p[axis] + 1 < d[axis]; ++p[axis])
      for (p[uv[0]] = 0; p[uv[0]] + 1 < d[uv[0]]; ++p[uv[0]])
        for (p[uv[1]] = 0; p[uv[1]] + 1 < d[uv[1]]; ++p[uv[1]]) {
          int above = 0;
          for (int k = 0; k < 4; ++k) {
            std::array<std::int64_t, 3> q = p;
            q[uv[0]] += k & 1;
            q[uv[1]] += k >> 1;
            above += g.at(q[0], q[1], q[2]) > isovalue;
          }
          faces += above != 0 && above != 4;
        }
  }
  return faces;
}

class ContinuityOnRandomVolumes : public ::testing::TestWithParam<ModeAndMethod> {};

TEST_P(ContinuityOnRandomVolumes, NeighboursShareZeroSetAndNormals) {
  for (unsigned seed : {1u, 2u, 3u}) {
    DenseGrid g = test::randomVolume(9, seed);
    BuildOptions o;
    o.normals = std::get<0>(GetParam());
    o.method = std::get<1>(GetParam());
    o.central =
        seed == 3 ? CentralRule::Interior : CentralRule::Zero;  // the central term vanishes on every face
    Model m = buildModel(g, o);
    int ambiguous = 0;
    for (const auto& c : m.cells)
      for (int f = 0; f < 6; ++f) ambiguous += cube::isAmbiguousFace(c.config, f);
    EXPECT_GT(ambiguous, 50) << "the random volume should be rich in ambiguous faces";
    ContinuityStats s = measureContinuity(m, kFaceSamples);
    std::printf("seed %u: %d face pairs, %d curve points, max gap %.3g voxel, max normal angle %.3g rad\n",
                seed, s.facePairs, s.curvePoints, s.maxGap, s.maxAngle);
    EXPECT_EQ(s.facePairs, facesWithACrossing(g, o.isovalue));
    EXPECT_GT(s.curvePoints, 3000);
    EXPECT_LT(s.maxGap, kJoinGap) << "seed " << seed;
    EXPECT_LT(s.maxAngle, kJoinAngle) << "seed " << seed;
    EXPECT_EQ(s.signDisagreements, 0) << "seed " << seed;
  }
}

INSTANTIATE_TEST_SUITE_P(NormalModes, ContinuityOnRandomVolumes,
                         ::testing::Combine(::testing::Values(NormalMode::Edge, NormalMode::Gradient),
                                            ::testing::Values(PatchMethod::Paper, PatchMethod::Fitted)),
                         modeAndMethodName);

class ContinuityExactGyroid : public ::testing::TestWithParam<PatchMethod> {};

TEST_P(ContinuityExactGyroid, NeighboursShareZeroSetAndNormals) {
  auto field = makeAnalyticField("gyroid");
  DenseGrid g = sampleField(*field, 12, "gyroid");
  BuildOptions o;
  o.normals = NormalMode::Exact;
  o.method = GetParam();
  o.exactField = field.get();
  Model m = buildModel(g, o);
  ContinuityStats s = measureContinuity(m, kFaceSamples);
  EXPECT_GT(s.curvePoints, 1000);
  EXPECT_LT(s.maxGap, kJoinGap);
  EXPECT_LT(s.maxAngle, kJoinAngle);
  EXPECT_EQ(s.signDisagreements, 0);
}

std::string methodName(const ::testing::TestParamInfo<PatchMethod>& param) {
  return toString(param.param);
}

INSTANTIATE_TEST_SUITE_P(Methods, ContinuityExactGyroid,
                         ::testing::Values(PatchMethod::Paper, PatchMethod::Fitted), methodName);

class LinearField : public ::testing::TestWithParam<ModeAndMethod> {};

TEST_P(LinearField, ReproducedExactlyByEveryCell) {
  auto field = makeAnalyticField("plane");
  // Several resolutions: at some, crossings land on or near grid points (small eq. 5 denominators).
  // Tolerance: 1e-12 voxel, rounding level for these coordinates.
  for (int resolution : {8, 16, 23}) {
    DenseGrid g = sampleField(*field, resolution, "plane");
    BuildOptions o;
    o.normals = std::get<0>(GetParam());
    o.method = std::get<1>(GetParam());
    o.exactField = field.get();
    Model m = buildModel(g, o);
    ASSERT_GT(m.cells.size(), 20u);
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    const Vec3 n = field->gradient(Vec3::Zero());
    for (std::size_t c = 0; c < m.cells.size(); ++c) {
      CornerPatch p = m.patch(c);
      Vec3 origin = m.cellOrigin(c);
      auto planeValue = [&](const Vec3& local) {
        return field->value(m.geometry.indexToWorld(origin + local));
      };
      for (int s = 0; s < 50; ++s) {
        Vec3 x(u(rng), u(rng), u(rng));
        double l = planeValue(x), value = p.value(x);
        // Same sign everywhere in the cell (the patch is the plane times a positive factor).
        if (std::abs(l) > 1e-9) {
          EXPECT_EQ(value > 0, l > 0) << "N " << resolution << " cell " << c;
        }
        // Points on the plane are zeros: project x onto the plane (world), back to cell-local.
        Vec3 w = m.geometry.indexToWorld(origin + x);
        Vec3 onPlane = m.geometry.worldToIndex(w - l / n.squaredNorm() * n) - origin;
        if ((onPlane.array() >= 0).all() && (onPlane.array() <= 1).all()) {
          PatchDerivatives d = p.derivatives(onPlane);
          EXPECT_LT(std::abs(d.value) / d.gradient.norm(), 1e-12) << "N " << resolution << " cell " << c;
          // The normal is the plane's normal (index space direction of the world gradient).
          Vec3 expected = n.cwiseProduct(m.geometry.spacing).normalized();
          EXPECT_NEAR(d.gradient.normalized().dot(expected), 1.0, 1e-12);
        }
      }
    }
  }
}

INSTANTIATE_TEST_SUITE_P(NormalModes, LinearField,
                         ::testing::Combine(::testing::Values(NormalMode::Gradient, NormalMode::Exact),
                                            ::testing::Values(PatchMethod::Paper, PatchMethod::Fitted)),
                         modeAndMethodName);
