// _marching_cubes: scikit-image's marching_cubes on libcip's marching cubes (linear edge crossings, gradient
// normals), wrapped with scikit-image's keywords and orientation by cip/__init__.py.
#include <pybind11/numpy.h>
#include <tbb/task_arena.h>

#include <algorithm>

#include "bindings.h"
#include "cancellable.h"
#include "cip/core/error.h"
#include "cip/mesh/marching_cubes.h"
#include "cip/model/model_builder.h"
#include "volume_array.h"

namespace py = pybind11;

namespace cip::python {

namespace {

/// scikit-image's `values`: per vertex, the largest range of samples (largest minus smallest) among the
/// cells whose triangles use it, its measure of how steep the data are there.
std::vector<float> vertexValues(const DenseGrid& grid, const Model& model, const TriangleMesh& mesh) {
  std::vector<float> out(mesh.positions.size(), 0.0f);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& index = model.cells[mesh.triangleCell[t]].index;
    double lo = grid.at(index[0], index[1], index[2]), hi = lo;
    for (int v = 1; v < 8; ++v) {
      const double x = grid.at(index[0] + (v & 1), index[1] + ((v >> 1) & 1), index[2] + ((v >> 2) & 1));
      lo = std::min(lo, x);
      hi = std::max(hi, x);
    }
    for (std::uint32_t v : mesh.triangles[t]) out[v] = std::max(out[v], static_cast<float>(hi - lo));
  }
  return out;
}

template <typename T>
py::array_t<T> rows(const std::vector<std::array<T, 3>>& data) {
  py::array_t<T> out({static_cast<py::ssize_t>(data.size()), py::ssize_t{3}});
  std::copy(data.begin(), data.end(), reinterpret_cast<std::array<T, 3>*>(out.mutable_data()));
  return out;
}

/// (verts, faces, normals, values) with triangles counter-clockwise seen from the side above `level` and
/// normals pointing the other way, to lower values, as scikit-image's do; verts float64 (cip/__init__.py
/// narrows them as scikit-image does), the rest float32 and int32 as scikit-image returns them.
py::tuple marchingCubes(const py::array& volume, const py::object& level, const py::object& spacing,
                        int threads) {
  const VolumeArray array(volume, optionalVec3(spacing, "spacing").value_or(Vec3::Ones()), Vec3::Zero());
  std::vector<std::array<double, 3>> verts;
  std::vector<std::array<float, 3>> normals;
  std::vector<std::array<std::int32_t, 3>> faces;
  std::vector<float> values;
  runCancellable(
      [&](const ReportProgress& report) {
        tbb::task_arena arena(threads > 0 ? threads : tbb::task_arena::automatic);
        arena.execute([&] {
          const DenseGrid grid = array.toGrid("numpy array");
          const auto [lo, hi] = grid.range();
          BuildOptions options;
          options.isovalue = level.is_none() ? 0.5 * (lo + hi) : level.cast<double>();
          if (!(options.isovalue >= lo && options.isovalue <= hi))
            throw Error("Surface level must be within volume data range.");
          options.method = PatchMethod::Paper;
          options.normals = NormalMode::Gradient;
          options.fitCoefficients = false;
          options.threads = threads;
          options.progress = report;
          const Model model = buildModel(grid, options);
          const TriangleMesh mesh = cip::marchingCubes(model, MarchingCubesOptions{threads, true});
          if (mesh.positions.size() > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
            throw Error("the mesh has more vertices than int32 faces can index");
          for (std::size_t v = 0; v < mesh.positions.size(); ++v) {
            verts.push_back({static_cast<float>(mesh.positions[v][0]),
                             static_cast<float>(mesh.positions[v][1]),
                             static_cast<float>(mesh.positions[v][2])});
            normals.push_back({static_cast<float>(-mesh.normals[v][0]),
                               static_cast<float>(-mesh.normals[v][1]),
                               static_cast<float>(-mesh.normals[v][2])});
          }
          for (const auto& t : mesh.triangles)
            faces.push_back({static_cast<std::int32_t>(t[0]), static_cast<std::int32_t>(t[1]),
                             static_cast<std::int32_t>(t[2])});
          values = vertexValues(grid, model, mesh);
        });
      },
      py::none());
  py::array_t<float> valueArray(static_cast<py::ssize_t>(values.size()));
  std::copy(values.begin(), values.end(), valueArray.mutable_data());
  return py::make_tuple(rows(verts), rows(faces), rows(normals), valueArray);
}

}  // namespace

void bindMarchingCubes(py::module_& m) {
  m.def("_marching_cubes", &marchingCubes, py::arg("volume"), py::arg("level"), py::arg("spacing"),
        py::arg("threads") = 0);
}

}  // namespace cip::python
