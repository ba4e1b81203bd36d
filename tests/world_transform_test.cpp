// Full index-to-world transforms: the map from a model's grid frame to the world of its outputs, meshes moved
// into it, and the orientation the model file carries.
#include "cip/core/world_transform.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <cstring>

#include "cip/core/error.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/mesh/triangle_mesh.h"
#include "cip/model/model_file.h"
#include "support/field_model.h"

using namespace cip;

namespace {

Mat3 rotation(const Vec3& axis, double degrees) {
  return Eigen::AngleAxisd(degrees * 3.14159265358979323846 / 180, axis.normalized()).toRotationMatrix();
}

GridGeometry orientedGeometry(const Mat3& direction) {
  GridGeometry g;
  g.dims = {10, 12, 14};
  g.origin = Vec3(3, -2, 5);
  g.spacing = Vec3(0.5, 2, 1.25);
  g.direction = direction;
  return g;
}

/// Signed volume enclosed by a closed mesh (positive when its triangles wind counter-clockwise seen from
/// outside).
double signedVolume(const TriangleMesh& m) {
  double v = 0;
  for (const auto& t : m.triangles)
    v += m.positions[t[0]].dot(m.positions[t[1]].cross(m.positions[t[2]])) / 6;
  return v;
}

/// Mean of (vertex normal . triangle's winding normal) over the triangles, unit vectors: +1 when the normals
/// point to the side from which the triangles wind counter-clockwise.
double normalWindingAgreement(const TriangleMesh& m) {
  double sum = 0;
  for (const auto& t : m.triangles) {
    const Vec3 w = (m.positions[t[1]] - m.positions[t[0]]).cross(m.positions[t[2]] - m.positions[t[0]]);
    if (w.norm() == 0) continue;
    sum += (m.normals[t[0]] + m.normals[t[1]] + m.normals[t[2]]).normalized().dot(w.normalized());
  }
  return sum / static_cast<double>(m.triangles.size());
}

}  // namespace

TEST(WorldTransform, MapsTheGridFrameByTheDirectionAboutTheOrigin) {
  const Mat3 d = rotation(Vec3(1, -2, 0.5), 71) * Vec3(-1, 1, 1).asDiagonal();
  const GridGeometry g = orientedGeometry(d);
  const WorldTransform w = WorldTransform::of(g);
  EXPECT_TRUE(w.flipsOrientation());
  EXPECT_LT((w.point(g.origin) - g.origin).norm(), 1e-14);  // grid point 0 stays where the file puts it
  for (const Vec3& ijk : {Vec3(1, 0, 0), Vec3(0, 3, 0), Vec3(2, 5, 7)}) {
    // world = origin + direction * (spacing * ijk): the file's index-to-world affine, computed directly
    const Vec3 expected = g.origin + d * g.spacing.cwiseProduct(ijk);
    EXPECT_LT((w.point(g.indexToWorld(ijk)) - expected).norm(), 1e-12);
    EXPECT_LT((g.worldToIndex(w.toFrame(expected)) - ijk).norm(), 1e-12);
    const Eigen::Vector4d h = w.indexToWorld(g) * ijk.homogeneous();  // the 4x4 matrix the stats report
    EXPECT_LT((h.head<3>() - expected).norm(), 1e-12);
    EXPECT_EQ(h[3], 1.0);
  }
  // Normals go by the inverse transpose: perpendicular to every mapped tangent.
  const Mat3 sheared = (Mat3() << 1, 0.4, 0, 0, 1, 0.3, 0, 0, 1).finished();
  GridGeometry gs = orientedGeometry(Mat3::Identity());
  setAxes(gs, sheared, "test");
  const WorldTransform ws = WorldTransform::of(gs);
  const Vec3 n(0.2, -0.7, 0.4), tangent = n.cross(Vec3(1, 0, 0));
  EXPECT_NEAR(ws.normal(n).dot(ws.linear * tangent), 0, 1e-14);
  EXPECT_FALSE(ws.flipsOrientation());
}

