#include "cip/tricubic_reference.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include "cip/cube_topology.h"
#include "cip/error.h"

namespace cip {

namespace {

/// Reconstruction::Central8: the stencil reaches kRadius points to each side, so a cell needs kWide samples
/// per axis; kCentral8[j - 1] weighs s[i + j] - s[i - j].
constexpr int kRadius = 4, kWide = 2 + 2 * kRadius;
constexpr double kCentral8[kRadius] = {4.0 / 5, -1.0 / 5, 4.0 / 105, -1.0 / 280};

/// Entry q of a line whose entries [first, last] are set, extended beyond them by odd reflection through the
/// end points (s[first - j] = 2 s[first] - s[first + j]), reflected again at the other end where the line is
/// shorter than the reach: linear data stay linear. A line of one entry is extended as a constant.
double reflected(const double* line, int stride, int first, int last, int q) {
  if (q >= first && q <= last) return line[q * stride];
  if (first == last) return line[first * stride];
  const int border = q < first ? first : last, mirror = 2 * border - q;
  const double across = mirror >= first && mirror <= last ? line[mirror * stride]
                                                          : reflected(line, stride, first, last, mirror);
  return 2 * line[border * stride] - across;
}

/// Entries q in [0, size) of a line outside [first, last] set by `reflected` from the entries inside.
void extendLine(double* line, int stride, int first, int last, int size) {
  for (int q = 0; q < first; ++q) line[q * stride] = reflected(line, stride, first, last, q);
  for (int q = last + 1; q < size; ++q) line[q * stride] = reflected(line, stride, first, last, q);
}

/// Throws for Reconstruction::Auto, which only buildModel resolves.
void requireResolved(Reconstruction kind) {
  if (kind == Reconstruction::Auto) throw Error("the reference needs a resolved reconstruction, not auto");
}

/// The 8th-order central difference at c[0] of samples `stride` apart.
inline double central8(const double* c, std::ptrdiff_t stride) {
  double sum = 0;
  for (int j = 1; j <= kRadius; ++j) sum += kCentral8[j - 1] * (c[j * stride] - c[-j * stride]);
  return sum;
}

/// The samples of the box of grid points origin + [0, size) per axis (size at most kWide), index i + size[0]
/// (j + size[1] k). The box must hold a grid point. Beyond the grid the samples are reflected oddly through
/// the border point (s[-j] = 2 s[0] - s[j]: linear fields stay linear), one axis after the other.
void reflectedBox(const DenseGrid& grid, const std::array<std::int64_t, 3>& origin,
                  const std::array<int, 3>& size, double* out) {
  const auto& dims = grid.geometry.dims;
  std::array<int, 3> first, last;  // box positions inside the grid, per axis
  for (int a = 0; a < 3; ++a) {
    first[a] = static_cast<int>(std::clamp<std::int64_t>(-origin[a], 0, size[a] - 1));
    last[a] = static_cast<int>(std::clamp<std::int64_t>(dims[a] - 1 - origin[a], 0, size[a] - 1));
  }
  const std::array<int, 3> stride{1, size[0], size[0] * size[1]};
  auto at = [&](int i, int j, int k) -> double& {
    return out[static_cast<std::size_t>(i + stride[1] * j + stride[2] * k)];
  };
  for (int k = first[2]; k <= last[2]; ++k)
    for (int j = first[1]; j <= last[1]; ++j) {
      const double* from = &grid.values[static_cast<std::size_t>(
          grid.index(origin[0] + first[0], origin[1] + j, origin[2] + k))];
      std::copy(from, from + (last[0] - first[0] + 1), &at(first[0], j, k));
    }
  // z first, x last: a point outside along several axes is then reflected along x outermost, as the
  // one-point linear extension of the monotone reference always did (the same rounding).
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
          extendLine(&at(i, j, k), stride[a], first[a], last[a], size[a]);
        }
  }
}

