// Test helpers: random volumes and per-cell corner data shared by several test files.
#pragma once
#include <random>

#include "cip/reference/isovertex.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/dense_grid.h"

namespace cip::test {

/// A volume of independent uniform values in [-1, 1]: about half of its faces with four crossings are
/// ambiguous. With `closedBorder`, border points are set to -1 so the surface is closed inside the volume.
inline DenseGrid randomVolume(int n, unsigned seed, bool closedBorder = false) {
  DenseGrid g;
  g.allocate({n, n, n});
  g.description = "random volume";
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (auto& v : g.values) v = u(rng);
  if (closedBorder)
    for (int k = 0; k < n; ++k)
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
          if (i == 0 || j == 0 || k == 0 || i == n - 1 || j == n - 1 || k == n - 1) g.at(i, j, k) = -1;
  return g;
}

/// Corner data of one cell with sign configuration `config`: random magnitudes in [0.2, 1], isovertices by
/// linear interpolation, random unit normals oriented towards the positive vertex (cell-local coordinates).
inline std::array<IsoVertex, 12> randomCellVertices(std::uint8_t config, std::mt19937& rng) {
  std::uniform_real_distribution<double> mag(0.2, 1.0), comp(-1.0, 1.0);
  std::array<double, 8> value;
  for (int v = 0; v < 8; ++v) value[v] = ((config >> v) & 1) ? mag(rng) : -mag(rng);
  std::array<IsoVertex, 12> vx;
  for (int e = 0; e < 12; ++e) {
    int a = cube::edgeVertex(e, 0), b = cube::edgeVertex(e, 1), axis = cube::edgeAxis(e);
    auto c = cube::vertexCoords(a);
    double t = linearCrossing(value[a], value[b], 0.0);
    vx[e].position = Vec3(c[0], c[1], c[2]);
    vx[e].position[axis] += t;
    Vec3 towardsPositive = Vec3::Unit(axis) * (value[b] > 0 ? 1.0 : -1.0);
    vx[e].normal =
        orientCornerNormal(Vec3(comp(rng), comp(rng), comp(rng)) + towardsPositive, towardsPositive);
  }
  return vx;
}

}  // namespace cip::test
