// _marching_cubes: scikit-image's marching_cubes (Lewiner's tables or Lorensen's) on libcip's
// lewinerMarchingCubes, reading the numpy buffer in place; cip/__init__.py adds the keywords, spacing and
// scikit-image's checks.
#include <pybind11/numpy.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>

#include "bindings.h"
#include "cancellable.h"
#include "cip/core/error.h"
#include "cip/mesh/lewiner_marching_cubes.h"
#include "volume_array.h"

namespace py = pybind11;

namespace cip::python {

namespace {

/// A numpy array of `Scalar` over the vector's own buffer (moved into a capsule that the array keeps): no
/// copy.
template <typename Scalar, typename T>
py::array_t<Scalar> own(std::vector<T>&& data, std::vector<py::ssize_t> shape) {
  static_assert(sizeof(T) % sizeof(Scalar) == 0);
  if (data.empty()) return py::array_t<Scalar>(shape);
  auto* owned = new std::vector<T>(std::move(data));
  py::capsule base(owned, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<Scalar>(shape, reinterpret_cast<const Scalar*>(owned->data()), base);
}
template <typename T, std::size_t N>
py::array_t<T> rows(std::vector<std::array<T, N>>&& data) {
  const auto n = static_cast<py::ssize_t>(data.size());
  return own<T>(std::move(data), {n, static_cast<py::ssize_t>(N)});
}

py::tuple toTuple(LewinerMesh&& mesh) {
  const auto n = static_cast<py::ssize_t>(mesh.values.size());
  return py::make_tuple(rows(std::move(mesh.vertices)), rows(std::move(mesh.faces)),
                        rows(std::move(mesh.normals)), own<float>(std::move(mesh.values), {n}));
}

/// The level scikit-image uses: `level` as a double, or the middle of the float32 range computed as numpy
/// does (the sum rounded to float32, then halved in double); ValueError outside the data's range.
double chooseLevel(const StridedSamples& samples, const std::optional<double>& level) {
  const Float32Range range = float32Range(samples);
  if (range.nonFinite) throw Error("volume contains NaN or infinite samples");
  if (!level) return 0.5 * static_cast<double>(range.min + range.max);
  const double value = *level;
  if (value < range.min || value > range.max) throw Error("Surface level must be within volume data range.");
  return value;
}

/// (verts (V, 3) float32 in array axis order and index units, faces (F, 3) int32, normals (V, 3) float32,
/// values (V,) float32), exactly as scikit-image's before its spacing and degenerate-face steps.
py::tuple marchingCubes(const py::array& volume, const py::object& level, int stepSize,
                        const std::string& method, bool descent, const py::object& mask, int threads,
                        const py::object& progress) {
  if (method != "lewiner" && method != "lorensen")
    throw Error("method should be one of 'lewiner' or 'lorensen'.");
  const VolumeArray array(volume, Vec3::Ones(), Vec3::Zero());
  const StridedSamples samples = array.samples();
  std::optional<VolumeArray> maskArray;
  StridedSamples maskSamples;
  LewinerOptions options;
  if (!mask.is_none()) {
    maskArray.emplace(mask.cast<py::array>(), Vec3::Ones(), Vec3::Zero());
    maskSamples = maskArray->samples();
    options.mask = &maskSamples;
  }
  options.stepSize = stepSize;
  options.classic = method == "lorensen";
  options.descent = descent;
  options.threads = threads;
  // Converted here, with the GIL: the work runs without it.
  const std::optional<double> requested =
      level.is_none() ? std::nullopt : std::optional<double>(py::float_(level).cast<double>());
  LewinerMesh mesh;
  runCancellable(
      [&](const ReportProgress& report) {
        options.level = chooseLevel(samples, requested);
        options.progress = report;
        mesh = lewinerMarchingCubes(samples, options);
      },
      progress);
  return toTuple(std::move(mesh));
}

/// scikit-image's remove_degenerate_faces on float32 vertices (already scaled by the spacing).
py::tuple removeDegenerate(const py::array_t<float, py::array::c_style | py::array::forcecast>& verts,
                           const py::array_t<std::int32_t, py::array::c_style | py::array::forcecast>& faces,
                           const py::array_t<float, py::array::c_style | py::array::forcecast>& normals,
                           const py::array_t<float, py::array::c_style | py::array::forcecast>& values) {
  const auto n = verts.ndim() == 2 && verts.shape(1) == 3 ? verts.shape(0) : -1;
  if (n < 0 || normals.ndim() != 2 || normals.shape(0) != n || normals.shape(1) != 3 || values.ndim() != 1 ||
      values.shape(0) != n || faces.ndim() != 2 || faces.shape(1) != 3)
    throw Error("verts, normals (V, 3), values (V,) and faces (F, 3) do not fit together");
  LewinerMesh mesh;
  mesh.vertices.resize(static_cast<std::size_t>(n));
  mesh.normals.resize(static_cast<std::size_t>(n));
  mesh.values.assign(values.data(), values.data() + n);
  std::copy_n(verts.data(), 3 * n, reinterpret_cast<float*>(mesh.vertices.data()));
  std::copy_n(normals.data(), 3 * n, reinterpret_cast<float*>(mesh.normals.data()));
  mesh.faces.resize(static_cast<std::size_t>(faces.shape(0)));
  for (std::size_t t = 0; t < mesh.faces.size(); ++t)
    for (int k = 0; k < 3; ++k) {
      const std::int32_t v = faces.data()[3 * t + static_cast<std::size_t>(k)];
      if (v < 0 || v >= n) throw Error("faces index a vertex that does not exist");
      mesh.faces[t][static_cast<std::size_t>(k)] = v;
    }
  {
    py::gil_scoped_release release;
    removeDegenerateFaces(mesh);
  }
  return toTuple(std::move(mesh));
}

}  // namespace

void bindMarchingCubes(py::module_& m) {
  m.def("_marching_cubes", &marchingCubes, py::arg("volume"), py::arg("level"), py::arg("step_size"),
        py::arg("method"), py::arg("descent"), py::arg("mask"), py::arg("threads") = 0,
        py::arg("progress") = py::none());
  m.def("_remove_degenerate_faces", &removeDegenerate, py::arg("verts"), py::arg("faces"), py::arg("normals"),
        py::arg("values"));
}

}  // namespace cip::python
