/// @file ply.h
/// @brief Reading and writing triangle meshes as PLY (Stanford polygon) files.
///
/// Writer: vertex x,y,z and (when the mesh has normals) nx,ny,nz as float; faces as `property list uchar int
/// vertex_indices` (`uint` when there are more than 2^31-1 vertices). Binary little-endian by default;
/// big-endian and ASCII on request. Files are written atomically (temporary file + rename).
///
/// Reader: binary little-endian, binary big-endian and ASCII. Vertex properties x,y,z (any numeric type;
/// float and double in practice) and optional nx,ny,nz; every other property of every element is skipped
/// according to its declared type. Faces come from the list property `vertex_indices` (or `vertex_index`)
/// with an integer count type and an integer index type; polygons with more than three vertices are
/// fan-triangulated (v0,vk,vk+1). Counts are checked against the bytes left before anything is allocated (a
/// header claiming 1e12 vertices over a 100-byte body is rejected with cip::Error), and every index against
/// the vertex count. Units are whatever the file uses; cip writes world coordinates.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cip/mesh/triangle_mesh.h"

namespace cip {

enum class PlyFormat : std::uint8_t { BinaryLittleEndian = 0, BinaryBigEndian = 1, Ascii = 2 };

struct PlyWriteOptions {
  PlyFormat format = PlyFormat::BinaryLittleEndian;
  bool normals = true;  ///< write nx,ny,nz when the mesh has normals
  std::string comment;  ///< optional single-line header comment (newlines are replaced by spaces)
};

/// The complete file contents for `mesh`. Throws cip::Error when the mesh is invalid (see validateMesh).
std::vector<std::uint8_t> encodePly(const TriangleMesh& mesh, const PlyWriteOptions& options = {});
/// Writes `mesh` to `path` atomically; returns the number of bytes written. Throws cip::Error with the path.
std::size_t writePly(const TriangleMesh& mesh, const std::string& path, const PlyWriteOptions& options = {});

/// Parses PLY file contents (a pure function of the bytes). Throws cip::Error starting with `name` on any
/// problem: bad header, unsupported format or type, truncated data, counts the data cannot hold, out-of-range
/// indices, non-finite coordinates. triangleCell of the result is empty; normals are empty unless the file
/// has nx,ny,nz.
TriangleMesh parsePly(const std::uint8_t* data, std::size_t size, const std::string& name = "PLY data");
/// Reads and parses a PLY file; errors name the path.
TriangleMesh readPly(const std::string& path);

}  // namespace cip
