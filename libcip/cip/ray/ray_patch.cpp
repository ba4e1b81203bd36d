#include "cip/ray/ray_patch.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

constexpr double kEps = std::numeric_limits<double>::epsilon();
using Coefficients = std::array<double, RayPolynomial::kMaxDegree + 1>;

/// Binomial coefficients C(n, k), n <= kMaxDegree (exact in double).
constexpr auto kBinomial = [] {
  std::array<std::array<double, RayPolynomial::kMaxDegree + 1>, RayPolynomial::kMaxDegree + 1> t{};
  for (int n = 0; n <= RayPolynomial::kMaxDegree; ++n) {
    t[n][0] = 1;
    for (int k = 1; k <= n; ++k) t[n][k] = t[n - 1][k - 1] + (k < n ? t[n - 1][k] : 0.0);
  }
  return t;
}();

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
/// from `start` (the midpoint when it is not inside the bracket) kept inside the shrinking bracket, bisection
/// whenever a step would leave it or converge slower than bisection. Stops when |p(x)| is within p's rounding
/// bound at x (its sign there is noise, so further steps would only wander within the noise; one last Newton
/// step is taken when it stays inside the bracket), when the bracket or the step is below `tolerance`, or
/// after maxIterations.
template <class Polynomial>
double refineBracketed(const Polynomial& p, double lo, double hi, double valueLo, double tolerance,
                       int maxIterations, double start) {
  // Orient so that g = s * p is negative at lo and positive at hi.
  const double s = valueLo < 0 ? 1.0 : -1.0;
  double x = start > lo && start < hi ? start : 0.5 * (lo + hi);
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

/// The root in (0, 1) of the polynomial with scaled Bernstein coefficients c[0..n] on [0, 1] (c_k = C(n, k)
/// b_k, RayPolynomial::scaledBernstein), whose ends are non-zero with opposite signs and which change sign
/// once: safeguarded Newton steps on the Bernstein form itself (each evaluation O(n), against O(terms x
/// degree) for the factored form), started where the control polygon crosses zero, until the step is below
/// 1e-9 or the value is within the evaluation's rounding. refineBracketed finishes from there on the factored
/// form.
double bernsteinRoot(const Coefficients& c, int n) {
  // Close enough for the factored refinement to finish in one or two evaluations (one Newton step from 1e-9
  // of the interval leaves an error far below rounding); the Horner chains here are long, so no further
  // steps.
  constexpr double kStartTolerance = 1e-9;
  // p(u) = (1-u)^n sum c_i s^i with s = u / (1-u) (for u <= 1/2; mirrored above), and
  // p'(u) = (1-u)^(n-1) sum e_i s^i with e_i = (i+1) c_{i+1} - (n-i) c_i.
  Coefficients e;
  for (int i = 0; i < n; ++i) e[i] = (i + 1) * c[i + 1] - (n - i) * c[i];
  auto evaluate = [&](double u, double& value, double& derivative, double& noise) {
    const bool low = u <= 0.5;
    const double w = low ? 1.0 - u : u, s = (low ? u : 1.0 - u) / w;
    double v = 0, d = 0, m = 0;
    if (low) {
      for (int i = n; i >= 0; --i) {
        v = v * s + c[i];
        m = m * s + std::abs(c[i]);
      }
      for (int i = n - 1; i >= 0; --i) d = d * s + e[i];
    } else {
      for (int i = 0; i <= n; ++i) {
        v = v * s + c[i];
        m = m * s + std::abs(c[i]);
      }
      for (int i = 0; i < n; ++i) d = d * s + e[i];
    }
    double wn1 = 1;
    for (int i = 1; i < n; ++i) wn1 *= w;
    value = v * wn1 * w;
    derivative = d * wn1;
    noise = 4 * (n + 2) * kEps * m * wn1 * w;
  };
  // Orient so that g = sign * p is negative at 0 and positive at 1.
  const double sign = c[0] < 0 ? 1.0 : -1.0;
  // Start where the control polygon (k / n, b_k) crosses zero.
  int k = 0, j = 1;
  while (j < n && !(c[j] != 0 && (c[j] < 0) != (c[0] < 0))) {
    if (c[j] != 0) k = j;
    ++j;
  }
  const double bk = c[k] / kBinomial[n][k], bj = c[j] / kBinomial[n][j];
  double u = (k + (j - k) * (bk / (bk - bj))) / n;
  double lo = 0, hi = 1;
  if (!(u > lo && u < hi)) u = 0.5;
  for (int it = 0; it < 60; ++it) {
    double g, dg, noise;
    evaluate(u, g, dg, noise);
    g *= sign;
    dg *= sign;
    if (g == 0) return u;
    (g < 0 ? lo : hi) = u;
    double next = dg != 0 ? u - g / dg : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (std::abs(g) <= noise || std::abs(next - u) <= kStartTolerance || hi - lo <= kStartTolerance)
      return next;
    u = next;
  }
  return u;
}

}  // namespace

