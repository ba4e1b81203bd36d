// Mesh files by extension (meshio/mesh_file.h): glTF binary files read back with tinygltf, an independent
// reader, agree with the mesh they were written from; STL and OBJ files have the sizes and lines their
// formats prescribe (python/tests read them back with meshio); names pick the format; failed writes leave old
// files.
#include "cip/meshio/mesh_file.h"

#include <gtest/gtest.h>

#define TINYGLTF_IMPLEMENTATION
#define TINYGLTF_NO_STB_IMAGE
#define TINYGLTF_NO_STB_IMAGE_WRITE
#define TINYGLTF_NO_EXTERNAL_IMAGE
#include <tiny_gltf.h>

#include <cstring>
#include <fstream>
#include <sstream>

#include "cip/core/error.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/mesh/ply.h"
#include "cip/model/model_builder.h"
#include "cip/volume/analytic_field.h"
#include "support/scratch_dir.h"

using namespace cip;

namespace {

/// A closed marching-cubes mesh of a torus, with normals.
TriangleMesh torusMesh() {
  auto field = makeAnalyticField("torus");
  DenseGrid grid = sampleField(*field, 12, "torus");
  BuildOptions options;
  options.isovalue = field->defaultIsovalue();
  options.method = PatchMethod::Paper;
  options.fitCoefficients = false;
  return marchingCubes(buildModel(grid, options));
}

/// The elements of accessor `a` as doubles (float32 and uint32 accessors, tightly packed).
std::vector<double> accessorValues(const tinygltf::Model& m, int a) {
  const tinygltf::Accessor& acc = m.accessors.at(static_cast<std::size_t>(a));
  const tinygltf::BufferView& view = m.bufferViews.at(static_cast<std::size_t>(acc.bufferView));
  const std::vector<unsigned char>& data = m.buffers.at(static_cast<std::size_t>(view.buffer)).data;
  const std::size_t n = acc.count * static_cast<std::size_t>(tinygltf::GetNumComponentsInType(acc.type));
  EXPECT_LE(view.byteOffset + acc.byteOffset + 4 * n, data.size());
  std::vector<double> out(n);
  for (std::size_t i = 0; i < n; ++i) {
    const unsigned char* p = data.data() + view.byteOffset + acc.byteOffset + 4 * i;
    if (acc.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT) {
      float f;
      std::memcpy(&f, p, 4);
      out[i] = f;
    } else {
      EXPECT_EQ(acc.componentType, TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT);
      std::uint32_t u;
      std::memcpy(&u, p, 4);
      out[i] = u;
    }
  }
  return out;
}

tinygltf::Model loadGlb(const std::string& path) {
  tinygltf::TinyGLTF loader;
  tinygltf::Model model;
  std::string err, warn;
  EXPECT_TRUE(loader.LoadBinaryFromFile(&model, &err, &warn, path)) << err;
  EXPECT_EQ(err, "");
  EXPECT_EQ(warn, "");
  return model;
}

std::string readText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

TEST(MeshFile, FormatFollowsTheExtension) {
  EXPECT_EQ(meshFormatOf("a/b.stl"), MeshFormat::Stl);
  EXPECT_EQ(meshFormatOf("B.STL"), MeshFormat::Stl);
  EXPECT_EQ(meshFormatOf("x.obj"), MeshFormat::Obj);
  EXPECT_EQ(meshFormatOf("x.GLB"), MeshFormat::Glb);
  EXPECT_EQ(meshFormatOf("x.ply"), MeshFormat::Ply);
  EXPECT_EQ(meshFormatOf("x.mesh"), MeshFormat::Ply);  // any other name: PLY, as before the other formats
  EXPECT_EQ(meshFormatOf("dir.stl/mesh"), MeshFormat::Ply);
  EXPECT_THROW(meshFormatOf("x.gltf"), Error);
}

TEST(MeshFile, GlbReadsBackWithTinyGltf) {
  test::ScratchDir dir;
  const TriangleMesh mesh = torusMesh();
  ASSERT_GT(mesh.triangles.size(), 100u);
  ASSERT_TRUE(mesh.hasNormals());
  const std::string path = dir.file("torus.glb");
  EXPECT_GT(writeMesh(mesh, path), 0u);
  const tinygltf::Model m = loadGlb(path);
  ASSERT_EQ(m.meshes.size(), 1u);
  ASSERT_EQ(m.scenes.size(), 1u);
  ASSERT_EQ(m.meshes[0].primitives.size(), 1u);
  const tinygltf::Primitive& prim = m.meshes[0].primitives[0];
  EXPECT_EQ(prim.mode, TINYGLTF_MODE_TRIANGLES);
  const auto positions = accessorValues(m, prim.attributes.at("POSITION"));
  const auto normals = accessorValues(m, prim.attributes.at("NORMAL"));
  const auto indices = accessorValues(m, prim.indices);
  ASSERT_EQ(positions.size(), 3 * mesh.positions.size());
  ASSERT_EQ(normals.size(), 3 * mesh.normals.size());
  ASSERT_EQ(indices.size(), 3 * mesh.triangles.size());
  const tinygltf::Accessor& pa = m.accessors[static_cast<std::size_t>(prim.attributes.at("POSITION"))];
  for (std::size_t v = 0; v < mesh.positions.size(); ++v)
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(positions[3 * v + a], static_cast<float>(mesh.positions[v][a]));
      EXPECT_EQ(normals[3 * v + a], static_cast<float>(mesh.normals[v][a]));
      EXPECT_GE(positions[3 * v + a], pa.minValues.at(a));
      EXPECT_LE(positions[3 * v + a], pa.maxValues.at(a));
    }
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k) EXPECT_EQ(indices[3 * t + k], mesh.triangles[t][k]);
}

