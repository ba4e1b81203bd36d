/// @file patch_ray_polynomial.h
/// @brief A corner patch restricted to a ray, kept in the patch's own form so that the root search's
/// evaluations run over all of its terms at once.
///
/// Every term of a corner patch is a coefficient, at most one corner plane (linear along a ray) and the
/// squares of some of the patch's bounding planes (corner: all but the two faces through its edge; side: all
/// but its face; central: all). Here every term gets every bounding plane, a plane it does not have being the
/// constant 1 in its place, and the constant 1 stands for a missing corner plane too. A constant 1 changes no
/// value, and in the scaled Bernstein basis it is a degree elevation; so all terms have one structure and one
/// degree, 1 + 2 |P|, and each step of an evaluation or of the Bernstein conversion is one loop over the
/// terms, which vectorises. The polynomial is the same as rayPolynomial(patch, ...) gives (ray_patch.h); only
/// its representation, never expanded into monomials, differs: its degree() is that sum's degree elevated to
/// 1 + 2 |P|.
#pragma once
#include <array>

#include "cip/core/vec3.h"
#include "cip/patch/corner_patch.h"

namespace cip {

class PatchRayPolynomial {
 public:
  /// Terms are kept in groups of kLanes (unused ones have coefficient 0).
  static constexpr int kLanes = 4;
  static constexpr int kMaxTerms = (CornerPatch::kMaxTerms + kLanes - 1) / kLanes * kLanes;
  static constexpr int kMaxFaces = 6;
  /// Degree of the largest representation (1 + 2 * 6).
  static constexpr int kMaxDegree = 1 + 2 * kMaxFaces;
  /// Room for the Bernstein coefficients (as RayPolynomial's, which the root search shares).
  static constexpr int kCoefficients = 33;
  using Coefficients = std::array<double, kCoefficients>;

  /// The patch on the ray origin + t * direction (cell-local coordinates), terms in CornerPatch's order
  /// (corners, sides, central), zero coefficients left out as rayPolynomial does.
  PatchRayPolynomial(const CornerPatch& patch, const Vec3& origin, const Vec3& direction);

  /// 1 + 2 |P|: the degree every term is represented in (an upper bound of the true degree).
  int degree() const { return degree_; }
  int numTerms() const { return numTerms_; }

  /// Value at t, evaluated in factored form; summed over the terms in their order.
  double value(double t) const;
  /// Value (the same bits as value(t)), derivative, and a bound of the value's rounding error (as
  /// RayPolynomial::roundingBound: the products of the factors perturbed by their rounding).
  void valueDerivativeAndBound(double t, double& value, double& derivative, double& bound) const;
  /// The rounding bound of valueDerivativeAndBound alone.
  double roundingBound(double t) const;
  /// Whether interval arithmetic over [a, b] proves |value| above 1e-12 of the terms' magnitude bound
  /// everywhere on [a, b] (as RayPolynomial::excludesZero).
  bool excludesZero(double a, double b) const;
  /// Scaled Bernstein coefficients on [a, b] (out[k] = C(n, k) b_k, n = degree()); returns n. Coefficients 0
  /// and n equal value(a) and value(b) bit for bit.
  int scaledBernstein(double a, double b, Coefficients& out) const;

  /// The terms, by field and then by term, so that every step is a loop over the terms (the kernels of
  /// patch_ray_polynomial.cpp take it whole).
  struct Terms {
    int faces = 0;  ///< |P|
    int lanes = 0;  ///< the number of terms rounded up to kLanes (the extra ones have coefficient 0)
    /// Per term: the coefficient and the corner plane offset + slope * t (1 + 0 t without one), with the
    /// factor 2 eps that scales its rounding (0 for the constant).
    alignas(32) std::array<double, kMaxTerms> coefficient, linearOffset, linearSlope, linearRounding;
    /// Per bounding plane (in increasing face order) and term: the plane along the ray if the term has it,
    /// otherwise the constant 1 (offset 1, slope 0, rounding 0).
    alignas(32) std::array<std::array<double, kMaxTerms>, kMaxFaces> faceOffset, faceSlope, faceRounding;
  };

 private:
  Terms terms_;
  int numTerms_ = 0;
  int degree_ = 1;
};

}  // namespace cip