/// The cell's Hermite data (layout of CellReference::hermite) with Reconstruction::Central8: one pass per
/// axis over the kWide^3 samples around the cell that keeps values at local 0 and 1 and adds their
/// derivatives, each pass on the previous one's output (so mixed derivatives are differences of differences).
/// Samples are read in place. Beyond the grid, the odd reflection is applied to what each pass reads: along x
/// to the samples of a line, along y to the x pass's output, along z to the y pass's. Every pass is linear,
/// so this is the pass over reflected samples, and each entry still depends only on the samples around its
/// grid point.
void central8Hermite(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell,
                     std::array<double, 64>& out) {
  const auto& dims = grid.geometry.dims;
  std::array<int, 3> first, last;  // box positions inside the grid, per axis (box origin cell - kRadius)
  for (int a = 0; a < 3; ++a) {
    const std::int64_t origin = cell[a] - kRadius;
    first[a] = static_cast<int>(std::clamp<std::int64_t>(-origin, 0, kWide - 1));
    last[a] = static_cast<int>(std::clamp<std::int64_t>(dims[a] - 1 - origin, 0, kWide - 1));
  }
  const bool insideX = first[0] == 0 && last[0] == kWide - 1;
  // x: lines of kWide samples -> 4 Hermite entries each; index kind + 4 (j + kWide k). Only the lines inside
  // the grid along y and z.
  std::array<double, 4 * kWide * kWide> byX;
  std::array<double, kWide> line;
  for (int k = first[2]; k <= last[2]; ++k)
    for (int j = first[1]; j <= last[1]; ++j) {
      const double* s = &grid.values[static_cast<std::size_t>(
          grid.index(cell[0] - kRadius + first[0], cell[1] - kRadius + j, cell[2] - kRadius + k))];
      if (insideX) {
        s += kRadius;
      } else {
        std::copy(s, s + (last[0] - first[0] + 1), &line[static_cast<std::size_t>(first[0])]);
        extendLine(line.data(), 1, first[0], last[0], kWide);
        s = &line[kRadius];
      }
      double* h = &byX[static_cast<std::size_t>(4 * (j + kWide * k))];
      h[0] = s[0];
      h[1] = central8(s, 1);
      h[2] = s[1];
      h[3] = central8(s + 1, 1);
    }
  // Lines along y beyond the grid, by reflection of the x pass's output.
  if (first[1] > 0 || last[1] < kWide - 1) {
    for (int k = first[2]; k <= last[2]; ++k)
      for (int kind = 0; kind < 4; ++kind)
        extendLine(&byX[static_cast<std::size_t>(kind + 4 * kWide * k)], 4, first[1], last[1], kWide);
  }
  // y: index i + 4 (kind + 4 k).
  std::array<double, 16 * kWide> byY;
  for (int k = first[2]; k <= last[2]; ++k)
    for (int i = 0; i < 4; ++i) {
      const double* s = &byX[static_cast<std::size_t>(i + 4 * (kRadius + kWide * k))];
      double* h = &byY[static_cast<std::size_t>(i + 16 * k)];
      h[0] = s[0];
      h[4] = central8(s, 4);
      h[8] = s[4];
      h[12] = central8(s + 4, 4);
    }
  // Planes along z beyond the grid, by reflection of the y pass's output.
  if (first[2] > 0 || last[2] < kWide - 1) {
    for (int ij = 0; ij < 16; ++ij)
      extendLine(&byY[static_cast<std::size_t>(ij)], 16, first[2], last[2], kWide);
  }
  // z: index i + 4 (j + 4 kind).
  for (int ij = 0; ij < 16; ++ij) {
    const double* s = &byY[static_cast<std::size_t>(ij + 16 * kRadius)];
    out[static_cast<std::size_t>(ij)] = s[0];
    out[static_cast<std::size_t>(ij + 16)] = central8(s, 16);
    out[static_cast<std::size_t>(ij + 32)] = s[16];
    out[static_cast<std::size_t>(ij + 48)] = central8(s + 16, 16);
  }
}

/// Derivative at a sample from the differences to its neighbours (left = s - s_prev, right = s_next - s):
/// their mean, zero at a local extremum, at most three times the smaller difference (Hyman's filter).
double limitedSlope(double left, double right) {
  // Written with selects rather than branches: the conditions follow the data, so branches mispredict.
  const double centred = 0.5 * (left + right);
  const double magnitude = std::min(std::abs(centred), 3 * std::min(std::abs(left), std::abs(right)));
  const double limited = std::copysign(magnitude, centred);
  return left * right > 0 ? limited : 0.0;
}

