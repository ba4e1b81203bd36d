#include "cip/patch/cell_fit.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <limits>
#include <utility>

#include "cip/core/vector_clones.h"
#include "cip/patch/fit_lattice.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/patch/sign_constraints.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

using namespace fit_lattice;

/// Samples per axis of the cell lattice of the sign checks (kCellLattice^3).
constexpr int kCellLattice = 6;
/// Samples near the surface that the clamping of a cell's coefficient found on the wrong side, from which on
/// the staggered lattice is checked too (fitCell). About 5 % of the cells on CT and fog volumes reach 6; 3
/// (a quarter of the cells) removed no more wrong-sign cells, 12 fewer.
constexpr int kStaggeredTrigger = 6;
using CellAxis = LatticeAxis<kCellLattice, kCellLattice, 1>;
/// The lattice of the sign checks on the faces of a cell that are not bounding planes (openFaceSamples):
/// 1/3 apart, border included, and a row kNearEdge inside each border, where the slope of the patch across
/// the edge is taken from.
struct OpenFaceAxis {
  static constexpr int n = 6;
  static constexpr double step = 1.0 / 3;  ///< the spacing of the regular points
  static constexpr double coord(int i) {
    return i == 0 ? 0.0 : i == 1 ? kNearEdge : i == n - 2 ? 1 - kNearEdge : i == n - 1 ? 1.0 : (i - 1) * step;
  }
};
/// The points halfway between those of CellAxis: with it, a body-centred lattice (see CellFit::secondLook).
using StaggeredCellAxis = LatticeAxis<kCellLattice - 1, kCellLattice, 3>;

/// The tricubic interpolant (Hermite data `hermite` as in CellReference, minus `isovalue`) on the n^3
/// lattice of the lattice points in line order: point i along axis L on line (p, q) of axes P, Q at index
/// i + n (p + n q). Contracted one axis at a time, Q, P, then L, each pass over contiguous arrays so that it
/// vectorises (the weights are the same on every axis).
template <class Axis, int n = Axis::n>
CIP_VECTOR_CLONES void tricubicLatticeInLineOrder(const double* hermite, double isovalue, int L, int P, int Q,
                                                  double* __restrict out) {
  // `out` aliases neither the weights nor the local arrays (restrict), so the passes stay vectorised.
  const LatticeWeights<Axis>& weights = LatticeWeights<Axis>::get();
  const auto& w = weights.w;
  constexpr int stride[3] = {1, 4, 16};
  double h[4][16];  // [Q index][L index + 4 P index]
  for (int iQ = 0; iQ < 4; ++iQ)
    for (int iP = 0; iP < 4; ++iP)
      for (int iL = 0; iL < 4; ++iL)
        h[iQ][iL + 4 * iP] = hermite[iL * stride[L] + iP * stride[P] + iQ * stride[Q]];
  double alongQ[n][16];
  for (int q = 0; q < n; ++q)
    for (int k = 0; k < 16; ++k)
      alongQ[q][k] = w[q][0] * h[0][k] + w[q][1] * h[1][k] + w[q][2] * h[2][k] + w[q][3] * h[3][k];
  double alongP[n][n][4];
  for (int q = 0; q < n; ++q)
    for (int p = 0; p < n; ++p)
      for (int iL = 0; iL < 4; ++iL)
        alongP[q][p][iL] = w[p][0] * alongQ[q][iL] + w[p][1] * alongQ[q][iL + 4] +
                           w[p][2] * alongQ[q][iL + 8] + w[p][3] * alongQ[q][iL + 12];
  const auto& wt = weights.byIndex;
  for (int q = 0; q < n; ++q)
    for (int p = 0; p < n; ++p) {
      const double* c = alongP[q][p];
      double* line = out + n * (p + n * q);
      for (int i = 0; i < n; ++i)
        line[i] = wt[0][i] * c[0] + wt[1][i] * c[1] + wt[2][i] * c[2] + wt[3][i] * c[3] - isovalue;
    }
}

/// Reference values at the cell lattice (CellAxis per axis) in the line order of PatchLines along axis
/// L (lattice point i along L on line (p, q) of the other axes at index i + n (p + n q)); an analytic
/// reference is evaluated through valuesOnLattice.
template <class Axis, int n = Axis::n>
void referenceCellLattice(const CellReference& ref, int L, double* out) {
  const auto other = cube::otherAxes(L);
  if (ref.field) {
    const WorldLattice<Axis> world(ref);
    const double* coordinate[3] = {world.coordinate[0], world.coordinate[1], world.coordinate[2]};
    std::array<int, 3> stride;
    stride[L] = 1;
    stride[other[0]] = n;
    stride[other[1]] = n * n;
    analyticLattice(ref, coordinate, {n, n, n}, stride, out);
    return;
  }
  tricubicLatticeInLineOrder<Axis>(ref.hermite.data(), ref.isovalue, L, other[0], other[1], out);
}

/// The terms of valueWithoutCentral as coefficient * (normal . x + offset) * squared face planes (mask): a
/// corner term's factor is its corner plane, a side term's the constant 1 (normal 0, offset 1). Listed once
/// per cell for all its lattices.
struct LinearTerms {
  struct Term {  // every member is set where a term is listed (no default values: the array is not cleared)
    double coefficient;
    Vec3 normal;
    double offset;
    std::uint8_t mask;
  };
  std::array<Term, CornerPatch::kMaxTerms> term;
  int count = 0;
  std::uint8_t faceMask = 0;  ///< the patch's bounding planes (the central term's mask)

