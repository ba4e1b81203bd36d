/// @file analytic_field.h
/// @brief Analytic test fields with exact values and gradients, and their sampling on a grid.
///
/// Every field is defined on the box [-1,1]^3 (world units). Level-set style fields (sphere, torus) are
/// signed distances, negative inside, isovalue 0. `resolution` N means N cells per axis (N+1 grid points,
/// spacing 2/N).
///  - sphere: |x| - 0.75
///  - torus: distance to a torus in the xy-plane, major radius 0.6, minor radius 0.25
///  - gyroid: sin(2 pi x) cos(2 pi y) + sin(2 pi y) cos(2 pi z) + sin(2 pi z) cos(2 pi x), isovalue 0
///  - marschner-lobb: the Marschner-Lobb test signal (f_M = 6, alpha = 0.25), isovalue 0.5
///  - plane: 0.3 x - 0.5 y + 0.81 z - 0.05 (a linear field, reproduced exactly by corner patches)
#pragma once
#include <memory>
#include <string>
#include <vector>

#include "cip/volume/dense_grid.h"
#include "cip/volume/scalar_field.h"

namespace cip {

class AnalyticField : public ScalarField {
 public:
  virtual std::string name() const = 0;
  /// The isovalue at which the field's surface is defined.
  virtual double defaultIsovalue() const { return 0.0; }
};

/// Names accepted by makeAnalyticField.
std::vector<std::string> analyticFieldNames();
/// Returns the named field, or nullptr if the name is unknown.
std::unique_ptr<AnalyticField> makeAnalyticField(const std::string& name);
/// The local frequency of the Marschner-Lobb field's radial ripple at world point p (cycles per world unit,
/// across the ripple): f_M pi/2 |sin(pi r/2)| with r the distance from the z-axis. A grid of spacing h
/// carries it only below its Nyquist limit 1 / (2 h).
double marschnerLobbRippleFrequency(const Vec3& p);
/// Samples a field at (N+1)^3 points over [-1,1]^3, a lattice per slice (ScalarField::valuesOnLattice, so a
/// separable field computes its costly parts per line), in parallel; throws cip::Error for N < 1 or absurd
/// sizes.
DenseGrid sampleField(const ScalarField& field, int resolution, const std::string& description);

}  // namespace cip
