#include "cip/reference/mask_reference.h"

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <vector>

#include "cip/core/vector_clones.h"
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

/// The two Gaussians of K_s and its weight a (mask_reference.h), and the factor that turns K_s * (chi_T -
/// chi_C) into a signed distance near a plane: s / (sqrt(2/pi) (a - (a - 1)/sqrt2)), its slope's inverse.
struct Kernel {
  GaussianTaps narrow, wide;
  double a = std::sqrt(2.0) / (std::sqrt(2.0) - 1);
  double toVoxels;
  explicit Kernel(double s)
      : narrow(s),
        wide(s * std::sqrt(2.0)),
        toVoxels(s / (std::sqrt(2.0 / 3.14159265358979323846) * (a - (a - 1) / std::sqrt(2.0)))) {}
};

constexpr int kScales = 3;

/// The kernels of kMaskScales, largest first, and the Gaussian of the scale mean.
struct Kernels {
  Kernel scale[kScales] = {Kernel(kMaskScales[0]), Kernel(kMaskScales[1]), Kernel(kMaskScales[2])};
  GaussianTaps weight{kMaskWeightSigma};
  int radius() const { return scale[0].wide.radius; }
};

const Kernels& kernels() {
  static const Kernels k;
  return k;
}

/// Grid points beyond a cell's corners that the reference reads (Central8), plus the corner itself.
int stencilReach() {
  return referenceReach(Reconstruction::Central8) + 1;
}

using Dims = std::array<std::int64_t, 3>;

/// Index v along an axis of n points, clamped into the grid: beyond it, the nearest grid point.
std::int64_t clampIntoGrid(std::int64_t v, std::int64_t n) {
  return std::min(std::max<std::int64_t>(v, 0), n - 1);
}

/// One block's work space: the region (the block grown by the kernel's radius, clamped into the grid) and
/// the passes' buffers, reused from block to block by one thread (the second pass's buffers are larger than
/// the allocator keeps for reuse: allocated per block, each would be faulted in again).
struct BlockScratch {
  std::vector<std::int64_t> cls;                      ///< the region's classes
  std::vector<double> in, x, xy;                      ///< indicator, after the x pass, after x and y
  std::vector<std::uint8_t> zeroX, zeroXY;            ///< rows of x and xy known to hold only zeros
  std::vector<double> sum[2];                         ///< the block's result per Gaussian
  std::vector<double> gap[2], next, mean[2], weight;  ///< the second pass's (blendBlock)
};

/// dst[i] = w[-R] src[i] + ... + w[R] src[i + 2R stride] for i < n, `src` at tap -R: added tap by tap in
/// increasing order, the first product as it is (fromZero false) or added to +0 (true), as a pass that adds
/// one tap at a time over the row gives them; columns a block at a time, so that the sums stay in registers
/// instead of being stored and loaded again for every tap.
template <bool fromZero>
CIP_VECTOR_CLONES void tapRow(const double* w, int R, const double* src, std::ptrdiff_t stride, double* dst,
                              std::int64_t n) {
  constexpr std::int64_t kColumns = 8;
  std::int64_t i0 = 0;
  for (; i0 + kColumns <= n; i0 += kColumns) {
    double acc[kColumns];
    for (std::int64_t l = 0; l < kColumns; ++l)
      acc[l] = fromZero ? 0.0 + w[-R] * src[i0 + l] : w[-R] * src[i0 + l];
    for (int t = -R + 1; t <= R; ++t) {
      const double wt = w[t];
      const double* row = src + (t + R) * stride + i0;
      for (std::int64_t l = 0; l < kColumns; ++l) acc[l] += wt * row[l];
    }
    for (std::int64_t l = 0; l < kColumns; ++l) dst[i0 + l] = acc[l];
  }
  for (std::int64_t i = i0; i < n; ++i) {
    double acc = fromZero ? 0.0 + w[-R] * src[i] : w[-R] * src[i];
    for (int t = -R + 1; t <= R; ++t) acc += w[t] * src[(t + R) * stride + i];
    dst[i] = acc;
  }
}

