// Isovertex normals (isovertex.h): the normal of an isovertex that lies on a grid point is kept from tilting
// its corner plane across the uncrossed grid edges from that point, and left alone along crossed ones.
#include "cip/reference/isovertex.h"

#include <gtest/gtest.h>

#include <cmath>

using namespace cip;

namespace {

/// 3 x 3 x 3 samples, all 0 (below the isovalue 0.5) but for the ones set by the test.
DenseGrid smallGrid() {
  DenseGrid g;
  g.geometry.dims = {3, 3, 3};
  g.values.assign(27, 0.0);
  return g;
}

}  // namespace

TEST(NormalClearOfUncrossedEdges, RemovesATiltAlongAnUncrossedEdge) {
  DenseGrid g = smallGrid();
  // The centre point lies on the isovalue (it counts as below); the edge along y to (1, 2, 1) crosses.
  g.at(1, 1, 1) = 0.5;
  g.at(1, 2, 1) = 1.0;
  g.at(1, 1, 0) = 1.0;  // and the one along -z: only the edge along +z is uncrossed of the two along z
  const Vec3 towardsPositive(0, 1, 0);
  // A normal leaning towards +x: along the uncrossed edge to (2, 1, 1), whose end is below, the corner plane
  // through the centre would rise above zero.
  const Vec3 n =
      normalClearOfUncrossedEdges(g, {1, 1, 1}, 1, 0.5, Vec3(0.3, 0.9, -0.2).normalized(), towardsPositive);
  EXPECT_EQ(n.x(), 0.0);
  // Towards +z the plane falls along the edge to (1, 1, 2), whose end is below, as it should: kept.
  EXPECT_LT(n.z(), 0.0);
  EXPECT_NEAR(n.norm(), 1.0, 1e-12);
  for (const Vec3& d : {Vec3(1, 0, 0), Vec3(-1, 0, 0), Vec3(0, 0, 1)})
    EXPECT_LE(n.dot(d), 0.0) << "the plane rises along an uncrossed edge";
}

TEST(NormalClearOfUncrossedEdges, KeepsTheTiltAlongACrossedEdge) {
  DenseGrid g = smallGrid();
  g.at(1, 1, 1) = 0.5;
  g.at(1, 2, 1) = 1.0;
  g.at(2, 1, 1) = 1.0;  // the edge along +x crosses too: the plane may rise towards it
  const Vec3 normal = Vec3(0.3, 0.9, 0).normalized();  // and it falls towards -x, uncrossed
  const Vec3 n = normalClearOfUncrossedEdges(g, {1, 1, 1}, 1, 0.5, normal, Vec3(0, 1, 0));
  EXPECT_NEAR((n - normal).norm(), 0.0, 1e-15);
}

TEST(NormalClearOfUncrossedEdges, PointsOnTheGridBorderHaveFewerEdges) {
  DenseGrid g = smallGrid();
  g.at(0, 0, 0) = 0.5;
  g.at(0, 1, 0) = 1.0;
  // Towards -x there is no grid point: that component stays; towards +x the edge is uncrossed: removed.
  const Vec3 away =
      normalClearOfUncrossedEdges(g, {0, 0, 0}, 1, 0.5, Vec3(-0.3, 0.9, 0).normalized(), Vec3(0, 1, 0));
  EXPECT_LT(away.x(), 0.0);
  const Vec3 into =
      normalClearOfUncrossedEdges(g, {0, 0, 0}, 1, 0.5, Vec3(0.3, 0.9, 0).normalized(), Vec3(0, 1, 0));
  EXPECT_EQ(into.x(), 0.0);
}