/// One pass of samplesToHermite along `axis` (stride 4^axis): entry low + stride (i + 4 high) is point i of
/// the line (low, high). The lines of one `high` are contiguous in `low`, so for y and z the pass vectorises.
template <int axis>
void hermitePass(std::array<double, 64>& data) {
  constexpr int stride = axis == 0 ? 1 : axis == 1 ? 4 : 16;
  for (int high = 0; high < 16 / stride; ++high)
    for (int low = 0; low < stride; ++low) {
      double* line = &data[static_cast<std::size_t>(low + 4 * stride * high)];
      // Indices of axes converted before this one are Hermite kinds (odd = derivative): x for the y and z
      // passes, y for the z pass.
      const int base = low + 4 * stride * high;
      const bool values = !((axis > 0 && (base & 1)) || (axis > 1 && ((base >> 2) & 1)));
      const double s0 = line[0], s1 = line[stride], s2 = line[2 * stride], s3 = line[3 * stride];
      const double d1 = values ? limitedSlope(s1 - s0, s2 - s1) : 0.5 * (s2 - s0);
      const double d2 = values ? limitedSlope(s2 - s1, s3 - s2) : 0.5 * (s3 - s1);
      line[0] = s1;
      line[stride] = d1;
      line[2 * stride] = s2;
      line[3 * stride] = d2;
    }
}

/// Turns the 4x4x4 samples at cell-local points -1..2 into the cell's Hermite data, one axis at a time (x, y,
/// z). A line of values (all its other indices already values, or samples) gets limited derivatives; a line
/// of derivatives gets central differences (mixed derivatives).
void samplesToHermite(std::array<double, 64>& data) {
  hermitePass<0>(data);
  hermitePass<1>(data);
  hermitePass<2>(data);
}

/// The 4x4x4 samples at cell-local points -1..2 of `cell` (index i + 4 (j + 4 k)). Beyond the grid they are
/// extended linearly by one point, 2 s[0] - s[1] (linear fields stay linear up to the border): reflectedBox's
/// odd reflection at that reach.
void sampleBlock(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell,
                 std::array<double, 64>& out) {
  reflectedBox(grid, {cell[0] - 1, cell[1] - 1, cell[2] - 1}, {4, 4, 4}, out.data());
}

/// Derivative along `axis` that samplesToHermite gives at sample `at` (an index 0..3 per axis into the block,
/// with 1 or 2 along `axis`), of the samples (limited slope).
double blockSlope(const std::array<double, 64>& block, std::array<int, 3> at, int axis) {
  constexpr int stride[3] = {1, 4, 16};
  const int base = at[0] + 4 * (at[1] + 4 * at[2]);
  const double s = block[static_cast<std::size_t>(base)];
  return limitedSlope(s - block[static_cast<std::size_t>(base - stride[axis])],
                      block[static_cast<std::size_t>(base + stride[axis])] - s);
}

/// Mixed derivative along axes a and b that samplesToHermite gives at sample `at` (1 or 2 along both): the
/// central difference, along the later axis of the two, of the limited slopes along the earlier one.
double blockMixed(const std::array<double, 64>& block, std::array<int, 3> at, int a, int b) {
  const int first = std::min(a, b), second = std::max(a, b);
  auto ahead = at, behind = at;
  ++ahead[second];
  --behind[second];
  return 0.5 * (blockSlope(block, ahead, first) - blockSlope(block, behind, first));
}

}  // namespace

void hermiteWeights(double t, double* w, double* d) {
  const double t2 = t * t, t3 = t2 * t;
  w[0] = 2 * t3 - 3 * t2 + 1;
  w[1] = t3 - 2 * t2 + t;
  w[2] = -2 * t3 + 3 * t2;
  w[3] = t3 - t2;
  if (d) {
    d[0] = 6 * t2 - 6 * t;
    d[1] = 3 * t2 - 4 * t + 1;
    d[2] = -6 * t2 + 6 * t;
    d[3] = 3 * t2 - 2 * t;
  }
}

double CellReference::value(const Vec3& local) const {
  if (field) return field->value(geometry->indexToWorld(origin + local)) - isovalue;
  double wx[4], wy[4], wz[4];
  hermiteWeights(local.x(), wx, nullptr);
  hermiteWeights(local.y(), wy, nullptr);
  hermiteWeights(local.z(), wz, nullptr);
  double sum = 0;
  for (int k = 0; k < 4; ++k) {
    double plane = 0;
    for (int j = 0; j < 4; ++j) {
      const double* row = &hermite[static_cast<std::size_t>(4 * (j + 4 * k))];
      plane += wy[j] * (wx[0] * row[0] + wx[1] * row[1] + wx[2] * row[2] + wx[3] * row[3]);
    }
    sum += wz[k] * plane;
  }
  return sum - isovalue;
}

