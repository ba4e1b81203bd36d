#include "cip/patch/face_fit.h"

#include <algorithm>
#include <array>
#include <cstdint>

#include "cip/patch/fit_lattice.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/patch/sign_constraints.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

using namespace fit_lattice;

/// Samples per axis of the sign checks on a face (kFaceLattice^2).
constexpr int kFaceLattice = 7;
using FaceAxis = LatticeAxis<kFaceLattice, kFaceLattice, 1>;

/// faceRestriction at the face lattice (index a + n b), by separable products: the perpendicular planes of
/// canonical edges 0, 1 depend on v only (v, 1 - v), those of edges 2, 3 on u only (u, 1 - u).
template <class Axis, int n = Axis::n>
CIP_VECTOR_CLONES void faceRestrictionLattice(const FaceCrossings& face, double* __restrict cornerPart,
                                              double* __restrict sideBasis) {
  // The product of the squared perpendicular planes of a set of crossed edges: those of edges 0, 1 (v, 1 - v)
  // depend on v, those of edges 2, 3 (u, 1 - u) on u, so it is su[a] sv[b] with the squares of
  // LatticeSquares for the patterns (edges >> 2) & 3 along u and edges & 3 along v.
  const LatticeSquares<Axis>& table = LatticeSquares<Axis>::get();  // the outputs alias nothing (restrict)
  const auto& t = table.t;
  const double* u = table.sq[(face.crossed >> 2) & 3];
  const double* v = table.sq[face.crossed & 3];
  for (int b = 0; b < n; ++b)
    for (int a = 0; a < n; ++a) {
      sideBasis[static_cast<std::size_t>(a + n * b)] = u[a] * v[b];
      cornerPart[static_cast<std::size_t>(a + n * b)] = 0;
    }
  for (int k = 0; k < 4; ++k) {
    if (!((face.crossed >> k) & 1)) continue;
    const unsigned others = face.crossed & ~(1u << k);
    u = table.sq[(others >> 2) & 3];
    v = table.sq[others & 3];
    const Vec2 normal = face.weight[k] * face.normal[k];
    const double nu = normal.x(), nv = normal.y(), offset = -normal.dot(face.point[k]);
    for (int b = 0; b < n; ++b) {
      const double along = nv * t[b], across = v[b];
      double* row = cornerPart + n * b;
      for (int a = 0; a < n; ++a) row[a] += (nu * t[a] + along + offset) * u[a] * across;
    }
  }
}

/// Points per canonical edge of a face for uncrossedEdgeSamples, ends included.
constexpr int kEdgePoints = 9;

/// The canonical vertex (a + 2 b at (u, v) = (a, b)) at the start of canonical edge k.
constexpr int kEdgeStartVertex[4] = {0, 2, 0, 1};

/// The point at parameter t of canonical edge k of a face (face frame).
Vec2 canonicalEdgePoint(int k, double t) {
  const double fixed = k & 1;
  return k < 2 ? Vec2(t, fixed) : Vec2(fixed, t);
}

/// The 7 points inside an edge at which referenceKeepsEdgeSign looks: 1/8 apart.
struct EdgeCheckAxis {
  static constexpr int n = 7;
  static constexpr double coord(int i) { return (i + 1) / 8.0; }
};

/// Whether the reference keeps the sign of the vertices (`positive`) along canonical edge k of face f of a
/// cell, at 7 points inside it. Where it does not, the reference surface itself crosses the edge (twice:
/// the configuration calls it uncrossed), and a side coefficient made to keep the vertices' sign along it
/// parts the patch from the reference there (Marschner-Lobb, whose ripples cross many such edges: 0.8
/// degrees more mean normal error at N = 64 in exact mode).
bool referenceKeepsEdgeSign(const CellReference& ref, int f, int k, bool positive) {
  const int e = cube::faceEdge(f, k), axis = cube::edgeAxis(e);
  const auto others = cube::otherAxes(axis);
  Vec3 x;
  x[others[0]] = e & 1;
  x[others[1]] = (e >> 1) & 1;
  constexpr int stride[3] = {1, 4, 16};
  // The reference along the edge is the cubic Hermite segment of its end data (values and slopes along it).
  const LatticeWeights<EdgeCheckAxis>& weights = LatticeWeights<EdgeCheckAxis>::get();
  double r[7];
  if (ref.field) {  // the 7 points as a lattice, which fields evaluate faster than point by point
    double along[7], fixed[2];
    const GridGeometry& g = *ref.geometry;
    for (int j = 0; j < 7; ++j)
      along[j] = g.origin[axis] + g.spacing[axis] * (ref.origin[axis] + EdgeCheckAxis::coord(j));
    for (int i = 0; i < 2; ++i)
      fixed[i] = g.origin[others[i]] + g.spacing[others[i]] * (ref.origin[others[i]] + x[others[i]]);
    const double* coordinate[3];
    std::array<int, 3> count{1, 1, 1}, strides{0, 0, 0};
    coordinate[axis] = along;
    coordinate[others[0]] = &fixed[0];
    coordinate[others[1]] = &fixed[1];
    count[axis] = 7;
    strides[axis] = 1;
    analyticLattice(ref, coordinate, count, strides, r);
  } else {
    const double* h =
        ref.hermite.data() + 2 * (e & 1) * stride[others[0]] + 2 * ((e >> 1) & 1) * stride[others[1]];
    const int s = stride[axis];
    for (int j = 0; j < 7; ++j) {
      const double* w = weights.w[j];
      r[j] = w[0] * h[0] + w[1] * h[s] + w[2] * h[2 * s] + w[3] * h[3 * s] - ref.isovalue;
    }
  }
  for (int j = 0; j < 7; ++j)
    if ((r[j] > 0) != positive) return false;
  return true;
}