// ---------------------------------------------------------------------------------------------------------------------
// RayPolynomial

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

bool RayPolynomial::excludesZero(double a, double b) const {
  // Each factor's range on [a, b], and the range of its square.
  std::array<double, kMaxFactors> lo, hi, sqLo, sqHi;
  for (int f = 0; f < numFactors_; ++f) {
    const double va = factors_[f](a), vb = factors_[f](b);
    lo[f] = std::min(va, vb);
    hi[f] = std::max(va, vb);
    sqHi[f] = std::max(va * va, vb * vb);
    sqLo[f] = lo[f] >= 0 ? lo[f] * lo[f] : (hi[f] <= 0 ? hi[f] * hi[f] : 0.0);
  }
  double sumLo = 0, sumHi = 0, size = 0;
  for (int i = 0; i < numTerms_; ++i) {
    const Term& term = terms_[i];
    // The term's range as [sl, sh] x [ql, qh]: the non-negative powers (squares, factors without a negative
    // value) multiplied into [ql, qh], every other one into the signed [sl, sh].
    double sl = term.coefficient, sh = term.coefficient, ql = 1, qh = 1;
    for (int j = 0; j < term.count; ++j) {
      const int f = term.factor[j], power = term.power[j];
      if (power == 2) {
        ql *= sqLo[f];
        qh *= sqHi[f];
        continue;
      }
      if (power == 1 && lo[f] >= 0) {
        ql *= lo[f];
        qh *= hi[f];
        continue;
      }
      // The range of factor^power: monotone for odd powers, through zero for even powers of a factor that
      // changes sign.
      double gl = lo[f], gh = hi[f];
      if (power % 2 == 0 && gl < 0) {
        const double m = std::max(-gl, std::abs(gh));
        gl = gh <= 0 ? -gh : 0.0;
        gh = m;
      }
      double pl = gl, ph = gh;
      for (int k = 1; k < power; ++k) {
        pl *= gl;
        ph *= gh;
      }
      const double p0 = sl * pl, p1 = sl * ph, p2 = sh * pl, p3 = sh * ph;
      sl = std::min(std::min(p0, p1), std::min(p2, p3));
      sh = std::max(std::max(p0, p1), std::max(p2, p3));
    }
    const double tl = sl >= 0 ? sl * ql : sl * qh, th = sh >= 0 ? sh * qh : sh * ql;
    sumLo += tl;
    sumHi += th;
    size += std::max(-tl, th);
  }
  const double margin = 1e-12 * size;
  return size > 0 && (sumLo > margin || sumHi < -margin);
}