TEST(WorldTransform, ConvertsBetweenAnatomicalFrames) {
  GridGeometry g = orientedGeometry(rotation(Vec3(0, 0, 1), 30));
  g.space = WorldSpace::RAS;
  const WorldTransform ras = WorldTransform::of(g);
  const WorldTransform lps = WorldTransform::of(g, WorldSpace::LPS);
  const WorldTransform las = WorldTransform::of(g, WorldSpace::LAS);
  EXPECT_EQ(lps.space, WorldSpace::LPS);
  EXPECT_EQ(ras.space, WorldSpace::RAS);
  const Vec3 p(1.5, -3, 2);
  EXPECT_LT((lps.point(p) - Vec3(-1, -1, 1).cwiseProduct(ras.point(p))).norm(), 1e-12);
  EXPECT_LT((las.point(p) - Vec3(-1, 1, 1).cwiseProduct(ras.point(p))).norm(), 1e-12);
  EXPECT_FALSE(lps.flipsOrientation());  // two negations: a rotation by 180 degrees
  EXPECT_TRUE(las.flipsOrientation());
  g.space = WorldSpace::LPS;  // and back from LPS
  EXPECT_LT((WorldTransform::of(g, WorldSpace::RAS).point(p) -
             Vec3(-1, -1, 1).cwiseProduct(WorldTransform::of(g).point(p)))
                .norm(),
            1e-12);
  g.space = WorldSpace::Unspecified;
  EXPECT_THROW(WorldTransform::of(g, WorldSpace::RAS), Error);
  EXPECT_NO_THROW(WorldTransform::of(g));
  EXPECT_EQ(parseWorldSpace("LpS"), WorldSpace::LPS);
  EXPECT_THROW(parseWorldSpace("xyz"), Error);
}

TEST(WorldTransform, SetAxesSplitsColumnsAndRejectsSingularMatrices) {
  GridGeometry g;
  const Mat3 columns = rotation(Vec3(1, 1, 0), 20) * Vec3(2, -3, 0.5).asDiagonal();
  setAxes(g, columns, "file");
  EXPECT_LT((g.direction * g.spacing.asDiagonal() - columns).norm(), 1e-14);
  EXPECT_LT((g.spacing - Vec3(2, 3, 0.5)).norm(), 1e-14);
  Mat3 singular = columns;
  singular.col(2) = singular.col(0) + singular.col(1);
  EXPECT_THROW(setAxes(g, singular, "file"), Error);
  Mat3 zero = columns;
  zero.col(1).setZero();
  EXPECT_THROW(setAxes(g, zero, "file"), Error);
  Mat3 nan = columns;
  nan(0, 0) = std::nan("");
  EXPECT_THROW(setAxes(g, nan, "file"), Error);
}

// A mesh moved through a flip stays closed and outward: the transform re-winds its triangles, so the signed
// volume keeps its sign and normals agree with the winding as before.
TEST(WorldTransform, MovedMeshesKeepWindingAndNormalsOutward) {
  Model model = test::fieldModel("sphere", 12, PatchMethod::Paper);
  const TriangleMesh plain = marchingCubes(model);
  ASSERT_TRUE(analyseTopology(plain).closedAndOriented());
  const double volume = signedVolume(plain), agreement = normalWindingAgreement(plain);
  ASSERT_GT(std::abs(agreement), 0.9);
  for (const Mat3& d : {rotation(Vec3(1, 2, 3), 50), Mat3(Vec3(-1, 1, 1).asDiagonal()),
                        Mat3(rotation(Vec3(0, 1, 1), 200) * Vec3(1, 1, -1).asDiagonal())}) {
    model.geometry.direction = d;
    TriangleMesh moved = plain;
    transformMesh(moved, WorldTransform::of(model.geometry));
    EXPECT_TRUE(analyseTopology(moved).closedAndOriented());
    EXPECT_NEAR(signedVolume(moved), volume, 1e-9 * std::abs(volume));
    EXPECT_NEAR(normalWindingAgreement(moved), agreement, 1e-9);
    for (std::size_t v = 0; v < plain.positions.size(); ++v) {
      EXPECT_LT(
          (moved.positions[v] - (model.geometry.origin + d * (plain.positions[v] - model.geometry.origin)))
              .norm(),
          1e-12);
      EXPECT_LT((moved.normals[v] - d * plain.normals[v]).norm(), 1e-12);  // orthogonal: d^-T = d
    }
  }
}