/// G * in over the block: `in` covers the region (dims r), the block starts at `o` in it (dims b), and the
/// region reaches at least the kernel's radius beyond the block on every side (classBlock pads it by the
/// largest kernel's radius; only the rows and slices within this kernel's radius are read). `s` lends the
/// passes' buffers.
void separableBlur(const GaussianTaps& g, const std::vector<double>& in, const Dims& r, const Dims& o,
                   const Dims& b, BlockScratch& s, std::vector<double>& out) {
  const int R = g.radius;
  const double* w = g.weights.data() + R;
  const std::int64_t j0 = o[1] - R, j1 = o[1] + b[1] + R, k0 = o[2] - R, k1 = o[2] + b[2] + R;
  // x: region rows, block columns. A row of one value (most, away from the surface) stays that value.
  s.x.resize(static_cast<std::size_t>(b[0] * r[1] * r[2]));
  s.zeroX.assign(static_cast<std::size_t>(r[1] * r[2]), 0);
  for (std::int64_t k = k0; k < k1; ++k)
    for (std::int64_t j = j0; j < j1; ++j) {
      const double* row = &in[static_cast<std::size_t>(r[0] * (j + r[1] * k))];
      double* dst = &s.x[static_cast<std::size_t>(b[0] * (j + r[1] * k))];
      const double* first = row + o[0] - R;
      if (std::all_of(first, row + o[0] + b[0] + R, [&](double v) { return v == *first; })) {
        std::fill(dst, dst + b[0], *first);
        s.zeroX[static_cast<std::size_t>(j + r[1] * k)] = *first == 0;
        continue;
      }
      tapRow<false>(w, R, first, 1, dst, b[0]);
    }
  // The y and z passes start every sum at +0 and add w[t] src with w[t] > 0: where every source is a zero
  // (of either sign) every partial sum is +0, which is what they write without the sums. Many rows and
  // slices of a block's sparse inputs (a class's indicator far from it, the points next to a surface) are.
  auto allZero = [](const std::uint8_t* flag, std::int64_t stride, int taps) {
    for (int t = 0; t < taps; ++t)
      if (!flag[t * stride]) return false;
    return true;
  };
  // y: block columns and rows, region slices.
  s.xy.resize(static_cast<std::size_t>(b[0] * b[1] * r[2]));
  s.zeroXY.assign(static_cast<std::size_t>(b[1] * r[2]), 0);
  for (std::int64_t k = k0; k < k1; ++k)
    for (std::int64_t j = 0; j < b[1]; ++j) {
      double* dst = &s.xy[static_cast<std::size_t>(b[0] * (j + b[1] * k))];
      if (allZero(&s.zeroX[static_cast<std::size_t>(o[1] + j - R + r[1] * k)], 1, 2 * R + 1)) {
        std::fill(dst, dst + b[0], 0.0);
        s.zeroXY[static_cast<std::size_t>(j + b[1] * k)] = 1;
        continue;
      }
      tapRow<true>(w, R, &s.x[static_cast<std::size_t>(b[0] * (o[1] + j - R + r[1] * k))], b[0], dst, b[0]);
    }
  // z: the block, row by row.
  out.resize(static_cast<std::size_t>(b[0] * b[1] * b[2]));
  for (std::int64_t k = 0; k < b[2]; ++k)
    for (std::int64_t j = 0; j < b[1]; ++j) {
      double* dst = &out[static_cast<std::size_t>(b[0] * (j + b[1] * k))];
      if (allZero(&s.zeroXY[static_cast<std::size_t>(j + b[1] * (o[2] + k - R))], b[1], 2 * R + 1)) {
        std::fill(dst, dst + b[0], 0.0);
        continue;
      }
      tapRow<true>(w, R, &s.xy[static_cast<std::size_t>(b[0] * (j + b[1] * (o[2] + k - R)))], b[0] * b[1],
                   dst, b[0]);
    }
}

/// K_s * s.in over the block into `out`, in voxels (Kernel::toVoxels).
void smoothBlock(const Kernel& k, const Dims& r, const Dims& o, const Dims& b, BlockScratch& s,
                 std::vector<double>& out) {
  separableBlur(k.narrow, s.in, r, o, b, s, s.sum[0]);
  separableBlur(k.wide, s.in, r, o, b, s, s.sum[1]);
  out.resize(s.sum[0].size());
  for (std::size_t n = 0; n < out.size(); ++n)
    out[n] = (k.a * s.sum[0][n] - (k.a - 1) * s.sum[1][n]) * k.toVoxels;
}