  explicit LinearTerms(const CornerPatch& patch) : faceMask(patch.faceMask) {
    std::array<PatchTerm, CornerPatch::kMaxTerms> terms;
    const int n = patch.terms(terms);
    for (int k = 0; k < n; ++k) {
      const PatchTerm& t = terms[static_cast<std::size_t>(k)];
      if (t.corner < 0 && t.faceSquares == patch.faceMask) continue;  // the central term
      Term& out = term[static_cast<std::size_t>(count++)];
      out.coefficient = t.coefficient;
      out.mask = t.faceSquares;
      if (t.corner >= 0) {
        out.normal = patch.normal[t.corner];
        out.offset = -patch.normal[t.corner].dot(patch.point[t.corner]);
      } else {
        out.normal = Vec3::Zero();
        out.offset = 1;
      }
    }
  }
  template <class F>
  void forEach(F&& fn) const {
    for (int k = 0; k < count; ++k) {
      const Term& t = term[static_cast<std::size_t>(k)];
      fn(t.coefficient, t.normal, t.offset, t.mask);
    }
  }
};

/// The patch on the lattice lines of a cell along one axis L (the other two axes at lattice coordinates):
/// every term is a corner plane (linear) times squared face planes, each depending on one coordinate, so on
/// the line through lattice point (p, q) of the other axes
///   valueWithoutCentral(x) = sum_m s_m(x) (A_m[p, q] + x B_m[p, q]),  centralBasis(x) = s_c(x) C[p, q],
/// with s_m(x) the product of the squared face planes across L selected by m (bit 0: plane x = 0, bit 1: x =
/// 1). Building A, B, C costs O(terms n^2); each lattice point or fit point on a line then costs a few flops.
template <class Axis, int n = Axis::n>
class PatchLines {
 public:
  PatchLines(const LinearTerms& terms, int lineAxis) : axis_(lineAxis), other_(cube::otherAxes(lineAxis)) {
    stride_[axis_] = 1;
    stride_[other_[0]] = n;
    stride_[other_[1]] = n * n;
    const LatticeSquares<Axis>& table = LatticeSquares<Axis>::get();
    std::copy(table.t, table.t + n, t_);
    std::copy(&table.sq[0][0], &table.sq[0][0] + 4 * n, &s_[0][0]);
    // A term c (n . x + o) s_mL(x_L) s_mP(x_P) s_mQ(x_Q) adds s_mP[p] (t[p] X[q] + Y[q]) to A_mL[p, q] and
    // s_mP[p] Z[q] to B_mL[p, q], with X = c n_P s_mQ, Y = c (o + n_Q t) s_mQ and Z = c n_L s_mQ: the terms
    // are summed per pattern pair (mL, mP) along q first, then each pair spreads over the lines once.
    double x[16][n], y[16][n], z[16][n];
    unsigned pairs = 0;
    auto add = [&](double coefficient, const Vec3& normal, double offset, std::uint8_t mask) {
      const int mL = pattern(mask, axis_), mP = pattern(mask, other_[0]), mQ = pattern(mask, other_[1]);
      const int pair = 4 * mL + mP;
      if (!((pairs >> pair) & 1)) {
        pairs |= 1u << pair;
        for (int q = 0; q < n; ++q) x[pair][q] = y[pair][q] = z[pair][q] = 0;
      }
      for (int q = 0; q < n; ++q) {
        const double c = coefficient * s_[mQ][q];
        x[pair][q] += c * normal[other_[0]];
        y[pair][q] += c * (offset + normal[other_[1]] * t_[q]);
        z[pair][q] += c * normal[axis_];
      }
    };
    terms.forEach(add);
    for (unsigned rest = pairs; rest; rest &= rest - 1) {
      const int pair = __builtin_ctz(rest), mL = pair / 4, mP = pair % 4;
      const bool first = !((used_ >> mL) & 1);
      used_ |= 1u << mL;
      double* a = a_[static_cast<std::size_t>(mL)].data();
      double* b = b_[static_cast<std::size_t>(mL)].data();
      for (int q = 0; q < n; ++q)
        for (int p = 0; p < n; ++p) {
          const double da = s_[mP][p] * (t_[p] * x[pair][q] + y[pair][q]), db = s_[mP][p] * z[pair][q];
          a[p + n * q] = first ? da : a[p + n * q] + da;
          b[p + n * q] = first ? db : b[p + n * q] + db;
        }
    }
    central_ = pattern(terms.faceMask, axis_);
    const int cP = pattern(terms.faceMask, other_[0]), cQ = pattern(terms.faceMask, other_[1]);
    for (int q = 0; q < n; ++q)
      for (int p = 0; p < n; ++p) c_[static_cast<std::size_t>(p + n * q)] = s_[cP][p] * s_[cQ][q];
  }

  /// The cell lattice in line order: point i along the line axis on line (p, q) has index i + n (p + n q).
  static int index(int i, int p, int q) { return i + n * (p + n * q); }
  /// Cell-local position of lattice point `index`.
  Vec3 point(int index) const {
    Vec3 x;
    x[axis_] = Axis::coord(index % n);
    x[other_[0]] = Axis::coord(index / n % n);
    x[other_[1]] = Axis::coord(index / (n * n));
    return x;
  }
  /// Gradient (per local unit) of lattice values r at lattice point `index`, by central differences
  /// (one-sided at the lattice border).
  Vec3 gradient(const double* r, int index) const {
    const int c[3] = {index % n, index / n % n, index / (n * n)};
    const int axes[3] = {axis_, other_[0], other_[1]};
    Vec3 g;
    for (int k = 0; k < 3; ++k) {
      const int up = c[k] + 1 < n ? 1 : 0, down = c[k] > 0 ? 1 : 0, step = stride_[axes[k]];
      g[axes[k]] = (r[index + up * step] - r[index - down * step]) / (Axis::step * (up + down));
    }
    return g;
  }

