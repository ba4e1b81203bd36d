// The reference field of sampled volumes (tricubic_reference.h): interpolation, linear precision, monotone
// grid lines, C1 joins between cells, the edge root, and the overshoot it exists to avoid; for the central8
// reconstruction also cubic precision and its better normals on smooth data.
#include "cip/reference/tricubic_reference.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "cip/topology/cube_topology.h"
#include "support/random_volume.h"

using namespace cip;

namespace {

// A cell-local point of cell (i, j, k) as a point of the whole grid.
Vec3 gridPoint(const std::array<std::int64_t, 3>& cell, const Vec3& local) {
  return Vec3(static_cast<double>(cell[0]), static_cast<double>(cell[1]), static_cast<double>(cell[2])) +
         local;
}

}  // namespace

const Reconstruction kKinds[] = {Reconstruction::Monotone, Reconstruction::Central8};

TEST(TricubicReference, InterpolatesTheSamples) {
  DenseGrid g = test::randomVolume(6, 11);
  for (Reconstruction kind : kKinds)
    for (std::int64_t k = 0; k < 5; ++k)
      for (std::int64_t j = 0; j < 5; ++j)
        for (std::int64_t i = 0; i < 5; ++i) {
          CellReference ref = tricubicReference(g, {i, j, k}, 0.25, kind);
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
  for (Reconstruction kind : kKinds)
    for (std::int64_t k = 0; k < 5; ++k)
      for (std::int64_t j = 0; j < 3; ++j)
        for (std::int64_t i = 0; i < 4; ++i) {
          CellReference ref = tricubicReference(g, {i, j, k}, 0.0, kind);
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
  for (Reconstruction kind : kKinds)
    for (int axis = 0; axis < 3; ++axis)
      for (std::int64_t k = 0; k < 5; ++k)
        for (std::int64_t j = 0; j < 5; ++j)
          for (std::int64_t i = 0; i < 5; ++i) {
            std::array<std::int64_t, 3> lower{i, j, k}, upper = lower;
            ++upper[static_cast<std::size_t>(axis)];
            CellReference a = tricubicReference(g, lower, 0.0, kind),
                          b = tricubicReference(g, upper, 0.0, kind);
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
  for (Reconstruction kind : kKinds) {
    TricubicInterpolant ref(g, kind);
    int roots = 0;
    for (int axis = 0; axis < 3; ++axis)
      for (std::int64_t k = 0; k < 6; ++k)
        for (std::int64_t j = 0; j < 6; ++j)
          for (std::int64_t i = 0; i < 6; ++i) {
            std::array<std::int64_t, 3> p0{i, j, k}, p1 = p0;
            if (++p1[static_cast<std::size_t>(axis)] >= 6) continue;
            if ((g.at(p0[0], p0[1], p0[2]) > 0) == (g.at(p1[0], p1[1], p1[2]) > 0)) continue;
            Vec3 normal;
            const double t = cubicEdgeVertex(g, p0, axis, 0.0, normal, kind);
            ASSERT_GE(t, 0.0);
            ASSERT_LE(t, 1.0);
            Vec3 p(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k));
            p[axis] += t;
            EXPECT_NEAR(ref.value(p), 0.0, 1e-12);
            const Vec3 gradient = ref.gradient(p);
            EXPECT_LT((normal - gradient.normalized()).norm(), 1e-9)
                << toString(kind) << " " << axis << " " << i << " " << j << " " << k;
            ++roots;
          }
    EXPECT_GT(roots, 150);
  }
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

// 8th-order differences are exact on cubics, so wherever the stencil (4 samples each side) lies inside the
// grid the central8 reference is the sampled cubic itself, values and gradients.
TEST(TricubicReference, Central8ReproducesCubicsInside) {
  auto cubic = [](const Vec3& p) {
    return 0.5 + p.x() * p.y() * p.z() - 0.3 * p.x() * p.x() * p.x() + 0.2 * p.y() * p.y() * p.z() +
           0.7 * p.z() * p.z() - p.x();
  };
  auto gradient = [](const Vec3& p) {
    return Vec3(p.y() * p.z() - 0.9 * p.x() * p.x() - 1, p.x() * p.z() + 0.4 * p.y() * p.z(),
                p.x() * p.y() + 0.2 * p.y() * p.y() + 1.4 * p.z());
  };
  DenseGrid g;
  g.allocate({11, 11, 12});
  for (std::int64_t k = 0; k < 12; ++k)
    for (std::int64_t j = 0; j < 11; ++j)
      for (std::int64_t i = 0; i < 11; ++i)
        g.at(i, j, k) =
            cubic(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)) * 0.1);
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (std::int64_t k = 4; k <= 6; ++k)
    for (std::int64_t i = 4; i <= 5; ++i) {
      const std::array<std::int64_t, 3> cell{i, 5, k};
      CellReference ref = tricubicReference(g, cell, 0.0, Reconstruction::Central8);
      for (int s = 0; s < 5; ++s) {
        const Vec3 local(u(rng), u(rng), u(rng)), p = gridPoint(cell, local) * 0.1;
        EXPECT_NEAR(ref.value(local), cubic(p), 1e-12);
        EXPECT_LT((ref.gradient(local) * 10 - gradient(p)).norm(), 1e-10);
      }
    }
  // The monotone reference is not: its limited slopes are second-order differences.
  CellReference monotone = tricubicReference(g, {4, 5, 4}, 0.0);
  EXPECT_GT(
      std::abs(monotone.value(Vec3(0.3, 0.6, 0.2)) - cubic(gridPoint({4, 5, 4}, Vec3(0.3, 0.6, 0.2)) * 0.1)),
      1e-9);
}

// A smooth ripple at four samples per wavelength along each axis: the central8 reference's normal is far
// closer to the true one than the monotone reference's, whose limiter flattens every sampled extremum.
TEST(TricubicReference, Central8KnowsTheNormalOfSmoothData) {
  const double w = 2 * 3.14159265358979 / 4.2;
  auto field = [w](const Vec3& p) {
    return std::sin(w * p.x() + 0.3) * std::cos(w * p.y() - 0.2) + 0.2 * p.z();
  };
  auto gradient = [w](const Vec3& p) {
    return Vec3(w * std::cos(w * p.x() + 0.3) * std::cos(w * p.y() - 0.2),
                -w * std::sin(w * p.x() + 0.3) * std::sin(w * p.y() - 0.2), 0.2);
  };
  DenseGrid g;
  g.allocate({24, 24, 24});
  for (std::int64_t k = 0; k < 24; ++k)
    for (std::int64_t j = 0; j < 24; ++j)
      for (std::int64_t i = 0; i < 24; ++i)
        g.at(i, j, k) = field(Vec3(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)));
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(6.0, 17.0);
  double error[2] = {0, 0};
  for (int s = 0; s < 400; ++s) {
    const Vec3 p(u(rng), u(rng), u(rng));
    const Vec3 truth = gradient(p).normalized();
    for (int kind = 0; kind < 2; ++kind) {
      const TricubicInterpolant ref(g, kKinds[kind]);
      error[kind] += std::acos(std::clamp(ref.gradient(p).normalized().dot(truth), -1.0, 1.0));
    }
  }
  EXPECT_LT(error[1], 0.25 * error[0]) << "mean angles " << error[0] / 400 << " and " << error[1] / 400;
}

