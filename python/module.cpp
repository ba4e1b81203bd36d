// The compiled part of the Python module `cip` (python/cip/__init__.py is the public face): pybind11 bindings
// over libcip and the renderer. cip::Error becomes cip.Error, a ValueError carrying the library's message.
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bindings.h"
#include "cip/core/error.h"

namespace py = pybind11;

namespace cip::python {

std::optional<Vec3> optionalVec3(const py::object& value, const char* what) {
  if (value.is_none()) return std::nullopt;
  try {
    const auto v = value.cast<std::vector<double>>();
    if (v.size() == 3) return Vec3(v[0], v[1], v[2]);
  } catch (const py::cast_error&) {
  }
  throw Error(std::string(what) + " must be three numbers, got " + std::string(py::repr(value)));
}

}  // namespace cip::python

PYBIND11_MODULE(_cip, m) {
  m.doc() = "cip: corner-patch isosurfaces (compiled part; use the package cip)";
  py::register_exception<cip::Error>(m, "Error", PyExc_ValueError);
  cip::python::bindModel(m);
  cip::python::bindMarchingCubes(m);
  cip::python::bindRender(m);
}