  /// valueWithoutCentral and centralBasis at every lattice point.
  void lattice(double* __restrict value, double* __restrict basis) const {
    int patterns[4], numPatterns = 0;
    for (int m = 0; m < 4; ++m)
      if ((used_ >> m) & 1) patterns[numPatterns++] = m;
    for (int q = 0; q < n; ++q)
      for (int p = 0; p < n; ++p) {
        const std::size_t pq = static_cast<std::size_t>(p + n * q);
        double v[n];
        for (int i = 0; i < n; ++i) v[i] = 0;
        for (int k = 0; k < numPatterns; ++k) {
          const int m = patterns[k];
          const double a = a_[m][pq], b = b_[m][pq];
          for (int i = 0; i < n; ++i) v[i] += s_[m][i] * (a + t_[i] * b);
        }
        for (int i = 0; i < n; ++i) {
          value[index(i, p, q)] = v[i];
          basis[index(i, p, q)] = s_[central_][i] * c_[pq];
        }
      }
  }

  /// valueWithoutCentral (returned) and centralBasis at coordinate x along the line (p, q).
  double at(double x, int p, int q, double& basis) const {
    const std::size_t pq = static_cast<std::size_t>(p + n * q);
    const double x2 = x * x, y2 = (1 - x) * (1 - x), s[4] = {1, x2, y2, x2 * y2};  // squares(m, x)
    double v = 0;
    for (int m = 0; m < 4; ++m)
      if ((used_ >> m) & 1) v += s[m] * (a_[m][pq] + x * b_[m][pq]);
    basis = s[central_] * c_[pq];
    return v;
  }

 private:
  int axis_;
  std::array<int, 2> other_;
  std::array<int, 3> stride_;  ///< lattice index steps along x, y, z
  int central_ = 0;
  unsigned used_ = 0;
  double t_[n], s_[4][n];
  std::array<std::array<double, n * n>, 4> a_, b_;  ///< valid for the patterns in used_
  std::array<double, n * n> c_;                     ///< every entry set by the constructor
};

/// valueWithoutCentral and centralBasis of a patch on face f's lattice (face frame, index a + n b), by
/// separable products as in PatchLines.
template <class Axis, int n = Axis::n>
void patchFaceLattice(const LinearTerms& terms, int f, double* __restrict value, double* __restrict basis) {
  const int axis = cube::faceAxis(f);
  const double side = cube::faceSide(f);
  const auto uv = cube::otherAxes(axis);
  const LatticeSquares<Axis>& table = LatticeSquares<Axis>::get();  // the outputs alias nothing (restrict)
  const auto& t = table.t;
  const auto& sq = table.sq;
  // A term adds su[a] (t[a] X[b] + Y[b]) with X = across sv n_u and Y = across sv (constant + n_v t): the
  // terms are summed per pattern along u first (as in PatchLines).
  double x[4][n], y[4][n];
  unsigned patterns = 0;
  auto add = [&](double coefficient, const Vec3& normal, double offset, std::uint8_t mask) {
    const double across = coefficient * squares(pattern(mask, axis), side);
    if (across == 0) return;
    const int mu = pattern(mask, uv[0]);
    const double* sv = sq[pattern(mask, uv[1])];
    if (!((patterns >> mu) & 1)) {
      patterns |= 1u << mu;
      for (int b = 0; b < n; ++b) x[mu][b] = y[mu][b] = 0;
    }
    const double constant = normal[axis] * side + offset;
    for (int b = 0; b < n; ++b) {
      x[mu][b] += across * sv[b] * normal[uv[0]];
      y[mu][b] += across * sv[b] * (constant + normal[uv[1]] * t[b]);
    }
  };
  terms.forEach(add);
  std::fill(value, value + n * n, 0.0);
  for (unsigned rest = patterns; rest; rest &= rest - 1) {
    const int mu = __builtin_ctz(rest);
    for (int b = 0; b < n; ++b)
      for (int a = 0; a < n; ++a) value[a + n * b] += sq[mu][a] * (t[a] * x[mu][b] + y[mu][b]);
  }
  const double across = squares(pattern(terms.faceMask, axis), side);
  const double* su = sq[pattern(terms.faceMask, uv[0])];
  const double* sv = sq[pattern(terms.faceMask, uv[1])];
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) basis[a + n * b] = across * su[a] * sv[b];
}

/// valueWithoutCentral and centralBasis of a patch on face f at any point (u, v) of the face frame: each
/// term is a linear function of (u, v) times squared face planes across u and across v (patterns mu, mv),
/// so the terms of one pattern pair sum to one linear function. For the points off a lattice
/// (openFaceSamples' ridge points and searches): a few flops per pattern pair instead of every term's planes.
class FacePatch {
 public:
  /// Nothing set: set() makes it (a default-constructed member array is not zero-filled, unlike the storage
  /// of an empty std::optional, which the compiler cleared per open face).
  FacePatch() {}
  void set(const LinearTerms& terms, int f) {
    pairs_ = 0;
    const int axis = cube::faceAxis(f);
    const double side = cube::faceSide(f);
    const auto uv = cube::otherAxes(axis);
    terms.forEach([&](double coefficient, const Vec3& normal, double offset, std::uint8_t mask) {
      const double across = coefficient * squares(pattern(mask, axis), side);
      if (across == 0) return;
      const int pair = pattern(mask, uv[0]) + 4 * pattern(mask, uv[1]);
      Linear& l = linear_[pair];
      if (!((pairs_ >> pair) & 1)) {
        pairs_ |= 1u << pair;
        l = Linear{0, 0, 0};
      }
      l.u += across * normal[uv[0]];
      l.v += across * normal[uv[1]];
      l.constant += across * (normal[axis] * side + offset);
    });
    centralAcross_ = squares(pattern(terms.faceMask, axis), side);
    centralPair_ = pattern(terms.faceMask, uv[0]) + 4 * pattern(terms.faceMask, uv[1]);
  }
  /// valueWithoutCentral (first) and centralBasis (second) at (u, v).
  std::pair<double, double> at(double u, double v) const {
    const double su[4] = {1, u * u, (1 - u) * (1 - u), u * u * (1 - u) * (1 - u)};
    const double sv[4] = {1, v * v, (1 - v) * (1 - v), v * v * (1 - v) * (1 - v)};
    double value = 0;
    for (unsigned rest = pairs_; rest; rest &= rest - 1) {
      const int pair = __builtin_ctz(rest);
      const Linear& l = linear_[pair];
      value += su[pair & 3] * sv[pair >> 2] * (l.u * u + l.v * v + l.constant);
    }
    return {value, centralAcross_ * su[centralPair_ & 3] * sv[centralPair_ >> 2]};
  }

