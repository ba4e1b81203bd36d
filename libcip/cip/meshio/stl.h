/// @file stl.h
/// @brief Writing triangle meshes as binary STL, the format 3D printing and CAD tools read.
///
/// Layout: an 80-byte header (text that does not start with "solid", so no reader takes the file for ASCII
/// STL), the triangle count (uint32), then per triangle its unit normal (from its vertices, right-handed: it
/// points to the side the triangles are counter-clockwise from; 0,0,0 for a degenerate triangle), its three
/// vertices (float32 x,y,z each) and a zero attribute word. STL has no shared vertices and no vertex normals:
/// the mesh's own normals are not written. Little-endian on every host.
#pragma once
#include <cstdint>
#include <vector>

#include "cip/mesh/triangle_mesh.h"

namespace cip {

/// The complete file contents for `mesh`. Throws cip::Error when the mesh is invalid (validateMesh) or has
/// more than 2^32-1 triangles.
std::vector<std::uint8_t> encodeStl(const TriangleMesh& mesh);

}  // namespace cip
