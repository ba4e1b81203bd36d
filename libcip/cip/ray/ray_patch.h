/// @file ray_patch.h
/// @brief Exact first intersection of a ray with a corner patch, in cell-local coordinates.
///
/// Along a ray every factor of a patch term is linear in t, so the restricted patch is searched in Bernstein
/// form built directly from the factors on an interval (never expanded into monomials): sign changes bound
/// the roots, one sign change is refined by safeguarded Newton/bisection in factored form, more are split,
/// left half first. docs/raycast.md ("How rays meet patches") gives each case and its reasoning.
#pragma once
#include <array>
#include <cstdint>
#include <optional>
#include <stdexcept>

#include "cip/patch/corner_patch.h"
#include "cip/ray/patch_ray_polynomial.h"

namespace cip {

/// A linear function of the ray parameter: value(t) = offset + slope * t. A plain aggregate (write
/// LinearFactor{offset, slope}; LinearFactor{} is zero) so that RayPolynomial's table is not zero-filled.
struct LinearFactor {
  double offset;
  double slope;
  double operator()(double t) const { return offset + slope * t; }
};

/// A univariate polynomial in the ray parameter t, kept as a sum of terms
/// coefficient * prod_i factor_i(t)^power_i over a shared table of linear factors. Fixed capacity, no
/// allocation; only the factors and terms in use are ever written (one is built for every cell a ray meets,
/// so nothing is zero-filled).
class RayPolynomial {
 public:
  static constexpr int kMaxFactors = 32;      ///< distinct linear factors
  static constexpr int kMaxTerms = 24;        ///< product terms
  static constexpr int kMaxTermFactors = 24;  ///< distinct factors in one term
  static constexpr int kMaxDegree = 32;       ///< degree of one term (sum of its powers)

  /// Adds a linear factor to the table; returns its index. Throws std::length_error when full.
  int addFactor(const LinearFactor& factor);
  /// Starts a new term `coefficient * 1`; returns its index. Throws std::length_error when full.
  int addTerm(double coefficient);
  /// Multiplies term `term` by factor(t)^power (power >= 1). Throws std::length_error beyond the capacities.
  void multiplyTerm(int term, int factor, int power = 1);

  int numTerms() const { return numTerms_; }
  int numFactors() const { return numFactors_; }
  const LinearFactor& factor(int i) const { return factors_[i]; }
  /// Largest term degree (an upper bound of the true degree: leading coefficients may cancel).
  int degree() const { return degree_; }

  /// Value at t, evaluated in factored form.
  double value(double t) const;
  /// Value and first derivative at t, evaluated in factored form (product rule, forward accumulation).
  void valueAndDerivative(double t, double& value, double& derivative) const;
  /// Bound of the rounding error of value(t): a small multiple of machine epsilon times
  /// sum |coefficient| * prod |factor(t)|^power. A value below it cannot be told apart from zero.
  double roundingBound(double t) const;
  /// valueAndDerivative and roundingBound at t in one pass over the terms (the same three numbers).
  void valueDerivativeAndBound(double t, double& value, double& derivative, double& bound) const;

  /// Whether interval arithmetic over [a,b] (each factor's range from its end values, multiplied term by
  /// term) proves |value| larger than 1e-12 of the terms' magnitude bound everywhere on [a,b]: far above the
  /// rounding of any evaluation, so no root search on [a,b] can report a root (firstRoot checks it before the
  /// first Bernstein conversion, which costs an order of magnitude more).
  bool excludesZero(double a, double b) const;

  /// Bernstein coefficients on [a,b] (degree = degree()), built from the factors' end values; returns the
  /// degree. Coefficient 0 is value(a) and coefficient degree is value(b), each computed as in value(). Terms
  /// of equal degree are summed before their sum is degree-elevated, once per degree step.
  int bernstein(double a, double b, std::array<double, kMaxDegree + 1>& out) const;
  /// The same in the scaled basis: out[k] = C(degree, k) * Bernstein coefficient k, computed without weights
  /// (c_k <- l0 c_k + l1 c_{k-1} per linear factor). Same signs and the same end coefficients; the root
  /// search works on these.
  int scaledBernstein(double a, double b, std::array<double, kMaxDegree + 1>& out) const;

