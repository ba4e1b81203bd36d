/// @file marching_cubes.h
/// @brief Marching cubes on a model's own grid: the piecewise-linear counterpart of the corner-patch surface.
///
/// The mesh uses exactly the model's isovertices (Model::vertices, in that order, as mesh vertices 0..V-1)
/// and the model's loops, so ambiguous faces are resolved as for the patches and identically in both cells
/// sharing a face. Each loop is triangulated by triangulateLoop (loop_triangulation.h): without new vertices
/// whenever possible; the rare loops that need one get a centre vertex, appended after the isovertices in
/// cell order. Every side of a loop lies in a grid face and is shared, reversed, with the neighbouring cell,
/// so a surface that stays inside the volume gives a closed, consistently oriented mesh.
///
/// Orientation: triangles are counter-clockwise seen from the positive side (values above the isovalue), i.e.
/// their right-handed normals point towards the positive side; for signed-distance volumes (negative inside)
/// that is outwards. Vertex normals are the isovertices' corner-plane normals (index space, pointing to the
/// positive side) converted to world space (divided by the spacing component-wise) and normalised. Positions
/// are world coordinates. Built in parallel (TBB); the result does not depend on the number of threads.
#pragma once
#include <cstddef>

#include "cip/mesh/triangle_mesh.h"
#include "cip/model/model.h"

namespace cip {

struct MarchingCubesOptions {
  int threads = 0;          ///< worker threads; 0 = all hardware threads
  bool recordCells = true;  ///< fill TriangleMesh::triangleCell
};

/// How the loops were triangulated (see LoopTriangulation).
struct MarchingCubesStats {
  std::size_t interiorLoops = 0;
  std::size_t upperFaceChordLoops = 0;
  std::size_t centreFanLoops = 0;  ///< = number of vertices added to the isovertices
};

TriangleMesh marchingCubes(const Model& model, const MarchingCubesOptions& options = {},
                           MarchingCubesStats* stats = nullptr);

/// Index-space normal (pointing to the positive side) to a unit world-space normal: n / spacing, normalised.
Vec3 indexNormalToWorld(const Vec3& indexNormal, const Vec3& spacing);

}  // namespace cip