 private:
  struct Linear {  // no default values: an entry is cleared where its pair is first met
    double u, v, constant;
  };
  std::array<Linear, 16> linear_;  ///< per pattern pair mu + 4 mv; valid for the pairs in pairs_
  unsigned pairs_;
  double centralAcross_;
  int centralPair_;
};

/// A point (u, v) of a face, the bound -s A / C of the central coefficient there and A, C.
struct FacePeak {
  double u, v, bound, a, c;
};

/// A compass search from `start` for where the bound -sign A / C of the central coefficient on `face` is
/// highest, steps halving from `step` to `minStep`, kept on the face.
FacePeak climbBound(const FacePatch& face, double sign, FacePeak start, double step, double minStep) {
  FacePeak p = start;
  while (step > minStep) {
    bool moved = false;
    for (int dir = 0; dir < 4; ++dir) {
      const double u = std::clamp(p.u + (dir == 0 ? step : dir == 1 ? -step : 0.0), 0.0, 1.0);
      const double v = std::clamp(p.v + (dir == 2 ? step : dir == 3 ? -step : 0.0), 0.0, 1.0);
      const auto [a, c] = face.at(u, v);
      if (c > 0 && -sign * a / c > p.bound) {
        p = {u, v, -sign * a / c, a, c};
        moved = true;
      }
    }
    if (!moved) step *= 0.5;
  }
  return p;
}

/// Samples that openFaceSamples writes at most per face: the lattice, a point next to each lattice point of
/// the border and the end of one search per edge.
constexpr int kOpenFaceSamples = OpenFaceAxis::n * OpenFaceAxis::n + 4 * OpenFaceAxis::n + 4;

/// Sign samples of the central coefficient on face f of a cell, a face that is not a bounding plane, written
/// as the fit's samples are: the sign of the face's corners (`positive`) as +1 or -1 in r, the patch without
/// the central term A in a, the central basis C in b. The patch must keep that sign on the whole face: no
/// patch across continues a zero set that reaches it, so a wrong sign there is a hole. The samples are the
/// OpenFaceAxis lattice, border included (where C = 0, on the face's edges with bounding planes, the side
/// coefficients decide, uncrossedEdgeSamples, and the sample is written as met), and points next to such
/// edges where a ridge of the bound may lie: with s the sign, s (A + w C) > 0 means s w > -s A / C, and
/// next to the edge C grows with the squared distance d from it while A starts at its value A0 there, so
/// with A = A0 + A1 d + ..., s A0 > 0 and s A1 < 0 the bound rises to a narrow ridge near d = -2 A0 / A1,
/// often before the lattice's first row (A1 from the lattice's row kNearEdge inside). From the highest such
/// point of each edge a compass search follows the ridge (along the edge, and towards a corner where two
/// such edges meet), and its end is one more sample. Returns the number of samples (at most
/// kOpenFaceSamples).
int openFaceSamples(const LinearTerms& terms, int f, bool positive, double* r, double* a, double* b) {
  using Axis = OpenFaceAxis;
  constexpr int n = Axis::n;
  const double sign = positive ? 1.0 : -1.0;
  patchFaceLattice<Axis>(terms, f, a, b);
  FacePatch face;  // for the ridge points, set where the first is needed
  bool faceSet = false;
  const double* av = a;  // the lattice's A and C, read by the ridge search before the edges are replaced
  const double* cv = b;
  int count = n * n;
  auto add = [&](double aa, double cc) {
    r[count] = sign, a[count] = aa, b[count] = cc;
    ++count;
  };
  // The lattice index of point i along edge e (v = 0, v = 1, u = 0, u = 1), j rows in.
  auto edgeIndex = [](int e, int i, int j) {
    return e == 0 ? i + n * j : e == 1 ? i + n * (n - 1 - j) : e == 2 ? j + n * i : n - 1 - j + n * i;
  };
  unsigned planeEdges = 0;  // the edges with bounding planes
  for (int e = 0; e < 4; ++e) {
    // The face coordinates at position `along` on edge e and distance d from it, and edgeIndex on it.
    auto at = [&](double along, double d) {
      return e < 2 ? Vec2(along, e == 0 ? d : 1 - d) : Vec2(e == 2 ? d : 1 - d, along);
    };
    auto index = [&](int i, int j) { return edgeIndex(e, i, j); };
    if (cv[index(n / 2, 0)] > 0) continue;  // not an edge with a bounding plane
    planeEdges |= 1u << e;
    // The edge's ridge point with the highest bound: face coordinates, A, C and distance from the edge.
    double bu = 0, bv = 0, ba = 0, bc = 0, best = -std::numeric_limits<double>::infinity(), ridgeStep = 0;
    for (int i = 2; i < n - 2; ++i) {
      const double a0 = sign * av[index(i, 0)], slope = (sign * av[index(i, 1)] - a0) / kNearEdge;
      if (!(a0 > 0) || !(slope < 0) || !(-2 * a0 / slope < Axis::step)) continue;
      const double d = std::max(-2 * a0 / slope, kNearEdge);
      const Vec2 p = at(Axis::coord(i), d);
      if (!faceSet) face.set(terms, f), faceSet = true;
      const auto [aa, cc] = face.at(p.x(), p.y());
      add(aa, cc);
      if (cc > 0 && -sign * aa / cc > best)
        best = -sign * aa / cc, bu = p.x(), bv = p.y(), ba = aa, bc = cc, ridgeStep = d;
    }
    if (!(ridgeStep > 0)) continue;
    const FacePeak peak = climbBound(face, sign, {bu, bv, best, ba, bc}, 0.5 * ridgeStep, 1e-3 * ridgeStep);
    add(peak.a, peak.c);
  }
  std::fill(r, r + n * n, sign);
  // On an edge with a bounding plane C = 0, and the side coefficients decide (uncrossedEdgeSamples): the
  // samples there are written as met.
  for (int e = 0; e < 4; ++e)
    if ((planeEdges >> e) & 1)
      for (int i = 0; i < n; ++i) a[edgeIndex(e, i, 0)] = sign;
  return count;
}