Vec3 CellReference::gradient(const Vec3& local) const {
  Vec3 g;
  valueAndGradient(local, g);
  return g;
}

double CellReference::valueAndGradient(const Vec3& local, Vec3& gradient) const {
  if (field) {
    const Vec3 world = geometry->indexToWorld(origin + local);
    gradient = field->gradient(world).cwiseProduct(geometry->spacing);
    return field->value(world) - isovalue;
  }
  // Contracted one axis at a time: x gives values and x-derivatives per (y, z) Hermite index, y and z follow.
  double w[3][4], d[3][4];
  for (int a = 0; a < 3; ++a) hermiteWeights(local[a], w[a], d[a]);
  double value = 0;
  gradient = Vec3::Zero();
  for (int k = 0; k < 4; ++k) {
    double plane = 0, planeDx = 0, planeDy = 0;
    for (int j = 0; j < 4; ++j) {
      const double* row = &hermite[static_cast<std::size_t>(4 * (j + 4 * k))];
      const double v = w[0][0] * row[0] + w[0][1] * row[1] + w[0][2] * row[2] + w[0][3] * row[3];
      const double dx = d[0][0] * row[0] + d[0][1] * row[1] + d[0][2] * row[2] + d[0][3] * row[3];
      plane += w[1][j] * v;
      planeDx += w[1][j] * dx;
      planeDy += d[1][j] * v;
    }
    value += w[2][k] * plane;
    gradient.x() += w[2][k] * planeDx;
    gradient.y() += w[2][k] * planeDy;
    gradient.z() += d[2][k] * plane;
  }
  return value - isovalue;
}

const char* toString(Reconstruction kind) {
  switch (kind) {
    case Reconstruction::Central8:
      return "central8";
    case Reconstruction::Auto:
      return "auto";
    case Reconstruction::Monotone:
      break;
  }
  return "monotone";
}

Reconstruction parseReconstruction(const std::string& text) {
  if (text == "monotone") return Reconstruction::Monotone;
  if (text == "central8") return Reconstruction::Central8;
  if (text == "auto") return Reconstruction::Auto;
  throw Error("unknown reconstruction '" + text + "' (expected auto, monotone or central8)");
}

int referenceReach(Reconstruction kind) {
  return kind == Reconstruction::Monotone ? 1 : kRadius;
}

CellReference tricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell,
                                double isovalue, Reconstruction kind) {
  CellReference ref;
  setTricubicReference(grid, cell, isovalue, ref, kind);
  return ref;
}

void setTricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell, double isovalue,
                          CellReference& ref, Reconstruction kind) {
  ref.field = nullptr;
  ref.geometry = nullptr;
  ref.origin = Vec3::Zero();
  ref.isovalue = isovalue;
  ref.metric = Vec3::Ones();
  requireResolved(kind);
  if (kind == Reconstruction::Central8) {
    central8Hermite(grid, cell, ref.hermite);
    return;
  }
  sampleBlock(grid, cell, ref.hermite);
  samplesToHermite(ref.hermite);
}

TricubicInterpolant::TricubicInterpolant(const DenseGrid& grid, Reconstruction kind)
    : grid_(grid), kind_(kind) {
  requireResolved(kind);
  static std::atomic<std::uint64_t> next{1};
  id_ = next++;
}

const CellReference& TricubicInterpolant::at(const Vec3& world, Vec3& local) const {
  const Vec3 index = grid_.geometry.worldToIndex(world);
  std::array<std::int64_t, 3> cell;
  for (int a = 0; a < 3; ++a) {
    const std::int64_t cells = std::max<std::int64_t>(1, grid_.geometry.dims[a] - 1);
    const double lower = std::floor(index[a]);
    cell[a] = std::isfinite(lower)
                  ? std::clamp<std::int64_t>(
                        static_cast<std::int64_t>(std::clamp(lower, -1.0, static_cast<double>(cells))), 0,
                        cells - 1)
                  : 0;
    local[a] = index[a] - static_cast<double>(cell[a]);
  }
  struct LastCell {
    std::uint64_t owner = 0;
    std::array<std::int64_t, 3> cell{};
    CellReference ref;
  };
  thread_local LastCell last;
  if (last.owner != id_ || last.cell != cell) {
    setTricubicReference(grid_, cell, 0.0, last.ref, kind_);
    last.owner = id_;
    last.cell = cell;
  }
  return last.ref;
}