TEST(MeshFile, GlbWithoutNormalsOrTriangles) {
  test::ScratchDir dir;
  TriangleMesh mesh = torusMesh();
  mesh.normals.clear();
  writeMesh(mesh, dir.file("bare.glb"));
  const tinygltf::Model bare = loadGlb(dir.file("bare.glb"));
  ASSERT_EQ(bare.meshes.size(), 1u);
  EXPECT_EQ(bare.meshes[0].primitives[0].attributes.count("NORMAL"), 0u);
  writeMesh(TriangleMesh{}, dir.file("empty.glb"));
  const tinygltf::Model empty = loadGlb(dir.file("empty.glb"));
  EXPECT_TRUE(empty.meshes.empty());
  EXPECT_EQ(empty.scenes.size(), 1u);
}

TEST(MeshFile, StlAndObjHaveTheirFormatsShape) {
  test::ScratchDir dir;
  const TriangleMesh mesh = torusMesh();
  EXPECT_EQ(writeMesh(mesh, dir.file("t.stl")), 84 + 50 * mesh.triangles.size());
  const std::string stl = readText(dir.file("t.stl"));
  EXPECT_NE(stl.compare(0, 5, "solid"), 0);
  std::uint32_t count;
  std::memcpy(&count, stl.data() + 80, 4);
  EXPECT_EQ(count, mesh.triangles.size());
  writeMesh(mesh, dir.file("t.obj"));
  std::istringstream obj(readText(dir.file("t.obj")));
  std::size_t v = 0, vn = 0, f = 0;
  for (std::string line; std::getline(obj, line);) {
    v += line.rfind("v ", 0) == 0;
    vn += line.rfind("vn ", 0) == 0;
    f += line.rfind("f ", 0) == 0;
  }
  EXPECT_EQ(v, mesh.positions.size());
  EXPECT_EQ(vn, mesh.normals.size());
  EXPECT_EQ(f, mesh.triangles.size());
}

TEST(MeshFile, PlyIsTheDefaultAndBadMeshesLeaveOldFiles) {
  test::ScratchDir dir;
  const TriangleMesh mesh = torusMesh();
  writeMesh(mesh, dir.file("t.mesh"));
  EXPECT_EQ(readPly(dir.file("t.mesh")).triangles, mesh.triangles);
  TriangleMesh bad = mesh;
  bad.triangles[0][0] = static_cast<std::uint32_t>(bad.positions.size());
  for (const char* name : {"t.stl", "t.obj", "t.glb"}) {
    writeMesh(mesh, dir.file(name));
    const std::string before = readText(dir.file(name));
    EXPECT_THROW(writeMesh(bad, dir.file(name)), Error) << name;
    EXPECT_EQ(readText(dir.file(name)), before) << name;
  }
}