constexpr int kLattice = CellAxis::n * CellAxis::n * CellAxis::n;
constexpr int kStaggered = StaggeredCellAxis::n * StaggeredCellAxis::n * StaggeredCellAxis::n;
constexpr int kOpen = 6 * kOpenFaceSamples;
/// The lattice on which a coefficient chosen with the open faces' samples is checked
/// (CellFit::verifyOpenFaces): 1/16 apart, border included.
struct DenseFaceAxis {
  static constexpr int n = 17;
  static constexpr double coord(int i) { return i / 16.0; }
};
/// How close to an open face, relative to its samples' magnitudes, a patch must come for a value that passes
/// the samples to be checked between them (CellFit::closeOpenFaces).
constexpr double kCloseToOpenFace = 0.1;
/// Checks of verifyOpenFaces per solve; each adds at most one sample per open face.
constexpr int kVerifyRounds = 3;
/// Room for the samples verifyOpenFaces adds, after the open faces' and after the staggered lattice's.
constexpr int kVerified = 2 * 6 * kVerifyRounds;

/// The samples of one cell's central coefficient and the tests the constraint solver asks of them. Samples:
/// the inset cell lattice, then the samples of each of the cell's faces that are not bounding planes (no
/// crossing on their edges: the cell across has no patch there or none that joins this one, so a wrong sign
/// anywhere on such a face is a hole; openFaceSamples) and the points between them where a value dipped
/// through such a face (verifyOpenFaces). After them, where the cell lattice suggests it (secondLook), the
/// staggered lattice (and again such points).
class CellFit {
 public:
  CellFit(const CornerPatch& patch, std::uint8_t config, const CellReference& ref);

  /// The least-squares central coefficient (0 without fit points).
  double leastSquares() const;
  /// The first `count` samples, for the solver.
  SignSamples samples(int count) const { return {r_.data(), value_.data(), basis_.data(), count}; }
  /// The cell lattice alone: where no value meets it, the cell is unresolved.
  SignedCoefficient solveLattice(SignConstraintSolver& solver, double fitted) {
    return solver.solve(fitted, samples(kLattice), farTest(), confirmFarTest());
  }
  /// The value that the fewest of the lattice's samples and the open faces' agreeing points contradict,
  /// nearest to 0 (better than the fit there: Marschner-Lobb at N = 32 exact has 0 wrong-sign cells with 0,
  /// 96 with the fit).
  double leastContradictedAgreeing() {
    const SignSamples agreeing = samples(gatherAgreeing());
    return leastContradicted(0.0, agreeing, farTest(), confirmFarTest());
  }
  SignedCoefficient joinOpenFaces(SignConstraintSolver& solver, SignConstraintSolver& latticeOnly,
                                  double fitted, const SignedCoefficient& lattice, int& used);
  /// Solves with the first `end` samples, then, while the value dips through an open face between the
  /// samples (verifyOpenFaces), with those points too; `end` grows by the points added.
  SignedCoefficient solveVerified(SignConstraintSolver& solver, double fitted, int& end);
  CellResult secondLook(SignConstraintSolver& solver, SignConstraintSolver& latticeOnly, double fitted,
                        const SignedCoefficient& before, int used);

 private:
  static int fitAxisOf(const CornerPatch& patch);
  int verifyOpenFaces(double w, int end, unsigned faces);
  unsigned closeOpenFaces(double w) const;
  bool staggeredSample(int i) const {
    return staggeredBegin_ >= 0 && i >= staggeredBegin_ && i < staggeredBegin_ + kStaggered;
  }
  Vec3 openPoint(int i) const {
    const auto [f, j] = faceOf_[static_cast<std::size_t>(i - kLattice)];
    return faceLatticePoint<OpenFaceAxis>(f, j % OpenFaceAxis::n, j / OpenFaceAxis::n);
  }
  Vec3 position(int i) const {
    if (i < kLattice) return lines_.point(i);
    if (!staggeredSample(i)) return openPoint(i);  // softOpen
    return staggeredLines_->point(i - staggeredBegin_);
  }
  bool far(int i) const;
  bool confirmFar(int i) const;
  /// far and confirmFar as the solver takes them.
  struct FarTest {
    const CellFit* fit;
    bool operator()(int i) const { return fit->far(i); }
  };
  struct ConfirmFarTest {
    const CellFit* fit;
    bool operator()(int i) const { return fit->confirmFar(i); }
  };
  FarTest farTest() const { return {this}; }
  ConfirmFarTest confirmFarTest() const { return {this}; }
  int gatherAgreeing();

