/// @file patch_coefficients.h
/// @brief Side and central coefficients of a corner patch (corner I-patch paper, eq. 5, eq. 6 and appendix
/// A).
///
/// A side coefficient w_f is computed from face f's own data, expressed in the face's canonical 2-D frame
/// (cube_topology.h: u, v in [0,1]), so that the two cells sharing the face compute bit-identical values.
#pragma once
#include <Eigen/Core>
#include <array>
#include <cmath>
#include <cstdint>

#include "cip/patch/corner_patch.h"

namespace cip {

using Vec2 = Eigen::Vector2d;

/// The crossings of one face, in its canonical frame. Edge k (0..3) is the face's canonical edge k.
struct FaceCrossings {
  std::uint8_t crossed = 0;        ///< bit k: edge k carries an isovertex
  std::array<Vec2, 4> point{};     ///< isovertex (u, v) on edge k
  std::array<Vec2, 4> normal{};    ///< in-face components (n_u, n_v) of edge k's corner-plane normal
  std::array<double, 4> weight{};  ///< corner coefficient of edge k
  bool pairing03 = false;  ///< ambiguous faces: crossings paired around vertices 0 and 3 (cell_loops.h)
};

/// Which rule of appendix A produced a side point.
enum class SideRule { Triangle, Tetragon };

/// Side point of the segment between the isovertices on canonical edges k1 and k2 (face frame): the centroid
/// of the triangle (both isovertices and the intersection of their corner lines, when that lies in the face)
/// or of the tetragon (both isovertices and each corner line's intersection with the other isovertex's edge,
/// clamped to it).
Vec2 sidePoint(const FaceCrossings& face, int k1, int k2, SideRule* rule = nullptr);

/// The side segments of a face as pairs of canonical edges (1 or 2 segments); returns their number.
int faceSegments(const FaceCrossings& face, std::array<std::array<int, 2>, 2>& segments);

/// Numerator and denominator of eq. 5 at face point q: the face restriction of the patch is R(q) + w * D(q),
/// up to a positive factor common to all its terms.
struct FaceRestriction {
  double cornerPart = 0;  ///< R(q) = sum_k a_k S_k(q) prod_{j crossed, j != k} P_j(q)^2
  double sideBasis =
      0;  ///< D(q) = prod_{j crossed} P_j(q)^2 (P_j: the plane perpendicular to edge j's face side)
  double cornerMagnitude = 0;  ///< sum of |terms| of R(q): the scale against which R(q) is rounding noise
};
/// Defined here, inline: the fitted construction evaluates it at every fit point of every face.
inline FaceRestriction faceRestriction(const FaceCrossings& face, const Vec2& q) {
  // Squares of the planes perpendicular to canonical edges 0..3 (through them, restricted to the face): v,
  // 1 - v, u, 1 - u.
  const double perp[4] = {q.y(), 1.0 - q.y(), q.x(), 1.0 - q.x()};
  double perp2[4];
  for (int k = 0; k < 4; ++k) perp2[k] = perp[k] * perp[k];
  FaceRestriction r;
  r.sideBasis = 1;
  for (int k = 0; k < 4; ++k)
    if ((face.crossed >> k) & 1) r.sideBasis *= perp2[k];
  for (int k = 0; k < 4; ++k) {
    if (!((face.crossed >> k) & 1)) continue;
    double term = face.weight[k] * face.normal[k].dot(q - face.point[k]);
    for (int j = 0; j < 4; ++j)
      if (j != k && ((face.crossed >> j) & 1)) term *= perp2[j];
    r.cornerPart += term;
    r.cornerMagnitude += std::abs(term);
  }
  return r;
}

/// Side coefficient of the face: eq. 5 at its side point; an ambiguous face (two segments) fits both side
/// points in the least-squares sense. Side points on (or within rounding of) the face border are left out
/// (eq. 5 is undefined there); with none left the coefficient is zero. A corner part that is rounding noise
/// (|R| <= 1e-12 sum|terms|, e.g. when the corner planes are one plane) counts as zero: dividing noise by a
/// small D would otherwise give an arbitrary, possibly huge, coefficient.
double fitFaceCoefficient(const FaceCrossings& face);

/// Central coefficient that makes the patch vanish at `interior` (cell-local): eq. 6. Returns 0 when
/// `interior` lies on a bounding plane.
double fitCentralCoefficient(const CornerPatch& patch, const Vec3& interior);

/// The canonical crossings of face f of a patch (whose corners and faceMask are set), with the given pairing.
FaceCrossings faceCrossingsOf(const CornerPatch& patch, int f, bool pairing03);

}  // namespace cip
