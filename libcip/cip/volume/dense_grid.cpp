#include "cip/volume/dense_grid.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <unistd.h>

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

std::pair<double, double> DenseGrid::range() const {
  // Blocks in parallel (min and max do not depend on the order), for the volume-sized scan before a build.
  using Range = std::pair<double, double>;
  const double inf = std::numeric_limits<double>::infinity();
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, values.size(), 1 << 16), Range(inf, -inf),
      [&](const tbb::blocked_range<std::size_t>& r, Range acc) {
        for (std::size_t n = r.begin(); n != r.end(); ++n) {
          const double v = values[n];
          if (!std::isfinite(v)) continue;
          acc.first = std::min(acc.first, v);
          acc.second = std::max(acc.second, v);
        }
        return acc;
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