  const CellReference& ref_;
  int fitAxis_;
  int lineAxes_[3];
  LinearTerms terms_;
  PatchLines<CellAxis> lines_;
  LatticeLayout cellLayout_;
  std::array<double, kLattice + kOpen + kStaggered + kVerified> r_, value_, basis_;  // set as they are used
  // The open faces' samples, face after face (the first OpenFaceAxis::n^2 of each are its lattice).
  int count_ = kLattice, numOpen_ = 0;
  std::array<std::array<int, 2>, 6> open_;  // face, first sample
  // The staggered lattice's patch lines and where its samples begin, while the second look has them (a
  // pointer rather than an optional: the optional's storage, 2 KB, was zero-filled in every cell).
  const PatchLines<StaggeredCellAxis>* staggeredLines_ = nullptr;
  int staggeredBegin_ = -1;
  // Where the open faces cannot be met with the lattice, their lattice points where the reference agrees
  // with the corners take their place as reference samples (gatherAgreeing): `softOpen_`, and per such
  // sample its face and index on the face's lattice.
  bool softOpen_ = false;
  std::array<std::array<int, 2>, 6 * OpenFaceAxis::n * OpenFaceAxis::n> faceOf_;
};

/// Fit points lie on the lattice lines along the axis closest to the mean corner normal.
int CellFit::fitAxisOf(const CornerPatch& patch) {
  Vec3 meanNormal = Vec3::Zero();
  for (int k = 0; k < patch.numCorners; ++k) meanNormal += patch.normal[k];
  int fitAxis = 0;
  meanNormal.cwiseAbs().maxCoeff(&fitAxis);
  return fitAxis;
}

CellFit::CellFit(const CornerPatch& patch, std::uint8_t config, const CellReference& ref)
    : ref_(ref),
      fitAxis_(fitAxisOf(patch)),
      lineAxes_{fitAxis_, cube::otherAxes(fitAxis_)[0], cube::otherAxes(fitAxis_)[1]},
      terms_(patch),
      lines_(terms_, fitAxis_),
      cellLayout_(LatticeLayout::of<CellAxis>(3, lineAxes_, ref.metric)) {
  referenceCellLattice<CellAxis>(ref, fitAxis_, r_.data());
  lines_.lattice(value_.data(), basis_.data());
  for (int f = 0; f < 6; ++f)
    if (!((patch.faceMask >> f) & 1)) {
      open_[static_cast<std::size_t>(numOpen_++)] = {f, count_};
      count_ += openFaceSamples(terms_, f, (config >> cube::faceVertex(f, 0)) & 1, &r_[count_],
                                &value_[count_], &basis_[count_]);
    }
}

/// Least-squares fit to the reference surface points between lattice neighbours along the fit axis (linear
/// interpolation of the reference), where the patch is evaluated exactly.
double CellFit::leastSquares() const {
  constexpr int n = CellAxis::n;
  double num = 0, den = 0;
  int fitCount = 0;
  // Sign changes along the lines as bits (few lines cross the surface: no branch per pair); line (p, q) is
  // the n bits from lines.index(0, p, q) on.
  std::array<std::uint64_t, (kLattice + 63) / 64> positive;
  for (int w = 0; w < (kLattice + 63) / 64; ++w)
    positive[static_cast<std::size_t>(w)] = positiveBits(r_.data() + 64 * w, std::min(64, kLattice - 64 * w));
  for (int q = 0; q < n; ++q)
    for (int p = 0; p < n; ++p) {
      const int start = lines_.index(0, p, q), word = start / 64, shift = start % 64;
      std::uint64_t line = positive[static_cast<std::size_t>(word)] >> shift;
      if (shift + n > 64) line |= positive[static_cast<std::size_t>(word + 1)] << (64 - shift);
      const auto signs = static_cast<unsigned>(line & ((1u << n) - 1));
      for (unsigned changes = (signs ^ (signs >> 1)) & ((1u << (n - 1)) - 1); changes;
           changes &= changes - 1) {
        const int i = __builtin_ctz(changes);
        const double r0 = r_[static_cast<std::size_t>(lines_.index(i, p, q))];
        const double r1 = r_[static_cast<std::size_t>(lines_.index(i + 1, p, q))];
        double b;
        const double v = lines_.at(CellAxis::coord(i) + r0 / (r0 - r1) * CellAxis::step, p, q, b);
        num += v * b;
        den += b * b;
        ++fitCount;
      }
    }
  const double cCentre = centreSquares(terms_.faceMask);  // patch.centralBasis((0.5, 0.5, 0.5))
  den += kRidge * cCentre * cCentre * std::max(1, fitCount);
  return fitCount > 0 ? -num / den : 0.0;
}

/// Samples within the margin by the first-order estimate are left free, but where the clamped coefficient
/// gives one of them the wrong sign, the estimate is checked by Newton steps on the reference (confirmFar);
/// a sample that turns out farther than kVerifiedVoxels from the surface counts after all.
bool CellFit::far(int i) const {
  if (i >= kLattice && !staggeredSample(i)) {
    if (!softOpen_) return true;  // an open-face sample counts always
    const auto [f, j] = faceOf_[static_cast<std::size_t>(i - kLattice)];
    return farFromSurface(ref_, r_[static_cast<std::size_t>(i)],
                          faceGradient(ref_, f, OpenFaceAxis::coord(j % OpenFaceAxis::n),
                                       OpenFaceAxis::coord(j / OpenFaceAxis::n)));
  }
  const Vec3 g = i < kLattice ? lines_.gradient(r_.data(), i)
                              : staggeredLines_->gradient(r_.data() + staggeredBegin_, i - staggeredBegin_);
  return farFromSurface(ref_, r_[static_cast<std::size_t>(i)], g);
}

bool CellFit::confirmFar(int i) const {
  if (i >= kLattice && !staggeredSample(i))  // softOpen: Newton steps only
    return !referenceSurfaceWithin(ref_, openPoint(i), r_[static_cast<std::size_t>(i)], kVerifiedVoxels);
  const bool near = i < kLattice
                        ? neighbourCrosses(r_.data(), i, cellLayout_, kVerifiedVoxels)
                        : neighbourCrosses(r_.data() + staggeredBegin_, i - staggeredBegin_,
                                           LatticeLayout::of<StaggeredCellAxis>(3, lineAxes_, ref_.metric),
                                           kVerifiedVoxels);
  return !near &&
         !referenceSurfaceWithin(ref_, position(i), r_[static_cast<std::size_t>(i)], kVerifiedVoxels);
}