// valueAndGradient contracts x and y with the z indices in vector lanes where the processor has AVX2; its
// value must be value()'s bit for bit (the same operations in the same order) and its gradient the tensor
// product of the weight derivatives, summed in the same order, on random Hermite data.
TEST(TricubicReference, ValueAndGradientIsTheTensorProductBitForBit) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0), t(0.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    CellReference ref;
    for (double& h : ref.hermite) h = u(rng);
    ref.isovalue = 0.1;
    const Vec3 x(t(rng), t(rng), t(rng));
    double w[3][4], d[3][4];
    for (int a = 0; a < 3; ++a) hermiteWeights(x[a], w[a], d[a]);
    double value = 0;
    Vec3 expected = Vec3::Zero();
    for (int k = 0; k < 4; ++k) {
      double plane = 0, planeDx = 0, planeDy = 0;
      for (int j = 0; j < 4; ++j) {
        const double* row = &ref.hermite[static_cast<std::size_t>(4 * (j + 4 * k))];
        const double v = w[0][0] * row[0] + w[0][1] * row[1] + w[0][2] * row[2] + w[0][3] * row[3];
        const double dx = d[0][0] * row[0] + d[0][1] * row[1] + d[0][2] * row[2] + d[0][3] * row[3];
        plane += w[1][j] * v;
        planeDx += w[1][j] * dx;
        planeDy += d[1][j] * v;
      }
      value += w[2][k] * plane;
      expected.x() += w[2][k] * planeDx;
      expected.y() += w[2][k] * planeDy;
      expected.z() += d[2][k] * plane;
    }
    Vec3 gradient;
    const double got = ref.valueAndGradient(x, gradient);
    EXPECT_EQ(got, value - ref.isovalue);
    EXPECT_EQ(got, ref.value(x));
    for (int a = 0; a < 3; ++a) EXPECT_EQ(gradient[a], expected[a]) << "axis " << a << ", trial " << trial;
  }
}
