// measureModelDisplacement finds the changes planted in a copy of a model, with the size the change implies:
// nothing for an identical copy, about the shift for isovertices slid along their edges, the turn for rotated
// corner normals, and a side coefficient changed on one face moves that face's two cells and no other.
#include "cip/measure/model_displacement.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <Eigen/Geometry>
#include <array>
#include <cmath>
#include <cstdio>

#include "cip/model/model_builder.h"
#include "cip/volume/analytic_field.h"
#include "support/field_model.h"

using namespace cip;

namespace {

Model fieldModel(const std::string& name, int n, NormalMode mode = NormalMode::Exact) {
  return test::fieldModel(name, n, mode);
}

/// The grid axis of the edge an isovertex lies on: its one coordinate that is not an integer, or -1 when it
/// sits on a grid point.
int edgeAxis(const Vec3& p) {
  for (int a = 0; a < 3; ++a)
    if (p[a] != std::floor(p[a])) return a;
  return -1;
}

/// Every isovertex slid along its edge by `delta` (index units), forwards unless that leaves the edge.
/// Returns how many moved.
int slideVertices(Model& m, double delta) {
  int moved = 0;
  for (IsoVertex& v : m.vertices) {
    const int a = edgeAxis(v.position);
    if (a < 0) continue;
    const double f = v.position[a] - std::floor(v.position[a]);
    v.position[a] += f + delta < 1 ? delta : -delta;
    ++moved;
  }
  return moved;
}

/// Every corner normal turned by `degrees` about an axis across it.
void turnNormals(Model& m, double degrees) {
  for (IsoVertex& v : m.vertices) {
    const Vec3 axis = v.normal.cross(Vec3(1, 2, 3).normalized()).normalized();
    v.normal = Eigen::AngleAxisd(degrees * M_PI / 180, axis) * v.normal;
  }
}

void expectSame(const ErrorSummary& a, const ErrorSummary& b) {
  EXPECT_EQ(a.count, b.count);
  EXPECT_EQ(a.mean, b.mean);
  EXPECT_EQ(a.p99, b.p99);
  EXPECT_EQ(a.max, b.max);
}

}  // namespace

// A copy measures exactly 0 everywhere; every ray through a cell the surface crosses is cast.
TEST(ModelDisplacement, IdenticalModelsMeasureExactlyZero) {
  for (const char* name : {"sphere", "gyroid"}) {
    const Model m = fieldModel(name, 16);
    const ModelDisplacement d = measureModelDisplacement(m, m);
    EXPECT_EQ(d.cellsCompared, static_cast<std::int64_t>(m.cells.size())) << name;
    EXPECT_EQ(d.cellsOnlyInReference + d.cellsOnlyInStored, 0) << name;
    EXPECT_EQ(d.oneSidedHits(), 0) << name;
    EXPECT_TRUE(d.sameGeometry);
    // 3 directions of 16 lines through the whole cell, 4 diagonals with a part of their 16.
    EXPECT_GE(d.rays, 60 * d.cellsCompared) << name;
    EXPECT_LE(d.rays, 112 * d.cellsCompared) << name;
    EXPECT_GT(d.bothHit, 10 * d.cellsCompared) << name;
    EXPECT_EQ(d.distanceVoxels.count, static_cast<std::size_t>(2 * d.bothHit)) << name;
    for (const ErrorSummary* s : {&d.depthVoxels, &d.rayNormalDegrees, &d.distanceVoxels, &d.normalDegrees}) {
      EXPECT_EQ(s->max, 0.0) << name;
      EXPECT_EQ(s->mean, 0.0) << name;
    }
  }
}

