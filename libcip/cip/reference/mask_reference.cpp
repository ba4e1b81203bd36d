#include "cip/reference/mask_reference.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "cip/reference/point_hermite.h"

namespace cip {

namespace {

/// A normalised Gaussian of standard deviation `sigma`, cut at ceil(3 sigma): weights[r + i] for offset i.
struct GaussianTaps {
  int radius;
  std::vector<double> weights;
  explicit GaussianTaps(double sigma) : radius(static_cast<int>(std::ceil(3 * sigma))) {
    weights.resize(static_cast<std::size_t>(2 * radius + 1));
    double sum = 0;
    for (int i = -radius; i <= radius; ++i)
      sum += weights[static_cast<std::size_t>(i + radius)] = std::exp(-0.5 * i * i / (sigma * sigma));
    for (double& w : weights) w /= sum;
  }
};

/// The two Gaussians of K and its weight a (mask_reference.h).
struct Kernel {
  GaussianTaps narrow{kMaskSigma}, wide{kMaskSigma * std::sqrt(2.0)};
  double a = std::sqrt(2.0) / (std::sqrt(2.0) - 1);
  int radius() const { return std::max(narrow.radius, wide.radius); }
};

const Kernel& kernel() {
  static const Kernel k;
  return k;
}

/// Grid points beyond a cell's corners that the reference reads (Central8), plus the corner itself.
int stencilReach() {
  return referenceReach(Reconstruction::Central8) + 1;
}

using Dims = std::array<std::int64_t, 3>;

/// One block's work space: the region (the block grown by the kernel's radius, clamped into the grid) and
/// the passes' buffers, reused from block to block by one thread.
struct BlockScratch {
  std::vector<std::int64_t> cls;  ///< the region's classes
  std::vector<double> in, x, xy;  ///< indicator, after the x pass, after x and y
  std::vector<double> sum[2];     ///< the block's result per Gaussian
};

/// G * in over the block: `in` covers the region (dims r), the block starts at `o` in it (dims b), and the
/// region reaches the kernel's radius beyond the block on every side (classBlock pads it).
void separableBlur(const GaussianTaps& g, const Dims& r, const Dims& o, const Dims& b, BlockScratch& s,
                   std::vector<double>& out) {
  const int R = g.radius;
  const double* w = g.weights.data() + R;
  // x: region rows, block columns. A row of one value (most, away from the surface) stays that value.
  s.x.resize(static_cast<std::size_t>(b[0] * r[1] * r[2]));
  for (std::int64_t k = 0; k < r[2]; ++k)
    for (std::int64_t j = 0; j < r[1]; ++j) {
      const double* row = &s.in[static_cast<std::size_t>(r[0] * (j + r[1] * k))];
      double* dst = &s.x[static_cast<std::size_t>(b[0] * (j + r[1] * k))];
      if (std::all_of(row, row + r[0], [&](double v) { return v == row[0]; })) {
        std::fill(dst, dst + b[0], row[0]);
        continue;
      }
      std::fill(dst, dst + b[0], 0.0);
      for (int t = -R; t <= R; ++t) {
        const double* src = row + o[0] + t;
        for (std::int64_t i = 0; i < b[0]; ++i) dst[i] += w[t] * src[i];
      }
    }
  // y: block columns and rows, region slices.
  s.xy.assign(static_cast<std::size_t>(b[0] * b[1] * r[2]), 0.0);
  for (std::int64_t k = 0; k < r[2]; ++k)
    for (std::int64_t j = 0; j < b[1]; ++j) {
      double* dst = &s.xy[static_cast<std::size_t>(b[0] * (j + b[1] * k))];
      for (int t = -R; t <= R; ++t) {
        const double* src = &s.x[static_cast<std::size_t>(b[0] * (o[1] + j + t + r[1] * k))];
        for (std::int64_t i = 0; i < b[0]; ++i) dst[i] += w[t] * src[i];
      }
    }
  // z: the block.
  out.assign(static_cast<std::size_t>(b[0] * b[1] * b[2]), 0.0);
  for (std::int64_t k = 0; k < b[2]; ++k)
    for (int t = -R; t <= R; ++t) {
      const double* src = &s.xy[static_cast<std::size_t>(b[0] * b[1] * (o[2] + k + t))];
      double* dst = &out[static_cast<std::size_t>(b[0] * b[1] * k)];
      for (std::int64_t n = 0; n < b[0] * b[1]; ++n) dst[n] += w[t] * src[n];
    }
}

/// K * in over the block into `out` (mask_reference.h).
void smoothBlock(const Dims& r, const Dims& o, const Dims& b, BlockScratch& s, std::vector<double>& out) {
  const Kernel& k = kernel();
  separableBlur(k.narrow, r, o, b, s, s.sum[0]);
  separableBlur(k.wide, r, o, b, s, s.sum[1]);
  out.resize(s.sum[0].size());
  for (std::size_t n = 0; n < out.size(); ++n) out[n] = k.a * s.sum[0][n] - (k.a - 1) * s.sum[1][n];
}

/// The field of class `target` in one block: `lo` its first point, `b` its size.
template <class ClassOf>
void classBlock(const DenseGrid& grid, const ClassOf& classOf, std::int64_t target, const Dims& lo,
                const Dims& b, BlockScratch& s, std::vector<double>& out) {
  const Dims& dims = grid.geometry.dims;
  const int R = kernel().radius();
  auto clampTo = [](std::int64_t v, std::int64_t n) { return std::min(std::max<std::int64_t>(v, 0), n - 1); };
  auto classAt = [&](std::int64_t i, std::int64_t j, std::int64_t k) {  // block-local, clamped into the grid
    return classOf(
        grid.at(clampTo(lo[0] + i, dims[0]), clampTo(lo[1] + j, dims[1]), clampTo(lo[2] + k, dims[2])));
  };
  const std::size_t blockPoints = static_cast<std::size_t>(b[0] * b[1] * b[2]);
  out.resize(blockPoints);
  // The classes within reach of the block's points decide whether its field is needed.
  const std::int64_t reach = stencilReach();
  bool mixed = false;
  const std::int64_t first = classAt(-reach, -reach, -reach);
  for (std::int64_t k = -reach; k < b[2] + reach && !mixed; ++k)
    for (std::int64_t j = -reach; j < b[1] + reach && !mixed; ++j)
      for (std::int64_t i = -reach; i < b[0] + reach; ++i)
        if (classAt(i, j, k) != first) {
          mixed = true;
          break;
        }
  if (!mixed) {
    std::fill(out.begin(), out.end(), first == target ? 1.0 : -1.0);
    return;
  }
  // The region: the block and R points around it, beyond the grid the nearest grid point's class.
  Dims r, o;
  for (int a = 0; a < 3; ++a) {
    r[a] = b[a] + 2 * R;
    o[a] = R;
  }
  s.cls.resize(static_cast<std::size_t>(r[0] * r[1] * r[2]));
  for (std::int64_t k = 0; k < r[2]; ++k)
    for (std::int64_t j = 0; j < r[1]; ++j) {
      const double* row = &grid.values[static_cast<std::size_t>(
          grid.index(0, clampTo(lo[1] - R + j, dims[1]), clampTo(lo[2] - R + k, dims[2])))];
      std::int64_t* dst = &s.cls[static_cast<std::size_t>(r[0] * (j + r[1] * k))];
      for (std::int64_t i = 0; i < r[0]; ++i) dst[i] = classOf(row[clampTo(lo[0] - R + i, dims[0])]);
    }
  auto regionClass = [&](std::int64_t i, std::int64_t j, std::int64_t k) {
    return s.cls[static_cast<std::size_t>(o[0] + i + r[0] * (o[1] + j + r[1] * (o[2] + k)))];
  };
  std::vector<std::int64_t> classes{s.cls[0]};  // in order of first appearance: few, so a linear search
  for (const std::int64_t c : s.cls)
    if (c != classes.back() && std::find(classes.begin(), classes.end(), c) == classes.end())
      classes.push_back(c);
  const bool hasTarget = std::find(classes.begin(), classes.end(), target) != classes.end();
  s.in.resize(s.cls.size());
  if (hasTarget && classes.size() == 2) {
    // f = K * (chi_T - chi_C): the other class's field is this one negated, number for number.
    for (std::size_t n = 0; n < s.cls.size(); ++n) s.in[n] = s.cls[n] == target ? 1.0 : -1.0;
    smoothBlock(r, o, b, s, out);
  } else {
    std::vector<double> g, own(blockPoints, 0.0), others(blockPoints, -HUGE_VAL);
    for (const std::int64_t c : classes) {
      for (std::size_t n = 0; n < s.cls.size(); ++n) s.in[n] = s.cls[n] == c ? 1.0 : 0.0;
      smoothBlock(r, o, b, s, g);
      if (c == target)
        own = g;
      else
        for (std::size_t n = 0; n < blockPoints; ++n) others[n] = std::max(others[n], g[n]);
    }
    for (std::size_t n = 0; n < blockPoints; ++n) out[n] = own[n] - others[n];
  }
  // Every point keeps its class's side.
  for (std::int64_t k = 0; k < b[2]; ++k)
    for (std::int64_t j = 0; j < b[1]; ++j)
      for (std::int64_t i = 0; i < b[0]; ++i) {
        double& v = out[static_cast<std::size_t>(i + b[0] * (j + b[1] * k))];
        v = regionClass(i, j, k) == target ? std::max(v, kMaskMargin) : std::min(v, -kMaskMargin);
      }
}

/// The field of class `target` over the grid, block by block in parallel, as samples offset + f.
template <class ClassOf>
DenseGrid classField(const DenseGrid& grid, const ClassOf& classOf, std::int64_t target, double offset,
                     std::int64_t firstSliceZ = 0) {
  DenseGrid out;
  out.geometry = grid.geometry;
  out.description = grid.description;
  out.allocate(grid.geometry.dims);
  const Dims& dims = grid.geometry.dims;
  Dims blocks;
  // Along z the blocks start where the slices of the larger grid do (firstSliceZ): the first may be shorter.
  const std::int64_t phase = firstSliceZ % kMaskBlock;
  for (int a = 0; a < 3; ++a) blocks[a] = (dims[a] + (a == 2 ? phase : 0) + kMaskBlock - 1) / kMaskBlock;
  const std::int64_t count = blocks[0] * blocks[1] * blocks[2];
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(0, count, 1), [&](const tbb::blocked_range<std::int64_t>& range) {
        BlockScratch scratch;
        std::vector<double> field;
        for (std::int64_t n = range.begin(); n != range.end(); ++n) {
          const Dims at{n % blocks[0], (n / blocks[0]) % blocks[1], n / (blocks[0] * blocks[1])};
          Dims lo, b;
          for (int a = 0; a < 3; ++a) {
            const std::int64_t shift = a == 2 ? phase : 0;
            lo[a] = std::max<std::int64_t>(0, at[a] * kMaskBlock - shift);
            b[a] = std::min<std::int64_t>((at[a] + 1) * kMaskBlock - shift, dims[a]) - lo[a];
          }
          classBlock(grid, classOf, target, lo, b, scratch, field);
          for (std::int64_t k = 0; k < b[2]; ++k)
            for (std::int64_t j = 0; j < b[1]; ++j)
              for (std::int64_t i = 0; i < b[0]; ++i)
                out.at(lo[0] + i, lo[1] + j, lo[2] + k) =
                    offset + field[static_cast<std::size_t>(i + b[0] * (j + b[1] * k))];
        }
      });
  return out;
}

/// What detectTwoValued gathers over a range of slices.
struct TwoValuedScan {
  bool conflict = false, haveBelow = false, haveAbove = false;
  double below = 0, above = 0;
  std::int64_t points = 0;

