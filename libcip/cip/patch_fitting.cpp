#include "cip/patch_fitting.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "cip/bisection.h"
#include "cip/cube_topology.h"
#include "cip/patch_coefficients.h"

namespace cip {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

/// Blend levels of a corner-plane normal: n = normalize((1 - beta) n_gradient + beta e_edge).
constexpr std::array<double, 5> kBlend{0.0, 0.25, 0.5, 0.75, 1.0};
constexpr int kMaxLevel = static_cast<int>(kBlend.size()) - 1;
/// Samples per axis of the sign checks: face lattice (kFaceLattice^2) and cell lattice (kCellLattice^3).
constexpr int kFaceLattice = 7, kCellLattice = 6;
/// Samples closer than this to the reference surface (first-order estimate |f| / |grad f|, voxels) are not
/// checked.
constexpr double kMarginVoxels = 0.35;
/// Lattice coordinates of the checks: n equally spaced points from kLatticeInset / (n - 1 + 2 kLatticeInset)
/// to its mirror image, i.e. closer to the faces than (a + 1/2) / n, where the central term is strongest far
/// from the bounding planes and wrong signs appear first.
constexpr double kLatticeInset = 0.25;
constexpr double latticeStep(int n) {
  return 1.0 / (n - 1 + 2 * kLatticeInset);
}
constexpr double latticeCoord(int i, int n) {
  return (i + kLatticeInset) * latticeStep(n);
}
/// Weight of the ridge term of the coefficient fits (relative to a fit point at the cell or face centre).
constexpr double kRidge = 1e-3;

/// Catmull-Rom weights for samples at -1, 0, 1, 2 and their derivatives, at t in [0, 1].
void catmullRom(double t, double* w, double* d) {
  double t2 = t * t, t3 = t2 * t;
  w[0] = 0.5 * (-t3 + 2 * t2 - t);
  w[1] = 0.5 * (3 * t3 - 5 * t2 + 2);
  w[2] = 0.5 * (-3 * t3 + 4 * t2 + t);
  w[3] = 0.5 * (t3 - t2);
  if (d) {
    d[0] = 0.5 * (-3 * t2 + 4 * t - 1);
    d[1] = 0.5 * (9 * t2 - 10 * t);
    d[2] = 0.5 * (-9 * t2 + 8 * t + 1);
    d[3] = 0.5 * (3 * t2 - 2 * t);
  }
}

std::int64_t clampIndex(std::int64_t i, std::int64_t n) {
  return std::clamp<std::int64_t>(i, 0, n - 1);
}

/// Sample at grid point p, extended linearly by one point beyond the grid along each axis (so that linear
/// fields stay linear up to the border), clamped further out.
double extendedSample(const DenseGrid& grid, std::array<std::int64_t, 3> p) {
  const auto& dims = grid.geometry.dims;
  for (int a = 0; a < 3; ++a) {
    if (dims[a] >= 2 && (p[a] == -1 || p[a] == dims[a])) {
      auto inner = p, next = p;
      inner[a] = p[a] < 0 ? 0 : dims[a] - 1;
      next[a] = p[a] < 0 ? 1 : dims[a] - 2;
      return 2 * extendedSample(grid, inner) - extendedSample(grid, next);
    }
  }
  for (int a = 0; a < 3; ++a) p[a] = clampIndex(p[a], dims[a]);
  return grid.at(p[0], p[1], p[2]);
}

/// Interval of a coefficient w with sign(s) * (a + w b) > 0 for all added constraints (b >= 0).
struct Interval {
  double lo = -kInf, hi = kInf;
  bool empty = false;
  // The tightest bounds so far as fractions -a / b (b > 0), compared without dividing.
  double loA = 0, loB = 0, hiA = 0, hiB = 0;
  void add(bool positive, double a, double b) {
    if (!(b > 1e-300)) {
      if ((a > 0) != positive) empty = true;
      return;
    }
    if (positive) {
      if (loB == 0 || a * loB < loA * b) {
        loA = a;
        loB = b;
      }
    } else if (hiB == 0 || a * hiB > hiA * b) {
      hiA = a;
      hiB = b;
    }
  }
  /// Turns the fractions into lo and hi; call once after the last add.
  void finish() {
    if (loB != 0) lo = -loA / loB;
    if (hiB != 0) hi = -hiA / hiB;
  }
  bool feasible() const { return !empty && lo < hi; }
  /// `w` moved into the interval, kept a relative margin away from each end (an end puts the zero set through
  /// the sample that defines it: at the end t = -a / b, a + w b >= kEps |a| needs w >= t + kEps |t|).
  double clamp(double w) const {
    constexpr double kEps = 0.05;
    double a = std::isfinite(lo) ? lo + kEps * std::abs(lo) : lo;
    double b = std::isfinite(hi) ? hi - kEps * std::abs(hi) : hi;
    if (!(a <= b)) return 0.5 * (lo + hi);
    return std::clamp(w, a, b);
  }
};

/// Reference values at the cell lattice (latticeCoord per axis, index a + n (b + n d)). The tricubic
/// interpolant is contracted one axis at a time (the weights are the same on every axis).
template <int n>
void referenceCellLattice(const CellReference& ref, std::array<double, n * n * n>& out) {
  if (ref.field) {
    for (int d = 0; d < n; ++d)
      for (int b = 0; b < n; ++b)
        for (int a = 0; a < n; ++a)
          out[static_cast<std::size_t>(a + n * (b + n * d))] =
              ref.value(Vec3(latticeCoord(a, n), latticeCoord(b, n), latticeCoord(d, n)));
    return;
  }
  double w[n][4];
  for (int i = 0; i < n; ++i) catmullRom(latticeCoord(i, n), w[i], nullptr);
  double ax[n][16], bxy[n * n][4];
  for (int a = 0; a < n; ++a)
    for (int jk = 0; jk < 16; ++jk) {
      const double* row = &ref.samples[static_cast<std::size_t>(4 * jk)];
      ax[a][jk] = w[a][0] * row[0] + w[a][1] * row[1] + w[a][2] * row[2] + w[a][3] * row[3];
    }
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a)
      for (int k = 0; k < 4; ++k)
        bxy[a + n * b][k] = w[b][0] * ax[a][4 * k] + w[b][1] * ax[a][1 + 4 * k] + w[b][2] * ax[a][2 + 4 * k] +
                            w[b][3] * ax[a][3 + 4 * k];
  for (int d = 0; d < n; ++d)
    for (int ab = 0; ab < n * n; ++ab)
      out[static_cast<std::size_t>(ab + n * n * d)] = w[d][0] * bxy[ab][0] + w[d][1] * bxy[ab][1] +
                                                      w[d][2] * bxy[ab][2] + w[d][3] * bxy[ab][3] -
                                                      ref.isovalue;
}

