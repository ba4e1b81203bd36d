#include "cip/reference/reconstruction_choice.h"

#include <cmath>
#include <limits>

namespace cip {

void SamplingEstimator::addCell(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell) {
  const auto& dims = grid.geometry.dims;
  const std::int64_t stride[3] = {1, dims[0], dims[0] * dims[1]};
  const double* p = &grid.values[static_cast<std::size_t>(grid.index(cell[0], cell[1], cell[2]))];
  SamplingTerm terms[3];
  std::size_t count = 0;
  for (int a = 0; a < 3; ++a) {
    if (cell[a] < 3 || cell[a] + 3 >= dims[a]) continue;
    const std::int64_t s = stride[a];
    const double m3 = p[-3 * s], m2 = p[-2 * s], m1 = p[-s], c = p[0], p1 = p[s], p2 = p[2 * s],
                 p3 = p[3 * s];
    const double d4 = m2 - 4 * m1 + 6 * c - 4 * p1 + p2;
    const double d6 = m3 - 6 * m2 + 15 * m1 - 20 * c + 15 * p1 - 6 * p2 + p3;
    if (!std::isfinite(d4) || !std::isfinite(d6)) continue;
    terms[count++] = SamplingTerm{d4 * d4, d6 * d6, c * c};
  }
  if (count == 0) return;
  if (record_) {
    record_->insert(record_->end(), terms, terms + count);
    ++cells_;
  } else {
    addTerms(terms, count, 1);
  }
}

void SamplingEstimator::addTerms(const SamplingTerm* terms, std::size_t count, std::int64_t cells) {
  for (std::size_t n = 0; n < count; ++n) {
    fourth_ += terms[n].fourth;
    sixth_ += terms[n].sixth;
    samples_ += terms[n].sample;
  }
  cells_ += cells;
}

SamplingEstimate SamplingEstimator::estimate() const {
  SamplingEstimate e;
  e.cells = cells_;
  if (cells_ == 0) return e;
  // Cubic (or flatter) along every measured line, to rounding: the rounding of a fourth difference is below
  // 16 eps |s|, so its square below 1.3e-29 s^2; 1e-24 leaves a factor 1e5.
  if (!(fourth_ > 1e-24 * samples_)) {
    e.wavelength = std::numeric_limits<double>::infinity();
    return e;
  }
  e.sixthToFourth = sixth_ / fourth_;
  // A sine of wavelength L samples: the k-th difference has amplitude (2 sin(pi/L))^k.
  const double x = std::sqrt(std::sqrt(e.sixthToFourth)) / 2;
  e.wavelength = x >= 1 ? 2.0 : x > 0 ? M_PI / std::asin(x) : std::numeric_limits<double>::infinity();
  return e;
}

SamplingEstimate estimateSampling(const DenseGrid& grid, double isovalue) {
  SamplingEstimator estimator;
  const auto& d = grid.geometry.dims;
  for (std::int64_t k = 0; k + 1 < d[2]; ++k)
    for (std::int64_t j = 0; j + 1 < d[1]; ++j)
      for (std::int64_t i = 0; i + 1 < d[0]; ++i) {
        bool above = false, below = false, finite = true;
        for (int v = 0; v < 8; ++v) {
          const double x = grid.at(i + (v & 1), j + ((v >> 1) & 1), k + ((v >> 2) & 1));
          finite = finite && std::isfinite(x);
          (x > isovalue ? above : below) = true;
        }
        if (finite && above && below) estimator.addCell(grid, {i, j, k});
      }
  return estimator.estimate();
}

Reconstruction chooseReconstruction(const SamplingEstimate& estimate) {
  if (estimate.cells == 0) return Reconstruction::Monotone;
  return estimate.wavelength >= kCentral8Wavelength ? Reconstruction::Central8 : Reconstruction::Monotone;
}

}  // namespace cip