/// Sign samples on canonical edge k of a face, an edge without a crossing (kEdgePoints of them), written as
/// the fit's samples are: the sign wanted (+1 or -1: that of the edge's vertices, `positive`) in r, the face
/// restriction's corner part R in a and its side basis D in b. On such an edge the patch is the face
/// restriction times a factor > 0, or, where the edge lies on a second bounding plane, zero along the edge
/// itself and the restrictions of both faces times the squared distance from each next to it. Either way a
/// restriction of the wrong sign on the edge puts the patch's zero set on a face that no neighbouring patch
/// continues: a hole. Ends where D = 0 (next to a crossing, where the corner planes alone decide) are left
/// out unless the corner planes give them the wrong sign (then no coefficient meets them); in their place a
/// point where the bound of w peaks next to such an end may follow (below). The kEdgePoints - 2 points inside
/// the edge come first, then the ends (or their ridge points). Returns the number of samples (at most
/// kEdgePoints).
int uncrossedEdgeSamples(const FaceCrossings& fc, int k, bool positive, double* r, double* a, double* b) {
  // The edge's points (t = j / (kEdgePoints - 1)), and a point kNearEdge inside each end for the slope there.
  constexpr int m = kEdgePoints + 2, kStart = kEdgePoints, kEnd = kEdgePoints + 1;
  double t[m];
  for (int j = 0; j < kEdgePoints; ++j) t[j] = static_cast<double>(j) / (kEdgePoints - 1);
  t[kStart] = kNearEdge;
  t[kEnd] = 1 - kNearEdge;
  int count = 0;
  const double sign = positive ? 1.0 : -1.0;
  // faceRestriction at the points, all at once. The squared perpendicular planes of canonical edges 0..3
  // are v^2, (1 - v)^2, u^2, (1 - u)^2; along this edge the one of the parallel edge is 1 (that of the
  // edge itself, uncrossed, is not used), those of the two perpendicular edges t^2 and (1 - t)^2.
  const double fixed = k & 1;
  const int first = k < 2 ? 2 : 0;  // the perpendicular edges: first (at t = 0) and first + 1 (at t = 1)
  double square[2][m], cornerPart[m], sideBasis[m];
  for (int j = 0; j < m; ++j) {
    square[0][j] = t[j] * t[j];
    square[1][j] = (1 - t[j]) * (1 - t[j]);
    cornerPart[j] = 0;
    sideBasis[j] = 1;
  }
  auto perpendicularSquare = [&](int c) -> const double* {
    return c == first ? square[0] : c == first + 1 ? square[1] : nullptr;  // null: the parallel edge, 1
  };
  for (int c = 0; c < 4; ++c) {
    if (!((fc.crossed >> c) & 1)) continue;
    const Vec2 n = fc.weight[c] * fc.normal[c];
    const double along = k < 2 ? n.x() : n.y(), offset = (k < 2 ? n.y() : n.x()) * fixed - n.dot(fc.point[c]);
    double term[m];
    for (int j = 0; j < m; ++j) term[j] = along * t[j] + offset;
    for (int o = 0; o < 4; ++o) {
      if (o == c || !((fc.crossed >> o) & 1)) continue;
      if (const double* sq = perpendicularSquare(o))
        for (int j = 0; j < m; ++j) term[j] *= sq[j];
    }
    for (int j = 0; j < m; ++j) cornerPart[j] += term[j];
    if (const double* sq = perpendicularSquare(c))
      for (int j = 0; j < m; ++j) sideBasis[j] *= sq[j];
  }
  auto add = [&](double cp, double sb) {
    r[count] = sign, a[count] = cp, b[count] = sb;
    ++count;
  };
  for (int j = 1; j < kEdgePoints - 1; ++j) add(cornerPart[j], sideBasis[j]);  // D > 0 inside
  for (int j : {0, kEdgePoints - 1}) {
    if (sideBasis[j] > 0 || sign * cornerPart[j] < 0) {
      add(cornerPart[j], sideBasis[j]);
      continue;
    }
    // An end next to a crossing (D = 0 there, and D grows with the squared distance d from it) with R of
    // the right sign or 0: where R starts towards the other sign, R = R0 + R1 d + ... (s R0 >= 0,
    // s R1 < 0), the bound -s R / D rises to a narrow ridge near d = -2 R0 / R1, often before the next
    // point. That point is a sample (R1 from the point kNearEdge inside).
    const double r0 = sign * cornerPart[j], r1 = (sign * cornerPart[j == 0 ? kStart : kEnd] - r0) / kNearEdge;
    if (!(r1 < 0) || !(-2 * r0 / r1 < 1.0 / (kEdgePoints - 1))) continue;
    const double d = std::max(-2 * r0 / r1, kNearEdge);
    const FaceRestriction fr = faceRestriction(fc, canonicalEdgePoint(k, j == 0 ? d : 1 - d));
    add(fr.cornerPart, fr.sideBasis);
  }
  return count;
}