/// Reference values and gradients on face f at the lattice coordinates in the face frame (index a + n
/// b).
template <int n>
void referenceFaceLattice(const CellReference& ref, int f, std::array<double, n * n>& value,
                          std::array<Vec3, n * n>& gradient) {
  const int axis = cube::faceAxis(f), side = cube::faceSide(f);
  const auto uv = cube::otherAxes(axis);
  if (ref.field) {
    for (int b = 0; b < n; ++b)
      for (int a = 0; a < n; ++a) {
        Vec3 x;
        x[axis] = side;
        x[uv[0]] = latticeCoord(a, n);
        x[uv[1]] = latticeCoord(b, n);
        value[static_cast<std::size_t>(a + n * b)] = ref.value(x);
        gradient[static_cast<std::size_t>(a + n * b)] = ref.gradient(x);
      }
    return;
  }
  // In-plane samples (node 1 + side across the face) and the across-face derivative at the node.
  const double dNode[2][4] = {{-0.5, 0, 0.5, 0}, {0, -0.5, 0, 0.5}};
  double p0[4][4], p1[4][4];
  for (int jb = 0; jb < 4; ++jb)
    for (int ia = 0; ia < 4; ++ia) {
      std::array<int, 3> i3{};
      i3[uv[0]] = ia;
      i3[uv[1]] = jb;
      auto at = [&](int c) {
        i3[axis] = c;
        return ref.samples[static_cast<std::size_t>(i3[0] + 4 * (i3[1] + 4 * i3[2]))];
      };
      p0[ia][jb] = at(1 + side);
      p1[ia][jb] =
          dNode[side][0] * at(0) + dNode[side][1] * at(1) + dNode[side][2] * at(2) + dNode[side][3] * at(3);
    }
  double w[n][4], dw[n][4];
  for (int i = 0; i < n; ++i) catmullRom(latticeCoord(i, n), w[i], dw[i]);
  double a0[n][4], ad[n][4], a1[n][4];
  for (int a = 0; a < n; ++a)
    for (int jb = 0; jb < 4; ++jb) {
      a0[a][jb] = ad[a][jb] = a1[a][jb] = 0;
      for (int ia = 0; ia < 4; ++ia) {
        a0[a][jb] += w[a][ia] * p0[ia][jb];
        ad[a][jb] += dw[a][ia] * p0[ia][jb];
        a1[a][jb] += w[a][ia] * p1[ia][jb];
      }
    }
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) {
      double v = 0, gu = 0, gv = 0, gn = 0;
      for (int jb = 0; jb < 4; ++jb) {
        v += w[b][jb] * a0[a][jb];
        gu += w[b][jb] * ad[a][jb];
        gv += dw[b][jb] * a0[a][jb];
        gn += w[b][jb] * a1[a][jb];
      }
      Vec3 g;
      g[axis] = gn;
      g[uv[0]] = gu;
      g[uv[1]] = gv;
      value[static_cast<std::size_t>(a + n * b)] = v - ref.isovalue;
      gradient[static_cast<std::size_t>(a + n * b)] = g;
    }
}