/// What the first pass keeps of a block whose field is needed: the target's field at each scale before
/// clamping (in voxels), the points next to a surface and how far the scales disagree there.
struct BandBlock {
  Dims lo{}, b{};
  std::vector<double> field[kScales];  ///< the target's field at each scale
  std::vector<double> gap[2];          ///< at the points next to a surface: |F_s - F_s'| of scales 0-1, 1-2
  std::vector<std::uint8_t> next;      ///< the points next to a surface between two classes
};

/// The points of a block next to a surface between two classes (a neighbour along an axis, in the grid, of
/// another class), and for each the classes whose surface it lies next to: its own and its neighbours'.
struct SurfacePoints {
  std::vector<std::size_t> points;                   ///< block-local indices
  std::vector<std::array<std::int64_t, 7>> classes;  ///< per point: their count, then the classes
};

/// SurfacePoints of the block at `lo` (size b) whose region (dims r, the block at o in it) has classes `cls`;
/// `next` receives 1 at those points.
SurfacePoints surfacePoints(const Dims& dims, const Dims& lo, const Dims& b, const Dims& r, const Dims& o,
                            const std::vector<std::int64_t>& cls, std::vector<std::uint8_t>& next) {
  auto regionAt = [&](std::int64_t i, std::int64_t j, std::int64_t k) {  // block-local
    return static_cast<std::size_t>(o[0] + i + r[0] * (o[1] + j + r[1] * (o[2] + k)));
  };
  SurfacePoints out;
  next.assign(static_cast<std::size_t>(b[0] * b[1] * b[2]), 0);
  for (std::int64_t k = 0; k < b[2]; ++k)
    for (std::int64_t j = 0; j < b[1]; ++j)
      for (std::int64_t i = 0; i < b[0]; ++i) {
        const std::int64_t here = cls[regionAt(i, j, k)];
        const std::int64_t p[3] = {lo[0] + i, lo[1] + j, lo[2] + k};
        std::array<std::int64_t, 7> near{};
        for (int a = 0; a < 3; ++a)
          for (int step : {-1, 1}) {
            if (p[a] + step < 0 || p[a] + step >= dims[a]) continue;
            std::int64_t q[3] = {i, j, k};
            q[a] += step;
            const std::int64_t c = cls[regionAt(q[0], q[1], q[2])];
            if (c == here) continue;
            if (near[0] == 0) near[++near[0]] = here;
            if (std::find(near.begin() + 1, near.begin() + 1 + near[0], c) == near.begin() + 1 + near[0])
              near[static_cast<std::size_t>(++near[0])] = c;
          }
        if (near[0] == 0) continue;
        const std::size_t n = static_cast<std::size_t>(i + b[0] * (j + b[1] * k));
        next[n] = 1;
        out.points.push_back(n);
        out.classes.push_back(near);
      }
  return out;
}

// Both of the following fill each scale's field of the target and, at the points next to a surface, the
// largest disagreement of the scales among the fields of the classes meeting there: the same for every
// target, so touching labels blend their scales alike and keep f_C = -f_T. `s.cls` holds the region's
// classes.

/// A region of two classes: f = K * (chi_A - chi_B), A the first class met; the other class's field is this
/// one negated, number for number.
void twoClassFields(std::int64_t target, const std::vector<std::int64_t>& classes, const Dims& r,
                    const Dims& o, const Dims& b, BlockScratch& s, const SurfacePoints& surface,
                    BandBlock& out) {
  std::vector<double> classField[kScales];
  for (std::size_t n = 0; n < s.cls.size(); ++n) s.in[n] = s.cls[n] == classes[0] ? 1.0 : -1.0;
  for (int scale = 0; scale < kScales; ++scale) {
    smoothBlock(kernels().scale[scale], r, o, b, s, classField[scale]);
    std::vector<double>& f = out.field[scale];
    f = classField[scale];
    if (target == classes[1]) {
      for (double& v : f) v = -v;
    } else if (target != classes[0]) {  // K * (0 - max(chi_A, chi_B)), chi_A + chi_B = 1
      const double toVoxels = kernels().scale[scale].toVoxels;
      for (double& v : f) v = -(toVoxels + std::abs(v)) / 2;
    }
  }
  for (const std::size_t n : surface.points)
    for (int pair = 0; pair < 2; ++pair)
      out.gap[pair][n] = std::abs(classField[pair][n] - classField[pair + 1][n]);
}

