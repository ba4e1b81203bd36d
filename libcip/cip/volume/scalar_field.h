/// @file scalar_field.h
/// @brief A scalar field given by a function of world position: the analytic fields, and interpolants of
/// samples, behind one interface for exact isovertices, gradients and fidelity measures.
#pragma once
#include <array>

#include "cip/core/vec3.h"

namespace cip {

/// A scalar field: exact isovertices and gradients of analytic fields, or an interpolant of samples.
/// Coordinates and gradients are in world units.
class ScalarField {
 public:
  virtual ~ScalarField() = default;
  virtual double value(const Vec3& world) const = 0;
  virtual Vec3 gradient(const Vec3& world) const = 0;
  /// Values at the tensor lattice (x[a], y[b], z[d]) (world), a < count[0], b < count[1], d < count[2],
  /// stored at out[a stride[0] + b stride[1] + d stride[2]]. Equal to value() at each point; the default
  /// calls it, fields whose costly parts depend on fewer coordinates override it (the fitted construction
  /// checks several hundred lattice points per cell).
  virtual void valuesOnLattice(const double* x, const double* y, const double* z,
                               const std::array<int, 3>& count, const std::array<int, 3>& stride,
                               double* out) const;
};

}  // namespace cip