/// valueWithoutCentral and centralBasis of a patch at the cell lattice, by separable products: every term is
/// a corner plane (linear) times squared face planes, each depending on one coordinate.
template <int n>
void patchCellLattice(const CornerPatch& patch, std::array<double, n * n * n>& value,
                      std::array<double, n * n * n>& basis) {
  // q[m][i]: product of the squared planes of one axis selected by m (bit 0: x = 0 plane, bit 1: x = 1
  // plane).
  double t[n], q[4][n];
  for (int i = 0; i < n; ++i) {
    t[i] = latticeCoord(i, n);
    q[0][i] = 1;
    q[1][i] = t[i] * t[i];
    q[2][i] = (1 - t[i]) * (1 - t[i]);
    q[3][i] = q[1][i] * q[2][i];
  }
  struct Term {
    double coefficient;
    Vec3 normal;  // zero for side terms
    double offset;
    int m[3];
  };
  std::array<Term, CornerPatch::kMaxTerms> terms;
  int numTerms = 0;
  auto split = [](std::uint8_t mask, int* m) {
    for (int a = 0; a < 3; ++a) m[a] = (mask >> (2 * a)) & 3;
  };
  for (int c = 0; c < patch.numCorners; ++c) {
    auto ef = cube::edgeFaces(patch.edge[c]);
    Term& term = terms[static_cast<std::size_t>(numTerms++)];
    term.coefficient = patch.weight[c];
    term.normal = patch.normal[c];
    term.offset = -patch.normal[c].dot(patch.point[c]);
    split(static_cast<std::uint8_t>(patch.faceMask & ~((1u << ef[0]) | (1u << ef[1]))), term.m);
  }
  for (int f = 0; f < 6; ++f) {
    if (!((patch.faceMask >> f) & 1) || patch.faceCoefficient[f] == 0) continue;
    Term& term = terms[static_cast<std::size_t>(numTerms++)];
    term.coefficient = patch.faceCoefficient[f];
    term.normal = Vec3::Zero();
    term.offset = 1;
    split(static_cast<std::uint8_t>(patch.faceMask & ~(1u << f)), term.m);
  }
  int central[3];
  split(patch.faceMask, central);
  for (int d = 0; d < n; ++d)
    for (int b = 0; b < n; ++b) {
      double* row = &value[static_cast<std::size_t>(n * (b + n * d))];
      for (int a = 0; a < n; ++a) row[a] = 0;
      for (int k = 0; k < numTerms; ++k) {
        const Term& term = terms[static_cast<std::size_t>(k)];
        double yz = term.coefficient * q[term.m[1]][b] * q[term.m[2]][d];
        double planeYZ = term.normal.y() * t[b] + term.normal.z() * t[d] + term.offset;
        const double* qx = q[term.m[0]];
        for (int a = 0; a < n; ++a) row[a] += yz * (term.normal.x() * t[a] + planeYZ) * qx[a];
      }
      double yz = q[central[1]][b] * q[central[2]][d];
      for (int a = 0; a < n; ++a)
        basis[static_cast<std::size_t>(a + n * (b + n * d))] = yz * q[central[0]][a];
    }
}