int RayPolynomial::scaledBernstein(double a, double b, std::array<double, kMaxDegree + 1>& out) const {
  const int n = degree_;
  std::array<double, kMaxFactors> la, lb;
  for (int f = 0; f < numFactors_; ++f) {
    la[f] = factors_[f](a);
    lb[f] = factors_[f](b);
  }
  // In the scaled basis u^k (1-u)^(m-k) a product by a linear factor with end values (l0, l1) is
  // c_k <- l0 c_k + l1 c_{k-1}, by its square c_k <- l0^2 c_k + 2 l0 l1 c_{k-1} + l1^2 c_{k-2}, and a degree
  // elevation c_k <- c_k + c_{k-1}: no weights. The sum of the terms of degree <= m, elevated to degree m, is
  // kept in `out`; each degree step elevates it once. The end coefficients (the same in both bases) are plain
  // products, summed apart in term order, so that they equal value(a) and value(b) bit for bit.
  std::array<double, kMaxTerms> ends0, ends1;
  int m = n;
  for (int i = 0; i < numTerms_; ++i) m = std::min(m, terms_[i].degree);
  std::fill(out.begin(), out.begin() + m + 1, 0.0);
  Coefficients cs;  // a term's coefficients
  double* const c = cs.data();
  for (;; ++m) {
    for (int i = 0; i < numTerms_; ++i) {
      const Term& term = terms_[i];
      if (term.degree != m) continue;
      // The ends in value()'s order of operations (bit for bit), apart from the interior's steps.
      double e0 = term.coefficient, e1 = term.coefficient;
      c[0] = term.coefficient;
      int k = 0;  // degree of c
      // A squared factor is one step with (l0^2, 2 l0 l1, l1^2): half the dependent steps of two linear ones,
      // whose latency, not their count, bounds this loop. The last step goes straight into `out`.
      for (int j = 0; j < term.count; ++j) {
        const double l0 = la[term.factor[j]], l1 = lb[term.factor[j]];
        const bool last = j + 1 == term.count;
        for (int p = 0; p < term.power[j]; ++p) {
          e0 *= l0;
          e1 *= l1;
        }
        // Upwards, carrying the two old coefficients below in registers: every load then reads what one store
        // of the previous step wrote (a vectorised in-place loop reads across two stores, which the processor
        // cannot forward: a stall per step).
        int steps = term.power[j];
        for (; steps >= 2; steps -= 2) {
          const double a0 = l0 * l0, a1 = 2 * l0 * l1, a2 = l1 * l1;
          double* const dst = last && steps == 2 ? out.data() : c;
          const bool accumulate = dst != c;
          double o1 = 0, o2 = 0;
          c[k + 1] = 0;
          c[k + 2] = 0;
          for (int q = 0; q <= k + 2; ++q) {
            const double old = c[q], v = a0 * old + a1 * o1 + a2 * o2;
            dst[q] = accumulate ? dst[q] + v : v;
            o2 = o1;
            o1 = old;
          }
          k += 2;
        }
        if (steps == 1) {
          double* const dst = last ? out.data() : c;
          const bool accumulate = dst != c;
          double o1 = 0;
          c[k + 1] = 0;
          for (int q = 0; q <= k + 1; ++q) {
            const double old = c[q], v = l0 * old + l1 * o1;
            dst[q] = accumulate ? dst[q] + v : v;
            o1 = old;
          }
          k += 1;
        }
      }
      if (term.count == 0) out[0] += c[0];
      ends0[i] = e0;
      ends1[i] = e1;
    }
    if (m >= n) break;
    out[m + 1] = out[m];
    for (int k = m; k >= 1; --k) out[k] += out[k - 1];
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

int RayPolynomial::bernstein(double a, double b, std::array<double, kMaxDegree + 1>& out) const {
  const int n = scaledBernstein(a, b, out);
  for (int k = 1; k < n; ++k) out[k] /= kBinomial[n][k];
  return n;
}

// ---------------------------------------------------------------------------------------------------------------------
// Root search

namespace {

template <class Polynomial>
std::optional<Root> firstRootOf(const Polynomial& p, double t0, double t1, const RootSearchOptions& options,
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

  // Depth-first over intervals, left half first: an explicit stack of [a,b] pairs (a plain struct: an array
  // of std::pair would be zero-filled, 4 KB for every cell a ray meets).
  struct Interval {
    double lo, hi;
  };
  constexpr int kStack = 256;
  std::array<Interval, kStack> stack;
  int top = 0;
  stack[top++] = Interval{t0, t1};
  // Most cells a ray crosses without a root are decided by a cheap interval bound.
  if (p.excludesZero(t0, t1)) return std::nullopt;
  Coefficients b;
  int examined = 0;
  while (top > 0) {
    const auto [lo, hi] = stack[--top];
    if (++examined > options.maxIntervals) {
      ++st.budgetExhausted;
      break;
    }
    ++st.intervals;
    const int n = p.scaledBernstein(lo, hi, b);  // signs and ends as the Bernstein coefficients'
    if (b[0] == 0) return Root{lo, RootKind::EndPoint};
    const int changes = signChanges(b, n);
    if (changes == 0) {
      if (b[n] == 0) return Root{hi, RootKind::EndPoint};
      continue;  // convex hull strictly on one side: no root in [lo, hi]
    }
    if (changes == 1 && b[n] != 0) {
      ++st.refinements;
      const double start = lo + bernsteinRoot(b, n) * (hi - lo);
      return Root{refineBracketed(p, lo, hi, b[0], tolerance, options.maxRefineIterations, start),
                  RootKind::Bracketed};
    }
    const double mid = lo + 0.5 * (hi - lo);
    if (hi - lo <= minWidth || top + 2 > kStack || !(mid > lo && mid < hi)) {
      // Depth limit: the roots here cannot be separated in double precision.
      if (sign(b[0]) * sign(b[n]) < 0) {  // odd count: a root exists by the intermediate value theorem
        ++st.refinements;
        return Root{refineBracketed(p, lo, hi, b[0], tolerance, options.maxRefineIterations, mid),
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
    stack[top++] = Interval{mid, hi};
    stack[top++] = Interval{lo, mid};
  }
  return std::nullopt;
}

template <class Polynomial>
std::optional<Root> firstCrossingOf(const Polynomial& p, double t0, double t1,
                                    const RootSearchOptions& options, RootSearchStats* stats) {
  if (!(t0 <= t1)) return std::nullopt;
  const double e = std::max(1e-9 * (t1 - t0), 4 * kEps * std::max(std::abs(t0), std::abs(t1)));
  double start = t0;
  for (int attempt = 0; attempt < 16; ++attempt) {
    auto root = firstRootOf(p, start, t1, options, stats);
    if (!root || root->kind == RootKind::Bracketed) return root;
    const double before = p.value(root->t - e), after = p.value(root->t + e);
    if (before != 0 && after != 0 && (before < 0) != (after < 0)) return root;
    start = root->t + e;  // an even-multiplicity zero (or a stretch where p vanishes): look further on
    if (!(start <= t1)) return std::nullopt;
  }
  return std::nullopt;
}

}  // namespace

std::optional<Root> firstRoot(const RayPolynomial& p, double t0, double t1, const RootSearchOptions& options,
                              RootSearchStats* stats) {
  return firstRootOf(p, t0, t1, options, stats);
}

std::optional<Root> firstRoot(const PatchRayPolynomial& p, double t0, double t1,
                              const RootSearchOptions& options, RootSearchStats* stats) {
  return firstRootOf(p, t0, t1, options, stats);
}

std::optional<Root> firstCrossing(const RayPolynomial& p, double t0, double t1,
                                  const RootSearchOptions& options, RootSearchStats* stats) {
  return firstCrossingOf(p, t0, t1, options, stats);
}

std::optional<Root> firstCrossing(const PatchRayPolynomial& p, double t0, double t1,
                                  const RootSearchOptions& options, RootSearchStats* stats) {
  return firstCrossingOf(p, t0, t1, options, stats);
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
  const PatchRayPolynomial poly(patch, origin + t0 * direction, direction);
  auto root = options.crossingsOnly ? firstCrossing(poly, 0.0, t1 - t0, options, stats)
                                    : firstRoot(poly, 0.0, t1 - t0, options, stats);
  if (!root) return std::nullopt;
  root->t = std::min(t0 + root->t, t1);
  return root;
}

}  // namespace cip
