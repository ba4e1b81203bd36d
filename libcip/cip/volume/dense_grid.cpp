#include "cip/volume/dense_grid.h"

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
  reserveHuge(values, static_cast<std::size_t>(n));
  values.assign(static_cast<std::size_t>(n), 0.0);
}

std::pair<double, double> DenseGrid::range() const {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (double v : values) {
    if (!std::isfinite(v)) continue;
    lo = std::min(lo, v);
    hi = std::max(hi, v);
  }
  return {lo, hi};
}

std::int64_t DenseGrid::nonFiniteCount() const {
  std::int64_t n = 0;
  for (double v : values) n += std::isfinite(v) ? 0 : 1;
  return n;
}

}  // namespace cip