struct FaceEntry {
  std::uint64_t key = 0;
  std::array<std::uint32_t, 2> cell{};
  std::array<std::int8_t, 2> face{};
  int count = 0;
};

struct FaceResult {
  double coefficient = 0;
  bool ok = true;
};

FaceResult fitFace(const Model& model, const FaceEntry& entry, const CellLoops& loops,
                   const CellReference& ref) {
  const std::size_t c = entry.cell[0];
  const int f = entry.face[0];
  CornerPatch patch = model.patch(c, loops);
  FaceCrossings fc = faceCrossingsOf(patch, f, (model.cells[c].pairing03 >> f) & 1);
  constexpr int n = kFaceLattice;
  std::array<double, n * n> r;
  std::array<Vec3, n * n> rg;
  referenceFaceLattice<n>(ref, f, r, rg);
  Interval interval;
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) {
      const std::size_t i = static_cast<std::size_t>(a + n * b);
      if (!(r[i] * r[i] > kMarginVoxels * kMarginVoxels * rg[i].cwiseProduct(ref.metric).squaredNorm()))
        continue;
      FaceRestriction fr = faceRestriction(fc, Vec2(latticeCoord(a, n), latticeCoord(b, n)));
      interval.add(r[i] > 0, fr.cornerPart, fr.sideBasis);
    }
  // Reference face-curve points: sign changes between neighbouring samples, linearly interpolated.
  double num = 0, den = 0;
  int fitCount = 0;
  auto addFit = [&](const Vec2& q0, double r0, const Vec2& q1, double r1) {
    if ((r0 > 0) == (r1 > 0)) return;
    double t = r0 / (r0 - r1);
    FaceRestriction fr = faceRestriction(fc, q0 + t * (q1 - q0));
    num += fr.cornerPart * fr.sideBasis;
    den += fr.sideBasis * fr.sideBasis;
    ++fitCount;
  };
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) {
      Vec2 q(latticeCoord(a, n), latticeCoord(b, n));
      if (a + 1 < n) addFit(q, r[a + n * b], Vec2(latticeCoord(a + 1, n), q.y()), r[a + 1 + n * b]);
      if (b + 1 < n) addFit(q, r[a + n * b], Vec2(q.x(), latticeCoord(b + 1, n)), r[a + n * (b + 1)]);
    }
  if (fitCount == 0) {
    // The reference curve passes between the samples (close to a face vertex): use the side points instead.
    std::array<std::array<int, 2>, 2> segments;
    int numSegments = faceSegments(fc, segments);
    for (int k = 0; k < numSegments; ++k) {
      FaceRestriction fr = faceRestriction(fc, sidePoint(fc, segments[k][0], segments[k][1]));
      num += fr.cornerPart * fr.sideBasis;
      den += fr.sideBasis * fr.sideBasis;
      ++fitCount;
    }
  }
  // Ridge term towards 0 at the scale of the side basis at the face centre: where every fit point has a tiny
  // side basis (a face curve hugging a face vertex) w hardly moves the face curve but would still weigh on
  // the interior.
  const double dCentre = faceRestriction(fc, Vec2(0.5, 0.5)).sideBasis;
  den += kRidge * dCentre * dCentre * std::max(1, fitCount);
  double w = -num / den;
  FaceResult out;
  interval.finish();
  out.ok = interval.feasible();
  out.coefficient = out.ok ? interval.clamp(w) : w;
  if (!std::isfinite(out.coefficient)) out.coefficient = 0;
  return out;
}

struct CellResult {
  double central = 0;
  bool ok = true;
};

