#include "cip/patch/patch_coefficients.h"

#include <algorithm>
#include <cmath>

#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

// Canonical edge k as a parametric segment in the face frame: start + s * dir, s in [0,1].
Vec2 edgeStart(int k) {
  return k == 0 ? Vec2(0, 0) : k == 1 ? Vec2(0, 1) : k == 2 ? Vec2(0, 0) : Vec2(1, 0);
}
Vec2 edgeDir(int k) {
  return k < 2 ? Vec2(1, 0) : Vec2(0, 1);
}

// Intersection of corner line k (n . (x - p) = 0) with the line of canonical edge `other`, clamped to the
// edge.
Vec2 lineOnEdge(const FaceCrossings& face, int k, int other) {
  const Vec2& n = face.normal[k];
  double den = n.dot(edgeDir(other));
  double s = 0.5;
  if (std::abs(den) > 1e-12) s = std::clamp(n.dot(face.point[k] - edgeStart(other)) / den, 0.0, 1.0);
  return edgeStart(other) + s * edgeDir(other);
}

}  // namespace

int faceSegments(const FaceCrossings& face, std::array<std::array<int, 2>, 2>& segments) {
  if (face.crossed == 0xF) {
    if (face.pairing03) {
      segments = {{{0, 2}, {1, 3}}};
    } else {
      segments = {{{0, 3}, {1, 2}}};
    }
    return 2;
  }
  int ks[2], n = 0;
  for (int k = 0; k < 4 && n < 2; ++k)
    if ((face.crossed >> k) & 1) ks[n++] = k;
  if (n != 2) return 0;
  segments[0] = {ks[0], ks[1]};
  return 1;
}

Vec2 sidePoint(const FaceCrossings& face, int k1, int k2, SideRule* rule) {
  const Vec2 &p1 = face.point[k1], &p2 = face.point[k2], &n1 = face.normal[k1], &n2 = face.normal[k2];
  double det = n1.x() * n2.y() - n1.y() * n2.x();
  double scale = n1.norm() * n2.norm();
  if (std::abs(det) > 1e-12 * scale && scale > 0) {
    double r1 = n1.dot(p1), r2 = n2.dot(p2);
    Vec2 q((r1 * n2.y() - r2 * n1.y()) / det, (n1.x() * r2 - n2.x() * r1) / det);
    if (q.x() >= 0 && q.x() <= 1 && q.y() >= 0 && q.y() <= 1) {
      if (rule) *rule = SideRule::Triangle;
      return (p1 + p2 + q) / 3.0;
    }
  }
  if (rule) *rule = SideRule::Tetragon;
  return (p1 + lineOnEdge(face, k1, k2) + p2 + lineOnEdge(face, k2, k1)) / 4.0;
}

// Eq. 5 divides by D = prod P_j^2 at the side point; below this (e.g. a side point within ~1e-5 of two face
// borders, as when two isovertices meet at a grid point) the coefficient would be decided by rounding.
constexpr double kMinSideBasis = 1e-20;

double fitFaceCoefficient(const FaceCrossings& face) {
  std::array<std::array<int, 2>, 2> segs;
  int n = faceSegments(face, segs);
  double num = 0, den = 0;
  for (int s = 0; s < n; ++s) {
    FaceRestriction r = faceRestriction(face, sidePoint(face, segs[s][0], segs[s][1]));
    if (r.sideBasis < kMinSideBasis) continue;  // side point (numerically) on the face border
    double cornerPart = std::abs(r.cornerPart) <= 1e-12 * r.cornerMagnitude ? 0.0 : r.cornerPart;
    num += cornerPart * r.sideBasis;
    den += r.sideBasis * r.sideBasis;
  }
  if (!(den > 0)) return 0.0;
  return -num / den;
}

double fitCentralCoefficient(const CornerPatch& patch, const Vec3& interior) {
  double basis = patch.centralBasis(interior);
  if (!(basis > 1e-300)) return 0.0;
  return -patch.valueWithoutCentral(interior) / basis;
}

FaceCrossings faceCrossingsOf(const CornerPatch& patch, int f, bool pairing03) {
  FaceCrossings face;
  face.pairing03 = pairing03;
  auto uv = cube::otherAxes(cube::faceAxis(f));
  for (int c = 0; c < patch.numCorners; ++c) {
    for (int k = 0; k < 4; ++k) {
      if (cube::faceEdge(f, k) != patch.edge[c]) continue;
      face.crossed = static_cast<std::uint8_t>(face.crossed | (1u << k));
      face.point[k] = Vec2(patch.point[c][uv[0]], patch.point[c][uv[1]]);
      face.normal[k] = Vec2(patch.normal[c][uv[0]], patch.normal[c][uv[1]]);
      face.weight[k] = patch.weight[c];
    }
  }
  return face;
}

}  // namespace cip