/// The open faces' lattice points where the reference agrees with the corners, as reference samples from
/// index kLattice on (over the open faces' own samples); returns the end of the samples.
int CellFit::gatherAgreeing() {
  constexpr int nf = OpenFaceAxis::n;
  int kept = kLattice;
  for (int k = 0; k < numOpen_; ++k) {
    std::array<double, nf * nf> reference;
    referenceFaceLattice<OpenFaceAxis>(ref_, open_[static_cast<std::size_t>(k)][0], reference.data());
    for (int j = 0; j < nf * nf; ++j) {
      const int i = open_[static_cast<std::size_t>(k)][1] + j;
      if ((reference[static_cast<std::size_t>(j)] > 0) != (r_[static_cast<std::size_t>(i)] > 0)) continue;
      r_[static_cast<std::size_t>(kept)] = reference[static_cast<std::size_t>(j)];
      value_[static_cast<std::size_t>(kept)] = value_[static_cast<std::size_t>(i)];
      basis_[static_cast<std::size_t>(kept)] = basis_[static_cast<std::size_t>(i)];
      faceOf_[static_cast<std::size_t>(kept - kLattice)] = {open_[static_cast<std::size_t>(k)][0], j};
      ++kept;
    }
  }
  softOpen_ = true;
  return kept;
}

/// The open faces' samples are a lattice 1/3 apart, and a patch that the lattice pulls towards an open face
/// can dip through it between them (a hole the samples do not see). Where the coefficient `w` gives the
/// patch the other sign than the face's corners at a point of an open face's DenseFaceAxis lattice where
/// the central basis C > 0, the point of the face where the bound -s A / C of w is highest, by a compass
/// search from the worst such lattice point, is written as one more sample at index `end` on; only the open
/// faces of `faces` (bit k: the k-th) are checked. Returns the end of the samples. (The samples' sign is the
/// corners': r of the face's first open sample.)
int CellFit::verifyOpenFaces(double w, int end, unsigned faces) {
  constexpr int n = DenseFaceAxis::n;
  for (int k = 0; k < numOpen_ && end < static_cast<int>(r_.size()); ++k) {
    if (!((faces >> k) & 1)) continue;
    const auto [f, firstSample] = open_[static_cast<std::size_t>(k)];
    const double sign = r_[static_cast<std::size_t>(firstSample)];
    std::array<double, n * n> a, c;
    patchFaceLattice<DenseFaceAxis>(terms_, f, a.data(), c.data());
    int worst = -1;
    double best = 0;
    for (int i = 0; i < n * n; ++i) {
      const double ai = a[static_cast<std::size_t>(i)], ci = c[static_cast<std::size_t>(i)];
      if (!(ci > 0) || sign * (ai + w * ci) > 0) continue;
      if (worst < 0 || -sign * ai / ci > best) worst = i, best = -sign * ai / ci;
    }
    if (worst < 0) continue;
    FacePatch face;
    face.set(terms_, f);
    const double u = DenseFaceAxis::coord(worst % n), v = DenseFaceAxis::coord(worst / n);
    const auto [a0, c0] = face.at(u, v);
    const FacePeak peak = climbBound(face, sign, {u, v, best, a0, c0}, 0.5 / (n - 1), 1e-4);
    const auto i = static_cast<std::size_t>(end++);
    r_[i] = sign, value_[i] = peak.a, basis_[i] = peak.c;
  }
  return end;
}

/// The open faces (bit k: the k-th) on which, with coefficient `w`, the patch comes close to the other sign:
/// at one of the face's regular samples where the central basis C > 0 (the rows kNearEdge inside the border
/// left out, where the patch starts from 0 on an edge with a bounding plane) its value with the corners' sign
/// is below kCloseToOpenFace times the largest magnitude of the regular samples, border included. Elsewhere
/// the samples pass with room and the dips verifyOpenFaces looks for are rare (checked in every cell, those
/// found came below 0.01 on the torus at N = 64, 16 of 16, and below 0.1 in 3 of 7 on the smoke at 0.1 and 1
/// of 1 on the CT head at 1150).
unsigned CellFit::closeOpenFaces(double w) const {
  constexpr int n = OpenFaceAxis::n;
  unsigned close = 0;
  for (int k = 0; k < numOpen_; ++k) {
    const int first = open_[static_cast<std::size_t>(k)][1];
    double low = std::numeric_limits<double>::infinity(), high = 0;
    for (int j = 0; j < n * n; ++j) {
      const int a = j % n, b = j / n;
      if (a == 1 || a == n - 2 || b == 1 || b == n - 2) continue;
      const auto i = static_cast<std::size_t>(first + j);
      const double v = r_[i] * (value_[i] + w * basis_[i]);
      if (basis_[i] > 0) low = std::min(low, v);
      high = std::max(high, std::abs(v));
    }
    if (low < kCloseToOpenFace * high) close |= 1u << k;
  }
  return close;
}

SignedCoefficient CellFit::solveVerified(SignConstraintSolver& solver, double fitted, int& end) {
  SignedCoefficient sc = solver.solve(fitted, samples(end), farTest(), confirmFarTest());
  for (int round = 0; sc.feasible && round < kVerifyRounds; ++round) {
    const unsigned close = closeOpenFaces(sc.value);
    if (!close) break;
    const int before = end;
    end = verifyOpenFaces(sc.value, end, close);
    if (end == before) break;
    sc = solver.solve(fitted, samples(end), farTest(), confirmFarTest());
  }
  return sc;
}