// Isovertices slid along their edges by delta: at each isovertex the surface moves by delta times the
// normal's component along the edge, up to delta where the normal follows the edge, and between them by a
// blend of the corner planes' shifts. For a small slide the largest distance is delta (first order); a large
// one bends the patches more (second order, most near cell edges), yet stays within twice the slide.
TEST(ModelDisplacement, IsoverticesSlidAlongTheirEdgesMoveTheSurfaceByTheSlide) {
  for (const char* name : {"sphere", "gyroid"}) {
    const Model m = fieldModel(name, 16);
    for (double delta : {0.002, 0.02}) {
      Model moved = m;
      ASSERT_GT(slideVertices(moved, delta), 0);
      const ModelDisplacement d = measureModelDisplacement(m, moved);
      std::printf(
          "%s, slide %.3f: distance max %.5f mean %.5f p99 %.5f, depth max %.5f, one-sided hits %lld\n", name,
          delta, d.distanceVoxels.max, d.distanceVoxels.mean, d.distanceVoxels.p99, d.depthVoxels.max,
          static_cast<long long>(d.oneSidedHits()));
      if (delta < 0.01) {
        EXPECT_GT(d.distanceVoxels.max, 0.9 * delta) << name;
        EXPECT_LT(d.distanceVoxels.max, 1.1 * delta) << name;
      } else {
        EXPECT_GT(d.distanceVoxels.max, 0.005) << name;
        EXPECT_LT(d.distanceVoxels.max, 2 * delta) << name;
      }
      EXPECT_GT(d.distanceVoxels.mean, 0.2 * delta) << name;
      EXPECT_LE(d.distanceVoxels.p99, d.distanceVoxels.max) << name;
      // The depth along a ray is at least the distance of its hits (oblique rays see more).
      EXPECT_GE(d.depthVoxels.max, d.distanceVoxels.p99) << name;
    }
  }
}

// Corner normals turned by theta: the patch's gradient at an isovertex follows its corner normal (every other
// term vanishes there to second order), so near the isovertices the normals differ by theta, and elsewhere by
// a blend of the turns: on average about 3/4 of theta, linear in it. Near cell edges, where every term is
// small, the patch turns much more (the maximum is many times theta), so the test holds the mean and the 99th
// percentile.
TEST(ModelDisplacement, TurnedCornerNormalsShowAsTheTurn) {
  for (const char* name : {"sphere", "gyroid"}) {
    const Model m = fieldModel(name, 16);
    std::array<double, 2> mean{};
    for (int i = 0; i < 2; ++i) {
      const double theta = 0.25 * (i + 1);
      Model turned = m;
      turnNormals(turned, theta);
      const ModelDisplacement d = measureModelDisplacement(m, turned);
      std::printf("%s, turn %.2f deg: normal max %.3f p99 %.3f mean %.4f deg, distance max %.5f\n", name,
                  theta, d.normalDegrees.max, d.normalDegrees.p99, d.normalDegrees.mean,
                  d.distanceVoxels.max);
      EXPECT_GT(d.normalDegrees.mean, 0.5 * theta) << name;
      EXPECT_LT(d.normalDegrees.mean, theta) << name;
      EXPECT_GT(d.normalDegrees.p99, theta) << name;
      EXPECT_LT(d.normalDegrees.p99, 5 * theta) << name;
      EXPECT_GE(d.normalDegrees.max, d.normalDegrees.p99) << name;
      EXPECT_GT(d.distanceVoxels.max, 0) << name;
      mean[static_cast<std::size_t>(i)] = d.normalDegrees.mean;
    }
    EXPECT_NEAR(mean[1] / mean[0], 2.0, 0.1) << name;
  }
}

// A side coefficient changed on one face, in both cells that share it (as the face's one coefficient): those
// two cells move, every other cell measures exactly 0.
TEST(ModelDisplacement, AChangedSideCoefficientMovesOnlyTheCellsOfItsFace) {
  const Model m = fieldModel("gyroid", 16);
  std::size_t lower = 0, upper = 0;
  int face = -1;
  for (std::size_t c = 0; c < m.cells.size() && face < 0; ++c) {
    const CornerPatch p = m.patch(c);
    for (int axis = 0; axis < 3 && face < 0; ++axis) {
      if (!((p.faceMask >> (2 * axis + 1)) & 1)) continue;
      std::array<std::int64_t, 3> i{m.cells[c].index[0], m.cells[c].index[1], m.cells[c].index[2]};
      ++i[axis];
      const std::int64_t b = m.findCell(i[0], i[1], i[2]);
      if (b < 0) continue;
      lower = c;
      upper = static_cast<std::size_t>(b);
      face = 2 * axis + 1;
    }
  }
  ASSERT_GE(face, 0);
  Model changed = m;
  changed.cells[lower].faceCoefficient[face] += 0.05;
  changed.cells[upper].faceCoefficient[face - 1] += 0.05;
  DisplacementOptions o;
  o.perCell = true;
  const ModelDisplacement d = measureModelDisplacement(m, changed, o);
  ASSERT_EQ(d.cellDistance.size(), m.cells.size());
  EXPECT_GT(d.cellDistance[lower], 1e-3);
  EXPECT_GT(d.cellDistance[upper], 1e-3);
  int others = 0;
  for (std::size_t c = 0; c < m.cells.size(); ++c)
    if (c != lower && c != upper && d.cellDistance[c] != 0) ++others;
  EXPECT_EQ(others, 0);
  EXPECT_EQ(d.distanceVoxels.max, std::max(d.cellDistance[lower], d.cellDistance[upper]));
  const auto& worst = d.cellDistance[lower] >= d.cellDistance[upper] ? m.cells[lower] : m.cells[upper];
  EXPECT_EQ(d.worstCell, worst.index);
}

