/// @file volume_array.h
/// @brief A numpy array as the builder's sample grid: array axis a is grid axis a (x, y, z), so vertex
/// coordinates come out in the array's axis order, as scikit-image gives them.
///
/// The builder works on doubles (DenseGrid), like every volume reader of libcip; the array's samples are
/// converted straight from its own buffer with its own strides, so a C-ordered, Fortran-ordered or strided
/// view is read once, with no intermediate numpy copy. Fortran order (axis 0 fastest) is the grid's own
/// layout and reads sequentially; other layouts are read in cache-sized tiles.
#pragma once
#include <pybind11/numpy.h>

#include <string>

#include "cip/volume/dense_grid.h"
#include "cip/volume/strided_samples.h"

namespace cip::python {

/// The samples of a 3-D array (bool, signed or unsigned integers of 1 to 8 bytes, float32 or float64, in
/// native byte order; the Python layer converts other dtypes first) and where the grid sits in the world.
/// Holds a reference to the array; call `toGrid` without the GIL. Throws cip::Error for a wrong ndim, an
/// axis with fewer than 2 samples, or an unsupported dtype, naming what it got.
class VolumeArray {
 public:
  VolumeArray(const pybind11::array& array, const Vec3& spacing, const Vec3& origin);
  /// The converted grid (in parallel over the array's slices).
  DenseGrid toGrid(const std::string& description) const;
  const GridGeometry& geometry() const { return geometry_; }
  /// The array's own buffer as a strided view (no copy; valid while this object lives).
  StridedSamples samples() const;

 private:
  pybind11::array array_;
  const char* data_;
  std::array<std::int64_t, 3> strides_;  ///< bytes
  char kind_;                            ///< numpy dtype kind: b, i, u or f
  std::size_t itemSize_;
  GridGeometry geometry_;
};

}  // namespace cip::python