// The model file carries the orientation and anatomical frame (both versions), and rejects a damaged
// orientation block.
TEST(WorldTransform, ModelFilesCarryTheOrientation) {
  Model model = test::fieldModel("torus", 10, PatchMethod::Fitted);
  const std::vector<std::uint8_t> axisAligned = serializeModel(model);
  model.geometry.direction = rotation(Vec3(3, 1, -1), 123) * Vec3(1, -1, 1).asDiagonal();
  model.geometry.space = WorldSpace::LPS;
  const std::vector<std::uint8_t> bytes = serializeModel(model);
  EXPECT_EQ(bytes.size(), axisAligned.size() + 9 * 8 + 1);
  const Model back = parseModel(bytes.data(), bytes.size(), "oriented.cip");
  EXPECT_EQ(back.geometry.direction, model.geometry.direction);
  EXPECT_EQ(back.geometry.space, WorldSpace::LPS);
  EXPECT_EQ(back.cells.size(), model.cells.size());
  const Model plainBack = parseModel(axisAligned.data(), axisAligned.size(), "plain.cip");
  EXPECT_TRUE(plainBack.geometry.axisAligned());
  EXPECT_EQ(plainBack.geometry.space, WorldSpace::Unspecified);

  ModelFileOptions v1;  // version 1 (lossless) carries it too
  v1.version = 1;
  const std::vector<std::uint8_t> v1Bytes = serializeModel(model, v1);
  const Model v1Back = parseModel(v1Bytes.data(), v1Bytes.size(), "oriented-v1.cip");
  EXPECT_EQ(v1Back.geometry.direction, model.geometry.direction);
  EXPECT_EQ(v1Back.geometry.space, WorldSpace::LPS);
  EXPECT_EQ(v1Back.vertices.size(), model.vertices.size());

  // A direction column that is not a unit vector: the block sits right after the source description.
  std::vector<std::uint8_t> damaged = bytes;
  std::size_t at = 0;
  for (std::size_t i = 0; i + 8 <= damaged.size(); ++i) {
    double v;
    std::memcpy(&v, damaged.data() + i, 8);
    if (v == model.geometry.direction(0, 0)) {
      at = i;
      break;
    }
  }
  ASSERT_GT(at, 0u);
  const double bad = 2.0;
  std::memcpy(damaged.data() + at, &bad, 8);
  EXPECT_THROW(parseModel(damaged.data(), damaged.size(), "damaged.cip"), Error);
}

TEST(WorldTransform, WorldBoundsHoldEveryMovedCellCorner) {
  Model model = test::fieldModel("sphere", 10, PatchMethod::Paper);
  model.geometry.spacing = Vec3(0.3, 0.5, 0.7);
  model.geometry.direction = rotation(Vec3(1, 0.2, -0.4), 33);
  const WorldTransform w = WorldTransform::of(model.geometry);
  const auto [lo, hi] = worldBounds(model, w);
  Vec3 tightLo = Vec3::Constant(1e300), tightHi = -tightLo;
  for (std::size_t c = 0; c < model.cells.size(); ++c)
    for (int k = 0; k < 8; ++k) {
      const Vec3 p =
          w.point(model.geometry.indexToWorld(model.cellOrigin(c) + Vec3(k & 1, (k >> 1) & 1, k >> 2)));
      tightLo = tightLo.cwiseMin(p);
      tightHi = tightHi.cwiseMax(p);
    }
  EXPECT_LT((lo - tightLo).norm(), 1e-12);
  EXPECT_LT((hi - tightHi).norm(), 1e-12);
}