CellResult fitCell(const CornerPatch& patch, const CellReference& ref) {
  constexpr int n = kCellLattice;
  std::array<double, n * n * n> r, patchValue, patchBasis;
  referenceCellLattice<n>(ref, r);
  patchCellLattice<n>(patch, patchValue, patchBasis);
  // Neighbours along an axis for the reference gradient (central differences, one-sided at the lattice
  // border), and 1 / (their distance).
  std::array<int, n> below, above;
  std::array<double, n> inverseSpan;
  for (int i = 0; i < n; ++i) {
    below[i] = std::max(i - 1, 0);
    above[i] = std::min(i + 1, n - 1);
    inverseSpan[i] = 1.0 / (latticeStep(n) * (above[i] - below[i]));
  }
  constexpr std::array<int, 3> stride{1, n, n * n};
  Vec3 meanNormal = Vec3::Zero();
  for (int k = 0; k < patch.numCorners; ++k) meanNormal += patch.normal[k];
  int fitAxis = 0;
  meanNormal.cwiseAbs().maxCoeff(&fitAxis);
  constexpr double margin2 = kMarginVoxels * kMarginVoxels;
  Interval interval;
  double num = 0, den = 0;
  int fitCount = 0;
  for (int d = 0; d < n; ++d)
    for (int b = 0; b < n; ++b)
      for (int a = 0; a < n; ++a) {
        const std::array<int, 3> i{a, b, d};
        const int idx = a + n * (b + n * d);
        const double value = r[static_cast<std::size_t>(idx)];
        double g2 = 0;
        for (int k = 0; k < 3; ++k) {
          double diff = (r[static_cast<std::size_t>(idx + (above[i[k]] - i[k]) * stride[k])] -
                         r[static_cast<std::size_t>(idx + (below[i[k]] - i[k]) * stride[k])]) *
                        inverseSpan[i[k]] * ref.metric[k];
          g2 += diff * diff;
        }
        if (value * value > margin2 * g2) {
          interval.add(value > 0, patchValue[static_cast<std::size_t>(idx)],
                       patchBasis[static_cast<std::size_t>(idx)]);
        }
        // Reference surface points between lattice neighbours along the axis closest to the surface normal
        // (linear interpolation of the reference) for the least-squares fit of the central coefficient.
        if (i[fitAxis] + 1 >= n) continue;
        const std::size_t j = static_cast<std::size_t>(idx + stride[fitAxis]);
        const double other = r[j];
        if ((value > 0) == (other > 0)) continue;
        Vec3 q(latticeCoord(a, n), latticeCoord(b, n), latticeCoord(d, n));
        q[fitAxis] += value / (value - other) * latticeStep(n);
        const double basis = patch.centralBasis(q);
        num += patch.valueWithoutCentral(q) * basis;
        den += basis * basis;
        ++fitCount;
      }
  CellResult out;
  const double cCentre = patch.centralBasis(Vec3(0.5, 0.5, 0.5));
  den += kRidge * cCentre * cCentre * std::max(1, fitCount);
  double w = fitCount > 0 ? -num / den : 0.0;
  interval.finish();
  out.ok = interval.feasible();
  out.central = out.ok ? interval.clamp(w) : 0.0;
  if (!std::isfinite(out.central)) out.central = 0;
  return out;
}

}  // namespace

double CellReference::value(const Vec3& local) const {
  if (field) return field->value(geometry->indexToWorld(origin + local)) - isovalue;
  double wx[4], wy[4], wz[4];
  catmullRom(local.x(), wx, nullptr);
  catmullRom(local.y(), wy, nullptr);
  catmullRom(local.z(), wz, nullptr);
  double sum = 0;
  for (int k = 0; k < 4; ++k) {
    double plane = 0;
    for (int j = 0; j < 4; ++j) {
      const double* row = &samples[static_cast<std::size_t>(4 * (j + 4 * k))];
      plane += wy[j] * (wx[0] * row[0] + wx[1] * row[1] + wx[2] * row[2] + wx[3] * row[3]);
    }
    sum += wz[k] * plane;
  }
  return sum - isovalue;
}

Vec3 CellReference::gradient(const Vec3& local) const {
  if (field) return field->gradient(geometry->indexToWorld(origin + local)).cwiseProduct(geometry->spacing);
  double w[3][4], d[3][4];
  for (int a = 0; a < 3; ++a) catmullRom(local[a], w[a], d[a]);
  Vec3 g = Vec3::Zero();
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 4; ++i) {
        double s = samples[static_cast<std::size_t>(i + 4 * (j + 4 * k))];
        g.x() += d[0][i] * w[1][j] * w[2][k] * s;
        g.y() += w[0][i] * d[1][j] * w[2][k] * s;
        g.z() += w[0][i] * w[1][j] * d[2][k] * s;
      }
  return g;
}

