#include "mesh_arrays.h"

#include <limits>

#include "cip/core/error.h"

namespace py = pybind11;

namespace cip::python {

namespace {

py::array_t<double> vectorArray(const std::vector<Vec3>& v) {
  py::array_t<double> out({static_cast<py::ssize_t>(v.size()), py::ssize_t{3}});
  auto a = out.mutable_unchecked<2>();
  for (std::size_t i = 0; i < v.size(); ++i)
    for (int k = 0; k < 3; ++k) a(static_cast<py::ssize_t>(i), k) = v[i][k];
  return out;
}

/// Rows of an (N,3) array converted to `T` (numpy casts; a copy only when the dtype or layout differs).
template <typename T>
py::array_t<T, py::array::c_style | py::array::forcecast> rows3(const py::array& a, const char* what) {
  auto out = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(a);
  if (!out || out.ndim() != 2 || out.shape(1) != 3)
    throw Error(std::string(what) + " must be an (N, 3) array of numbers");
  return out;
}

std::vector<Vec3> vectors(const py::array& a, const char* what) {
  const auto array = rows3<double>(a, what);
  const auto r = array.unchecked<2>();
  std::vector<Vec3> out(static_cast<std::size_t>(r.shape(0)));
  for (py::ssize_t i = 0; i < r.shape(0); ++i)
    out[static_cast<std::size_t>(i)] = Vec3(r(i, 0), r(i, 1), r(i, 2));
  return out;
}

}  // namespace

py::tuple meshArrays(const TriangleMesh& mesh) {
  py::array_t<std::int64_t> faces({static_cast<py::ssize_t>(mesh.triangles.size()), py::ssize_t{3}});
  auto f = faces.mutable_unchecked<2>();
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k) f(static_cast<py::ssize_t>(t), k) = mesh.triangles[t][k];
  return py::make_tuple(vectorArray(mesh.positions), faces,
                        vectorArray(mesh.hasNormals() ? mesh.normals : std::vector<Vec3>{}));
}

TriangleMesh meshFromArrays(const py::array& verts, const py::array& faces, const py::object& normals) {
  TriangleMesh mesh;
  mesh.positions = vectors(verts, "verts");
  if (!normals.is_none()) {
    mesh.normals = vectors(py::array::ensure(normals), "normals");
    if (mesh.normals.size() != mesh.positions.size())
      throw Error("normals must have one row per vertex (" + std::to_string(mesh.positions.size()) +
                  "), got " + std::to_string(mesh.normals.size()));
  }
  const py::dtype kind = faces.dtype();
  if (kind.kind() != 'i' && kind.kind() != 'u') throw Error("faces must be an (F, 3) array of integers");
  const auto array = rows3<std::int64_t>(faces, "faces");
  const auto r = array.unchecked<2>();
  mesh.triangles.resize(static_cast<std::size_t>(r.shape(0)));
  for (py::ssize_t t = 0; t < r.shape(0); ++t)
    for (int k = 0; k < 3; ++k) {
      const std::int64_t i = r(t, k);
      if (i < 0 || i >= static_cast<std::int64_t>(mesh.positions.size()))
        throw Error("faces: vertex index " + std::to_string(i) + " out of range (there are " +
                    std::to_string(mesh.positions.size()) + " vertices)");
      mesh.triangles[static_cast<std::size_t>(t)][k] = static_cast<std::uint32_t>(i);
    }
  validateMesh(mesh, "mesh");
  return mesh;
}

}  // namespace cip::python
