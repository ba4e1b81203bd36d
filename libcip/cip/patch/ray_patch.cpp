#include "cip/patch/ray_patch.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

constexpr double kEps = std::numeric_limits<double>::epsilon();
using Coefficients = std::array<double, RayPolynomial::kMaxDegree + 1>;

/// In place: b (degree m, Bernstein on [a,b]) times the linear function with end values (l0, l1); result
/// degree m+1. c_k = (l0 b_k (m+1-k) + l1 b_{k-1} k) / (m+1); the end coefficients are plain products so that
/// they equal the factored evaluation at the interval ends bit for bit.
void multiplyLinear(Coefficients& b, int m, double l0, double l1) {
  const double inv = 1.0 / (m + 1);
  b[m + 1] = l1 * b[m];
  for (int k = m; k >= 1; --k) b[k] = (l0 * b[k] * (m + 1 - k) + l1 * b[k - 1] * k) * inv;
  b[0] = l0 * b[0];
}

/// In place: degree elevation from m to m+1 (multiplication by the constant 1, end values (1, 1)).
void elevate(Coefficients& b, int m) {
  const double inv = 1.0 / (m + 1);
  b[m + 1] = b[m];
  for (int k = m; k >= 1; --k) b[k] = (b[k] * (m + 1 - k) + b[k - 1] * k) * inv;
}

int sign(double x) {
  return (x > 0) - (x < 0);
}

/// Number of sign changes of b[0..n], zeros ignored.
int signChanges(const Coefficients& b, int n) {
  int changes = 0, last = 0;
  for (int k = 0; k <= n; ++k) {
    int s = sign(b[k]);
    if (s == 0) continue;
    if (last != 0 && s != last) ++changes;
    last = s;
  }
  return changes;
}