CellReference tricubicReference(const DenseGrid& grid, const std::array<std::int64_t, 3>& cell,
                                double isovalue) {
  CellReference ref;
  ref.isovalue = isovalue;
  const auto& dims = grid.geometry.dims;
  if (cell[0] >= 1 && cell[1] >= 1 && cell[2] >= 1 && cell[0] + 2 < dims[0] && cell[1] + 2 < dims[1] &&
      cell[2] + 2 < dims[2]) {
    for (int k = 0; k < 4; ++k)
      for (int j = 0; j < 4; ++j) {
        const double* row =
            &grid.values[static_cast<std::size_t>(grid.index(cell[0] - 1, cell[1] - 1 + j, cell[2] - 1 + k))];
        std::copy(row, row + 4, ref.samples.begin() + 4 * (j + 4 * k));
      }
    return ref;
  }
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 4; ++i)
        ref.samples[static_cast<std::size_t>(i + 4 * (j + 4 * k))] =
            extendedSample(grid, {cell[0] - 1 + i, cell[1] - 1 + j, cell[2] - 1 + k});
  return ref;
}

CellReference TricubicInterpolant::at(const Vec3& world, Vec3& local) const {
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
  return tricubicReference(grid_, cell, 0.0);
}

double TricubicInterpolant::value(const Vec3& world) const {
  Vec3 local;
  CellReference ref = at(world, local);
  return ref.value(local);
}

Vec3 TricubicInterpolant::gradient(const Vec3& world) const {
  Vec3 local;
  CellReference ref = at(world, local);
  return ref.gradient(local).cwiseQuotient(grid_.geometry.spacing);
}

double cubicEdgeVertex(const DenseGrid& grid, const std::array<std::int64_t, 3>& point, int axis,
                       double isovalue, Vec3& normal) {
  const auto& dims = grid.geometry.dims;
  const bool inside = point[0] >= 1 && point[1] >= 1 && point[2] >= 1 && point[0] + 2 < dims[0] &&
                      point[1] + 2 < dims[1] && point[2] + 2 < dims[2];
  auto sample = [&](const std::array<std::int64_t, 3>& p) {
    return inside ? grid.at(p[0], p[1], p[2]) : extendedSample(grid, p);
  };
  auto along = [&](int s) {
    auto p = point;
    p[axis] += s;
    return p;
  };
  std::array<double, 4> s;
  for (int i = 0; i < 4; ++i) s[i] = sample(along(i - 1)) - isovalue;
  auto cubic = [&](double t) {
    double w[4];
    catmullRom(t, w, nullptr);
    return w[0] * s[0] + w[1] * s[1] + w[2] * s[2] + w[3] * s[3];
  };
  const double tLinear = linearCrossing(s[1], s[2], 0.0);
  // All sign changes of the cubic on [0,1] (16 brackets), each refined by bisection; keep the one nearest the
  // linear crossing. The end values bracket the isovalue, so there is at least one.
  constexpr int kBrackets = 16;
  double best = tLinear, bestGap = kInf;
  double t0 = 0, c0 = s[1];
  for (int b = 1; b <= kBrackets; ++b) {
    double t1 = static_cast<double>(b) / kBrackets, c1 = b == kBrackets ? s[2] : cubic(t1);
    if ((c0 > 0) != (c1 > 0)) {
      double root = bisectSignChange(cubic, t0, t1, c0, 44);  // bracket width 2^-48
      if (std::abs(root - tLinear) < bestGap) {
        bestGap = std::abs(root - tLinear);
        best = root;
      }
    }
    t0 = t1;
    c0 = c1;
  }
  // Gradient of the tricubic interpolant at the root: along the edge, the cubic's derivative; across it, the
  // cubic interpolation of central differences (one-sided at the grid border).
  double w[4], d[4];
  catmullRom(best, w, d);
  Vec3 g = Vec3::Zero();
  for (int i = 0; i < 4; ++i) g[axis] += d[i] * s[i];
  for (int other : cube::otherAxes(axis)) {
    for (int i = 0; i < 4; ++i) {
      auto p = along(i - 1);
      p[axis] = clampIndex(p[axis], dims[axis]);
      auto lo = p, hi = p;
      if (lo[other] > 0) --lo[other];
      if (hi[other] + 1 < dims[other]) ++hi[other];
      double span = static_cast<double>(hi[other] - lo[other]);
      if (span > 0) g[other] += w[i] * (sample(hi) - sample(lo)) / span;
    }
  }
  Vec3 towardsPositive = Vec3::Unit(axis) * (s[2] > 0 ? 1.0 : -1.0);
  normal = orientCornerNormal(g, towardsPositive);
  return best;
}

