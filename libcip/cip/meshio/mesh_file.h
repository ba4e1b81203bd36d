/// @file mesh_file.h
/// @brief Writing a triangle mesh in the format its file name asks for: the one entry point `extract`
/// (--mc-mesh, --patch-mesh) and the Python module use, so both write every format the same way.
///
/// By extension, case-insensitive: `.stl` binary STL (stl.h), `.obj` Wavefront OBJ with normals (obj.h),
/// `.glb` binary glTF 2.0 (glb.h), `.ply` and any other name binary little-endian PLY (ply.h; every name
/// wrote PLY before the other formats existed, so it still does). `.gltf` (glTF with a separate buffer
/// file) is refused with a message that names `.glb`.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cip/mesh/triangle_mesh.h"

namespace cip {

enum class MeshFormat : std::uint8_t { Ply = 0, Stl = 1, Obj = 2, Glb = 3 };
/// "PLY", "STL", "OBJ", "glTF binary".
const char* toString(MeshFormat format);

/// The format for `path` (see above). Throws cip::Error for a name this writer refuses (.gltf).
MeshFormat meshFormatOf(const std::string& path);

/// The complete file contents of `mesh` in `format`. Throws cip::Error for an invalid mesh.
std::vector<std::uint8_t> encodeMesh(const TriangleMesh& mesh, MeshFormat format);

/// Writes `mesh` to `path` in the format of its name, atomically (atomic_file.h); returns the bytes written.
/// Throws cip::Error starting with the path; a file already at `path` is then left as it was.
std::size_t writeMesh(const TriangleMesh& mesh, const std::string& path);

}  // namespace cip
