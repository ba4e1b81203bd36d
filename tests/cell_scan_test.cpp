// The builder's scan: a dense grid built as one brick (crossed cells visited between the rows' sign changes,
// edges taken from the point rows, already in key order) against the same grid cut into bricks (edges taken
// from the crossed cells, sorted and merged), byte for byte, on grids made to stress the row trimming: flat
// rows on either side, rows that change side only at their ends, samples exactly at the isovalue, plateaus
// that differ between neighbouring rows, and NaN samples (skipped cells).
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/topology/cube_topology.h"
#include "support/model_bytes.h"

namespace {

using cip::DenseGrid;
using cip::GridBrick;

/// The grid cut into bricks of at most `size` cells per axis, each with `apron` points around its cells
/// (copied from the grid where it has them).
struct Bricked {
  std::vector<DenseGrid> grids;
  std::vector<GridBrick> bricks;
};

Bricked cut(const DenseGrid& g, std::int64_t size, int apron) {
  Bricked out;
  const auto& d = g.geometry.dims;
  std::vector<std::array<std::int64_t, 6>> boxes;  // cell ranges
  for (std::int64_t z = 0; z < d[2] - 1; z += size)
    for (std::int64_t y = 0; y < d[1] - 1; y += size)
      for (std::int64_t x = 0; x < d[0] - 1; x += size)
        boxes.push_back({x, y, z, std::min(x + size, d[0] - 1), std::min(y + size, d[1] - 1),
                         std::min(z + size, d[2] - 1)});
  out.grids.resize(boxes.size());
  for (std::size_t b = 0; b < boxes.size(); ++b) {
    const auto& box = boxes[b];
    std::array<std::int64_t, 3> lo, hi;
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::max<std::int64_t>(0, box[a] - apron);
      hi[a] = std::min<std::int64_t>(d[a] - 1, box[a + 3] + apron);  // last point, inclusive
    }
    DenseGrid& bg = out.grids[b];
    bg.allocate({hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1});
    bg.geometry.origin = g.geometry.origin;
    bg.geometry.spacing = g.geometry.spacing;
    for (std::int64_t k = lo[2]; k <= hi[2]; ++k)
      for (std::int64_t j = lo[1]; j <= hi[1]; ++j)
        for (std::int64_t i = lo[0]; i <= hi[0]; ++i) bg.at(i - lo[0], j - lo[1], k - lo[2]) = g.at(i, j, k);
    GridBrick br;
    br.offset = lo;
    for (int a = 0; a < 3; ++a) {
      br.cellBegin[a] = box[a] - lo[a];
      br.cellEnd[a] = box[a + 3] - lo[a];
    }
    out.bricks.push_back(br);
  }
  for (std::size_t b = 0; b < out.bricks.size(); ++b) out.bricks[b].grid = &out.grids[b];
  return out;
}

/// A field with every hard case of the scan: a smooth blob, plateaus exactly at the isovalue, rows whose sign
/// changes only at their first or last point, flat planes of opposite sign in neighbouring rows, and noise.
DenseGrid stressGrid(std::uint32_t seed, bool withNaN) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> noise(-1, 1);
  DenseGrid g;
  const std::int64_t nx = 23, ny = 17, nz = 14;
  g.allocate({nx, ny, nz});
  g.geometry.origin = cip::Vec3::Zero();
  g.geometry.spacing = cip::Vec3::Ones();
  for (std::int64_t k = 0; k < nz; ++k)
    for (std::int64_t j = 0; j < ny; ++j)
      for (std::int64_t i = 0; i < nx; ++i) {
        const double x = (double(i) - 11) / 6, y = (double(j) - 8) / 5, z = (double(k) - 7) / 4;
        double v = std::sqrt(x * x + y * y + z * z) - 1.0;   // a blob
        if (j == 2) v = (k % 2 == 0) ? 1.0 : -1.0;           // flat rows, sides alternating in z
        if (j == 3 && k == 4) v = i == 0 ? -1.0 : 1.0;       // changes side at its first point only
        if (j == 4 && k == 5) v = i == nx - 1 ? -1.0 : 1.0;  // ... at its last point only
        if (j == 14 && (i + k) % 3 == 0) v = 0.0;            // samples exactly at the isovalue
        if (k == 11) v = 0.3 * noise(rng);                   // a noisy slab
        g.at(i, j, k) = v;
      }
  if (withNaN) {
    g.at(5, 6, 7) = std::numeric_limits<double>::quiet_NaN();
    g.at(20, 15, 12) = std::numeric_limits<double>::infinity();
  }
  return g;
}

