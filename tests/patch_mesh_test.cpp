// Triangle meshes of the corner-patch surface: crack-free (closed) on analytic and random volumes, vertices
// on the patches' zero sets, close to the exact sphere, normals from the patch gradients, thread-count
// independence.
#include "cip/mesh/patch_mesh.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <iostream>

#include "cip/core/error.h"
#include "cip/model/model_builder.h"
#include "cip/volume/analytic_field.h"
#include "support/random_volume.h"

using namespace cip;

namespace {

void closeBorder(DenseGrid& g) {
  const auto& d = g.geometry.dims;
  for (std::int64_t k = 0; k < d[2]; ++k)
    for (std::int64_t j = 0; j < d[1]; ++j)
      for (std::int64_t i = 0; i < d[0]; ++i)
        if (i == 0 || j == 0 || k == 0 || i == d[0] - 1 || j == d[1] - 1 || k == d[2] - 1) g.at(i, j, k) = -1;
}

Model fieldModel(const std::string& name, int n, NormalMode normals, PatchMethod method,
                 bool closed = false) {
  auto field = makeAnalyticField(name);
  DenseGrid g = sampleField(*field, n, name);
  if (closed) closeBorder(g);
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  o.normals = normals;
  o.method = method;
  if (normals == NormalMode::Exact) o.exactField = field.get();
  return buildModel(g, o);
}

/// Number of vertices farther than 1e-9 (cell-local units, |I| / |grad I|) from the zero set of the patch of
/// the cell that placed them; each vertex must also lie in that cell.
std::size_t verticesOffTheZeroSet(const Model& model, const TriangleMesh& mesh) {
  std::size_t off = 0;
  EXPECT_EQ(mesh.vertexCell.size(), mesh.positions.size());
  for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
    std::size_t c = mesh.vertexCell[v];
    Vec3 local = model.geometry.worldToIndex(mesh.positions[v]) - model.cellOrigin(c);
    EXPECT_GE(local.minCoeff(), -1e-9);
    EXPECT_LE(local.maxCoeff(), 1 + 1e-9);
    PatchDerivatives d = model.patch(c).derivatives(local);
    double g = d.gradient.norm();
    if (!(std::abs(d.value) <= 1e-9 * g)) ++off;
  }
  return off;
}

/// Fraction of non-degenerate triangles whose geometric normal agrees with the mean of their vertex normals.
double normalAgreement(const TriangleMesh& m) {
  std::size_t agree = 0, counted = 0;
  for (const auto& t : m.triangles) {
    Vec3 n = (m.positions[t[1]] - m.positions[t[0]]).cross(m.positions[t[2]] - m.positions[t[0]]);
    if (n.norm() < 1e-14) continue;
    ++counted;
    if (n.dot(m.normals[t[0]] + m.normals[t[1]] + m.normals[t[2]]) > 0) ++agree;
  }
  return counted == 0 ? 1.0 : static_cast<double>(agree) / static_cast<double>(counted);
}

}  // namespace

