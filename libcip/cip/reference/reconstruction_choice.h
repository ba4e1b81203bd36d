/// @file reconstruction_choice.h
/// @brief Reconstruction::Auto: the reference of sampled data chosen from how the samples near the isosurface
/// behave at the finest scale the grid carries.
///
/// `central8` (tricubic_reference.h) knows the normal of smooth, finely sampled data far better than
/// `monotone`, but overshoots where the data change at the scale of the grid: next to steps (CT bone), at the
/// clamped band of a narrow-band level set, and where the samples alias. A local test cannot tell those from
/// a well-sampled crest (docs/method.md), so the choice is made once per volume from the spectrum of the
/// samples near the surface, through the energy of their sixth differences over that of their fourth:
///     R = sum (D6 s)^2 / sum (D4 s)^2,
/// summed along all three axes at the lowest corner of every crossed cell. For samples of a sine of
/// wavelength L samples, R = (2 sin(pi / L))^4, so R gives an effective wavelength
///     L = pi / asin(R^(1/4) / 2)          (2 at R >= 16, the grid's Nyquist limit).
/// Smooth fields have a spectrum that falls off towards the grid's Nyquist limit, and a long L; steps, kinks
/// and aliased ripples keep energy up to that limit, and a short one. Measured (docs/method.md):
/// Marschner-Lobb at N = 64 3.9 samples, at N = 32 2.5; headsq 2.7; the tooth 2.8; the OpenVDB level set 2.0;
/// torus and gyroid at N = 32 4.6 and 16. Central8 is chosen from kCentral8Wavelength samples up.
#pragma once
#include <array>
#include <cstdint>

#include "cip/reference/tricubic_reference.h"
#include "cip/volume/dense_grid.h"

namespace cip {

/// Effective wavelength (in samples) from which Reconstruction::Auto takes Central8.
constexpr double kCentral8Wavelength = 3.3;

/// The spectral measure of the samples near the isosurface.
struct SamplingEstimate {
  double sixthToFourth = 0;  ///< R above (0 when nothing was measured)
  double wavelength = 0;     ///< effective wavelength in samples (infinity for cubic data; 0 if unmeasured)
  std::int64_t cells = 0;    ///< crossed cells measured
};

/// Accumulates the estimate over crossed cells. At each cell's lowest corner, along each axis, it adds the
/// squared fourth and sixth differences centred at the corner; an axis whose 7 samples leave the grid or are
/// not all finite is left out there. Fourth differences below 1e-12 of the samples' size (a cubic, to
/// rounding) count as none: such data have no finest scale, and get an infinite wavelength. The sums, and so
/// the result, depend on the order of the cells only through rounding; buildModel adds them in grid order.
class SamplingEstimator {
 public:
  /// `cell`: the crossed cell's lowest point, in `grid`'s own indices (a brick's grid for sparse volumes).
  void addCell(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell);
  SamplingEstimate estimate() const;

 private:
  double fourth_ = 0, sixth_ = 0, samples_ = 0;  ///< sums of squares (samples_: of the centre samples)
  std::int64_t cells_ = 0;
};

/// The estimate over every crossed cell of a dense grid (corners on both sides of the isovalue, all finite).
SamplingEstimate estimateSampling(const DenseGrid& grid, double isovalue);

/// Reconstruction::Auto resolved: Central8 when the effective wavelength is at least kCentral8Wavelength
/// samples, else Monotone (also when no cell was measured).
Reconstruction chooseReconstruction(const SamplingEstimate& estimate);

}  // namespace cip
