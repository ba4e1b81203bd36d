// The reference field of sampled volumes (tricubic_reference.h): interpolation, linear precision, monotone
// grid lines, C1 joins between cells, the edge root, and the overshoot it exists to avoid.
#include "cip/tricubic_reference.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "cip/cube_topology.h"
#include "support/random_volume.h"

using namespace cip;

namespace {

// A cell-local point of cell (i, j, k) as a point of the whole grid.
Vec3 gridPoint(const std::array<std::int64_t, 3>& cell, const Vec3& local) {
  return Vec3(static_cast<double>(cell[0]), static_cast<double>(cell[1]), static_cast<double>(cell[2])) +
         local;
}

}  // namespace

TEST(TricubicReference, InterpolatesTheSamples) {
  DenseGrid g = test::randomVolume(6, 11);
  for (std::int64_t k = 0; k < 5; ++k)
    for (std::int64_t j = 0; j < 5; ++j)
      for (std::int64_t i = 0; i < 5; ++i) {
        CellReference ref = tricubicReference(g, {i, j, k}, 0.25);
        for (int v = 0; v < 8; ++v) {
          auto c = cube::vertexCoords(v);
          EXPECT_EQ(ref.value(Vec3(c[0], c[1], c[2])), g.at(i + c[0], j + c[1], k + c[2]) - 0.25);
        }
      }
}

TEST(TricubicReference, ReproducesLinearFieldsUpToTheBorder) {
  DenseGrid g;
  g.allocate({5, 4, 6});
  const Vec3 slope(0.7, -1.3, 0.4);
  for (std::int64_t k = 0; k < 6; ++k)
    for (std::int64_t j = 0; j < 4; ++j)
      for (std::int64_t i = 0; i < 5; ++i)
        g.at(i, j, k) =
            2.0 + slope.dot(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (std::int64_t k = 0; k < 5; ++k)
    for (std::int64_t j = 0; j < 3; ++j)
      for (std::int64_t i = 0; i < 4; ++i) {
        CellReference ref = tricubicReference(g, {i, j, k}, 0.0);
        for (int s = 0; s < 5; ++s) {
          Vec3 local(u(rng), u(rng), u(rng));
          EXPECT_NEAR(ref.value(local), 2.0 + slope.dot(gridPoint({i, j, k}, local)), 1e-12);
          EXPECT_LT((ref.gradient(local) - slope).norm(), 1e-12);
        }
      }
}

// Between two consecutive samples of a grid line the reference is monotone, so it crosses an isovalue on a
// cell edge exactly when the end samples straddle it: the edge signs are the marching-cubes configuration's.
TEST(TricubicReference, MonotoneAlongEveryGridLine) {
  DenseGrid g = test::randomVolume(7, 5);
  for (std::int64_t k = 0; k < 6; ++k)
    for (std::int64_t j = 0; j < 6; ++j)
      for (std::int64_t i = 0; i < 6; ++i) {
        const std::array<std::int64_t, 3> cell{i, j, k};
        CellReference ref = tricubicReference(g, cell, 0.0);
        for (int e = 0; e < 12; ++e) {
          auto c0 = cube::vertexCoords(cube::edgeVertex(e, 0));
          const int axis = cube::edgeAxis(e);
          const double a = g.at(i + c0[0], j + c0[1], k + c0[2]);
          Vec3 local(c0[0], c0[1], c0[2]);
          local[axis] = 1;
          const double b = ref.value(local);
          double previous = a;
          for (int s = 1; s <= 64; ++s) {
            local[axis] = s / 64.0;
            const double v = ref.value(local);
            EXPECT_GE((v - previous) * (b - a), -1e-14)
                << "cell " << i << " " << j << " " << k << " edge " << e;
            previous = v;
          }
        }
      }
}

// Grid-point data depend only on the samples around the point, so two cells sharing a face give the same
// values and gradients on it.
TEST(TricubicReference, ValueAndGradientContinuousAcrossCells) {
  DenseGrid g = test::randomVolume(7, 9);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int axis = 0; axis < 3; ++axis)
    for (std::int64_t k = 0; k < 5; ++k)
      for (std::int64_t j = 0; j < 5; ++j)
        for (std::int64_t i = 0; i < 5; ++i) {
          std::array<std::int64_t, 3> lower{i, j, k}, upper = lower;
          ++upper[static_cast<std::size_t>(axis)];
          CellReference a = tricubicReference(g, lower, 0.0), b = tricubicReference(g, upper, 0.0);
          Vec3 onLower(u(rng), u(rng), u(rng));
          onLower[axis] = 1;
          Vec3 onUpper = onLower;
          onUpper[axis] = 0;
          EXPECT_NEAR(a.value(onLower), b.value(onUpper), 1e-12);
          EXPECT_LT((a.gradient(onLower) - b.gradient(onUpper)).norm(), 1e-11);
        }
}

TEST(TricubicReference, EdgeRootLiesOnTheReferenceWithItsGradientAsNormal) {
  // Edges along every axis, inside the grid and on its faces (where the edge lies on the far side of the cell
  // that holds it).
  DenseGrid g = test::randomVolume(6, 21);
  TricubicInterpolant ref(g);
  int roots = 0;
  for (int axis = 0; axis < 3; ++axis)
    for (std::int64_t k = 0; k < 6; ++k)
      for (std::int64_t j = 0; j < 6; ++j)
        for (std::int64_t i = 0; i < 6; ++i) {
          std::array<std::int64_t, 3> p0{i, j, k}, p1 = p0;
          if (++p1[static_cast<std::size_t>(axis)] >= 6) continue;
          if ((g.at(p0[0], p0[1], p0[2]) > 0) == (g.at(p1[0], p1[1], p1[2]) > 0)) continue;
          Vec3 normal;
          const double t = cubicEdgeVertex(g, p0, axis, 0.0, normal);
          ASSERT_GE(t, 0.0);
          ASSERT_LE(t, 1.0);
          Vec3 p(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k));
          p[axis] += t;
          EXPECT_NEAR(ref.value(p), 0.0, 1e-12);
          const Vec3 gradient = ref.gradient(p);
          EXPECT_LT((normal - gradient.normalized()).norm(), 1e-9)
              << axis << " " << i << " " << j << " " << k;
          ++roots;
        }
  EXPECT_GT(roots, 150);
}

// A steep step next to a sample just below the isovalue: Catmull-Rom's tangent there, (100.2 - 0) / 2, would
// carry the cubic from 100 to over 110 on an edge whose end samples 100 and 100.2 both lie below 100.5, i.e.
// cross the isovalue twice on an edge the marching-cubes configuration calls uncrossed.
TEST(TricubicReference, NoOvershootNextToASteepStep) {
  DenseGrid g;
  g.allocate({5, 4, 4});
  const double line[5] = {0, 100, 100.2, 100.3, 100.35};
  for (std::int64_t k = 0; k < 4; ++k)
    for (std::int64_t j = 0; j < 4; ++j)
      for (std::int64_t i = 0; i < 5; ++i) g.at(i, j, k) = line[i];
  CellReference ref = tricubicReference(g, {1, 1, 1}, 100.5);
  double highest = -1e300;
  for (int s = 0; s <= 100; ++s) highest = std::max(highest, ref.value(Vec3(s / 100.0, 0.5, 0.5)));
  EXPECT_LE(highest, 100.2 - 100.5);
}
