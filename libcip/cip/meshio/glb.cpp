#include "cip/meshio/glb.h"

#include <cstdio>
#include <limits>
#include <string>

#include "cip/core/error.h"
#include "cip/meshio/byte_buffer.h"

namespace cip {

namespace {

constexpr std::uint32_t kMagic = 0x46546C67;      // "glTF"
constexpr std::uint32_t kJsonChunk = 0x4E4F534A;  // "JSON"
constexpr std::uint32_t kBinChunk = 0x004E4942;   // "BIN\0"
constexpr int kFloat = 5126, kUnsignedInt = 5125;
constexpr int kArrayBuffer = 34962, kElementArrayBuffer = 34963;

/// A float32 value in full (17 digits), so that the JSON number is the float itself, not a neighbour of it.
std::string number(float v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", static_cast<double>(v));
  return buf;
}

/// The binary buffer: positions, normals (if any) and indices, each 4-byte aligned by construction.
struct BinaryBuffer {
  ByteBuffer data;
  std::size_t normalsOffset = 0, indicesOffset = 0;
  float lo[3], hi[3];
};

BinaryBuffer binaryBuffer(const TriangleMesh& mesh) {
  BinaryBuffer b;
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = std::numeric_limits<float>::infinity();
    b.hi[a] = -std::numeric_limits<float>::infinity();
  }
  for (const Vec3& p : mesh.positions)
    for (int a = 0; a < 3; ++a) {
      const float f = static_cast<float>(p[a]);
      b.data.put(f);
      b.lo[a] = std::min(b.lo[a], f);
      b.hi[a] = std::max(b.hi[a], f);
    }
  b.normalsOffset = b.data.size();
  if (mesh.hasNormals())
    for (const Vec3& n : mesh.normals)
      for (int a = 0; a < 3; ++a) b.data.put(static_cast<float>(n[a]));
  b.indicesOffset = b.data.size();
  for (const auto& t : mesh.triangles)
    for (std::uint32_t i : t) b.data.put(i);
  return b;
}

std::string bufferView(std::size_t offset, std::size_t length, int target) {
  return "{\"buffer\":0,\"byteOffset\":" + std::to_string(offset) +
         ",\"byteLength\":" + std::to_string(length) + ",\"target\":" + std::to_string(target) + "}";
}

std::string vec3Accessor(int view, std::size_t count, const std::string& extra) {
  return "{\"bufferView\":" + std::to_string(view) + ",\"componentType\":" + std::to_string(kFloat) +
         ",\"count\":" + std::to_string(count) + ",\"type\":\"VEC3\"" + extra + "}";
}

/// The JSON chunk's text for a mesh with triangles, laid out in `b`.
std::string meshJson(const TriangleMesh& mesh, const BinaryBuffer& b) {
  const bool normals = mesh.hasNormals();
  const std::size_t nv = mesh.positions.size();
  std::string minMax = ",\"min\":[" + number(b.lo[0]) + "," + number(b.lo[1]) + "," + number(b.lo[2]) +
                       "],\"max\":[" + number(b.hi[0]) + "," + number(b.hi[1]) + "," + number(b.hi[2]) + "]";
  std::string views = bufferView(0, b.normalsOffset, kArrayBuffer);
  std::string accessors = vec3Accessor(0, nv, minMax);
  std::string attributes = "\"POSITION\":0";
  int next = 1;
  if (normals) {
    views += "," + bufferView(b.normalsOffset, b.indicesOffset - b.normalsOffset, kArrayBuffer);
    accessors += "," + vec3Accessor(next, nv, "");
    attributes += ",\"NORMAL\":" + std::to_string(next);
    ++next;
  }
  views += "," + bufferView(b.indicesOffset, b.data.size() - b.indicesOffset, kElementArrayBuffer);
  accessors += ",{\"bufferView\":" + std::to_string(next) +
               ",\"componentType\":" + std::to_string(kUnsignedInt) +
               ",\"count\":" + std::to_string(3 * mesh.triangles.size()) + ",\"type\":\"SCALAR\"}";
  return "{\"asset\":{\"version\":\"2.0\",\"generator\":\"cip\"},\"scene\":0,\"scenes\":[{\"nodes\":[0]}],"
         "\"nodes\":[{\"mesh\":0}],\"meshes\":[{\"primitives\":[{\"attributes\":{" +
         attributes + "},\"indices\":" + std::to_string(next) + ",\"mode\":4}]}],\"accessors\":[" +
         accessors + "],\"bufferViews\":[" + views +
         "],\"buffers\":[{\"byteLength\":" + std::to_string(b.data.size()) + "}]}";
}

}  // namespace

std::vector<std::uint8_t> encodeGlb(const TriangleMesh& mesh) {
  validateMesh(mesh, "glTF output");
  const std::size_t bytesNeeded = mesh.positions.size() * 24 + mesh.triangles.size() * 12 + 4096;
  if (bytesNeeded > std::numeric_limits<std::uint32_t>::max())
    throw Error("glTF output: the mesh needs more than the 4 GiB a binary glTF file can hold");
  const bool empty = mesh.triangles.empty();
  BinaryBuffer bin;
  std::string json =
      "{\"asset\":{\"version\":\"2.0\",\"generator\":\"cip\"},\"scene\":0,\"scenes\":[{\"nodes\":[]}]}";
  if (!empty) {
    bin = binaryBuffer(mesh);
    json = meshJson(mesh, bin);
  }
  ByteBuffer jsonChunk;
  jsonChunk.putText(json);
  jsonChunk.pad(4, ' ');
  bin.data.pad(4, 0);
  const std::size_t total = 12 + 8 + jsonChunk.size() + (empty ? 0 : 8 + bin.data.size());
  ByteBuffer out;
  out.bytes.reserve(total);
  out.put(kMagic);
  out.put(std::uint32_t{2});
  out.put(static_cast<std::uint32_t>(total));
  out.put(static_cast<std::uint32_t>(jsonChunk.size()));
  out.put(kJsonChunk);
  out.putBytes(jsonChunk.bytes.data(), jsonChunk.size());
  if (!empty) {
    out.put(static_cast<std::uint32_t>(bin.data.size()));
    out.put(kBinChunk);
    out.putBytes(bin.data.bytes.data(), bin.data.size());
  }
  return std::move(out.bytes);
}

}  // namespace cip
