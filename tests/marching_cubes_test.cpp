// Marching cubes on the model grid: loop triangulations for every configuration, closed and consistently
// oriented meshes on analytic and random volumes, vertices identical to the model's isovertices, Euler
// characteristics, normals and thread-count independence.
#include "cip/mesh/marching_cubes.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <iostream>
#include <map>

#include "cip/mesh/loop_triangulation.h"
#include "cip/model/model_builder.h"
#include "cip/topology/cell_loops.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "support/random_volume.h"

using namespace cip;

namespace {

Model fieldModel(const std::string& name, int n, bool closeBorder = false) {
  auto field = makeAnalyticField(name);
  DenseGrid g = sampleField(*field, n, name);
  if (closeBorder) {
    const auto& d = g.geometry.dims;
    for (std::int64_t k = 0; k < d[2]; ++k)
      for (std::int64_t j = 0; j < d[1]; ++j)
        for (std::int64_t i = 0; i < d[0]; ++i)
          if (i == 0 || j == 0 || k == 0 || i == d[0] - 1 || j == d[1] - 1 || k == d[2] - 1)
            g.at(i, j, k) = -1;
  }
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  return buildModel(g, o);
}

double signedVolume(const TriangleMesh& m) {
  double v = 0;
  for (const auto& t : m.triangles)
    v += m.positions[t[0]].dot(m.positions[t[1]].cross(m.positions[t[2]])) / 6.0;
  return v;
}

void expectVerticesAreIsovertices(const Model& model, const TriangleMesh& mesh) {
  ASSERT_GE(mesh.positions.size(), model.vertices.size());
  for (std::size_t v = 0; v < model.vertices.size(); ++v) {
    Vec3 w = model.geometry.indexToWorld(model.vertices[v].position);
    ASSERT_LE((mesh.positions[v] - w).norm(), 1e-12) << "vertex " << v;
    ASSERT_NEAR(mesh.normals[v].norm(), 1.0, 1e-12);
    // The world normal points to the same side as the index-space normal.
    ASSERT_GT(mesh.normals[v].cwiseProduct(model.geometry.spacing).dot(model.vertices[v].normal), 0);
  }
}

/// Fraction of non-degenerate triangles whose geometric normal agrees with the mean of their vertex normals.
/// (Isovertices at grid points, where the field is exactly at the isovalue, give zero-area triangles.)
double normalAgreement(const TriangleMesh& m) {
  std::size_t agree = 0, counted = 0;
  for (const auto& t : m.triangles) {
    Vec3 n = (m.positions[t[1]] - m.positions[t[0]]).cross(m.positions[t[2]] - m.positions[t[0]]);
    if (n.norm() < 1e-12) continue;
    Vec3 vn = m.normals[t[0]] + m.normals[t[1]] + m.normals[t[2]];
    ++counted;
    if (n.dot(vn) > 0) ++agree;
  }
  return counted == 0 ? 1.0 : static_cast<double>(agree) / static_cast<double>(counted);
}

}  // namespace

TEST(LoopTriangulation, EveryConfigurationAndPairing) {
  std::map<LoopTriangulation, int> kinds;
  for (int config = 1; config < 255; ++config) {
    for (int pairing = 0; pairing < 64; ++pairing) {
      CellLoops loops = buildCellLoops(static_cast<std::uint8_t>(config), static_cast<std::uint8_t>(pairing));
      int start = 0;
      for (int l = 0; l < loops.numLoops; ++l) {
        const int n = loops.loopSize[l];
        std::array<Vec3, 12> p;
        for (int k = 0; k < n; ++k) {
          int e = loops.edges[start + k];
          auto a = cube::vertexCoords(cube::edgeVertex(e, 0));
          p[k] = Vec3(a[0], a[1], a[2]);
          p[k][cube::edgeAxis(e)] = 0.5;
        }
        LoopTriangles t = triangulateLoop(n, &loops.edges[start], p.data());
        ++kinds[t.kind];
        const bool centre = t.kind == LoopTriangulation::CentreFan;
        ASSERT_EQ(t.count, centre ? n : n - 2);
        // Each side appears once, forwards; every other edge twice, once in each direction.
        std::map<std::pair<int, int>, int> directed;
        for (int i = 0; i < t.count; ++i)
          for (int k = 0; k < 3; ++k) ++directed[{t.triangles[i][k], t.triangles[i][(k + 1) % 3]}];
        for (const auto& [e, count] : directed) {
          ASSERT_EQ(count, 1);
          bool side = e.second == (e.first + 1) % n && e.first < n;
          if (!side) {
            ASSERT_TRUE(directed.count({e.second, e.first}))
                << "config " << config << " chord " << e.first << "-" << e.second;
            // Chords never lie in a face unless it is an upper face and the tier allows it.
            if (e.first < n && e.second < n) {
              int f = cube::commonFace(loops.edges[start + e.first], loops.edges[start + e.second]);
              if (t.kind == LoopTriangulation::Interior) {
                ASSERT_LT(f, 0);
              }
              if (f >= 0) {
                ASSERT_EQ(cube::faceSide(f), 1);
              }
            }
          }
        }
        for (int k = 0; k < n; ++k)
          ASSERT_TRUE(directed.count({k, (k + 1) % n})) << "side " << k << " missing";
        start += n;
      }
    }
  }
  EXPECT_GT(kinds[LoopTriangulation::Interior], 0);
  EXPECT_GT(kinds[LoopTriangulation::UpperFaceChords], 0);
  EXPECT_GT(kinds[LoopTriangulation::CentreFan], 0);
}