// A tiny change stays tiny, also on rays that graze one surface and miss the other: their hits count by their
// distance to the other surface, not by how far along the ray the other one's hit would be.
TEST(ModelDisplacement, GrazingMissesOfANearlyIdenticalSurfaceCountAsSmall) {
  constexpr double kDelta = 1e-5;
  const Model m = fieldModel("gyroid", 24);
  Model moved = m;
  slideVertices(moved, kDelta);
  const ModelDisplacement d = measureModelDisplacement(m, moved);
  std::printf("one-sided hits %lld, their max %.3g, distance max %.3g, depth max %.3g\n",
              static_cast<long long>(d.oneSidedHits()), d.oneSidedDistanceVoxels.max, d.distanceVoxels.max,
              d.depthVoxels.max);
  EXPECT_GT(d.distanceVoxels.max, 0);
  EXPECT_LT(d.distanceVoxels.max, 2 * kDelta);
  EXPECT_LT(d.oneSidedDistanceVoxels.max, 2 * kDelta);
}

// A cell the stored model lost (or gained) is counted, not compared.
TEST(ModelDisplacement, CellsPresentInOneModelOnlyAreCounted) {
  const Model m = fieldModel("sphere", 12);
  Model fewer = m;
  fewer.cells.erase(fewer.cells.begin() + 7);
  DisplacementOptions o;
  o.perCell = true;
  const ModelDisplacement d = measureModelDisplacement(m, fewer, o);
  EXPECT_EQ(d.cellsOnlyInReference, 1);
  EXPECT_EQ(d.cellsOnlyInStored, 0);
  EXPECT_EQ(d.cellsCompared, static_cast<std::int64_t>(m.cells.size()) - 1);
  EXPECT_TRUE(std::isnan(d.cellDistance[7]));
  EXPECT_EQ(d.distanceVoxels.max, 0);
  const ModelDisplacement back = measureModelDisplacement(fewer, m);
  EXPECT_EQ(back.cellsOnlyInReference, 0);
  EXPECT_EQ(back.cellsOnlyInStored, 1);
  Model otherGrid = m;
  otherGrid.geometry.dims[0] += 1;
  EXPECT_THROW(measureModelDisplacement(m, otherGrid), Error);
}

// The figures are the same, bit for bit, on one thread and on all.
TEST(ModelDisplacement, DoesNotDependOnTheThreadCount) {
  const Model m = fieldModel("gyroid", 16);
  Model moved = m;
  slideVertices(moved, 0.01);
  turnNormals(moved, 0.5);
  const ModelDisplacement all = measureModelDisplacement(m, moved);
  ModelDisplacement one;
  {
    tbb::global_control single(tbb::global_control::max_allowed_parallelism, 1);
    one = measureModelDisplacement(m, moved);
  }
  EXPECT_EQ(all.rays, one.rays);
  EXPECT_EQ(all.bothHit, one.bothHit);
  EXPECT_EQ(all.oneSidedHits(), one.oneSidedHits());
  EXPECT_EQ(all.firstOrderEstimates, one.firstOrderEstimates);
  expectSame(all.depthVoxels, one.depthVoxels);
  expectSame(all.distanceVoxels, one.distanceVoxels);
  expectSame(all.normalDegrees, one.normalDegrees);
  expectSame(all.rayNormalDegrees, one.rayNormalDegrees);
  EXPECT_EQ(all.worstCell, one.worstCell);
}