/// The single root of p in [lo, hi], where p(lo) and p(hi) are non-zero with opposite signs: Newton steps
/// kept inside the shrinking bracket, bisection whenever a step would leave it or converge slower than
/// bisection. Stops when |p(x)| is within p's rounding bound at x (its sign there is noise, so further steps
/// would only wander within the noise; one last Newton step is taken when it stays inside the bracket), when
/// the bracket or the step is below `tolerance`, or after maxIterations.
double refineBracketed(const RayPolynomial& p, double lo, double hi, double valueLo, double tolerance,
                       int maxIterations) {
  // Orient so that g = s * p is negative at lo and positive at hi.
  const double s = valueLo < 0 ? 1.0 : -1.0;
  double x = 0.5 * (lo + hi);
  double dxOld = hi - lo, dx = dxOld;
  double g = 0, dg = 0, bound = 0;
  p.valueDerivativeAndBound(x, g, dg, bound);
  g *= s;
  dg *= s;
  for (int it = 0; it < maxIterations; ++it) {
    if (g == 0) return x;
    if (g < 0) {
      lo = x;
    } else {
      hi = x;
    }
    if (std::abs(g) <= bound) {
      const double newton = dg != 0 ? x - g / dg : x;
      return newton > lo && newton < hi ? newton : x;
    }
    const bool newtonLeaves = ((x - hi) * dg - g) * ((x - lo) * dg - g) > 0;
    const bool newtonSlow = std::abs(2.0 * g) > std::abs(dxOld * dg);
    if (newtonLeaves || newtonSlow || dg == 0) {
      dxOld = dx;
      dx = 0.5 * (hi - lo);
      x = lo + dx;
    } else {
      dxOld = dx;
      dx = g / dg;
      x -= dx;
      if (!(x > lo && x < hi)) {  // rounding pushed the step onto the bracket: bisect instead
        dx = 0.5 * (hi - lo);
        x = lo + dx;
      }
    }
    if (hi - lo <= tolerance || std::abs(dx) <= 0.5 * tolerance) break;
    p.valueDerivativeAndBound(x, g, dg, bound);
    g *= s;
    dg *= s;
  }
  return std::clamp(x, lo, hi);
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------------
// RayPolynomial

int RayPolynomial::addFactor(const LinearFactor& factor) {
  if (numFactors_ >= kMaxFactors) throw std::length_error("RayPolynomial: too many factors");
  factors_[numFactors_] = factor;
  return numFactors_++;
}

int RayPolynomial::addTerm(double coefficient) {
  if (numTerms_ >= kMaxTerms) throw std::length_error("RayPolynomial: too many terms");
  Term& term = terms_[numTerms_];
  term.coefficient = coefficient;
  term.count = 0;
  term.degree = 0;
  return numTerms_++;
}

void RayPolynomial::multiplyTerm(int term, int factor, int power) {
  if (term < 0 || term >= numTerms_ || factor < 0 || factor >= numFactors_ || power < 1)
    throw std::length_error("RayPolynomial: bad term, factor or power");
  Term& t = terms_[term];
  if (t.count >= kMaxTermFactors || t.degree + power > kMaxDegree)
    throw std::length_error("RayPolynomial: term degree too high");
  t.factor[t.count] = static_cast<std::uint8_t>(factor);
  t.power[t.count] = static_cast<std::uint8_t>(power);
  ++t.count;
  t.degree += power;
  degree_ = std::max(degree_, t.degree);
}

double RayPolynomial::value(double t) const {
  std::array<double, kMaxFactors> l;
  for (int f = 0; f < numFactors_; ++f) l[f] = factors_[f](t);
  double sum = 0;
  for (int i = 0; i < numTerms_; ++i) {
    const Term& term = terms_[i];
    double r = term.coefficient;
    for (int j = 0; j < term.count; ++j)
      for (int p = 0; p < term.power[j]; ++p) r *= l[term.factor[j]];
    sum += r;
  }
  return sum;
}

void RayPolynomial::valueAndDerivative(double t, double& value, double& derivative) const {
  std::array<double, kMaxFactors> l;
  for (int f = 0; f < numFactors_; ++f) l[f] = factors_[f](t);
  value = 0;
  derivative = 0;
  for (int i = 0; i < numTerms_; ++i) {
    const Term& term = terms_[i];
    double v = term.coefficient, d = 0;
    for (int j = 0; j < term.count; ++j) {
      const double lf = l[term.factor[j]], sf = factors_[term.factor[j]].slope;
      for (int p = 0; p < term.power[j]; ++p) {
        d = d * lf + v * sf;
        v *= lf;
      }
    }
    value += v;
    derivative += d;
  }
}

double RayPolynomial::roundingBound(double t) const {
  // Each factor value carries an absolute error of about eps (|offset| + |slope t|), which may be large
  // relative to the value itself near the factor's zero; bound every product by the perturbed magnitudes.
  std::array<double, kMaxFactors> mag, pert;
  for (int f = 0; f < numFactors_; ++f) {
    const double v = std::abs(factors_[f](t));
    mag[f] = v;
    pert[f] = v + 2 * kEps * (std::abs(factors_[f].offset) + std::abs(factors_[f].slope * t));
  }
  double spread = 0, size = 0;
  for (int i = 0; i < numTerms_; ++i) {
    const Term& term = terms_[i];
    double exact = std::abs(term.coefficient), perturbed = exact;
    for (int j = 0; j < term.count; ++j)
      for (int p = 0; p < term.power[j]; ++p) {
        exact *= mag[term.factor[j]];
        perturbed *= pert[term.factor[j]];
      }
    spread += perturbed - exact;
    size += perturbed;
  }
  return 4.0 * (spread + (degree() + numTerms_ + 2) * kEps * size);
}

void RayPolynomial::valueDerivativeAndBound(double t, double& value, double& derivative,
                                            double& bound) const {
  // valueAndDerivative and roundingBound fused: the same operations in the same order.
  std::array<double, kMaxFactors> l, mag, pert;
  for (int f = 0; f < numFactors_; ++f) {
    l[f] = factors_[f](t);
    mag[f] = std::abs(l[f]);
    pert[f] = mag[f] + 2 * kEps * (std::abs(factors_[f].offset) + std::abs(factors_[f].slope * t));
  }
  value = 0;
  derivative = 0;
  double spread = 0, size = 0;
  for (int i = 0; i < numTerms_; ++i) {
    const Term& term = terms_[i];
    double v = term.coefficient, d = 0, exact = std::abs(term.coefficient), perturbed = exact;
    for (int j = 0; j < term.count; ++j) {
      const int f = term.factor[j];
      const double lf = l[f], sf = factors_[f].slope, mf = mag[f], pf = pert[f];
      for (int p = 0; p < term.power[j]; ++p) {
        d = d * lf + v * sf;
        v *= lf;
        exact *= mf;
        perturbed *= pf;
      }
    }
    value += v;
    derivative += d;
    spread += perturbed - exact;
    size += perturbed;
  }
  bound = 4.0 * (spread + (degree_ + numTerms_ + 2) * kEps * size);
}

int RayPolynomial::bernstein(double a, double b, std::array<double, kMaxDegree + 1>& out) const {
  const int n = degree_;
  std::array<double, kMaxFactors> la, lb;
  for (int f = 0; f < numFactors_; ++f) {
    la[f] = factors_[f](a);
    lb[f] = factors_[f](b);
  }
  // The sum of the terms of degree <= m, elevated to degree m, is kept in `out`; each degree step elevates it
  // once. The end coefficients are summed apart, in term order, so that they equal value(a) and value(b).
  std::array<double, kMaxTerms> ends0, ends1;
  int m = n;
  for (int i = 0; i < numTerms_; ++i) m = std::min(m, terms_[i].degree);
  std::fill(out.begin(), out.begin() + m + 1, 0.0);
  Coefficients c;
  for (;; ++m) {
    for (int i = 0; i < numTerms_; ++i) {
      const Term& term = terms_[i];
      if (term.degree != m) continue;
      c[0] = term.coefficient;
      if (m == 0) {
        out[0] += c[0];
        ends0[i] = ends1[i] = c[0];
        continue;
      }
      // All factors but the last into c; the last one's product goes straight into `out` (storing it in c and
      // reading it back stalled on store forwarding), with the same operations as multiplyLinear.
      int k = 0;
      for (int j = 0; j < term.count; ++j)
        for (int p = j + 1 < term.count ? 0 : 1; p < term.power[j]; ++p)
          multiplyLinear(c, k++, la[term.factor[j]], lb[term.factor[j]]);
      const int last = term.factor[term.count - 1];
      const double l0 = la[last], l1 = lb[last], inv = 1.0 / m;
      ends0[i] = l0 * c[0];
      ends1[i] = l1 * c[k];
      out[m] += ends1[i];
      for (int q = k; q >= 1; --q) out[q] += (l0 * c[q] * (m - q) + l1 * c[q - 1] * q) * inv;
      out[0] += ends0[i];
    }
    if (m >= n) break;
    elevate(out, m);
  }
  double end0 = 0, end1 = 0;
  for (int i = 0; i < numTerms_; ++i) {
    end0 += ends0[i];
    end1 += ends1[i];
  }
  out[0] = end0;
  out[n] = end1;
  return n;
}

// ---------------------------------------------------------------------------------------------------------------------
// Root search

std::optional<Root> firstRoot(const RayPolynomial& p, double t0, double t1, const RootSearchOptions& options,
                              RootSearchStats* stats) {
  RootSearchStats local;
  RootSearchStats& st = stats ? *stats : local;
  ++st.searches;
  if (!(t0 <= t1)) return std::nullopt;  // also rejects NaN
  if (t0 == t1) {
    if (p.value(t0) == 0) return Root{t0, RootKind::EndPoint};
    return std::nullopt;
  }
  const double width = t1 - t0;
  const double scale = std::max(std::abs(t0), std::abs(t1));
  const double minWidth = std::max(options.minRelativeWidth * width, 4 * kEps * scale);
  const double tolerance = std::max(2 * kEps * scale, kEps * width);

  // Depth-first over intervals, left half first: an explicit stack of [a,b] pairs.
  constexpr int kStack = 256;
  std::array<std::pair<double, double>, kStack> stack;
  int top = 0;
  stack[top++] = {t0, t1};
  Coefficients b;
  int examined = 0;
  while (top > 0) {
    const auto [lo, hi] = stack[--top];
    if (++examined > options.maxIntervals) {
      ++st.budgetExhausted;
      break;
    }
    ++st.intervals;
    const int n = p.bernstein(lo, hi, b);
    if (b[0] == 0) return Root{lo, RootKind::EndPoint};
    const int changes = signChanges(b, n);
    if (changes == 0) {
      if (b[n] == 0) return Root{hi, RootKind::EndPoint};
      continue;  // convex hull strictly on one side: no root in [lo, hi]
    }
    if (changes == 1 && b[n] != 0) {
      ++st.refinements;
      return Root{refineBracketed(p, lo, hi, b[0], tolerance, options.maxRefineIterations),
                  RootKind::Bracketed};
    }
    const double mid = lo + 0.5 * (hi - lo);
    if (hi - lo <= minWidth || top + 2 > kStack || !(mid > lo && mid < hi)) {
      // Depth limit: the roots here cannot be separated in double precision.
      if (sign(b[0]) * sign(b[n]) < 0) {  // odd count: a root exists by the intermediate value theorem
        ++st.refinements;
        return Root{refineBracketed(p, lo, hi, b[0], tolerance, options.maxRefineIterations),
                    RootKind::Bracketed};
      }
      if (b[n] == 0) return Root{hi, RootKind::EndPoint};
      for (double x : {mid, lo, hi}) {
        if (std::abs(p.value(x)) <= p.roundingBound(x)) {
          ++st.touches;
          return Root{x, RootKind::Touch};
        }
      }
      continue;
    }
    stack[top++] = {mid, hi};
    stack[top++] = {lo, mid};
  }
  return std::nullopt;
}

std::optional<Root> firstCrossing(const RayPolynomial& p, double t0, double t1,
                                  const RootSearchOptions& options, RootSearchStats* stats) {
  if (!(t0 <= t1)) return std::nullopt;
  const double e = std::max(1e-9 * (t1 - t0), 4 * kEps * std::max(std::abs(t0), std::abs(t1)));
  double start = t0;
  for (int attempt = 0; attempt < 16; ++attempt) {
    auto root = firstRoot(p, start, t1, options, stats);
    if (!root || root->kind == RootKind::Bracketed) return root;
    const double before = p.value(root->t - e), after = p.value(root->t + e);
    if (before != 0 && after != 0 && (before < 0) != (after < 0)) return root;
    start = root->t + e;  // an even-multiplicity zero (or a stretch where p vanishes): look further on
    if (!(start <= t1)) return std::nullopt;
  }
  return std::nullopt;
}

RayPolynomial rayPolynomial(const CornerPatch& patch, const Vec3& origin, const Vec3& direction) {
  // The terms of CornerPatch::terms, in its order, without building its table.
  RayPolynomial poly;
  std::array<int, 6> faceFactor;
  faceFactor.fill(-1);
  auto multiplyFaces = [&](int t, unsigned mask) {
    for (int f = 0; f < 6; ++f) {
      if (!((mask >> f) & 1)) continue;
      int& ff = faceFactor[f];
      if (ff < 0) {
        const int axis = f / 2;
        ff = poly.addFactor((f & 1) ? LinearFactor{1.0 - origin[axis], -direction[axis]}
                                    : LinearFactor{origin[axis], direction[axis]});
      }
      poly.multiplyTerm(t, ff, 2);
    }
  };
  const unsigned faces = patch.faceMask;
  for (int c = 0; c < patch.numCorners; ++c) {
    if (patch.weight[c] == 0) continue;
    const int t = poly.addTerm(patch.weight[c]);
    const Vec3& nc = patch.normal[c];
    poly.multiplyTerm(t, poly.addFactor(LinearFactor{nc.dot(origin - patch.point[c]), nc.dot(direction)}), 1);
    const auto ef = cube::edgeFaces(patch.edge[c]);
    multiplyFaces(t, faces & ~((1u << ef[0]) | (1u << ef[1])));
  }
  for (int f = 0; f < 6; ++f)
    if (((faces >> f) & 1) && patch.faceCoefficient[f] != 0)
      multiplyFaces(poly.addTerm(patch.faceCoefficient[f]), faces & ~(1u << f));
  if (patch.central != 0) multiplyFaces(poly.addTerm(patch.central), faces);
  return poly;
}

bool clipRayToCell(const Vec3& origin, const Vec3& direction, double tMin, double tMax, double& t0,
                   double& t1, double pad) {
  double lo = tMin, hi = tMax;
  for (int a = 0; a < 3; ++a) {
    const double boxLo = -pad, boxHi = 1.0 + pad;
    if (direction[a] == 0) {
      if (!(origin[a] >= boxLo && origin[a] <= boxHi)) return false;
      continue;
    }
    const double inv = 1.0 / direction[a];
    double ta = (boxLo - origin[a]) * inv, tb = (boxHi - origin[a]) * inv;
    if (ta > tb) std::swap(ta, tb);
    lo = std::max(lo, ta);
    hi = std::min(hi, tb);
  }
  if (!(lo <= hi)) return false;
  t0 = lo;
  t1 = hi;
  return true;
}

std::optional<Root> intersectRayPatch(const CornerPatch& patch, const Vec3& origin, const Vec3& direction,
                                      double tMin, double tMax, const RootSearchOptions& options,
                                      RootSearchStats* stats, double pad) {
  double t0 = 0, t1 = 0;
  if (!clipRayToCell(origin, direction, tMin, tMax, t0, t1, pad)) return std::nullopt;
  const RayPolynomial poly = rayPolynomial(patch, origin + t0 * direction, direction);
  auto root = options.crossingsOnly ? firstCrossing(poly, 0.0, t1 - t0, options, stats)
                                    : firstRoot(poly, 0.0, t1 - t0, options, stats);
  if (!root) return std::nullopt;
  root->t = std::min(t0 + root->t, t1);
  return root;
}

}  // namespace cip