TEST(MarchingCubes, SphereIsAClosedSphere) {
  for (int n : {8, 16, 33}) {
    Model model = fieldModel("sphere", n);
    MarchingCubesStats stats;
    TriangleMesh mesh = marchingCubes(model, {}, &stats);
    MeshTopology topo = analyseTopology(mesh);
    EXPECT_TRUE(topo.closedAndOriented()) << topo.describe();
    EXPECT_EQ(topo.eulerCharacteristic, 2) << topo.describe();
    EXPECT_EQ(topo.components, 1u);
    EXPECT_EQ(mesh.positions.size(), model.vertices.size());
    EXPECT_EQ(stats.centreFanLoops, 0u);
    expectVerticesAreIsovertices(model, mesh);
    // Positive side outwards: positive enclosed volume close to the sphere's.
    double volume = 4.0 / 3.0 * M_PI * 0.75 * 0.75 * 0.75;
    EXPECT_NEAR(signedVolume(mesh), volume, 0.1 * volume);
    EXPECT_GT(normalAgreement(mesh), 0.99);
    ASSERT_EQ(mesh.triangleCell.size(), mesh.triangles.size());
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      // Each triangle lies in the closed cell it was made in.
      Vec3 origin = model.cellOrigin(mesh.triangleCell[t]);
      for (auto v : mesh.triangles[t]) {
        Vec3 local = model.geometry.worldToIndex(mesh.positions[v]) - origin;
        ASSERT_GE(local.minCoeff(), -1e-9);
        ASSERT_LE(local.maxCoeff(), 1 + 1e-9);
      }
    }
  }
}

TEST(MarchingCubes, TorusHasEulerCharacteristicZero) {
  for (int n : {16, 24, 40}) {
    Model model = fieldModel("torus", n);
    TriangleMesh mesh = marchingCubes(model);
    MeshTopology topo = analyseTopology(mesh);
    EXPECT_TRUE(topo.closedAndOriented()) << topo.describe();
    EXPECT_EQ(topo.eulerCharacteristic, 0) << topo.describe();
    EXPECT_EQ(mesh.positions.size(), model.vertices.size());
    expectVerticesAreIsovertices(model, mesh);
    EXPECT_GT(signedVolume(mesh), 0);
    EXPECT_GT(normalAgreement(mesh), 0.99);
  }
}

TEST(MarchingCubes, GyroidInABoxIsClosed) {
  for (int n : {12, 20, 31}) {
    Model model = fieldModel("gyroid", n, true);
    TriangleMesh mesh = marchingCubes(model);
    MeshTopology topo = analyseTopology(mesh);
    EXPECT_TRUE(topo.closedAndOriented()) << "n=" << n << ": " << topo.describe();
    expectVerticesAreIsovertices(model, mesh);
    EXPECT_GT(normalAgreement(mesh), 0.95);
  }
}

// The volume's border cuts the gyroid: the mesh's boundary edges (used by one triangle) must all lie on the
// border, each in one of its planes, and they are the marching-squares segments of the border's cell faces:
// one per two crossed edges of each such face, counted from the samples.
TEST(MarchingCubes, OpenSurfaceHasBoundaryOnlyAtTheVolumeBorder) {
  const auto field = makeAnalyticField("gyroid");
  const DenseGrid grid = sampleField(*field, 16, "gyroid");
  Model model = fieldModel("gyroid", 16);
  TriangleMesh mesh = marchingCubes(model);
  MeshTopology topo = analyseTopology(mesh);
  EXPECT_EQ(topo.nonManifoldEdges, 0u);
  EXPECT_EQ(topo.misorientedEdges, 0u);
  std::map<std::pair<std::uint32_t, std::uint32_t>, int> uses;
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) ++uses[std::minmax(t[k], t[(k + 1) % 3])];
  const auto& dims = grid.geometry.dims;
  std::size_t boundary = 0;
  for (const auto& [edge, n] : uses) {
    if (n != 1) continue;
    ++boundary;
    const Vec3 a = model.geometry.worldToIndex(mesh.positions[edge.first]);
    const Vec3 b = model.geometry.worldToIndex(mesh.positions[edge.second]);
    bool onBorder = false;  // both ends in the same border plane
    for (int axis = 0; axis < 3; ++axis)
      for (double plane : {0.0, static_cast<double>(dims[axis] - 1)})
        onBorder = onBorder || (std::abs(a[axis] - plane) < 1e-9 && std::abs(b[axis] - plane) < 1e-9);
    EXPECT_TRUE(onBorder) << "boundary edge from " << a.transpose() << " to " << b.transpose();
  }
  EXPECT_EQ(boundary, topo.boundaryEdges);
  std::size_t crossings = 0;  // crossed edges of the border's cell faces, counted once for each such face
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    for (std::int64_t side : {std::int64_t{0}, dims[axis] - 1})
      for (std::int64_t i = 0; i + 1 < dims[u]; ++i)
        for (std::int64_t j = 0; j + 1 < dims[v]; ++j) {
          auto above = [&](std::int64_t du, std::int64_t dv) {
            std::array<std::int64_t, 3> p{};
            p[axis] = side;
            p[u] = i + du;
            p[v] = j + dv;
            return grid.at(p[0], p[1], p[2]) > model.isovalue;
          };
          crossings += (above(0, 0) != above(1, 0)) + (above(0, 1) != above(1, 1)) +
                       (above(0, 0) != above(0, 1)) + (above(1, 0) != above(1, 1));
        }
  }
  EXPECT_GT(crossings, 0u);
  EXPECT_EQ(boundary, crossings / 2);
}

