/// @file glb.h
/// @brief Writing triangle meshes as binary glTF 2.0 (`.glb`), the format web viewers, game engines and
/// Blender read.
///
/// One scene with one node holding one mesh of one indexed triangle primitive: POSITION (float32 VEC3, with
/// the min and max the specification requires), NORMAL when the mesh has normals (float32 VEC3), and
/// indices (uint32 SCALAR), each in its own buffer view of the one binary buffer. glTF has no units and says
/// +Y is up; the mesh's world coordinates are written as they are. A mesh without triangles gives a valid
/// file whose scene has no node (glTF accessors cannot be empty). The container (12-byte header, JSON chunk
/// padded with spaces, BIN chunk padded with zeros) is written here rather than through a glTF library: it
/// is a few dozen lines, and libcip stays free of another dependency; the tests read the files back with
/// tinygltf.
#pragma once
#include <cstdint>
#include <vector>

#include "cip/mesh/triangle_mesh.h"

namespace cip {

/// The complete file contents for `mesh`. Throws cip::Error when the mesh is invalid (validateMesh) or too
/// large for a glTF binary (over 4 GiB).
std::vector<std::uint8_t> encodeGlb(const TriangleMesh& mesh);

}  // namespace cip
