#include "cip/meshio/stl.h"

#include <Eigen/Geometry>
#include <limits>

#include "cip/core/error.h"
#include "cip/meshio/byte_buffer.h"

namespace cip {

std::vector<std::uint8_t> encodeStl(const TriangleMesh& mesh) {
  validateMesh(mesh, "STL output");
  if (mesh.triangles.size() > std::numeric_limits<std::uint32_t>::max())
    throw Error("STL output: more than 2^32-1 triangles");
  ByteBuffer out;
  std::string header = "binary STL written by cip";
  header.resize(80, ' ');
  out.putText(header);
  out.put(static_cast<std::uint32_t>(mesh.triangles.size()));
  out.bytes.reserve(84 + 50 * mesh.triangles.size());
  auto putVec = [&](const Vec3& v) {
    for (int a = 0; a < 3; ++a) out.put(static_cast<float>(v[a]));
  };
  for (const auto& t : mesh.triangles) {
    const Vec3& p0 = mesh.positions[t[0]];
    const Vec3& p1 = mesh.positions[t[1]];
    const Vec3& p2 = mesh.positions[t[2]];
    const Vec3 n = (p1 - p0).cross(p2 - p0);
    const double length = n.norm();
    putVec(length > 0 ? Vec3(n / length) : Vec3(Vec3::Zero()));
    putVec(p0);
    putVec(p1);
    putVec(p2);
    out.put(std::uint16_t{0});
  }
  return std::move(out.bytes);
}

}  // namespace cip
