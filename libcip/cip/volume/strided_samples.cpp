#include "cip/volume/strided_samples.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "cip/core/error.h"

namespace cip {

namespace {

template <typename T>
Float32Range rangeOf(const StridedSamples& s) {
  Float32Range r;
  r.min = std::numeric_limits<float>::infinity();
  r.max = -r.min;
  // The axis with the smallest stride innermost.
  std::array<int, 3> order{0, 1, 2};
  std::sort(order.begin(), order.end(),
            [&](int a, int b) { return std::abs(s.strides[a]) > std::abs(s.strides[b]); });
  std::array<std::int64_t, 3> p{};
  for (p[order[0]] = 0; p[order[0]] < s.shape[order[0]]; ++p[order[0]])
    for (p[order[1]] = 0; p[order[1]] < s.shape[order[1]]; ++p[order[1]]) {
      p[order[2]] = 0;
      const char* row = s.at(p[0], p[1], p[2]);
      const std::int64_t stride = s.strides[order[2]];
      for (std::int64_t i = 0; i < s.shape[order[2]]; ++i) {
        const float v = loadFloat32<T>(row + i * stride);
        if (!std::isfinite(v)) {
          r.nonFinite = true;
          continue;
        }
        r.min = std::min(r.min, v);
        r.max = std::max(r.max, v);
      }
    }
  if (r.min > r.max) r.min = r.max = 0;  // no finite sample
  return r;
}

}  // namespace

Float32Range float32Range(const StridedSamples& samples) {
  if (samples.shape[0] < 1 || samples.shape[1] < 1 || samples.shape[2] < 1)
    throw Error("the volume has no samples");
  return visitElementType(samples.type, [&](auto tag) { return rangeOf<decltype(tag)>(samples); });
}

}  // namespace cip
