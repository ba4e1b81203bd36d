/// @file obj.h
/// @brief Writing triangle meshes as Wavefront OBJ text, the format nearly every modelling tool reads.
///
/// One `v x y z` line per vertex, then (when the mesh has normals) one `vn x y z` line per vertex, then one
/// face line per triangle: `f a//a b//b c//c` with normals, `f a b c` without (1-based indices, the same
/// index for a vertex and its normal). Numbers are written with 9 significant digits, so they read back as
/// the same float32 values the binary formats store. Counter-clockwise triangles, as in the mesh.
#pragma once
#include <cstdint>
#include <vector>

#include "cip/mesh/triangle_mesh.h"

namespace cip {

/// The complete file contents for `mesh`. Throws cip::Error when the mesh is invalid (validateMesh).
std::vector<std::uint8_t> encodeObj(const TriangleMesh& mesh);

}  // namespace cip