/// A region of three or more classes: each class's smoothed indicator at each scale; f_c = K * chi_c - max
/// over the others.
void manyClassFields(std::int64_t target, const std::vector<std::int64_t>& classes, const Dims& r,
                     const Dims& o, const Dims& b, BlockScratch& s, const SurfacePoints& surface,
                     BandBlock& out) {
  const std::size_t C = classes.size(), blockPoints = static_cast<std::size_t>(b[0] * b[1] * b[2]);
  std::vector<std::vector<double>> g(C * kScales);
  auto smoothed = [&](std::size_t c, int scale) -> const std::vector<double>& {
    return g[c * kScales + static_cast<std::size_t>(scale)];
  };
  for (std::size_t c = 0; c < C; ++c) {
    for (std::size_t n = 0; n < s.cls.size(); ++n) s.in[n] = s.cls[n] == classes[c] ? 1.0 : 0.0;
    for (int scale = 0; scale < kScales; ++scale)
      smoothBlock(kernels().scale[scale], r, o, b, s, g[c * kScales + static_cast<std::size_t>(scale)]);
  }
  auto othersMax = [&](std::size_t c, int scale, std::size_t n) {  // c = C: over every class
    double others = -HUGE_VAL;
    for (std::size_t d = 0; d < C; ++d)
      if (d != c) others = std::max(others, smoothed(d, scale)[n]);
    return others;
  };
  auto fieldOf = [&](std::size_t c, int scale, std::size_t n) {
    return smoothed(c, scale)[n] - othersMax(c, scale, n);
  };
  const auto t =
      static_cast<std::size_t>(std::find(classes.begin(), classes.end(), target) - classes.begin());
  for (int scale = 0; scale < kScales; ++scale) {
    std::vector<double>& f = out.field[scale];
    f.resize(blockPoints);
    for (std::size_t n = 0; n < blockPoints; ++n)
      f[n] = t < C ? fieldOf(t, scale, n) : -othersMax(C, scale, n);
  }
  for (std::size_t m = 0; m < surface.points.size(); ++m) {
    const std::size_t n = surface.points[m];
    const auto& near = surface.classes[m];
    for (std::int64_t k = 1; k <= near[0]; ++k) {
      const auto c = static_cast<std::size_t>(
          std::find(classes.begin(), classes.end(), near[static_cast<std::size_t>(k)]) - classes.begin());
      for (int pair = 0; pair < 2; ++pair)
        out.gap[pair][n] =
            std::max(out.gap[pair][n], std::abs(fieldOf(c, pair, n) - fieldOf(c, pair + 1, n)));
    }
  }
}

/// The first pass over one block: `lo` its first point, `b` its size. Returns false (and fills nothing) when
/// no two classes lie within reach of its points: its field is then +1 or -1 (`constant`).
template <class ClassOf>
bool classBlock(const DenseGrid& grid, const ClassOf& classOf, std::int64_t target, BlockScratch& s,
                BandBlock& out, double& constant) {
  const Dims& dims = grid.geometry.dims;
  const Dims& lo = out.lo;
  const Dims& b = out.b;
  const int R = kernels().radius();
  auto classAt = [&](std::int64_t i, std::int64_t j, std::int64_t k) {  // block-local, clamped into the grid
    return classOf(grid.at(clampIntoGrid(lo[0] + i, dims[0]), clampIntoGrid(lo[1] + j, dims[1]),
                           clampIntoGrid(lo[2] + k, dims[2])));
  };
  const std::size_t blockPoints = static_cast<std::size_t>(b[0] * b[1] * b[2]);
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
    constant = first == target ? 1.0 : -1.0;
    return false;
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
          grid.index(0, clampIntoGrid(lo[1] - R + j, dims[1]), clampIntoGrid(lo[2] - R + k, dims[2])))];
      std::int64_t* dst = &s.cls[static_cast<std::size_t>(r[0] * (j + r[1] * k))];
      for (std::int64_t i = 0; i < r[0]; ++i) dst[i] = classOf(row[clampIntoGrid(lo[0] - R + i, dims[0])]);
    }
  std::vector<std::int64_t> classes{s.cls[0]};  // in order of first appearance: few, so a linear search
  for (const std::int64_t c : s.cls)
    if (c != classes.back() && std::find(classes.begin(), classes.end(), c) == classes.end())
      classes.push_back(c);
  const SurfacePoints surface = surfacePoints(dims, lo, b, r, o, s.cls, out.next);
  for (int pair = 0; pair < 2; ++pair) out.gap[pair].assign(blockPoints, 0.0);
  s.in.resize(s.cls.size());
  if (classes.size() == 2)
    twoClassFields(target, classes, r, o, b, s, surface, out);
  else
    manyClassFields(target, classes, r, o, b, s, surface, out);
  return true;
}