std::vector<std::uint8_t> bytes(const cip::Model& m) {
  return cip::test::modelBytes(m);
}

void expectSameModels(const DenseGrid& g, cip::BuildOptions o) {
  for (int threads : {1, 2}) {
    o.threads = threads;
    const cip::Model whole = cip::buildModel(g, o);
    ASSERT_GT(whole.cells.size(), 100u);
    // Every crossed edge of every cell is in the vertex table, and the table has no other vertex.
    std::size_t corners = 0;
    for (const auto& c : whole.cells) corners += static_cast<std::size_t>(c.numCorners());
    EXPECT_EQ(corners, whole.corners.size());
    std::vector<bool> used(whole.vertices.size(), false);
    for (std::uint32_t v : whole.corners) used.at(v) = true;
    for (std::size_t v = 0; v < used.size(); ++v) EXPECT_TRUE(used[v]) << "isovertex " << v << " of no cell";
    for (std::int64_t size : {4, 7}) {
      const Bricked b = cut(g, size, cip::brickApron(o));
      const cip::Model parts = cip::buildModel(g.geometry, b.bricks, o, g.description);
      EXPECT_EQ(bytes(whole), bytes(parts)) << "bricks of " << size << " cells, " << threads << " threads";
    }
  }
}

TEST(CellScan, OneBrickEqualsBricks) {
  for (std::uint32_t seed : {1u, 2u, 3u})
    for (cip::PatchMethod method : {cip::PatchMethod::Paper, cip::PatchMethod::Fitted}) {
      cip::BuildOptions o;
      o.method = method;
      expectSameModels(stressGrid(seed, false), o);
    }
}

TEST(CellScan, SkippedNonFiniteCellsEqualBricks) {
  cip::BuildOptions o;
  o.skipNonFinite = true;
  o.method = cip::PatchMethod::Paper;
  const DenseGrid g = stressGrid(4, true);
  expectSameModels(g, o);
  // The cells around the NaN and the infinity are left out, the others are there.
  const cip::Model m = cip::buildModel(g, o);
  for (const auto& c : m.cells) {
    const bool nearNaN = c.index[0] + 1 >= 5 && c.index[0] <= 5 && c.index[1] + 1 >= 6 && c.index[1] <= 6 &&
                         c.index[2] + 1 >= 7 && c.index[2] <= 7;
    EXPECT_FALSE(nearNaN);
  }
}

TEST(CellScan, NonFiniteSampleThrowsWithoutSkip) {
  cip::BuildOptions o;
  o.method = cip::PatchMethod::Paper;
  EXPECT_THROW(cip::buildModel(stressGrid(5, true), o), cip::NonFiniteSampleError);
}

TEST(CellScan, CrossedCellsAreExactlyTheMixedOnes) {
  // Against a plain loop over every cell: the trimmed scan neither misses nor adds a cell.
  const DenseGrid g = stressGrid(6, false);
  cip::BuildOptions o;
  o.method = cip::PatchMethod::Paper;
  o.fitCoefficients = false;
  const cip::Model m = cip::buildModel(g, o);
  std::size_t n = 0;
  const auto& d = g.geometry.dims;
  for (std::int64_t k = 0; k + 1 < d[2]; ++k)
    for (std::int64_t j = 0; j + 1 < d[1]; ++j)
      for (std::int64_t i = 0; i + 1 < d[0]; ++i) {
        unsigned config = 0;
        for (int v = 0; v < 8; ++v) {
          const auto c = cip::cube::vertexCoords(v);
          if (g.at(i + c[0], j + c[1], k + c[2]) > 0) config |= 1u << v;
        }
        if (config == 0 || config == 255) continue;
        ASSERT_LT(n, m.cells.size());
        EXPECT_EQ(m.cells[n].index,
                  (std::array<std::uint32_t, 3>{static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(j),
                                                static_cast<std::uint32_t>(k)}));
        EXPECT_EQ(m.cells[n].config, config);
        ++n;
      }
  EXPECT_EQ(n, m.cells.size());
}

}  // namespace