TEST(MarchingCubes, RandomVolumesAreClosed) {
  MarchingCubesStats total;
  for (unsigned seed = 1; seed <= 40; ++seed) {
    DenseGrid g = test::randomVolume(12, seed, true);
    if (seed % 2 == 0)  // also the complement: a positive border around a negative blob
      for (auto& v : g.values) v = -v;
    Model model = buildModel(g, BuildOptions{});
    MarchingCubesStats stats;
    TriangleMesh mesh = marchingCubes(model, {}, &stats);
    MeshTopology topo = analyseTopology(mesh);
    ASSERT_TRUE(topo.closedAndOriented()) << "seed " << seed << ": " << topo.describe();
    EXPECT_EQ(mesh.positions.size(), model.vertices.size() + stats.centreFanLoops);
    expectVerticesAreIsovertices(model, mesh);
    total.interiorLoops += stats.interiorLoops;
    total.upperFaceChordLoops += stats.upperFaceChordLoops;
    total.centreFanLoops += stats.centreFanLoops;
  }
  // The random volumes exercise the rarer triangulation tiers as well.
  EXPECT_GT(total.upperFaceChordLoops, 0u);
  std::cout << "loops: interior " << total.interiorLoops << ", upper-face chords "
            << total.upperFaceChordLoops << ", centre fans " << total.centreFanLoops << "\n";
}

TEST(MarchingCubes, IndependentOfThreadCount) {
  DenseGrid g = test::randomVolume(20, 7, true);
  Model model = buildModel(g, BuildOptions{});
  MarchingCubesOptions one;
  one.threads = 1;
  TriangleMesh a = marchingCubes(model, one), b = marchingCubes(model);
  EXPECT_EQ(a.triangles, b.triangles);
  EXPECT_EQ(a.triangleCell, b.triangleCell);
  ASSERT_EQ(a.positions.size(), b.positions.size());
  for (std::size_t v = 0; v < a.positions.size(); ++v) EXPECT_EQ(a.positions[v], b.positions[v]);
}

TEST(MarchingCubes, AnisotropicSpacingConvertsNormals) {
  auto field = makeAnalyticField("sphere");
  DenseGrid g = sampleField(*field, 16, "sphere");
  g.geometry.spacing = Vec3(0.5, 1.0, 2.0);  // the same samples, stretched: an ellipsoid
  Model model = buildModel(g, BuildOptions{});
  TriangleMesh mesh = marchingCubes(model);
  EXPECT_TRUE(analyseTopology(mesh).closedAndOriented());
  expectVerticesAreIsovertices(model, mesh);
  EXPECT_GT(normalAgreement(mesh), 0.99);
}

TEST(MarchingCubes, SameMeshWithoutPatchCoefficients) {
  // The marching-cubes front end of the builder skips coefficient fitting; the mesh needs only isovertices
  // and loops.
  DenseGrid g = test::randomVolume(10, 11, true);
  BuildOptions o;
  Model full = buildModel(g, o);
  o.fitCoefficients = false;
  Model bare = buildModel(g, o);
  TriangleMesh a = marchingCubes(full), b = marchingCubes(bare);
  EXPECT_EQ(a.triangles, b.triangles);
  EXPECT_EQ(a.positions, b.positions);
}

TEST(MarchingCubes, EmptyModel) {
  Model model;
  model.geometry.dims = {4, 4, 4};
  TriangleMesh mesh = marchingCubes(model);
  EXPECT_TRUE(mesh.positions.empty());
  EXPECT_TRUE(mesh.triangles.empty());
}