FittingStats fitModelPatches(Model& model, const std::function<CellReference(std::size_t)>& reference) {
  FittingStats stats;
  const std::size_t numCells = model.cells.size(), numVertices = model.vertices.size();
  if (numCells == 0) return stats;
  // Edge direction (towards the positive vertex) and gradient normal of every isovertex.
  std::vector<Vec3> baseNormal(numVertices), edgeDirection(numVertices, Vec3::UnitX());
  for (std::size_t v = 0; v < numVertices; ++v) baseNormal[v] = model.vertices[v].normal;
  std::vector<CellLoops> loops(numCells);
  tbb::parallel_for(std::size_t(0), numCells, [&](std::size_t c) { loops[c] = model.loops(c); });
  for (std::size_t c = 0; c < numCells; ++c) {
    const ModelCell& cell = model.cells[c];
    for (int k = 0; k < cell.numCorners(); ++k) {
      std::uint32_t v = model.corners[cell.firstCorner + k];
      int axis = cube::edgeAxis(loops[c].edges[k]);
      edgeDirection[v] = Vec3::Unit(axis) * (baseNormal[v][axis] >= 0 ? 1.0 : -1.0);
    }
  }
  // Grid faces with crossings, each with its (one or two) cells; the first cell (lowest index) computes it.
  const auto& dims = model.geometry.dims;
  std::vector<FaceEntry> refs;
  for (std::size_t c = 0; c < numCells; ++c) {
    const ModelCell& cell = model.cells[c];
    for (int f = 0; f < 6; ++f) {
      if (!((loops[c].faceMask >> f) & 1)) continue;
      std::array<std::uint64_t, 3> p{cell.index[0], cell.index[1], cell.index[2]};
      p[cube::faceAxis(f)] += static_cast<std::uint64_t>(cube::faceSide(f));
      FaceEntry e;
      e.key =
          ((p[2] * static_cast<std::uint64_t>(dims[1]) + p[1]) * static_cast<std::uint64_t>(dims[0]) + p[0]) *
              3 +
          static_cast<std::uint64_t>(cube::faceAxis(f));
      e.cell[0] = static_cast<std::uint32_t>(c);
      e.face[0] = static_cast<std::int8_t>(f);
      e.count = 1;
      refs.push_back(e);
    }
  }
  std::sort(refs.begin(), refs.end(), [](const FaceEntry& a, const FaceEntry& b) {
    return a.key != b.key ? a.key < b.key : a.cell[0] < b.cell[0];
  });
  std::vector<FaceEntry> faces;
  for (const FaceEntry& e : refs) {
    if (!faces.empty() && faces.back().key == e.key && faces.back().count < 2) {
      faces.back().cell[1] = e.cell[0];
      faces.back().face[1] = e.face[0];
      faces.back().count = 2;
    } else {
      faces.push_back(e);
    }
  }
  refs.clear();
  refs.shrink_to_fit();
  // Faces of each cell (index into `faces`), for dirtiness propagation.
  std::vector<std::array<std::int32_t, 6>> cellFaces(numCells);
  for (auto& cf : cellFaces) cf.fill(-1);
  for (std::size_t i = 0; i < faces.size(); ++i)
    for (int s = 0; s < faces[i].count; ++s)
      cellFaces[faces[i].cell[s]][faces[i].face[s]] = static_cast<std::int32_t>(i);

  std::vector<std::uint8_t> level(numVertices, 0), bump(numVertices, 0);
  std::vector<std::uint8_t> faceDirty(faces.size(), 1), cellDirty(numCells, 1);
  std::vector<std::uint8_t> faceOk(faces.size(), 1), cellOk(numCells, 1);
  std::vector<double> faceCoefficient(faces.size(), 0.0);
  auto cellVertex = [&](std::size_t c, int k) { return model.corners[model.cells[c].firstCorner + k]; };
  for (int round = 0;; ++round) {
    stats.rounds = round + 1;
    tbb::parallel_for(std::size_t(0), numVertices, [&](std::size_t v) {
      double beta = kBlend[level[v]];
      Vec3 n = (1 - beta) * baseNormal[v] + beta * edgeDirection[v];
      model.vertices[v].normal = n.norm() > 1e-12 ? Vec3(n.normalized()) : edgeDirection[v];
    });
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, faces.size(), 64), [&](const tbb::blocked_range<std::size_t>& r) {
          for (std::size_t i = r.begin(); i != r.end(); ++i) {
            if (!faceDirty[i]) continue;
            FaceResult fr = fitFace(model, faces[i], loops[faces[i].cell[0]], reference(faces[i].cell[0]));
            faceCoefficient[i] = fr.coefficient;
            faceOk[i] = fr.ok;
          }
        });
    for (std::size_t i = 0; i < faces.size(); ++i)
      if (faceDirty[i])
        for (int s = 0; s < faces[i].count; ++s)
          model.cells[faces[i].cell[s]].faceCoefficient[faces[i].face[s]] = faceCoefficient[i];
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numCells, 32),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t c = r.begin(); c != r.end(); ++c) {
                          if (!cellDirty[c]) continue;
                          model.cells[c].central = 0;
                          CellResult cr = fitCell(model.patch(c, loops[c]), reference(c));
                          model.cells[c].central = cr.central;
                          cellOk[c] = cr.ok;
                        }
                      });
    // Isovertices of failed faces and cells move one blend level towards the edge direction.
    std::fill(bump.begin(), bump.end(), 0);
    bool any = false;
    auto mark = [&](std::size_t c, std::uint16_t edgeMask) {
      const ModelCell& cell = model.cells[c];
      for (int k = 0; k < cell.numCorners(); ++k) {
        if (!((edgeMask >> loops[c].edges[k]) & 1)) continue;
        std::uint32_t v = cellVertex(c, k);
        if (level[v] < kMaxLevel) {
          bump[v] = 1;
          any = true;
        }
      }
    };
    for (std::size_t i = 0; i < faces.size(); ++i) {
      if (faceOk[i]) continue;
      std::uint16_t mask = 0;
      for (int k = 0; k < 4; ++k)
        mask = static_cast<std::uint16_t>(mask | (1u << cube::faceEdge(faces[i].face[0], k)));
      mark(faces[i].cell[0], mask);
    }
    for (std::size_t c = 0; c < numCells; ++c)
      if (!cellOk[c]) mark(c, 0xFFF);
    if (!any) break;
    for (std::size_t v = 0; v < numVertices; ++v) level[v] = static_cast<std::uint8_t>(level[v] + bump[v]);
    std::fill(faceDirty.begin(), faceDirty.end(), 0);
    std::fill(cellDirty.begin(), cellDirty.end(), 0);
    for (std::size_t c = 0; c < numCells; ++c) {
      const ModelCell& cell = model.cells[c];
      for (int k = 0; k < cell.numCorners() && !cellDirty[c]; ++k)
        if (bump[cellVertex(c, k)]) cellDirty[c] = 1;
      if (!cellDirty[c]) continue;
      for (int f = 0; f < 6; ++f)
        if (cellFaces[c][f] >= 0) faceDirty[static_cast<std::size_t>(cellFaces[c][f])] = 1;
    }
    // A face whose coefficient changes changes its other cell too.
    for (std::size_t i = 0; i < faces.size(); ++i)
      if (faceDirty[i])
        for (int s = 0; s < faces[i].count; ++s) cellDirty[faces[i].cell[s]] = 1;
  }
  for (std::size_t v = 0; v < numVertices; ++v) {
    stats.blendedVertices += level[v] > 0;
    ++stats.levelCount[level[v]];
  }
  for (auto ok : faceOk) stats.failedFaces += !ok;
  for (auto ok : cellOk) stats.failedCells += !ok;
  return stats;
}

}  // namespace cip
