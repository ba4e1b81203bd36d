/// @file reconstruction_choice.h
/// @brief Reconstruction::Auto: the reference of sampled data chosen once per volume from how the samples
/// near the isosurface behave at the finest scale the grid carries.
///
/// `central8` knows the normal of smooth, finely sampled data far better than `monotone` but overshoots at
/// steps and on aliased data. The ratio of the energies of the samples' sixth and fourth differences near the
/// surface gives an effective wavelength (a sampled sine of wavelength L gives exactly L); central8 is chosen
/// from kCentral8Wavelength samples up. docs/method.md derives the estimate and measures it per volume.
#pragma once
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

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
///
/// A build split between processes (docs/mpi.md) records the terms of its cells instead (the estimator made
/// with a record), and every process adds all processes' records in grid order (addTerms): the same sums,
/// to the bit, as one process adding the cells.
struct SamplingTerm {
  double fourth = 0, sixth = 0, sample = 0;  ///< squares of one axis's differences and centre sample
};

class SamplingEstimator {
 public:
  SamplingEstimator() = default;
  /// An estimator that appends each measured axis's terms to `*record` (in the order it adds them) and
  /// counts the measured cells, rather than summing them.
  explicit SamplingEstimator(std::vector<SamplingTerm>* record) : record_(record) {}
  /// `cell`: the crossed cell's lowest point, in `grid`'s own indices (a brick's grid for sparse volumes).
  void addCell(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell);
  /// Adds recorded terms, in their order, and `cells` measured cells.
  void addTerms(const SamplingTerm* terms, std::size_t count, std::int64_t cells);
  /// Crossed cells measured so far.
  std::int64_t cells() const { return cells_; }
  SamplingEstimate estimate() const;

 private:
  double fourth_ = 0, sixth_ = 0, samples_ = 0;  ///< sums of squares (samples_: of the centre samples)
  std::int64_t cells_ = 0;
  std::vector<SamplingTerm>* record_ = nullptr;
};

/// The estimate over every crossed cell of a dense grid (corners on both sides of the isovalue, all finite).
SamplingEstimate estimateSampling(const DenseGrid& grid, double isovalue);

/// Reconstruction::Auto resolved: Central8 when the effective wavelength is at least kCentral8Wavelength
/// samples, else Monotone (also when no cell was measured).
Reconstruction chooseReconstruction(const SamplingEstimate& estimate);

}  // namespace cip