  void add(double v, double iso) {
    if (!std::isfinite(v)) {
      conflict = true;
    } else if (v > iso) {
      if (haveAbove && v != above) conflict = true;
      haveAbove = true;
      above = v;
    } else {
      if (haveBelow && v != below) conflict = true;
      haveBelow = true;
      below = v;
    }
    ++points;
  }
  void join(const TwoValuedScan& o) {
    conflict = conflict || o.conflict || (haveBelow && o.haveBelow && below != o.below) ||
               (haveAbove && o.haveAbove && above != o.above);
    if (o.haveBelow) below = o.below, haveBelow = true;
    if (o.haveAbove) above = o.above, haveAbove = true;
    points += o.points;
  }
};

}  // namespace

int maskKernelRadius() {
  return kernel().radius();
}

int maskReach() {
  return kernel().radius() + referenceReach(Reconstruction::Central8);
}

TwoValuedSamples detectTwoValued(const DenseGrid& grid, double isovalue) {
  const Dims& d = grid.geometry.dims;
  const TwoValuedScan scan = tbb::parallel_reduce(
      tbb::blocked_range<std::int64_t>(0, d[2]), TwoValuedScan(),
      [&](const tbb::blocked_range<std::int64_t>& r, TwoValuedScan s) {
        for (std::int64_t k = r.begin(); k != r.end() && !s.conflict; ++k)
          for (std::int64_t j = 0; j < d[1]; ++j) {
            const double* p = &grid.values[static_cast<std::size_t>(grid.index(0, j, k))];
            for (std::int64_t i = 0; i < d[0]; ++i) {
              const bool side = p[i] > isovalue;
              const std::int64_t step[3] = {1, d[0], d[0] * d[1]};
              const bool inside[3] = {i + 1 < d[0], j + 1 < d[1], k + 1 < d[2]};
              for (int a = 0; a < 3; ++a)
                if (inside[a] && (p[i + step[a]] > isovalue) != side) {
                  s.add(p[i], isovalue);
                  s.add(p[i + step[a]], isovalue);
                }
            }
          }
        return s;
      },
      [](TwoValuedScan x, const TwoValuedScan& y) {
        x.join(y);
        return x;
      });
  TwoValuedSamples result;
  result.points = scan.points;
  result.twoValued = !scan.conflict && scan.haveBelow && scan.haveAbove;
  result.below = scan.below;
  result.above = scan.above;
  return result;
}

DenseGrid smoothMask(const DenseGrid& grid, double isovalue) {
  return classField(
      grid, [isovalue](double v) { return static_cast<std::int64_t>(v > isovalue); }, 1, isovalue);
}

DenseGrid smoothClass(const DenseGrid& grid, const std::function<std::int64_t(double)>& classOf,
                      std::int64_t target, std::int64_t firstSliceZ) {
  return classField(grid, classOf, target, 0.0, firstSliceZ);
}

}  // namespace cip
