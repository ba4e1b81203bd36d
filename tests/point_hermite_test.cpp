// The reference's data at grid points (point_hermite.h): a table computed over tiles gives every cell and
// edge exactly the data of the per-cell reference, at the border too; the data are the derivatives of
// polynomials the reconstructions reproduce.
#include "cip/reference/point_hermite.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "cip/core/error.h"
#include "cip/reference/point_hermite_table.h"
#include "cip/topology/cube_topology.h"
#include "support/random_volume.h"

using namespace cip;

namespace {

const Reconstruction kKinds[] = {Reconstruction::Monotone, Reconstruction::Central8};

// A random volume whose dims span several tiles of the table along every axis and are not multiples of them.
DenseGrid unevenVolume(unsigned seed) {
  DenseGrid g;
  g.allocate({70, 37, 35});
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (auto& v : g.values) v = u(rng);
  return g;
}

// Every cell with a corner on the border, and one interior cell in eight.
std::vector<std::array<std::int64_t, 3>> someCells(const DenseGrid& g) {
  std::vector<std::array<std::int64_t, 3>> cells;
  const auto& d = g.geometry.dims;
  std::int64_t n = 0;
  for (std::int64_t k = 0; k + 1 < d[2]; ++k)
    for (std::int64_t j = 0; j + 1 < d[1]; ++j)
      for (std::int64_t i = 0; i + 1 < d[0]; ++i) {
        const bool border = i == 0 || j == 0 || k == 0 || i + 2 == d[0] || j + 2 == d[1] || k + 2 == d[2];
        if (border || ++n % 8 == 0) cells.push_back({i, j, k});
      }
  return cells;
}

std::vector<std::int64_t> indices(const DenseGrid& g, const std::vector<std::array<std::int64_t, 3>>& cells) {
  std::vector<std::int64_t> out;
  for (const auto& c : cells) out.push_back(g.index(c[0], c[1], c[2]));
  return out;
}

}  // namespace

TEST(PointHermiteTable, GivesEachCellThePerCellReference) {
  const DenseGrid g = unevenVolume(5);
  const auto cells = someCells(g);
  for (Reconstruction kind : kKinds) {
    const PointHermiteTable table(g, indices(g, cells), kind);
    std::size_t mismatches = 0;
    for (const auto& c : cells) {
      CellReference fromTable, perCell;
      fromTable.metric = Vec3::Constant(2.0);  // setReference resets every member
      table.setReference(c, 0.3, fromTable);
      setTricubicReference(g, c, 0.3, perCell, kind);
      mismatches += fromTable.hermite != perCell.hermite;
      EXPECT_EQ(fromTable.isovalue, 0.3);
      EXPECT_EQ(fromTable.metric, Vec3::Ones());
      EXPECT_EQ(fromTable.field, nullptr);
    }
    EXPECT_EQ(mismatches, 0u) << toString(kind) << ", of " << cells.size() << " cells";
  }
}

TEST(PointHermiteTable, HoldsEveryCornerOfItsCellsOnce) {
  const DenseGrid g = unevenVolume(6);
  const std::vector<std::array<std::int64_t, 3>> cells{{0, 0, 0}, {1, 0, 0}, {68, 35, 33}, {40, 20, 20}};
  const PointHermiteTable table(g, indices(g, cells), Reconstruction::Monotone);
  EXPECT_EQ(table.size(), 8u + 4u + 8u + 8u);       // the first two cells share a face
  EXPECT_THROW(table.at(g.index(3, 3, 3)), Error);  // not a corner of the table's cells
  EXPECT_THROW(table.at(-1), Error);
  EXPECT_THROW(table.at(g.geometry.pointCount()), Error);
  CellReference ref;
  EXPECT_THROW(table.setReference({2, 0, 0}, 0.0, ref), Error);  // shares 4 corners with {1, 0, 0}, not 8
  for (const auto& c : cells)
    for (int v = 0; v < 8; ++v) {
      const auto o = cube::vertexCoords(v);
      EXPECT_EQ(table.at(g.index(c[0] + o[0], c[1] + o[1], c[2] + o[2]))[0],
                g.at(c[0] + o[0], c[1] + o[1], c[2] + o[2]));
    }
}

