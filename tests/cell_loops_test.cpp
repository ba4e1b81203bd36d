// Loops of all 256 sign configurations against an independent oracle: on the cube's surface (a sphere) the
// loops separate the sign regions, so every loop is the set of crossed edges between one positive and one
// negative region, and #loops = #regions - 1.
#include "cip/topology/cell_loops.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <set>

#include "cip/topology/cube_topology.h"

using namespace cip;

namespace {

// Connected components of same-sign vertices on the cube surface: along uncrossed edges, and across an
// ambiguous face's diagonal when the pairing keeps that diagonal's vertices connected (i.e. cuts off the
// other diagonal).
std::array<int, 8> surfaceRegions(std::uint8_t config, std::uint8_t pairing03) {
  std::array<int, 8> comp;
  for (int v = 0; v < 8; ++v) comp[v] = v;
  auto find = [&](int v) {
    while (comp[v] != v) v = comp[v];
    return v;
  };
  auto join = [&](int a, int b) { comp[find(a)] = find(b); };
  auto sign = [&](int v) { return (config >> v) & 1; };
  for (int e = 0; e < 12; ++e) {
    int a = cube::edgeVertex(e, 0), b = cube::edgeVertex(e, 1);
    if (sign(a) == sign(b)) join(a, b);
  }
  for (int f = 0; f < 6; ++f) {
    if (!cube::isAmbiguousFace(config, f)) continue;
    if ((pairing03 >> f) & 1) {
      join(cube::faceVertex(f, 1), cube::faceVertex(f, 2));  // 0 and 3 cut off: 1 and 2 connected
    } else {
      join(cube::faceVertex(f, 0), cube::faceVertex(f, 3));
    }
  }
  for (int v = 0; v < 8; ++v) comp[v] = find(v);
  return comp;
}

}  // namespace

TEST(CubeTopology, EdgesAndFacesAreConsistent) {
  for (int e = 0; e < 12; ++e) {
    auto a = cube::vertexCoords(cube::edgeVertex(e, 0)), b = cube::vertexCoords(cube::edgeVertex(e, 1));
    int diff = 0;
    for (int k = 0; k < 3; ++k) diff += a[k] != b[k];
    EXPECT_EQ(diff, 1);
    EXPECT_EQ(b[cube::edgeAxis(e)] - a[cube::edgeAxis(e)], 1);
    for (int f : cube::edgeFaces(e)) {
      bool found = false;
      for (int k = 0; k < 4; ++k) found |= cube::faceEdge(f, k) == e;
      EXPECT_TRUE(found) << "edge " << e << " face " << f;
    }
  }
  for (int f = 0; f < 6; ++f) {
    std::set<int> edges;
    for (int k = 0; k < 4; ++k) edges.insert(cube::faceEdge(f, k));
    EXPECT_EQ(edges.size(), 4u);
    // Canonical vertex k = (u,v); canonical edge 0 joins vertices 0 and 1, edge 2 joins 0 and 2.
    auto ends = [](int e) { return std::set<int>{cube::edgeVertex(e, 0), cube::edgeVertex(e, 1)}; };
    EXPECT_EQ(ends(cube::faceEdge(f, 0)), (std::set<int>{cube::faceVertex(f, 0), cube::faceVertex(f, 1)}));
    EXPECT_EQ(ends(cube::faceEdge(f, 1)), (std::set<int>{cube::faceVertex(f, 2), cube::faceVertex(f, 3)}));
    EXPECT_EQ(ends(cube::faceEdge(f, 2)), (std::set<int>{cube::faceVertex(f, 0), cube::faceVertex(f, 2)}));
    EXPECT_EQ(ends(cube::faceEdge(f, 3)), (std::set<int>{cube::faceVertex(f, 1), cube::faceVertex(f, 3)}));
  }
}

TEST(CellLoops, AllConfigurationsAndPairingsMatchTheSurfaceRegions) {
  int configsWithAmbiguity = 0;
  for (int config = 0; config < 256; ++config) {
    std::uint8_t c = static_cast<std::uint8_t>(config);
    std::uint8_t ambiguous = 0;
    for (int f = 0; f < 6; ++f)
      if (cube::isAmbiguousFace(c, f)) ambiguous = static_cast<std::uint8_t>(ambiguous | (1u << f));
    configsWithAmbiguity += ambiguous != 0;
    for (int pairing = 0; pairing < 64; ++pairing) {
      if ((pairing & ~ambiguous) != 0) continue;  // only vary the ambiguous faces
      CellLoops loops = buildCellLoops(c, static_cast<std::uint8_t>(pairing));
      std::uint16_t crossed = cube::crossedEdges(c);
      ASSERT_EQ(loops.numCorners(), __builtin_popcount(crossed)) << config;
      EXPECT_EQ(loops.faceMask, cube::crossedFaces(c));
      // Each crossed edge appears once; consecutive corners share a face; no side on a face twice in a loop
      // except ambiguous faces.
      std::set<int> seen;
      for (int k = 0; k < loops.numCorners(); ++k) {
        EXPECT_TRUE((crossed >> loops.edges[k]) & 1);
        EXPECT_TRUE(seen.insert(loops.edges[k]).second);
        EXPECT_GE(loops.sideFace(k), 0) << "config " << config << " corner " << k;
      }
      // Oracle: regions and the crossed edges between each pair of regions.
      auto comp = surfaceRegions(c, static_cast<std::uint8_t>(pairing));
      std::set<int> regions(comp.begin(), comp.end());
      std::map<std::pair<int, int>, std::set<int>> between;
      for (int e = 0; e < 12; ++e)
        if ((crossed >> e) & 1) {
          int a = comp[cube::edgeVertex(e, 0)], b = comp[cube::edgeVertex(e, 1)];
          between[{std::min(a, b), std::max(a, b)}].insert(e);
        }
      if (config == 0 || config == 255) {
        EXPECT_EQ(loops.numLoops, 0);
        continue;
      }
      ASSERT_EQ(loops.numLoops, static_cast<int>(regions.size()) - 1) << "config " << config;
      ASSERT_EQ(static_cast<int>(between.size()), loops.numLoops);
      std::multiset<std::set<int>> expected, actual;
      for (auto& kv : between) expected.insert(kv.second);
      int start = 0;
      for (int l = 0; l < loops.numLoops; ++l) {
        EXPECT_GE(loops.loopSize[l], 3);
        actual.insert(
            std::set<int>(loops.edges.begin() + start, loops.edges.begin() + start + loops.loopSize[l]));
        start += loops.loopSize[l];
      }
      EXPECT_EQ(actual, expected) << "config " << config << " pairing " << pairing;
    }
  }
  EXPECT_GT(configsWithAmbiguity, 0);
}