/// The blocks of a grid (kMaskBlock points a side; along z starting where the larger grid's do) and the
/// first pass's result for each.
struct BlockGrid {
  Dims dims{}, blocks{};
  std::int64_t phase = 0;
  std::vector<BandBlock> band;   ///< per block; empty fields where the block is constant
  std::vector<double> constant;  ///< per block: +-1 where constant

  std::int64_t count() const { return blocks[0] * blocks[1] * blocks[2]; }
  /// The block holding point p, and p's index in it.
  std::pair<std::int64_t, std::size_t> at(std::int64_t i, std::int64_t j, std::int64_t k) const {
    const std::int64_t bz = (k + phase) / kMaskBlock;
    const std::int64_t n = i / kMaskBlock + blocks[0] * (j / kMaskBlock + blocks[1] * bz);
    const BandBlock& blk = band[static_cast<std::size_t>(n)];
    return {
        n, static_cast<std::size_t>(i - blk.lo[0] + blk.b[0] * (j - blk.lo[1] + blk.b[1] * (k - blk.lo[2])))};
  }
};

/// The second pass over one band block: the mean over the points next to the surface, within
/// maskWeightRadius(), of how far the scales disagree, and from it the blend of the scales; clamped so that
/// every point keeps its class's side. `out` receives the field in the units of the largest kernel.
template <class ClassOf>
void blendBlock(const DenseGrid& grid, const ClassOf& classOf, std::int64_t target, const BlockGrid& g,
                const BandBlock& blk, BlockScratch& s, std::vector<double>& out) {
  const Dims& dims = grid.geometry.dims;
  const GaussianTaps& taps = kernels().weight;
  const int W = taps.radius;
  Dims r, o;
  for (int a = 0; a < 3; ++a) {
    r[a] = blk.b[a] + 2 * W;
    o[a] = W;
  }
  const std::size_t regionPoints = static_cast<std::size_t>(r[0] * r[1] * r[2]);
  // The region's disagreements of the two pairs of scales at the points next to the surface, and those
  // points.
  std::vector<double>(&gap)[2] = s.gap;
  std::vector<double>& next = s.next;
  next.assign(regionPoints, 0.0);
  gap[0].assign(regionPoints, 0.0);
  gap[1].assign(regionPoints, 0.0);
  for (std::int64_t k = 0; k < r[2]; ++k)
    for (std::int64_t j = 0; j < r[1]; ++j)
      for (std::int64_t i = 0; i < r[0]; ++i) {
        const auto [n, at] =
            g.at(clampIntoGrid(blk.lo[0] - W + i, dims[0]), clampIntoGrid(blk.lo[1] - W + j, dims[1]),
                 clampIntoGrid(blk.lo[2] - W + k, dims[2]));
        const BandBlock& other = g.band[static_cast<std::size_t>(n)];
        if (other.next.empty() || !other.next[at]) continue;
        const std::size_t m = static_cast<std::size_t>(i + r[0] * (j + r[1] * k));
        next[m] = 1.0;
        gap[0][m] = other.gap[0][at];
        gap[1][m] = other.gap[1][at];
      }
  std::vector<double>(&mean)[2] = s.mean;
  std::vector<double>& weight = s.weight;
  separableBlur(taps, next, r, o, blk.b, s, weight);
  for (int pair = 0; pair < 2; ++pair) separableBlur(taps, gap[pair], r, o, blk.b, s, mean[pair]);
  const Kernel& largest = kernels().scale[0];
  auto ramp = [](double x, const double(&range)[2]) {
    return std::min(1.0, std::max(0.0, (x - range[0]) / (range[1] - range[0])));
  };
  out.resize(blk.next.size());
  for (std::int64_t k = 0; k < blk.b[2]; ++k)
    for (std::int64_t j = 0; j < blk.b[1]; ++j)
      for (std::int64_t i = 0; i < blk.b[0]; ++i) {
        const std::size_t n = static_cast<std::size_t>(i + blk.b[0] * (j + blk.b[1] * k));
        const double norm = std::max(weight[n], 1e-3);
        const double w1 = ramp(mean[0][n] / norm, kMaskSwitch[0]),
                     w2 = ramp(mean[1][n] / norm, kMaskSwitch[1]);
        const double f =
            (1 - w1) * blk.field[0][n] + w1 * ((1 - w2) * blk.field[1][n] + w2 * blk.field[2][n]);
        const double v = f / largest.toVoxels;
        const bool own = classOf(grid.at(blk.lo[0] + i, blk.lo[1] + j, blk.lo[2] + k)) == target;
        out[n] = own ? std::max(v, kMaskMargin) : std::min(v, -kMaskMargin);
      }
}

