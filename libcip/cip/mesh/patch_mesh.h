/// @file patch_mesh.h
/// @brief A crack-free triangle mesh of the corner-patch surface itself, sampled finer than the grid.
///
/// Marching cubes on a K-times refined grid restricted to the model's non-empty cells, each refined point
/// signed by a function of the point alone (data sign on grid points and uncrossed edges and faces, else the
/// patch of one canonical cell), so neighbouring cells agree and the mesh is indexed and crack-free. Vertices
/// lie on the patches (regula falsi), normals are the patches' exact gradients. Positions and normals in
/// world coordinates; triangles counter-clockwise seen from the positive side. docs/meshes.md has the rules.
#pragma once
#include <cstddef>

#include "cip/mesh/triangle_mesh.h"
#include "cip/model/model.h"

namespace cip {

struct PatchMeshOptions {
  int threads = 0;  ///< worker threads; 0 = all hardware threads
};

struct PatchMeshStats {
  std::size_t refinedCells = 0;  ///< refined cells with a sign change
  std::size_t edgeVertices = 0;  ///< distinct refined-edge vertices
  /// Edge vertices whose owning patch had no matching sign change (see above).
  std::size_t unbracketedEdges = 0;
  std::size_t centreFans = 0;  ///< loops triangulated around an added centre vertex
};

/// Meshes the model's patch surface with `subdiv` (1..64) subcells per cell axis. Throws cip::Error for a bad
/// subdiv or when the mesh would need more than 2^32-1 vertices.
TriangleMesh patchMesh(const Model& model, int subdiv, const PatchMeshOptions& options = {},
                       PatchMeshStats* stats = nullptr);

}  // namespace cip