TEST(PointHermiteTable, GivesEachEdgeThePerEdgeVertex) {
  DenseGrid g = unevenVolume(7);
  const auto cells = someCells(g);
  const double iso = 0.1;
  for (Reconstruction kind : kKinds) {
    const PointHermiteTable table(g, indices(g, cells), kind);
    int edges = 0;
    for (const auto& c : cells)
      for (int axis = 0; axis < 3; ++axis) {
        auto end = c;
        ++end[static_cast<std::size_t>(axis)];
        const double v0 = g.at(c[0], c[1], c[2]), v1 = g.at(end[0], end[1], end[2]);
        if ((v0 > iso) == (v1 > iso)) continue;
        Vec3 fromGrid, fromTable;
        const double t = cubicEdgeVertex(g, c, axis, iso, fromGrid, kind);
        EXPECT_EQ(cubicEdgeVertex(table.at(g.index(c[0], c[1], c[2])),
                                  table.at(g.index(end[0], end[1], end[2])), axis, iso, fromTable),
                  t);
        EXPECT_EQ(fromTable, fromGrid);
        ++edges;
      }
    EXPECT_GT(edges, 1000);
  }
}

TEST(HermiteInBox, GivesTheDerivativesOfPolynomialsTheReconstructionReproduces) {
  // Central8 is exact for polynomials up to degree 8 along each axis, so for this cubic at interior points
  // and, through the odd reflection, for its linear part at the border; Monotone for linear fields.
  DenseGrid g;
  g.allocate({12, 11, 13});
  auto cubic = [](double x, double y, double z) {
    return 0.01 * x * x * x - 0.02 * x * y * z + 0.03 * y * y * z + 0.5 * x - 0.25 * z;
  };
  auto derivatives = [](double x, double y, double z) -> PointHermite {
    return {0.01 * x * x * x - 0.02 * x * y * z + 0.03 * y * y * z + 0.5 * x - 0.25 * z,
            0.03 * x * x - 0.02 * y * z + 0.5,
            -0.02 * x * z + 0.06 * y * z,
            -0.02 * z,
            -0.02 * x * y + 0.03 * y * y - 0.25,
            -0.02 * y,
            -0.02 * x + 0.06 * y,
            -0.02};
  };
  for (std::int64_t k = 0; k < 13; ++k)
    for (std::int64_t j = 0; j < 11; ++j)
      for (std::int64_t i = 0; i < 12; ++i)
        g.at(i, j, k) = cubic(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k));
  const std::array<std::int64_t, 3> lo{4, 4, 4};
  const std::array<std::array<int, 3>, 3> at{{{0, 0, 0}, {2, 1, 0}, {1, 2, 4}}};
  std::array<PointHermite, 3> out;
  hermiteInBox(g, Reconstruction::Central8, lo, {3, 3, 5}, at.data(), at.size(), out.data());
  for (std::size_t n = 0; n < at.size(); ++n) {
    const PointHermite want =
        derivatives(static_cast<double>(lo[0] + at[n][0]), static_cast<double>(lo[1] + at[n][1]),
                    static_cast<double>(lo[2] + at[n][2]));
    for (int d = 0; d < 8; ++d)
      EXPECT_NEAR(out[n][static_cast<std::size_t>(d)], want[static_cast<std::size_t>(d)], 1e-9)
          << n << " " << d;
  }
  // A linear field: both reconstructions give its gradient everywhere, at the corners of the grid too.
  for (std::int64_t k = 0; k < 13; ++k)
    for (std::int64_t j = 0; j < 11; ++j)
      for (std::int64_t i = 0; i < 12; ++i)
        g.at(i, j, k) = 1.0 + 0.5 * static_cast<double>(i) - 0.75 * static_cast<double>(j) +
                        0.125 * static_cast<double>(k);
  for (Reconstruction kind : kKinds) {
    const std::array<std::array<int, 3>, 2> corners{{{0, 0, 0}, {11, 10, 12}}};
    std::array<PointHermite, 2> linear;
    hermiteInBox(g, kind, {0, 0, 0}, {12, 11, 13}, corners.data(), corners.size(), linear.data());
    for (const PointHermite& p : linear) {
      EXPECT_NEAR(p[1], 0.5, 1e-12) << toString(kind);
      EXPECT_NEAR(p[2], -0.75, 1e-12) << toString(kind);
      EXPECT_NEAR(p[4], 0.125, 1e-12) << toString(kind);
      for (int d : {3, 5, 6, 7}) EXPECT_NEAR(p[static_cast<std::size_t>(d)], 0.0, 1e-12) << toString(kind);
    }
  }
  EXPECT_THROW(hermiteInBox(g, Reconstruction::Auto, lo, {1, 1, 1}, at.data(), 1, out.data()), Error);
}