/// The field of class `target` over the grid, as samples offset + f: the first pass computes each band
/// block's scales, the second blends them (both block by block in parallel).
template <class ClassOf>
DenseGrid classField(const DenseGrid& grid, const ClassOf& classOf, std::int64_t target, double offset,
                     std::int64_t firstSliceZ = 0) {
  DenseGrid out;
  out.geometry = grid.geometry;
  out.description = grid.description;
  out.allocate(grid.geometry.dims);
  BlockGrid g;
  g.dims = grid.geometry.dims;
  // Along z the blocks start where the slices of the larger grid do (firstSliceZ): the first may be shorter.
  g.phase = firstSliceZ % kMaskBlock;
  for (int a = 0; a < 3; ++a)
    g.blocks[a] = (g.dims[a] + (a == 2 ? g.phase : 0) + kMaskBlock - 1) / kMaskBlock;
  const std::int64_t count = g.count();
  g.band.resize(static_cast<std::size_t>(count));
  g.constant.assign(static_cast<std::size_t>(count), 0.0);
  for (std::int64_t n = 0; n < count; ++n) {
    const Dims at{n % g.blocks[0], (n / g.blocks[0]) % g.blocks[1], n / (g.blocks[0] * g.blocks[1])};
    BandBlock& blk = g.band[static_cast<std::size_t>(n)];
    for (int a = 0; a < 3; ++a) {
      const std::int64_t shift = a == 2 ? g.phase : 0;
      blk.lo[a] = std::max<std::int64_t>(0, at[a] * kMaskBlock - shift);
      blk.b[a] = std::min<std::int64_t>((at[a] + 1) * kMaskBlock - shift, g.dims[a]) - blk.lo[a];
    }
  }
  tbb::enumerable_thread_specific<BlockScratch> scratches;  // one per thread, reused over both passes
  tbb::parallel_for(tbb::blocked_range<std::int64_t>(0, count, 1),
                    [&](const tbb::blocked_range<std::int64_t>& range) {
                      BlockScratch& scratch = scratches.local();
                      for (std::int64_t n = range.begin(); n != range.end(); ++n)
                        classBlock(grid, classOf, target, scratch, g.band[static_cast<std::size_t>(n)],
                                   g.constant[static_cast<std::size_t>(n)]);
                    });
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(0, count, 1), [&](const tbb::blocked_range<std::int64_t>& range) {
        BlockScratch& scratch = scratches.local();
        std::vector<double> field;
        for (std::int64_t n = range.begin(); n != range.end(); ++n) {
          const BandBlock& blk = g.band[static_cast<std::size_t>(n)];
          const bool band = !blk.next.empty();
          if (band) blendBlock(grid, classOf, target, g, blk, scratch, field);
          for (std::int64_t k = 0; k < blk.b[2]; ++k)
            for (std::int64_t j = 0; j < blk.b[1]; ++j)
              for (std::int64_t i = 0; i < blk.b[0]; ++i)
                out.at(blk.lo[0] + i, blk.lo[1] + j, blk.lo[2] + k) =
                    offset + (band ? field[static_cast<std::size_t>(i + blk.b[0] * (j + blk.b[1] * k))]
                                   : g.constant[static_cast<std::size_t>(n)]);
        }
      });
  return out;
}

