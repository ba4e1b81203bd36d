// cip.render: the raycast command's renderer (cip_raycast: Embree scene of the patches, exact ray-patch
// roots, shading) on a Model, returning the channels the command writes to its EXR file as numpy arrays.
#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <algorithm>

#include "bindings.h"
#include "camera.h"
#include "cancellable.h"
#include "cip/core/error.h"
#include "image_output.h"
#include "patch_scene.h"
#include "renderer.h"

namespace py = pybind11;

namespace cip::python {

namespace {

template <typename T>
py::array_t<T> channel(const std::vector<T>& data, int width, int height, int stride, int offset) {
  py::array_t<T> out({static_cast<py::ssize_t>(height), static_cast<py::ssize_t>(width)});
  T* o = out.mutable_data();
  const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  for (std::size_t p = 0; p < n; ++p)
    o[p] = data[p * static_cast<std::size_t>(stride) + static_cast<std::size_t>(offset)];
  return out;
}

py::dict render(const std::shared_ptr<Model>& model, const py::object& eye, const py::object& look,
                const py::object& up, double fov, const std::pair<int, int>& size, const std::string& shading,
                int spp, bool shadows, bool ortho, const py::object& curvatureRange, int threads,
                const py::object& progress, const py::object& space) {
  const auto [width, height] = size;
  if (width < 1 || height < 1 || width > 32768 || height > 32768)
    throw Error("size must be (width, height) with sizes from 1 to 32768");
  if (spp < 1 || spp > 4096) throw Error("spp must be between 1 and 4096");
  if (!(fov > 0 && fov < 180)) throw Error("fov must be between 0 and 180 degrees");
  raycast::RenderOptions options;
  options.samplesPerPixel = spp;
  options.threads = threads;
  options.shading.mode = raycast::parseShadingMode(shading);
  options.shading.shadows = shadows;
  if (!curvatureRange.is_none()) {
    const auto r = curvatureRange.cast<std::pair<double, double>>();
    if (!(r.first < r.second)) throw Error("curvature_range needs two increasing numbers, e.g. (-2, 2)");
    options.shading.curvatureRange = r;
  }
  raycast::CameraSettings camera;
  camera.eye = optionalVec3(eye, "eye");
  camera.look = optionalVec3(look, "look");
  camera.up = optionalVec3(up, "up");
  camera.fovDegrees = fov;
  camera.orthographic = ortho;
  raycast::RenderImage image;
  runCancellable(
      [&](const ReportProgress& report) {
        raycast::PatchSceneOptions sceneOptions;
        sceneOptions.curvature =
            options.shading.mode == raycast::ShadingMode::Curvature;  // Hessian only then
        sceneOptions.threads = threads;
        if (!space.is_none()) sceneOptions.space = parseWorldSpace(space.cast<std::string>());
        const raycast::PatchScene scene(*model, sceneOptions);
        options.progress = report;
        image = raycast::render(scene, raycast::makeCamera(camera, scene.bounds(), width, height), options);
      },
      progress);
  py::dict out;
  const char* const* names = raycast::kExrChannels;
  for (int c = 0; c < 4; ++c) out[names[c]] = channel(image.rgba, width, height, 4, c);
  out[names[4]] = channel(image.depth, width, height, 1, 0);
  for (int c = 0; c < 3; ++c) out[names[5 + c]] = channel(image.normal, width, height, 3, c);
  out[names[8]] = channel(image.id, width, height, 1, 0);
  return out;
}

}  // namespace

void bindRender(py::module_& m) {
  m.def("_render", &render, py::arg("model"), py::arg("eye"), py::arg("look"), py::arg("up"), py::arg("fov"),
        py::arg("size"), py::arg("shading"), py::arg("spp"), py::arg("shadows"), py::arg("ortho"),
        py::arg("curvature_range"), py::arg("threads"), py::arg("progress"), py::arg("space") = py::none());
}

}  // namespace cip::python