/// The open faces' samples join where the lattice's coefficient fails one of them, or where it dips through
/// an open face between them (verifyOpenFaces), and every value chosen with them is checked so too. Where no
/// value meets them with the lattice (the reference crosses an open face or bulges towards it with sign
/// structure the cell's loops do not have, as on Marschner-Lobb, or the patch without the central term is too
/// far off there), the open faces' lattice points count only where the reference has the corners' sign too,
/// and only where they lie away from its surface, as the cell lattice's do. Where not even those can be met,
/// the lattice decides. Either way the patch may cross the face there, a hole (docs/method.md, "Holes");
/// failing the cell instead makes the fallback rounds blend normals, which spread failures (Marschner-Lobb
/// at N = 32 exact: 16 more unresolved cells, 144 blended isovertices and 0.3 degrees more normal error).
/// Sets `used` to the samples the solver knows, from index 0; `latticeOnly` keeps it as it was after the
/// lattice.
SignedCoefficient CellFit::joinOpenFaces(SignConstraintSolver& solver, SignConstraintSolver& latticeOnly,
                                         double fitted, const SignedCoefficient& lattice, int& used) {
  SignedCoefficient sc = lattice;
  used = kLattice;
  std::array<std::uint64_t, (kOpen + 63) / 64> failing;
  const bool openFails = count_ > kLattice &&
                         slackSweep({&r_[kLattice], &value_[kLattice], &basis_[kLattice], count_ - kLattice},
                                    lattice.value, failing.data()) > 0;
  if (!openFails) {
    // The samples pass; the patch may still dip through an open face between them where it comes close to
    // the face (closeOpenFaces).
    const unsigned close = closeOpenFaces(lattice.value);
    if (!close) return sc;
    const int end = verifyOpenFaces(lattice.value, count_, close);
    if (end == count_) return sc;
    count_ = end;
  }
  latticeOnly = solver;
  sc = solveVerified(solver, fitted, count_);
  used = count_;
  if (!sc.feasible) {
    solver = latticeOnly;
    used = gatherAgreeing();
    sc = solver.solve(fitted, samples(used), farTest(), confirmFarTest());
  }
  if (!sc.feasible) {
    solver = latticeOnly;
    sc = lattice;
    used = kLattice;
  }
  return sc;
}

/// A second look, between the lattice points: where the clamping found kStaggeredTrigger or more samples on
/// the wrong side that lie near the surface, the patch and the reference part ways inside the cell, and a
/// wrong sign farther out can hide between the lattice points. The staggered lattice (with the cell
/// lattice, a body-centred one) joins the samples; where no value meets it with the open faces' samples,
/// it is tried with the lattice alone, as in joinOpenFaces. If no coefficient meets the lattices, the cell is
/// unresolved, so that the fallback rounds blend its normals; it keeps the coefficient it had before the
/// second look meanwhile, and at the end if it stays unresolved.
CellResult CellFit::secondLook(SignConstraintSolver& solver, SignConstraintSolver& latticeOnly, double fitted,
                               const SignedCoefficient& before, int used) {
  const PatchLines<StaggeredCellAxis> staggered(terms_, fitAxis_);
  staggeredLines_ = &staggered;
  staggeredBegin_ = used;
  referenceCellLattice<StaggeredCellAxis>(ref_, fitAxis_, r_.data() + staggeredBegin_);
  staggeredLines_->lattice(value_.data() + staggeredBegin_, basis_.data() + staggeredBegin_);
  // With the open faces' own samples, checked between them as in joinOpenFaces (after the staggered lattice).
  int end = used + kStaggered;
  SignedCoefficient sc = used > kLattice && !softOpen_
                             ? solveVerified(solver, fitted, end)
                             : solver.solve(fitted, samples(end), farTest(), confirmFarTest());
  if (!sc.feasible && used > kLattice) {
    std::copy_n(r_.data() + staggeredBegin_, kStaggered, r_.data() + kLattice);
    std::copy_n(value_.data() + staggeredBegin_, kStaggered, value_.data() + kLattice);
    std::copy_n(basis_.data() + staggeredBegin_, kStaggered, basis_.data() + kLattice);
    staggeredBegin_ = kLattice;
    sc = latticeOnly.solve(fitted, samples(kLattice + kStaggered), farTest(), confirmFarTest());
  }
  staggeredLines_ = nullptr;  // `staggered` ends here; no sample is examined after it
  if (!sc.feasible) return CellResult{before.value, false};
  return CellResult{sc.value, true};
}

}  // namespace

CellResult fitCell(const CornerPatch& patch, std::uint8_t config, const CellReference& ref,
                   bool fallBackToLeastContradicted) {
  CellFit fit(patch, config, ref);
  const double fitted = fit.leastSquares();
  // The lattice first. Where no value meets it, the cell is unresolved; the last fallback takes the value
  // that the fewest of its samples and the open faces' agreeing points contradict.
  thread_local SignConstraintSolver solver, latticeOnly;
  solver.reset();
  const SignedCoefficient lattice = fit.solveLattice(solver, fitted);
  if (!lattice.feasible) {
    if (!fallBackToLeastContradicted) return CellResult{0.0, false};
    return CellResult{fit.leastContradictedAgreeing(), false};
  }
  // Then the open faces' samples, where the lattice's coefficient fails one of them.
  int used;
  const SignedCoefficient sc = fit.joinOpenFaces(solver, latticeOnly, fitted, lattice, used);
  // Then, where the clamping found kStaggeredTrigger or more samples near the surface on the wrong side, a
  // second look between the lattice points.
  if (solver.confirmedNear() < kStaggeredTrigger) return CellResult{sc.value, true};
  return fit.secondLook(solver, latticeOnly, fitted, sc, used);
}

}  // namespace cip
