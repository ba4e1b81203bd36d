/// @file corner_patch.h
/// @brief The multi-loop corner I-patch of one cell: a polynomial in cell-local coordinates.
///
/// With P the set of the cell's bounding planes (faces that carry a side; each distinct face plane taken
/// once), B_f the face functions of cube_topology.h, and per corner c an isovertex p_c on edge e_c with
/// corner-plane normal n_c, corner coefficient (weight) a_c and corner plane S_c(x) = n_c . (x - p_c):
///
///   I(x) = sum_c a_c S_c(x) prod_{h in P \ faces(e_c)} B_h(x)^2     (corner terms)
///        + sum_{f in P} w_f prod_{h in P \ {f}} B_h(x)^2            (side terms, one coefficient per face)
///        + w prod_{h in P} B_h(x)^2                                 (central term)
///
/// This is eq. 8 of the corner I-patch paper with each coinciding bounding plane entering once. On face f the
/// patch depends only on that face's corner planes, the perpendicular face planes and w_f, so neighbouring
/// cells join with C0 and G1 continuity. I > 0 on the positive side (value > isovalue) near the isovertices.
/// Degree <= 12.
#pragma once
#include <array>
#include <cstdint>

#include "cip/core/vec3.h"

namespace cip {

/// One product term of a patch: coefficient * [corner plane S_corner] * prod_{h in faceSquares} B_h^2.
struct PatchTerm {
  double coefficient = 0;
  int corner = -1;               ///< corner whose plane is a factor, or -1 (side and central terms)
  std::uint8_t faceSquares = 0;  ///< bit mask of faces whose squared plane is a factor
};

/// Value, gradient and Hessian of a patch at a point (cell-local coordinates; derivatives per local unit).
struct PatchDerivatives {
  double value = 0;
  Vec3 gradient = Vec3::Zero();
  Mat3 hessian = Mat3::Zero();
};

struct CornerPatch {
  static constexpr int kMaxCorners = 12;
  static constexpr int kMaxTerms = kMaxCorners + 6 + 1;

  int numCorners = 0;
  std::array<Vec3, kMaxCorners> point{};        ///< isovertex, cell-local coordinates
  std::array<Vec3, kMaxCorners> normal{};       ///< corner-plane normal (unit, index-space orientation)
  std::array<double, kMaxCorners> weight{};     ///< corner coefficient a_c
  std::array<std::int8_t, kMaxCorners> edge{};  ///< cell edge of each corner (cube_topology.h numbering)
  std::uint8_t faceMask = 0;                    ///< bounding planes P
  std::array<double, 6> faceCoefficient{};      ///< w_f (0 for faces not in P)
  double central = 0;                           ///< w

  /// S_c(x) = n_c . (x - p_c).
  double cornerPlane(int c, const Vec3& x) const { return normal[c].dot(x - point[c]); }
  /// B_f(x): distance from face f inside the unit cube (x[axis] or 1 - x[axis]).
  static double facePlane(int f, const Vec3& x) { return (f & 1) ? 1.0 - x[f / 2] : x[f / 2]; }
  /// Gradient of B_f (constant).
  static Vec3 facePlaneGradient(int f);

  /// All non-zero terms of the sum; returns their number. The ray intersector multiplies their linear
  /// factors.
  int terms(std::array<PatchTerm, kMaxTerms>& out) const;
  /// Terms other than the central one, including zero side coefficients (for coefficient fitting).
  double valueWithoutCentral(const Vec3& x) const;
  /// prod_{h in P} B_h(x)^2: the function the central coefficient multiplies.
  double centralBasis(const Vec3& x) const;

  double value(const Vec3& x) const;
  /// Exact value, gradient and Hessian from the factored form (no finite differences).
  PatchDerivatives derivatives(const Vec3& x) const;
  /// Value and gradient as in derivatives() (to rounding, the terms' factors taken in another order), without
  /// the Hessian (left zero): a quarter of the work, for normals.
  PatchDerivatives valueAndGradient(const Vec3& x) const;
  /// Total polynomial degree (2 |P|, or less when the central coefficient is zero).
  int degree() const;
};

}  // namespace cip
