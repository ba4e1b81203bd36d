/// @file mesh_arrays.h
/// @brief Triangle meshes as numpy arrays and back: (verts, faces, normals) in, TriangleMesh out, for the
/// meshes a Model makes and for cip.write_mesh.
#pragma once
#include <pybind11/numpy.h>

#include "cip/mesh/triangle_mesh.h"

namespace cip::python {

/// (verts (V,3) float64, faces (F,3) int64, normals (V,3) float64; normals has 0 rows when the mesh has
/// none).
pybind11::tuple meshArrays(const TriangleMesh& mesh);

/// The mesh of `verts` (V,3), `faces` (F,3) integer and optional `normals` (V,3) (None for none). Throws
/// cip::Error for wrong shapes, negative or out-of-range indices and non-finite coordinates.
TriangleMesh meshFromArrays(const pybind11::array& verts, const pybind11::array& faces,
                            const pybind11::object& normals);

}  // namespace cip::python