double TricubicInterpolant::value(const Vec3& world) const {
  Vec3 local;
  const CellReference& ref = at(world, local);
  return ref.value(local);
}

Vec3 TricubicInterpolant::gradient(const Vec3& world) const {
  Vec3 local;
  const CellReference& ref = at(world, local);
  return ref.gradient(local).cwiseQuotient(grid_.geometry.spacing);
}

namespace {

/// The Hermite data of the reference on one grid edge: along it, (value, slope) at both ends; across it along
/// each other axis, (slope, mixed derivative with the edge axis) at both ends. Enough for the value along the
/// edge and the gradient on it.
struct EdgeHermite {
  std::array<double, 4> along;
  std::array<std::array<double, 4>, 3> across;  ///< indexed by axis; the edge axis' entry unused
};

/// EdgeHermite with Reconstruction::Monotone, from the cell's 4x4x4 samples (a cell that has the edge: at
/// local coordinate 0 across each other axis where the grid allows).
EdgeHermite monotoneEdge(const DenseGrid& grid, const std::array<std::int64_t, 3>& point, int axis) {
  const auto& dims = grid.geometry.dims;
  std::array<std::int64_t, 3> cell = point;
  std::array<int, 3> end0{1, 1, 1};
  for (int other : cube::otherAxes(axis))
    if (point[other] + 1 >= dims[other] && point[other] > 0) {
      --cell[other];
      end0[other] = 2;
    }
  std::array<double, 64> block;
  sampleBlock(grid, cell, block);
  std::array<int, 3> end1 = end0;
  end1[axis] = 2;
  auto sample = [&](const std::array<int, 3>& at) {
    return block[static_cast<std::size_t>(at[0] + 4 * (at[1] + 4 * at[2]))];
  };
  EdgeHermite e{};
  e.along = {sample(end0), blockSlope(block, end0, axis), sample(end1), blockSlope(block, end1, axis)};
  for (int other : cube::otherAxes(axis))
    e.across[other] = {blockSlope(block, end0, other), blockMixed(block, end0, axis, other),
                       blockSlope(block, end1, other), blockMixed(block, end1, axis, other)};
  return e;
}

/// EdgeHermite with Reconstruction::Central8, from one plane of samples per other axis (kWide along the edge,
/// 2 kRadius + 1 across it) instead of the kWide^3 of a cell.
EdgeHermite central8Edge(const DenseGrid& grid, const std::array<std::int64_t, 3>& point, int axis) {
  constexpr int kAcross = 2 * kRadius + 1;
  EdgeHermite e{};
  for (int other : cube::otherAxes(axis)) {
    std::array<std::int64_t, 3> origin = point;
    std::array<int, 3> size{1, 1, 1};
    origin[axis] -= kRadius;
    origin[other] -= kRadius;
    size[axis] = kWide;
    size[other] = kAcross;
    bool inside = true;
    for (int a = 0; a < 3; ++a)
      inside = inside && origin[a] >= 0 && origin[a] + size[a] <= grid.geometry.dims[a];
    // The plane's samples, read in place inside the grid and gathered with reflection elsewhere; strides
    // along the edge and across it.
    std::array<double, kWide * kAcross> plane;
    const double* first;
    std::ptrdiff_t alongStride, acrossStride;
    if (inside) {
      const std::ptrdiff_t stride[3] = {
          1, static_cast<std::ptrdiff_t>(grid.geometry.dims[0]),
          static_cast<std::ptrdiff_t>(grid.geometry.dims[0] * grid.geometry.dims[1])};
      first = &grid.values[static_cast<std::size_t>(grid.index(origin[0], origin[1], origin[2]))];
      alongStride = stride[axis];
      acrossStride = stride[other];
    } else {
      reflectedBox(grid, origin, size, plane.data());
      first = plane.data();
      alongStride = axis < other ? 1 : kAcross;  // the box's index order is x, y, z
      acrossStride = axis < other ? kWide : 1;
    }
    const double* centre = first + kRadius * acrossStride;
    // The cross slope at every point of the centre line, then its differences along the edge.
    std::array<double, kWide> slope;
    for (int q = 0; q < kWide; ++q)
      slope[static_cast<std::size_t>(q)] = central8(centre + q * alongStride, acrossStride);
    e.across[other] = {slope[kRadius], central8(&slope[kRadius], 1), slope[kRadius + 1],
                       central8(&slope[kRadius + 1], 1)};
    if (other == cube::otherAxes(axis)[0]) {  // the edge's own line lies in both planes
      const double* end0 = centre + kRadius * alongStride;
      e.along = {end0[0], central8(end0, alongStride), end0[alongStride],
                 central8(end0 + alongStride, alongStride)};
    }
  }
  return e;
}

}  // namespace

