#include "cip/meshio/mesh_file.h"

#include <algorithm>
#include <cctype>

#include "cip/core/atomic_file.h"
#include "cip/core/error.h"
#include "cip/mesh/ply.h"
#include "cip/meshio/glb.h"
#include "cip/meshio/obj.h"
#include "cip/meshio/stl.h"

namespace cip {

const char* toString(MeshFormat format) {
  switch (format) {
    case MeshFormat::Ply:
      return "PLY";
    case MeshFormat::Stl:
      return "STL";
    case MeshFormat::Obj:
      return "OBJ";
    case MeshFormat::Glb:
      return "glTF binary";
  }
  return "?";
}

MeshFormat meshFormatOf(const std::string& path) {
  std::string name =
      path.substr(path.find_last_of('/') == std::string::npos ? 0 : path.find_last_of('/') + 1);
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  const std::size_t dot = name.find_last_of('.');
  const std::string ext = dot == std::string::npos ? "" : name.substr(dot);
  if (ext == ".stl") return MeshFormat::Stl;
  if (ext == ".obj") return MeshFormat::Obj;
  if (ext == ".glb") return MeshFormat::Glb;
  if (ext == ".gltf")
    throw Error(path +
                ": glTF is written as one binary file; name it .glb (a .gltf needs separate buffer files)");
  return MeshFormat::Ply;
}

std::vector<std::uint8_t> encodeMesh(const TriangleMesh& mesh, MeshFormat format) {
  switch (format) {
    case MeshFormat::Stl:
      return encodeStl(mesh);
    case MeshFormat::Obj:
      return encodeObj(mesh);
    case MeshFormat::Glb:
      return encodeGlb(mesh);
    case MeshFormat::Ply:
      break;
  }
  return encodePly(mesh);
}

std::size_t writeMesh(const TriangleMesh& mesh, const std::string& path) {
  const MeshFormat format = meshFormatOf(path);
  std::vector<std::uint8_t> bytes;
  try {
    bytes = encodeMesh(mesh, format);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  return writeFileAtomically(path, [&](std::FILE* f) { writeBytes(f, bytes.data(), bytes.size()); });
}

}  // namespace cip
