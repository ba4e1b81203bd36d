#include "cip/mesh/triangle_mesh.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "cip/core/error.h"

namespace cip {

std::string MeshTopology::describe() const {
  return "vertices " + std::to_string(usedVertices) + ", edges " + std::to_string(edges) +
         ", boundary edges " + std::to_string(boundaryEdges) + ", non-manifold edges " +
         std::to_string(nonManifoldEdges) + ", misoriented edges " + std::to_string(misorientedEdges) +
         ", degenerate triangles " + std::to_string(degenerateTriangles) + ", bad indices " +
         std::to_string(badIndices) + ", components " + std::to_string(components) +
         ", Euler characteristic " + std::to_string(eulerCharacteristic);
}

MeshTopology analyseTopology(const TriangleMesh& mesh) {
  MeshTopology t;
  const std::size_t nv = mesh.positions.size();
  // Directed half-edges (min, max, forward?) sorted so that both directions of an edge are adjacent.
  struct HalfEdge {
    std::uint32_t a, b;
    bool forward;
    bool operator<(const HalfEdge& o) const {
      return a != o.a ? a < o.a : b != o.b ? b < o.b : forward < o.forward;
    }
  };
  std::vector<HalfEdge> half;
  half.reserve(mesh.triangles.size() * 3);
  std::vector<std::uint32_t> parent(nv);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t v) {
    while (parent[v] != v) v = parent[v] = parent[parent[v]];
    return v;
  };
  std::vector<char> used(nv, 0);
  std::size_t goodTriangles = 0;
  for (const auto& tri : mesh.triangles) {
    if (tri[0] >= nv || tri[1] >= nv || tri[2] >= nv) {
      ++t.badIndices;
      continue;
    }
    if (tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) {
      ++t.degenerateTriangles;
      continue;
    }
    ++goodTriangles;
    for (int k = 0; k < 3; ++k) {
      std::uint32_t u = tri[k], v = tri[(k + 1) % 3];
      used[u] = 1;
      half.push_back(u < v ? HalfEdge{u, v, true} : HalfEdge{v, u, false});
      std::uint32_t ru = find(u), rv = find(v);
      if (ru != rv) parent[std::max(ru, rv)] = std::min(ru, rv);
    }
  }
  std::sort(half.begin(), half.end());
  for (std::size_t i = 0; i < half.size();) {
    std::size_t j = i, forward = 0;
    while (j < half.size() && half[j].a == half[i].a && half[j].b == half[i].b) forward += half[j++].forward;
    std::size_t n = j - i;
    ++t.edges;
    if (n == 1) ++t.boundaryEdges;
    if (n >= 3) ++t.nonManifoldEdges;
    if (n == 2 && forward != 1) ++t.misorientedEdges;
    i = j;
  }
  for (std::uint32_t v = 0; v < nv; ++v) {
    if (!used[v]) continue;
    ++t.usedVertices;
    if (find(v) == v) ++t.components;
  }
  t.eulerCharacteristic = static_cast<std::int64_t>(t.usedVertices) - static_cast<std::int64_t>(t.edges) +
                          static_cast<std::int64_t>(goodTriangles);
  return t;
}

void validateMesh(const TriangleMesh& mesh, const std::string& name) {
  const std::size_t nv = mesh.positions.size();
  if (!mesh.normals.empty() && mesh.normals.size() != nv) {
    throw Error(name + ": " + std::to_string(mesh.normals.size()) + " normals for " + std::to_string(nv) +
                " vertices");
  }
  if (!mesh.triangleCell.empty() && mesh.triangleCell.size() != mesh.triangles.size()) {
    throw Error(name + ": " + std::to_string(mesh.triangleCell.size()) + " triangle cells for " +
                std::to_string(mesh.triangles.size()) + " triangles");
  }
  if (!mesh.vertexCell.empty() && mesh.vertexCell.size() != nv) {
    throw Error(name + ": " + std::to_string(mesh.vertexCell.size()) + " vertex cells for " +
                std::to_string(nv) + " vertices");
  }
  for (std::size_t v = 0; v < nv; ++v) {
    if (!mesh.positions[v].allFinite())
      throw Error(name + ": vertex " + std::to_string(v) + " is not finite");
  }
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    for (std::uint32_t v : mesh.triangles[i]) {
      if (v >= nv) {
        throw Error(name + ": triangle " + std::to_string(i) + " uses vertex " + std::to_string(v) + " of " +
                    std::to_string(nv));
      }
    }
  }
}

void transformMesh(TriangleMesh& mesh, const WorldTransform& transform) {
  if (transform.isIdentity()) return;
  for (Vec3& p : mesh.positions) p = transform.point(p);
  for (Vec3& n : mesh.normals) {
    const Vec3 w = transform.normal(n);
    const double len = w.norm();
    n = len > 0 ? Vec3(w / len) : w;
  }
  if (transform.flipsOrientation())
    for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
}

}  // namespace cip