 private:
  // Entries past numFactors_, numTerms_ and a term's count are never read, so they are left unwritten.
  struct Term {
    double coefficient;
    int count;
    int degree;
    std::array<std::uint8_t, kMaxTermFactors> factor;
    std::array<std::uint8_t, kMaxTermFactors> power;
  };
  std::array<LinearFactor, kMaxFactors> factors_;
  std::array<Term, kMaxTerms> terms_;
  int numFactors_ = 0;
  int numTerms_ = 0;
  int degree_ = 0;
};

// The patch's own form (patch_ray_polynomial.h, which cannot include this header) holds as many Bernstein
// coefficients as the general polynomial: the root search is one template over both.
static_assert(PatchRayPolynomial::kCoefficients == RayPolynomial::kMaxDegree + 1,
              "PatchRayPolynomial and RayPolynomial must have the same maximal degree");

// Inline: rayPolynomial calls these some fifty times for every cell a ray meets.

inline int RayPolynomial::addFactor(const LinearFactor& factor) {
  if (numFactors_ >= kMaxFactors) throw std::length_error("RayPolynomial: too many factors");
  factors_[numFactors_] = factor;
  return numFactors_++;
}

inline int RayPolynomial::addTerm(double coefficient) {
  if (numTerms_ >= kMaxTerms) throw std::length_error("RayPolynomial: too many terms");
  Term& term = terms_[numTerms_];
  term.coefficient = coefficient;
  term.count = 0;
  term.degree = 0;
  return numTerms_++;
}

inline void RayPolynomial::multiplyTerm(int term, int factor, int power) {
  if (term < 0 || term >= numTerms_ || factor < 0 || factor >= numFactors_ || power < 1)
    throw std::length_error("RayPolynomial: bad term, factor or power");
  Term& t = terms_[term];
  if (t.count >= kMaxTermFactors || t.degree + power > kMaxDegree)
    throw std::length_error("RayPolynomial: term degree too high");
  t.factor[t.count] = static_cast<std::uint8_t>(factor);
  t.power[t.count] = static_cast<std::uint8_t>(power);
  ++t.count;
  t.degree += power;
  if (t.degree > degree_) degree_ = t.degree;
}

/// Limits of the root search.
struct RootSearchOptions {
  /// Subdivision stops when an interval is narrower than this fraction of the searched interval's width (or a
  /// few units in the last place of t, whichever is larger).
  double minRelativeWidth = 1e-15;
  /// Maximum number of intervals examined in one search; when exceeded the search reports no root.
  int maxIntervals = 4096;
  /// Newton / bisection iterations for one bracketed root. Refinement also stops once |value| is within
  /// roundingBound (after a last Newton step): beyond it the steps only follow rounding noise.
  int maxRefineIterations = 200;
  /// intersectRayPatch only: report only zeros where the polynomial changes sign (see firstCrossing).
  bool crossingsOnly = false;
};

/// Counters of one or more searches (add them up across calls; not thread-safe, keep one per thread).
struct RootSearchStats {
  std::int64_t searches = 0;
  std::int64_t intervals = 0;        ///< Bernstein intervals examined
  std::int64_t refinements = 0;      ///< bracketed roots refined
  std::int64_t touches = 0;          ///< roots accepted at the depth limit (tangent grazes, multiple roots)
  std::int64_t budgetExhausted = 0;  ///< searches that hit maxIntervals
};

/// How a root was found.
enum class RootKind : std::uint8_t {
  Bracketed = 0,  ///< single sign change, refined to a few ulps
  EndPoint = 1,   ///< value exactly zero at an interval end
  Touch = 2,  ///< depth limit reached; |value| within rounding (tangent graze, multiple or clustered roots)
};

struct Root {
  double t = 0;
  RootKind kind = RootKind::Bracketed;
};

/// First root of `p` in the closed interval [t0, t1] (t0 <= t1), or nothing. Deterministic.
std::optional<Root> firstRoot(const RayPolynomial& p, double t0, double t1,
                              const RootSearchOptions& options = {}, RootSearchStats* stats = nullptr);
/// The same search on a patch kept in its own form (patch_ray_polynomial.h).
std::optional<Root> firstRoot(const PatchRayPolynomial& p, double t0, double t1,
                              const RootSearchOptions& options = {}, RootSearchStats* stats = nullptr);

/// First zero of `p` in [t0, t1] at which p changes sign: like firstRoot, but a zero found at an interval end
/// or as a touch is accepted only if p(t - e) and p(t + e) are non-zero with opposite signs, e = 1e-9 (t1 -
/// t0) (evaluated beyond [t0, t1] when t is at an end); otherwise the search resumes after t + e.
/// Even-multiplicity zeros are skipped: tangent grazes, and the zeros every corner patch has at the cube
/// vertices and along the edges shared by two bounding planes that no corner lies on (each term has a squared
/// bounding plane vanishing there).
std::optional<Root> firstCrossing(const RayPolynomial& p, double t0, double t1,
                                  const RootSearchOptions& options = {}, RootSearchStats* stats = nullptr);
std::optional<Root> firstCrossing(const PatchRayPolynomial& p, double t0, double t1,
                                  const RootSearchOptions& options = {}, RootSearchStats* stats = nullptr);

/// The patch restricted to the ray origin + t * direction (cell-local coordinates; t in units of
/// |direction|): one factor per face plane of the patch and per corner plane used, one term per patch term.
RayPolynomial rayPolynomial(const CornerPatch& patch, const Vec3& origin, const Vec3& direction);

/// Default enlargement of the cell box used by clipRayToCell (cell-local units): a root on a face shared by
/// two cells lies strictly inside both cells' intervals, so neither misses it through rounding of the clip.
constexpr double kCellClipPad = 1e-9;

/// Clips the ray origin + t * direction (cell-local coordinates) with t in [tMin, tMax] to the box
/// [-pad, 1 + pad]^3. Returns false when the clipped interval is empty; otherwise sets [t0, t1].
/// Components of `direction` that are zero are handled (the ray is inside the slab or misses it).
bool clipRayToCell(const Vec3& origin, const Vec3& direction, double tMin, double tMax, double& t0,
                   double& t1, double pad = kCellClipPad);

/// The first intersection of the ray origin + t * direction (cell-local coordinates of the patch's cell) with
/// the patch's zero set, with t in [tMin, tMax] clipped to the padded cell box. Internally the ray is
/// re-based at the clipped entry point so the root finder works on [0, t1 - t0], on the patch in its own form
/// (PatchRayPolynomial). Returns the ray parameter t
/// (same units as tMin).
std::optional<Root> intersectRayPatch(const CornerPatch& patch, const Vec3& origin, const Vec3& direction,
                                      double tMin, double tMax, const RootSearchOptions& options = {},
                                      RootSearchStats* stats = nullptr, double pad = kCellClipPad);

}  // namespace cip
