#include "cip/reference/point_hermite.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "cip/core/error.h"

namespace cip {

namespace {

/// Entry q of a line whose entries [first, last] are set, extended beyond them by odd reflection through the
/// end points (s[first - j] = 2 s[first] - s[first + j]), reflected again at the other end where the line is
/// shorter than the reach: linear data stay linear. A line of one entry is extended as a constant.
double reflected(const double* line, std::ptrdiff_t stride, int first, int last, int q) {
  if (q >= first && q <= last) return line[q * stride];
  if (first == last) return line[first * stride];
  const int border = q < first ? first : last, mirror = 2 * border - q;
  const double across = mirror >= first && mirror <= last ? line[mirror * stride]
                                                          : reflected(line, stride, first, last, mirror);
  return 2 * line[border * stride] - across;
}

/// The samples of the box of grid points origin + [0, size) per axis, index i + size[0] (j + size[1] k).
/// The box must hold a grid point. Beyond the grid the samples are reflected oddly through the border point
/// (`reflected`), one axis after the other: z first, x last, so a point outside along several axes is
/// reflected along x outermost. Every value depends only on the grid and its position, not on the box.
void reflectedBox(const DenseGrid& grid, const std::array<std::int64_t, 3>& origin,
                  const std::array<int, 3>& size, double* out) {
  const auto& dims = grid.geometry.dims;
  std::array<int, 3> first, last;  // box positions inside the grid, per axis
  for (int a = 0; a < 3; ++a) {
    first[a] = static_cast<int>(std::clamp<std::int64_t>(-origin[a], 0, size[a] - 1));
    last[a] = static_cast<int>(std::clamp<std::int64_t>(dims[a] - 1 - origin[a], 0, size[a] - 1));
  }
  const std::array<std::ptrdiff_t, 3> stride{1, size[0], static_cast<std::ptrdiff_t>(size[0]) * size[1]};
  auto at = [&](int i, int j, int k) -> double& { return out[i + stride[1] * j + stride[2] * k]; };
  for (int k = first[2]; k <= last[2]; ++k)
    for (int j = first[1]; j <= last[1]; ++j) {
      const double* from = &grid.values[static_cast<std::size_t>(
          grid.index(origin[0] + first[0], origin[1] + j, origin[2] + k))];
      std::copy(from, from + (last[0] - first[0] + 1), &at(first[0], j, k));
    }
  for (int a = 2; a >= 0; --a) {
    if (first[a] == 0 && last[a] == size[a] - 1) continue;
    // The lines along a whose earlier axes are inside the grid (later axes already extended).
    std::array<int, 3> lo{0, 0, 0}, hi{size[0] - 1, size[1] - 1, size[2] - 1};
    for (int b = 0; b < a; ++b) {
      lo[b] = first[b];
      hi[b] = last[b];
    }
    lo[a] = hi[a] = 0;
    for (int k = lo[2]; k <= hi[2]; ++k)
      for (int j = lo[1]; j <= hi[1]; ++j)
        for (int i = lo[0]; i <= hi[0]; ++i) {
          double* line = &at(i, j, k);
          for (int q = 0; q < first[a]; ++q)
            line[q * stride[a]] = reflected(line, stride[a], first[a], last[a], q);
          for (int q = last[a] + 1; q < size[a]; ++q)
            line[q * stride[a]] = reflected(line, stride[a], first[a], last[a], q);
        }
  }
}

/// Derivative at a sample from the differences to its neighbours (left = s - s_prev, right = s_next - s):
/// their mean, zero at a local extremum, at most three times the smaller difference (Hyman's filter).
inline double limitedSlope(double left, double right) {
  // Written with selects rather than branches: the conditions follow the data, so branches mispredict.
  const double centred = 0.5 * (left + right);
  const double magnitude = std::min(std::abs(centred), 3 * std::min(std::abs(left), std::abs(right)));
  const double limited = std::copysign(magnitude, centred);
  return left * right > 0 ? limited : 0.0;
}

/// Reconstruction::Monotone: a line of values (samples, or data whose earlier axes are all values) gets
/// limited slopes; a line of derivatives gets central differences (mixed derivatives).
struct MonotoneStencil {
  static constexpr int kReach = 1;
  static double value(const double* c, std::ptrdiff_t stride) {
    return limitedSlope(c[0] - c[-stride], c[stride] - c[0]);
  }
  static double mixed(const double* c, std::ptrdiff_t stride) { return 0.5 * (c[stride] - c[-stride]); }
};

/// Reconstruction::Central8: the 8th-order central difference for every line; kWeights[j - 1] weighs
/// s[i + j] - s[i - j].
struct Central8Stencil {
  static constexpr int kReach = 4;
  static constexpr double kWeights[kReach] = {4.0 / 5, -1.0 / 5, 4.0 / 105, -1.0 / 280};
  static double value(const double* c, std::ptrdiff_t stride) {
    double sum = 0;
    for (int j = 1; j <= kReach; ++j) sum += kWeights[j - 1] * (c[j * stride] - c[-j * stride]);
    return sum;
  }
  static double mixed(const double* c, std::ptrdiff_t stride) { return value(c, stride); }
};

/// hermiteInBox for one stencil: the samples of the box grown by the reach (reflected beyond the grid), an x
/// pass over every line of them, a y pass over the x pass's output and the samples, and the z pass at the
/// points asked for only.
template <class Stencil>
void boxPasses(const DenseGrid& grid, const std::array<std::int64_t, 3>& lo, const std::array<int, 3>& size,
               const std::array<int, 3>* at, std::size_t count, PointHermite* out) {
  constexpr int R = Stencil::kReach;
  const std::ptrdiff_t W = size[0], H = size[1];
  const std::ptrdiff_t X = W + 2 * R, Y = H + 2 * R, Z = size[2] + 2 * R;
  thread_local std::vector<double> samples, dx, dy, dxy;
  samples.resize(static_cast<std::size_t>(X * Y * Z));
  dx.resize(static_cast<std::size_t>(W * Y * Z));
  dy.resize(static_cast<std::size_t>(W * H * Z));
  dxy.resize(dy.size());
  reflectedBox(grid, {lo[0] - R, lo[1] - R, lo[2] - R},
               {static_cast<int>(X), static_cast<int>(Y), static_cast<int>(Z)}, samples.data());
  // x: derivatives at the box's x positions, on every line of the grown box.
  for (std::ptrdiff_t z = 0; z < Z; ++z)
    for (std::ptrdiff_t y = 0; y < Y; ++y) {
      const double* s = &samples[static_cast<std::size_t>(R + X * (y + Y * z))];
      double* o = &dx[static_cast<std::size_t>(W * (y + Y * z))];
      for (std::ptrdiff_t x = 0; x < W; ++x) o[x] = Stencil::value(s + x, 1);
    }
  // y: at the box's x and y positions, on every z of the grown box.
  for (std::ptrdiff_t z = 0; z < Z; ++z)
    for (std::ptrdiff_t y = 0; y < H; ++y) {
      const double* s = &samples[static_cast<std::size_t>(R + X * (y + R + Y * z))];
      const double* d = &dx[static_cast<std::size_t>(W * (y + R + Y * z))];
      double* oy = &dy[static_cast<std::size_t>(W * (y + H * z))];
      double* oxy = &dxy[static_cast<std::size_t>(W * (y + H * z))];
      for (std::ptrdiff_t x = 0; x < W; ++x) {
        oy[x] = Stencil::value(s + x, X);
        oxy[x] = Stencil::mixed(d + x, W);
      }
    }
  // z: at the points.
  for (std::size_t n = 0; n < count; ++n) {
    const std::ptrdiff_t px = at[n][0], py = at[n][1], pz = at[n][2] + R;
    const double* s = &samples[static_cast<std::size_t>(px + R + X * (py + R + Y * pz))];
    const double* a = &dx[static_cast<std::size_t>(px + W * (py + R + Y * pz))];
    const double* b = &dy[static_cast<std::size_t>(px + W * (py + H * pz))];
    const double* c = &dxy[static_cast<std::size_t>(px + W * (py + H * pz))];
    out[n] = {s[0],
              a[0],
              b[0],
              c[0],
              Stencil::value(s, X * Y),
              Stencil::mixed(a, W * Y),
              Stencil::mixed(b, W * H),
              Stencil::mixed(c, W * H)};
  }
}

}  // namespace

int referenceReach(Reconstruction kind) {
  return kind == Reconstruction::Monotone ? MonotoneStencil::kReach : Central8Stencil::kReach;
}

void hermiteInBox(const DenseGrid& grid, Reconstruction kind, const std::array<std::int64_t, 3>& lo,
                  const std::array<int, 3>& size, const std::array<int, 3>* at, std::size_t count,
                  PointHermite* out) {
  if (kind == Reconstruction::Central8) {
    boxPasses<Central8Stencil>(grid, lo, size, at, count, out);
  } else if (kind == Reconstruction::Monotone) {
    boxPasses<MonotoneStencil>(grid, lo, size, at, count, out);
  } else {
    throw Error("the reference needs a resolved reconstruction (monotone or central8), not auto or mask");
  }
}

void cellHermite(const std::array<const PointHermite*, 8>& corners, std::array<double, 64>& out) {
  for (int v = 0; v < 8; ++v) {
    const int cx = v & 1, cy = (v >> 1) & 1, cz = v >> 2;
    for (int d = 0; d < 8; ++d) {
      const int i = 2 * cx + (d & 1), j = 2 * cy + ((d >> 1) & 1), k = 2 * cz + (d >> 2);
      out[static_cast<std::size_t>(i + 4 * (j + 4 * k))] = (*corners[static_cast<std::size_t>(v)])[d];
    }
  }
}

}  // namespace cip