TEST(CellLoops, CanonicalMarchingCubesCases) {
  // A few of the 15 basic cases, as loop-size multisets (ambiguous faces resolved to keep positives apart).
  auto sizes = [](std::uint8_t config) {
    std::uint8_t pairing = 0;  // cut off the positive diagonal on every ambiguous face
    for (int f = 0; f < 6; ++f)
      if ((config >> cube::faceVertex(f, 0)) & 1) pairing = static_cast<std::uint8_t>(pairing | (1u << f));
    CellLoops l = buildCellLoops(config, pairing);
    std::multiset<int> s(l.loopSize.begin(), l.loopSize.begin() + l.numLoops);
    return s;
  };
  EXPECT_EQ(sizes(0x01), (std::multiset<int>{3}));           // case 1: one corner
  EXPECT_EQ(sizes(0x03), (std::multiset<int>{4}));           // case 2: an edge
  EXPECT_EQ(sizes(0x07), (std::multiset<int>{5}));           // case 5: three corners of a face
  EXPECT_EQ(sizes(0x0F), (std::multiset<int>{4}));           // case 8: a whole face
  EXPECT_EQ(sizes(0x81), (std::multiset<int>{3, 3}));        // case 4: opposite corners (no shared face)
  EXPECT_EQ(sizes(0x17), (std::multiset<int>{6}));           // case 9/11 family: hexagon
  EXPECT_EQ(sizes(0x69), (std::multiset<int>{3, 3, 3, 3}));  // case 13: four isolated corners
  EXPECT_EQ(sizes(0x09), (std::multiset<int>{3, 3}));        // case 3: diagonal corners of a face, kept apart
  EXPECT_EQ(sizes(0x0C), (std::multiset<int>{4}));           // case 2 again, another edge
}

TEST(CellLoops, AmbiguousPairingByShortestSegments) {
  // Crossings near vertex 0 on edges 0 and 2: the segments around vertex 0 are short -> pair around 0 and 3.
  EXPECT_TRUE(cutsOffDiagonal03({0.1, 0.9, 0.1, 0.9}, true));
  EXPECT_FALSE(cutsOffDiagonal03({0.9, 0.1, 0.9, 0.1}, true));
  // Exact tie: the negative diagonal is cut off.
  EXPECT_FALSE(cutsOffDiagonal03({0.5, 0.5, 0.5, 0.5}, true));
  EXPECT_TRUE(cutsOffDiagonal03({0.5, 0.5, 0.5, 0.5}, false));
}

TEST(CellLoops, OrientationPositiveSideOnTheLeft) {
  // For every configuration, consecutive corners form segments on faces; the positive vertex of the first
  // edge lies to the left of the segment seen from outside the cube.
  for (int config = 1; config < 255; ++config) {
    CellLoops loops = buildCellLoops(static_cast<std::uint8_t>(config), 0);
    for (int k = 0; k < loops.numCorners(); ++k) {
      int e1 = loops.edges[k], e2 = loops.edges[loops.nextCorner(k)], f = loops.sideFace(k);
      ASSERT_GE(f, 0);
      auto mid = [](int e) {
        auto a = cube::vertexCoords(cube::edgeVertex(e, 0)), b = cube::vertexCoords(cube::edgeVertex(e, 1));
        return std::array<double, 3>{(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0, (a[2] + b[2]) / 2.0};
      };
      auto m1 = mid(e1), m2 = mid(e2);
      int pv = ((config >> cube::edgeVertex(e2, 1)) & 1) ? cube::edgeVertex(e2, 1) : cube::edgeVertex(e2, 0);
      auto p = cube::vertexCoords(pv);
      double d[3] = {m2[0] - m1[0], m2[1] - m1[1], m2[2] - m1[2]};
      double q[3] = {p[0] - m2[0], p[1] - m2[1], p[2] - m2[2]};
      double n[3] = {0, 0, 0};
      n[cube::faceAxis(f)] = cube::faceSide(f) ? 1 : -1;
      double cross[3] = {d[1] * q[2] - d[2] * q[1], d[2] * q[0] - d[0] * q[2], d[0] * q[1] - d[1] * q[0]};
      EXPECT_GT(cross[0] * n[0] + cross[1] * n[1] + cross[2] * n[2], 0) << config << " corner " << k;
    }
  }
}