/// A face's sign samples: its FaceAxis lattice, then the samples of the uncrossed edges that join them
/// (uncrossedEdgeSamples), as the fit's samples are (r, the face restriction's corner part R and side basis
/// D).
struct FaceSamples {
  static constexpr int kLattice = FaceAxis::n * FaceAxis::n;
  std::array<double, kLattice + 2 * kEdgePoints> r, cornerPart, sideBasis;  // set as they are used
  SignSamples first(int count) const { return {r.data(), cornerPart.data(), sideBasis.data(), count}; }
};

/// The least-squares side coefficient of a face with crossings `fc` against the reference values `r` on its
/// lattice: the face restriction R + w D fitted to reference face-curve points, with a ridge term towards 0.
double fittedSide(const FaceCrossings& fc, const double* r) {
  using Axis = FaceAxis;
  constexpr int n = Axis::n;
  // Reference face-curve points: sign changes between neighbouring samples, linearly interpolated.
  double num = 0, den = 0;
  int fitCount = 0;
  auto addPoint = [&](const Vec2& q) {
    const FaceRestriction fr = faceRestriction(fc, q);
    num += fr.cornerPart * fr.sideBasis;
    den += fr.sideBasis * fr.sideBasis;
    ++fitCount;
  };
  auto addFit = [&](const Vec2& q0, double r0, const Vec2& q1, double r1) {
    addPoint(q0 + r0 / (r0 - r1) * (q1 - q0));
  };
  // Sign changes between lattice neighbours as bits (most pairs have none: no branch per pair), visited in
  // lattice order.
  static_assert(n * n <= 64, "face lattice signs in one word");
  const std::uint64_t signs = positiveBits(r, n * n);
  std::uint64_t lastColumn = 0;
  for (int b = 0; b < n; ++b) lastColumn |= std::uint64_t{1} << (n - 1 + n * b);
  const std::uint64_t alongU = (signs ^ (signs >> 1)) & ~lastColumn & ((std::uint64_t{1} << (n * n)) - 1);
  const std::uint64_t alongV = (signs ^ (signs >> n)) & ((std::uint64_t{1} << (n * (n - 1))) - 1);
  for (std::uint64_t pairs = alongU | alongV; pairs; pairs &= pairs - 1) {
    const int k = __builtin_ctzll(pairs), a = k % n, b = k / n;
    const Vec2 q(Axis::coord(a), Axis::coord(b));
    if ((alongU >> k) & 1) addFit(q, r[k], Vec2(Axis::coord(a + 1), q.y()), r[k + 1]);
    if ((alongV >> k) & 1) addFit(q, r[k], Vec2(q.x(), Axis::coord(b + 1)), r[k + n]);
  }
  if (fitCount == 0) {
    // The reference curve passes between the samples (close to a face vertex): use the side points instead.
    std::array<std::array<int, 2>, 2> segments;
    int numSegments = faceSegments(fc, segments);
    for (int k = 0; k < numSegments; ++k) addPoint(sidePoint(fc, segments[k][0], segments[k][1]));
  }
  // Ridge term towards 0 at the scale of the side basis at the face centre: where every fit point has a tiny
  // side basis (a face curve hugging a face vertex) w hardly moves the face curve but would still weigh on
  // the interior.
  const double dCentre = centreSquares(fc.crossed);  // faceRestriction(fc, (0.5, 0.5)).sideBasis
  den += kRidge * dCentre * dCentre * std::max(1, fitCount);
  return -num / den;
}

