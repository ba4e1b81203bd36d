#include "cip/meshio/obj.h"

#include <cstdio>
#include <string>

namespace cip {

std::vector<std::uint8_t> encodeObj(const TriangleMesh& mesh) {
  validateMesh(mesh, "OBJ output");
  std::vector<std::uint8_t> out;
  out.reserve(40 * mesh.positions.size() * (mesh.hasNormals() ? 2 : 1) + 30 * mesh.triangles.size());
  char line[160];
  auto append = [&](int n) { out.insert(out.end(), line, line + n); };
  append(std::snprintf(line, sizeof line, "# Wavefront OBJ written by cip: %zu vertices, %zu triangles\n",
                       mesh.positions.size(), mesh.triangles.size()));
  auto putVector = [&](const char* tag, const Vec3& v) {
    append(std::snprintf(
        line, sizeof line, "%s %.9g %.9g %.9g\n", tag, static_cast<double>(static_cast<float>(v[0])),
        static_cast<double>(static_cast<float>(v[1])), static_cast<double>(static_cast<float>(v[2]))));
  };
  for (const Vec3& p : mesh.positions) putVector("v", p);
  const bool normals = mesh.hasNormals();
  if (normals)
    for (const Vec3& n : mesh.normals) putVector("vn", n);
  for (const auto& t : mesh.triangles) {
    const unsigned long a = t[0] + 1ul, b = t[1] + 1ul, c = t[2] + 1ul;
    append(normals ? std::snprintf(line, sizeof line, "f %lu//%lu %lu//%lu %lu//%lu\n", a, a, b, b, c, c)
                   : std::snprintf(line, sizeof line, "f %lu %lu %lu\n", a, b, c));
  }
  return out;
}

}  // namespace cip