TEST(PatchMesh, ExactSphereIsClosedAndOnTheSphere) {
  Model model = fieldModel("sphere", 16, NormalMode::Exact, PatchMethod::Fitted);
  PatchMeshStats stats;
  TriangleMesh mesh = patchMesh(model, 4, {}, &stats);
  MeshTopology topo = analyseTopology(mesh);
  EXPECT_TRUE(topo.closedAndOriented()) << topo.describe();
  EXPECT_EQ(topo.eulerCharacteristic, 2) << topo.describe();
  EXPECT_EQ(topo.components, 1u);
  EXPECT_EQ(stats.unbracketedEdges, 0u);
  EXPECT_EQ(verticesOffTheZeroSet(model, mesh), 0u);
  std::vector<double> dist;
  for (const Vec3& p : mesh.positions) dist.push_back(std::abs(p.norm() - 0.75));
  std::sort(dist.begin(), dist.end());
  const double spacing = model.geometry.spacing[0], median = dist[dist.size() / 2],
               p99 = dist[dist.size() * 99 / 100];
  std::cout << "exact sphere N=16 subdiv 4 (fitted): " << mesh.positions.size() << " vertices, "
            << mesh.triangles.size() << " triangles; distance to the sphere: median " << median << ", 99% "
            << p99 << ", max " << dist.back() << " (spacing " << spacing << ")\n";
  EXPECT_LT(median, 0.002 * spacing);
  EXPECT_LT(p99, 0.05 * spacing);
  EXPECT_LT(dist.back(), 0.25 * spacing);
  EXPECT_GT(normalAgreement(mesh), 0.99);
  // Normals are unit and outward (the positive side of a signed distance), except at the few vertices on cell
  // edges and corners where the patch gradient vanishes (zeros of its squared face factors).
  std::size_t outward = 0;
  for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
    EXPECT_NEAR(mesh.normals[v].norm(), 1.0, 1e-12);
    if (mesh.normals[v].dot(mesh.positions[v].normalized()) > 0.9) ++outward;
  }
  EXPECT_GT(outward, mesh.positions.size() * 99 / 100);
  // Normals are the world-space patch gradients of CornerPatch::derivatives wherever those do not vanish.
  for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
    std::size_t c = mesh.vertexCell[v];
    Vec3 local = model.geometry.worldToIndex(mesh.positions[v]) - model.cellOrigin(c);
    Vec3 g = model.patch(c).derivatives(local).gradient;
    if (g.norm() < 1e-9) continue;
    Vec3 expected = g.cwiseQuotient(model.geometry.spacing).normalized();
    EXPECT_LT((mesh.normals[v] - expected).norm(), 1e-9) << "vertex " << v;
  }
  // Each triangle lies in the cell it was made in.
  ASSERT_EQ(mesh.triangleCell.size(), mesh.triangles.size());
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (auto v : mesh.triangles[t]) {
      Vec3 local = model.geometry.worldToIndex(mesh.positions[v]) - model.cellOrigin(mesh.triangleCell[t]);
      ASSERT_GE(local.minCoeff(), -1e-9);
      ASSERT_LE(local.maxCoeff(), 1 + 1e-9);
    }
  }
}

TEST(PatchMesh, PaperPatchesLeavingTheirCellsAreClosedInTheFace) {
  // With the paper's coefficients, the patches of the 24 cells at the six poles of this sphere (grid points
  // lie exactly on it, so isovertices coincide) change sign on faces without crossings: the mesh follows them
  // to the face and closes them there, so it stays closed; only those vertices are off the zero set.
  Model model = fieldModel("sphere", 16, NormalMode::Exact, PatchMethod::Paper);
  PatchMeshStats stats;
  TriangleMesh mesh = patchMesh(model, 4, {}, &stats);
  MeshTopology topo = analyseTopology(mesh);
  EXPECT_TRUE(topo.closedAndOriented()) << topo.describe();
  EXPECT_EQ(topo.eulerCharacteristic, 2) << topo.describe();
  EXPECT_GT(stats.unbracketedEdges, 0u);
  std::size_t off = verticesOffTheZeroSet(model, mesh);
  EXPECT_LE(off, stats.unbracketedEdges);
  EXPECT_LT(off, mesh.positions.size() / 50);
  std::vector<double> dist;
  for (const Vec3& p : mesh.positions) dist.push_back(std::abs(p.norm() - 0.75));
  std::sort(dist.begin(), dist.end());
  EXPECT_LT(dist[dist.size() / 2], 0.01 * model.geometry.spacing[0]);
}

TEST(PatchMesh, SubdivisionsOfTheGradientSphere) {
  for (PatchMethod method : {PatchMethod::Paper, PatchMethod::Fitted}) {
    Model model = fieldModel("sphere", 12, NormalMode::Gradient, method);
    for (int k : {1, 2, 3, 5}) {
      PatchMeshStats stats;
      TriangleMesh mesh = patchMesh(model, k, {}, &stats);
      MeshTopology topo = analyseTopology(mesh);
      EXPECT_TRUE(topo.closedAndOriented()) << "subdiv " << k << ": " << topo.describe();
      EXPECT_LE(verticesOffTheZeroSet(model, mesh), stats.unbracketedEdges) << "subdiv " << k;
      // The paper's patches of this coarse sphere have extra sheets; the fitted ones follow the sphere.
      if (method == PatchMethod::Fitted || k == 1) {
        EXPECT_EQ(topo.eulerCharacteristic, 2)
            << toString(method) << " subdiv " << k << ": " << topo.describe();
      }
      if (method == PatchMethod::Fitted) {
        EXPECT_EQ(stats.unbracketedEdges, 0u);
      }
    }
  }
}

