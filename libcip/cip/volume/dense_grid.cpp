#include "cip/volume/dense_grid.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "cip/core/error.h"
#include "cip/core/huge_pages.h"

namespace cip {

std::size_t DenseGrid::defaultMaxBytes() {
  long pages = ::sysconf(_SC_PHYS_PAGES);
  long pageSize = ::sysconf(_SC_PAGE_SIZE);
  if (pages <= 0 || pageSize <= 0) return std::size_t(8) << 30;
  return static_cast<std::size_t>(pages) / 4 * 3 * static_cast<std::size_t>(pageSize);
}

std::int64_t checkedVolumeSize(const std::array<std::int64_t, 3>& dims, std::size_t bytesPerElement,
                               std::size_t maxBytes) {
  auto describe = [&] {
    return std::to_string(dims[0]) + "x" + std::to_string(dims[1]) + "x" + std::to_string(dims[2]);
  };
  std::int64_t n = 1;
  for (auto d : dims) {
    if (d < 0) throw Error("invalid volume dimensions " + describe() + ": negative extent");
    if (__builtin_mul_overflow(n, d, &n))
      throw Error("volume dimensions " + describe() + " overflow 64 bits");
  }
  std::uint64_t bytes = 0;
  if (__builtin_mul_overflow(static_cast<std::uint64_t>(n), static_cast<std::uint64_t>(bytesPerElement),
                             &bytes)) {
    throw Error("volume dimensions " + describe() + " overflow 64 bits");
  }
  if (bytes > maxBytes) {
    throw Error("volume " + describe() + " needs " + std::to_string(bytes >> 20) + " MiB, more than the " +
                std::to_string(maxBytes >> 20) + " MiB allowed");
  }
  return n;
}

void DenseGrid::allocate(const std::array<std::int64_t, 3>& dims, std::size_t maxBytes) {
  std::int64_t n = checkedVolumeSize(dims, sizeof(double), maxBytes);
  geometry.dims = dims;
  values.clear();
  resizeHuge(values, static_cast<std::size_t>(n));  // zeros
}

std::pair<double, double> finiteRange(const double* values, std::size_t n) {
  constexpr double kInf = std::numeric_limits<double>::infinity(), kMax = std::numeric_limits<double>::max();
  // Branch-free, in four independent lanes: one running minimum is a chain of dependent comparisons, four
  // run side by side. (The compiler does not turn it into packed instructions: IEEE rules forbid reordering a
  // floating-point minimum.)
  constexpr std::size_t kLanes = 4;
  double lo[kLanes], hi[kLanes];
  for (std::size_t j = 0; j < kLanes; ++j) lo[j] = kInf, hi[j] = -kInf;
  auto take = [&](std::size_t j, double v) {
    const bool finite = std::abs(v) <= kMax;  // false for NaN and infinities
    const double forLo = finite ? v : kInf, forHi = finite ? v : -kInf;
    lo[j] = forLo < lo[j] ? forLo : lo[j];
    hi[j] = forHi > hi[j] ? forHi : hi[j];
  };
  std::size_t i = 0;
  for (; i + kLanes <= n; i += kLanes)
    for (std::size_t j = 0; j < kLanes; ++j) take(j, values[i + j]);
  for (; i < n; ++i) take(0, values[i]);
  return {std::min(std::min(lo[0], lo[1]), std::min(lo[2], lo[3])),
          std::max(std::max(hi[0], hi[1]), std::max(hi[2], hi[3]))};
}

std::pair<double, double> DenseGrid::range() const {
  // Blocks in parallel (min and max do not depend on the order), for the volume-sized scan before a build.
  using Range = std::pair<double, double>;
  const double inf = std::numeric_limits<double>::infinity();
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, values.size(), 1 << 16), Range(inf, -inf),
      [&](const tbb::blocked_range<std::size_t>& r, Range acc) {
        const Range block = finiteRange(values.data() + r.begin(), r.size());
        return Range(std::min(acc.first, block.first), std::max(acc.second, block.second));
      },
      [](const Range& a, const Range& b) {
        return Range(std::min(a.first, b.first), std::max(a.second, b.second));
      });
}

std::int64_t DenseGrid::nonFiniteCount() const {
  std::int64_t n = 0;
  for (double v : values) n += std::isfinite(v) ? 0 : 1;
  return n;
}

}  // namespace cip