/// The face's edges without a crossing: there the face restriction must keep the sign of the edge's vertices
/// everywhere, or the patch's zero set reaches the edge, where no patch continues it (a hole; see
/// uncrossedEdgeSamples). An edge whose samples the lattice's coefficient `w` fails joins the samples of `s`
/// after the lattice (they count always), unless the reference itself crosses it (referenceKeepsEdgeSign).
/// Returns the number of samples; sets `pointFails` to the joined edges with the wrong sign inside (not only
/// at an end, where an isovertex on a grid point makes the restriction 0 up to rounding, or at a ridge point
/// next to a crossing, a sliver).
int joinUncrossedEdges(const FaceCrossings& fc, std::uint8_t config, int f, const CellReference& ref,
                       double w, FaceSamples& s, std::uint8_t& pointFails) {
  auto& r = s.r;
  auto& cornerPart = s.cornerPart;
  auto& sideBasis = s.sideBasis;
  int count = FaceSamples::kLattice;
  pointFails = 0;
  for (int k = 0; k < 4; ++k) {
    if ((fc.crossed >> k) & 1) continue;
    const bool positive = (config >> cube::faceVertex(f, kEdgeStartVertex[k])) & 1;
    const int added = uncrossedEdgeSamples(fc, k, positive, &r[static_cast<std::size_t>(count)],
                                           &cornerPart[static_cast<std::size_t>(count)],
                                           &sideBasis[static_cast<std::size_t>(count)]);
    bool fails = false, pointFailsHere = false;
    for (int i = count; i < count + added; ++i) {
      const double a = cornerPart[static_cast<std::size_t>(i)], b = sideBasis[static_cast<std::size_t>(i)];
      fails |= CoefficientInterval::slack(positive, a, b, w) < 0;  // with the clamp's margin
      const double v = a + w * b;
      pointFailsHere |= i < count + kEdgePoints - 2 && (positive ? v < 0 : v > 0);
    }
    if (fails && referenceKeepsEdgeSign(ref, f, k, positive)) {
      count += added;
      pointFails = static_cast<std::uint8_t>(pointFails | (unsigned{pointFailsHere} << k));
    }
  }
  return count;
}

}  // namespace

FaceResult fitFace(const CornerPatch& patch, std::uint8_t config, std::uint8_t pairing03, int f,
                   const CellReference& ref, bool fallBackToLeastContradicted) {
  FaceCrossings fc = faceCrossingsOf(patch, f, (pairing03 >> f) & 1);
  using Axis = FaceAxis;
  constexpr int n = Axis::n;
  FaceSamples s;
  const auto& r = s.r;
  referenceFaceLattice<Axis>(ref, f, s.r.data());
  faceRestrictionLattice<Axis>(fc, s.cornerPart.data(), s.sideBasis.data());
  const LatticeLayout faceLayout =
      LatticeLayout::of<Axis>(2, cube::otherAxes(cube::faceAxis(f)).data(), ref.metric);
  auto far = [&](int i) {
    return i >= n * n ||
           farFromSurface(ref, r[i], faceGradient(ref, f, Axis::coord(i % n), Axis::coord(i / n)));
  };
  auto confirmFar = [&](int i) {
    return !neighbourCrosses(r.data(), i, faceLayout, kVerifiedVoxels) &&
           !referenceSurfaceWithin(ref, faceLatticePoint<Axis>(f, i % n, i / n), r[i], kVerifiedVoxels);
  };
  thread_local SignConstraintSolver solver;
  solver.reset();
  const double fitted = fittedSide(fc, r.data());
  const SignSamples lattice = s.first(n * n);
  const SignedCoefficient alone = solver.solve(fitted, lattice, far, confirmFar);
  FaceResult out;
  out.ok = alone.feasible;
  out.coefficient = alone.value;
  if (!alone.feasible) {
    if (fallBackToLeastContradicted)
      out.coefficient = leastContradicted(alone.value, lattice, far, confirmFar);
    return out;
  }
  std::uint8_t pointFails;
  const int count = joinUncrossedEdges(fc, config, f, ref, alone.value, s, pointFails);
  if (count == n * n) return out;
  // No value meets the edges together with the lattice (the reference bulges towards an edge, or the corner
  // planes tilt across it): the lattice's stays, as without the edges, and the patch may cross the edge
  // there, a hole (docs/method.md, "Holes"). Failing the face instead makes the fallback rounds blend
  // normals, which spread failures (docs/method.md, step 7).
  const SignedCoefficient both = solver.solve(fitted, s.first(count), far, confirmFar);
  if (both.feasible)
    out.coefficient = both.value;
  else
    out.holeEdges = pointFails;
  return out;
}

}  // namespace cip