TEST(PatchMesh, TorusIsClosed) {
  for (PatchMethod method : {PatchMethod::Paper, PatchMethod::Fitted}) {
    for (NormalMode normals : {NormalMode::Gradient, NormalMode::Exact}) {
      Model model = fieldModel("torus", 24, normals, method);
      // subdiv 1 samples only the grid: the topology of marching cubes on the same loops.
      TriangleMesh coarse = patchMesh(model, 1);
      MeshTopology coarseTopo = analyseTopology(coarse);
      EXPECT_TRUE(coarseTopo.closedAndOriented()) << coarseTopo.describe();
      EXPECT_EQ(coarseTopo.eulerCharacteristic, 0) << coarseTopo.describe();
      PatchMeshStats stats;
      TriangleMesh mesh = patchMesh(model, 3, {}, &stats);
      MeshTopology topo = analyseTopology(mesh);
      EXPECT_TRUE(topo.closedAndOriented()) << topo.describe();
      EXPECT_LE(verticesOffTheZeroSet(model, mesh), stats.unbracketedEdges);
      std::cout << "torus N=24 subdiv 3 (" << toString(method) << ", " << toString(normals)
                << " normals): " << topo.describe() << ", " << stats.unbracketedEdges << " unbracketed of "
                << stats.edgeVertices << "\n";
      if (method == PatchMethod::Fitted) {
        // Finer sampling follows the patches; the fitted ones stay in their cells and keep the torus'
        // topology.
        EXPECT_EQ(topo.eulerCharacteristic, 0) << topo.describe();
        EXPECT_EQ(topo.components, 1u);
        EXPECT_EQ(stats.unbracketedEdges, 0u);
        EXPECT_GT(normalAgreement(mesh), 0.99);
      }
    }
  }
}

TEST(PatchMesh, GyroidInABoxIsClosed) {
  Model model = fieldModel("gyroid", 20, NormalMode::Gradient, PatchMethod::Paper, true);
  PatchMeshStats stats;
  TriangleMesh mesh = patchMesh(model, 3, {}, &stats);
  MeshTopology topo = analyseTopology(mesh);
  EXPECT_TRUE(topo.closedAndOriented()) << topo.describe();
  std::cout << "gyroid: unbracketed edges " << stats.unbracketedEdges << " of " << stats.edgeVertices
            << ", centre fans " << stats.centreFans << "\n";
  EXPECT_GT(normalAgreement(mesh), 0.95);
}

TEST(PatchMesh, RandomVolumesAreClosed) {
  PatchMeshStats total;
  for (unsigned seed = 1; seed <= 8; ++seed) {
    DenseGrid g = test::randomVolume(12, seed, true);
    if (seed % 2 == 0)
      for (auto& v : g.values) v = -v;
    Model model = buildModel(g, BuildOptions{});
    for (int k : {1, 2, 3}) {
      PatchMeshStats stats;
      TriangleMesh mesh = patchMesh(model, k, {}, &stats);
      MeshTopology topo = analyseTopology(mesh);
      ASSERT_TRUE(topo.closedAndOriented()) << "seed " << seed << " subdiv " << k << ": " << topo.describe();
      EXPECT_LE(verticesOffTheZeroSet(model, mesh), stats.unbracketedEdges);
      total.edgeVertices += stats.edgeVertices;
      total.unbracketedEdges += stats.unbracketedEdges;
      total.centreFans += stats.centreFans;
    }
  }
  std::cout << "random volumes: unbracketed edges " << total.unbracketedEdges << " of " << total.edgeVertices
            << ", centre fans " << total.centreFans << "\n";
}

TEST(PatchMesh, IndependentOfThreadCount) {
  DenseGrid g = test::randomVolume(14, 3, true);
  Model model = buildModel(g, BuildOptions{});
  PatchMeshOptions one;
  one.threads = 1;
  TriangleMesh a = patchMesh(model, 3, one), b = patchMesh(model, 3);
  EXPECT_EQ(a.triangles, b.triangles);
  EXPECT_EQ(a.triangleCell, b.triangleCell);
  EXPECT_EQ(a.vertexCell, b.vertexCell);
  ASSERT_EQ(a.positions.size(), b.positions.size());
  for (std::size_t v = 0; v < a.positions.size(); ++v) {
    EXPECT_EQ(a.positions[v], b.positions[v]);
    EXPECT_EQ(a.normals[v], b.normals[v]);
  }
}

TEST(PatchMesh, RejectsBadSubdivision) {
  Model model = fieldModel("sphere", 4, NormalMode::Gradient, PatchMethod::Paper);
  EXPECT_THROW(patchMesh(model, 0), Error);
  EXPECT_THROW(patchMesh(model, 65), Error);
}