/// What detectTwoValued gathers over a range of slices.
struct TwoValuedScan {
  bool conflict = false, haveBelow = false, haveAbove = false, integral = true;
  bool counting = true;  ///< this scan's edges may be counted (not joined)
  double below = 0, above = 0;
  std::int64_t points = 0, crossedEdges = 0;

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
  /// The two samples of a crossed grid edge; `counted`: the edge is counted and its samples checked for
  /// integers.
  void addEdge(double a, double b, double iso, bool counted) {
    add(a, iso);
    add(b, iso);
    if (!counted) return;
    ++crossedEdges;
    const bool integers = std::isfinite(a) && std::isfinite(b) && a == std::trunc(a) && b == std::trunc(b);
    integral = integral && integers;
  }
  /// Neither verdict can change: the samples are not two-valued, and those of the counted edges not all
  /// integers.
  bool settlesAll() const { return conflict && !integral; }
  /// The rest of this scan's samples can change neither verdict.
  bool settled() const { return conflict && (!integral || !counting); }
  void join(const TwoValuedScan& o) {
    conflict = conflict || o.conflict || (haveBelow && o.haveBelow && below != o.below) ||
               (haveAbove && o.haveAbove && above != o.above);
    integral = integral && o.integral;
    if (o.haveBelow) below = o.below, haveBelow = true;
    if (o.haveAbove) above = o.above, haveAbove = true;
    points += o.points;
    crossedEdges += o.crossedEdges;
  }
};

}  // namespace

int maskKernelRadius() {
  return kernels().radius();
}

int maskWeightRadius() {
  return kernels().weight.radius;
}

int maskReach() {
  return kernels().radius() + kernels().weight.radius + referenceReach(Reconstruction::Central8);
}

TwoValuedSamples detectTwoValued(const DenseGrid& grid, double isovalue, const CountedEdges& count) {
  const Dims& d = grid.geometry.dims;
  std::array<std::int64_t, 3> end = count.end;
  for (std::size_t a = 0; a < 3; ++a)
    if (end[a] < 0) end[a] = d[a];
  const bool integerIsovalue = isovalue == std::trunc(isovalue);
  auto countsSlice = [&](std::int64_t k) {
    return integerIsovalue && k >= count.begin[2] && k < end[2] &&
           (count.firstSliceZ + k) % CountedEdges::kSliceStride == 0;
  };
  auto counted = [&](std::int64_t i, std::int64_t j) {
    return i >= count.begin[0] && i < end[0] && j >= count.begin[1] && j < end[1];
  };
  // Each slice is scanned on its own, until its samples can change neither verdict (not two-valued, and not
  // integers or not counted), so that the verdicts do not depend on how the slices are split between
  // threads; once one slice has settled both for the whole grid, the others stop too (the counts then stay
  // partial; the verdicts do not change).
  std::atomic<bool> settled{false};
  const TwoValuedScan scan = tbb::parallel_reduce(
      tbb::blocked_range<std::int64_t>(0, d[2]), TwoValuedScan(),
      [&](const tbb::blocked_range<std::int64_t>& r, TwoValuedScan s) {
        for (std::int64_t k = r.begin(); k != r.end() && !settled.load(std::memory_order_relaxed); ++k) {
          TwoValuedScan slice;
          const bool countHere = countsSlice(k);
          slice.counting = countHere;
          for (std::int64_t j = 0; j < d[1] && !slice.settled(); ++j) {
            const double* p = &grid.values[static_cast<std::size_t>(grid.index(0, j, k))];
            for (std::int64_t i = 0; i < d[0]; ++i) {
              const bool side = p[i] > isovalue;
              const std::int64_t step[3] = {1, d[0], d[0] * d[1]};
              const bool inside[3] = {i + 1 < d[0], j + 1 < d[1], k + 1 < d[2]};
              for (int a = 0; a < 3; ++a)
                if (inside[a] && (p[i + step[a]] > isovalue) != side)
                  slice.addEdge(p[i], p[i + step[a]], isovalue, countHere && counted(i, j));
            }
          }
          if (slice.settlesAll()) settled.store(true, std::memory_order_relaxed);
          s.join(slice);
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
  result.crossedEdges = scan.crossedEdges;
  result.integral = scan.integral;
  return result;
}

DenseGrid smoothMask(const DenseGrid& grid, double isovalue) {
  return classField(
      grid, [isovalue](double v) { return static_cast<std::int64_t>(v > isovalue); }, 1, isovalue);
}

DenseGrid smoothLabel(const DenseGrid& grid, std::int64_t label, std::int64_t firstSliceZ) {
  return classField(
      grid, [](double v) { return static_cast<std::int64_t>(std::llround(v)); }, label, 0.0, firstSliceZ);
}

}  // namespace cip