double cubicEdgeVertex(const DenseGrid& grid, const std::array<std::int64_t, 3>& point, int axis,
                       double isovalue, Vec3& normal, Reconstruction kind) {
  requireResolved(kind);
  const EdgeHermite e =
      kind == Reconstruction::Central8 ? central8Edge(grid, point, axis) : monotoneEdge(grid, point, axis);
  // The reference along the edge: a cubic Hermite segment, in powers of t (one variable on [0, 1] with
  // coefficients of the size of the data: no cancellation to fear), evaluated by Horner.
  const double v0 = e.along[0] - isovalue, d0 = e.along[1], v1 = e.along[2] - isovalue, d1 = e.along[3];
  const double k0 = v0, k1 = d0, k2 = -3 * v0 - 2 * d0 + 3 * v1 - d1, k3 = 2 * v0 + d0 - 2 * v1 + d1;
  auto cubic = [&](double t) { return ((k3 * t + k2) * t + k1) * t + k0; };
  auto slope = [&](double t) { return (3 * k3 * t + 2 * k2) * t + k1; };
  const double tLinear = linearCrossing(v0, v1, 0.0);
  // All sign changes on [0,1] (16 brackets; the segment is monotone, so there is one), each refined by Newton
  // steps kept inside the bracket (bisection when a step leaves it); keep the root nearest the linear
  // crossing. The end values bracket the isovalue, so there is at least one.
  constexpr int kBrackets = 16;
  double best = tLinear, bestGap = std::numeric_limits<double>::infinity();
  double t0 = 0, c0 = v0;
  for (int b = 1; b <= kBrackets; ++b) {
    const double t1 = static_cast<double>(b) / kBrackets, c1 = b == kBrackets ? v1 : cubic(t1);
    if ((c0 > 0) != (c1 > 0)) {
      double lo = t0, hi = t1, fLo = c0, t = 0.5 * (t0 + t1);
      for (int it = 0; it < 60 && hi - lo > 0x1p-50; ++it) {
        const double ft = cubic(t);
        if (ft == 0) break;
        if ((ft > 0) == (fLo > 0)) {
          lo = t;
          fLo = ft;
        } else {
          hi = t;
        }
        const double d = slope(t), next = d != 0 ? t - ft / d : 0.5 * (lo + hi);
        if (std::abs(next - t) < 0x1p-50) {  // converged (the step may sit on a bracket end)
          t = std::clamp(next, lo, hi);
          break;
        }
        t = next > lo && next < hi ? next : 0.5 * (lo + hi);
      }
      if (std::abs(t - tLinear) < bestGap) {
        bestGap = std::abs(t - tLinear);
        best = t;
      }
    }
    t0 = t1;
    c0 = c1;
  }
  // The gradient there, as CellReference::gradient computes it on the edge: along the edge the cubic's
  // derivative, across it the Hermite segment of the cross slopes and mixed derivatives.
  double w[4], dw[4];
  hermiteWeights(best, w, dw);
  Vec3 gradient;
  gradient[axis] = dw[0] * e.along[0] + dw[1] * d0 + dw[2] * e.along[2] + dw[3] * d1;
  for (int other : cube::otherAxes(axis)) {
    const auto& h = e.across[other];
    gradient[other] = w[0] * h[0] + w[1] * h[1] + w[2] * h[2] + w[3] * h[3];
  }
  const Vec3 towardsPositive = Vec3::Unit(axis) * (v1 > 0 ? 1.0 : -1.0);
  normal = orientCornerNormal(gradient, towardsPositive);
  return best;
}

}  // namespace cip
