/// @file bindings.h
/// @brief The parts of the Python module `cip._cip`, one function each that adds its classes and functions
/// to the module (module.cpp calls them), and the small conversions they share.
#pragma once
#include <pybind11/pybind11.h>

#include <optional>

#include "cip/core/vec3.h"

namespace cip::python {

void bindModel(pybind11::module_& m);          ///< Model, load, extract, write_mesh (model_binding.cpp)
void bindMarchingCubes(pybind11::module_& m);  ///< _marching_cubes (marching_cubes_binding.cpp)
void bindRender(pybind11::module_& m);         ///< render (render_binding.cpp)

/// Three numbers from a Python sequence, or nullopt for None; throws cip::Error naming `what` otherwise.
std::optional<Vec3> optionalVec3(const pybind11::object& value, const char* what);

}  // namespace cip::python
