/// @file triangle_mesh.h
/// @brief An indexed triangle mesh (world coordinates, per-vertex unit normals) and topology checks on it.
///
/// Meshes come from marching cubes on the model's grid (marching_cubes.h), from the corner-patch surface
/// itself (patch_mesh.h) and from PLY files (ply.h). Positions are double so that mesh vertices can be
/// compared with the model's isovertices to rounding; the PLY writer stores them as float.
#pragma once
#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "cip/core/vec3.h"
#include "cip/core/world_transform.h"

namespace cip {

struct TriangleMesh {
  std::vector<Vec3> positions;  ///< world coordinates
  std::vector<Vec3> normals;    ///< unit normals per vertex (world), or empty when unknown
  /// Vertex indices, counter-clockwise seen from the side the normals point to.
  std::vector<std::array<std::uint32_t, 3>> triangles;
  /// Optional: per triangle, the index into Model::cells of the cell it was made in (else empty).
  std::vector<std::uint32_t> triangleCell;
  /// Optional: per vertex, the index into Model::cells of the cell whose patch placed it (patch meshes only).
  std::vector<std::uint32_t> vertexCell;

  std::size_t vertexCount() const { return positions.size(); }
  std::size_t triangleCount() const { return triangles.size(); }
  bool hasNormals() const { return !normals.empty() && normals.size() == positions.size(); }
};

/// Result of analyseTopology. An edge is an unordered pair of distinct vertex indices.
struct MeshTopology {
  std::size_t usedVertices = 0;      ///< vertices referenced by at least one triangle
  std::size_t edges = 0;             ///< distinct undirected edges
  std::size_t boundaryEdges = 0;     ///< edges used by exactly one triangle
  std::size_t nonManifoldEdges = 0;  ///< edges used by three or more triangles
  std::size_t misorientedEdges = 0;  ///< edges used by two triangles that traverse it in the same direction
  std::size_t degenerateTriangles = 0;   ///< triangles that repeat a vertex index
  std::size_t badIndices = 0;            ///< triangle indices >= vertex count
  std::size_t components = 0;            ///< connected components of the triangles (through shared vertices)
  std::int64_t eulerCharacteristic = 0;  ///< usedVertices - edges + triangles

  /// Every edge is shared by exactly two triangles that traverse it in opposite directions, and no triangle
  /// is degenerate or indexes outside the vertex table: a closed, consistently oriented 2-manifold (up to
  /// vertices where several sheets meet, which this edge test does not see).
  bool closedAndOriented() const {
    return boundaryEdges == 0 && nonManifoldEdges == 0 && misorientedEdges == 0 && degenerateTriangles == 0 &&
           badIndices == 0;
  }
  /// One-line summary for test failure messages.
  std::string describe() const;
};

/// Counts boundary, non-manifold and inconsistently oriented edges, components and the Euler characteristic.
MeshTopology analyseTopology(const TriangleMesh& mesh);

/// Maps a mesh in a model's grid frame to the world of `transform`: positions affinely, normals by the
/// inverse transpose (renormalised), and triangles re-wound when the map flips orientation, so that winding
/// and normals stay outward (towards the same side of the surface as before).
void transformMesh(TriangleMesh& mesh, const WorldTransform& transform);

/// Throws cip::Error when a triangle index is out of range, the normal table has the wrong size, or a
/// position is not finite (`name` starts the message).
void validateMesh(const TriangleMesh& mesh, const std::string& name = "mesh");

}  // namespace cip
