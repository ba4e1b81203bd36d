#include "cip/ray/patch_ray_polynomial.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include "cip/core/vector_clones.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

constexpr double kEps = std::numeric_limits<double>::epsilon();
constexpr int kMaxTerms = PatchRayPolynomial::kMaxTerms;
constexpr int kMaxFaces = PatchRayPolynomial::kMaxFaces;
using Terms = PatchRayPolynomial::Terms;
using Row = std::array<double, kMaxTerms>;

// The kernels: each step a loop over the terms (written so that it vectorises: no branch, selects only),
// compiled for AVX2 and the baseline (vector_clones.h; no fused multiply-add, so both give the same bits).

/// The face rows of the terms: per bounding plane s (plane offset + slope * t along the ray) and term i, the
/// plane where bit s of has[i] is set, the constant 1 elsewhere.
CIP_VECTOR_CLONES void fillFaceRows(Terms& terms, const double* planeOffset, const double* planeSlope,
                                    const std::uint64_t* has) {
  for (int s = 0; s < terms.faces; ++s) {
    const auto ss = static_cast<std::size_t>(s);
    const double o = planeOffset[s], d = planeSlope[s];
    double* __restrict fo = terms.faceOffset[ss].data();
    double* __restrict fs = terms.faceSlope[ss].data();
    double* __restrict fr = terms.faceRounding[ss].data();
    for (int i = 0; i < terms.lanes; ++i) {
      const bool used = (has[i] >> s) & 1;
      fo[i] = used ? o : 1.0;
      fs[i] = used ? d : 0.0;
      fr[i] = used ? 2 * kEps : 0.0;
    }
  }
}

/// The terms' products at t: coefficient * linear(t), then times plane(t)^2 per plane, each square formed
/// first. value(), valueDerivativeAndBound() and the ends of scaledBernstein() form their values in exactly
/// this order, so they agree bit for bit.
CIP_VECTOR_CLONES void termValues(const Terms& terms, double t, double* __restrict out) {
  const double* c = terms.coefficient.data();
  const double* lo = terms.linearOffset.data();
  const double* ls = terms.linearSlope.data();
  for (int i = 0; i < terms.lanes; ++i) out[i] = c[i] * (lo[i] + ls[i] * t);
  for (int s = 0; s < terms.faces; ++s) {
    const double* fo = terms.faceOffset[static_cast<std::size_t>(s)].data();
    const double* fs = terms.faceSlope[static_cast<std::size_t>(s)].data();
    for (int i = 0; i < terms.lanes; ++i) {
      const double g = fo[i] + fs[i] * t;
      out[i] = out[i] * (g * g);
    }
  }
}

/// Per term, forward accumulation of value (as termValues) and derivative, and the products of the factors'
/// magnitudes, exactly and perturbed by their rounding (rounding * (|offset| + |slope t|) each).
CIP_VECTOR_CLONES void termValueDerivativeAndMagnitudes(const Terms& terms, double t, double* __restrict v,
                                                        double* __restrict d, double* __restrict exact,
                                                        double* __restrict perturbed) {
  const double* c = terms.coefficient.data();
  const double* lo = terms.linearOffset.data();
  const double* ls = terms.linearSlope.data();
  const double* lr = terms.linearRounding.data();
  for (int i = 0; i < terms.lanes; ++i) {
    const double l = lo[i] + ls[i] * t, m = std::abs(l);
    const double p = m + lr[i] * (std::abs(lo[i]) + std::abs(ls[i] * t));
    const double a = std::abs(c[i]);
    v[i] = c[i] * l;
    d[i] = c[i] * ls[i];
    exact[i] = a * m;
    perturbed[i] = a * p;
  }
  for (int s = 0; s < terms.faces; ++s) {
    const auto ss = static_cast<std::size_t>(s);
    const double* fo = terms.faceOffset[ss].data();
    const double* fs = terms.faceSlope[ss].data();
    const double* fr = terms.faceRounding[ss].data();
    for (int i = 0; i < terms.lanes; ++i) {
      const double g = fo[i] + fs[i] * t, m = std::abs(g);
      const double p = m + fr[i] * (std::abs(fo[i]) + std::abs(fs[i] * t));
      const double gg = g * g;
      d[i] = d[i] * gg + v[i] * (2 * g * fs[i]);
      v[i] = v[i] * gg;
      exact[i] = exact[i] * (m * m);
      perturbed[i] = perturbed[i] * (p * p);
    }
  }
}

/// Per term on [a, b]: coefficient * corner plane as a signed range [sl, sh] and the product of the squared
/// planes as a range [ql, qh] >= 0; the term's range is then their product, written to [lo, hi].
CIP_VECTOR_CLONES void termRanges(const Terms& terms, double a, double b, double* __restrict lo,
                                  double* __restrict hi) {
  const double* c = terms.coefficient.data();
  const double* lo0 = terms.linearOffset.data();
  const double* ls = terms.linearSlope.data();
  alignas(32) Row ql, qh;
  for (int i = 0; i < terms.lanes; ++i) {
    ql[static_cast<std::size_t>(i)] = 1;
    qh[static_cast<std::size_t>(i)] = 1;
  }
  for (int s = 0; s < terms.faces; ++s) {
    const double* fo = terms.faceOffset[static_cast<std::size_t>(s)].data();
    const double* fs = terms.faceSlope[static_cast<std::size_t>(s)].data();
    for (int i = 0; i < terms.lanes; ++i) {
      const double ga = fo[i] + fs[i] * a, gb = fo[i] + fs[i] * b;
      // The square's lower end: gl^2 where the plane is >= 0, gh^2 where <= 0, 0 where it changes sign
      // (one of the two terms is 0; no branch, so the loop vectorises).
      const bool up = ga < gb;
      const double mn = up ? ga : gb, mx = up ? gb : ga;
      const double gl = mn > 0 ? mn : 0.0, gh = mx < 0 ? mx : 0.0;
      const double sa = ga * ga, sb = gb * gb;
      ql[static_cast<std::size_t>(i)] *= gl * gl + gh * gh;
      qh[static_cast<std::size_t>(i)] *= sa < sb ? sb : sa;
    }
  }
  for (int i = 0; i < terms.lanes; ++i) {
    const double la = lo0[i] + ls[i] * a, lb = lo0[i] + ls[i] * b;
    const double p = c[i] * la, q = c[i] * lb;  // the signed factor's range ends
    const double sl = std::min(p, q), sh = std::max(p, q);
    const double l = ql[static_cast<std::size_t>(i)], h = qh[static_cast<std::size_t>(i)];
    const double forLo = sl >= 0 ? l : h, forHi = sh >= 0 ? h : l;  // selects only: no branch
    lo[i] = sl * forLo;
    hi[i] = sh * forHi;
  }
}

/// Scaled Bernstein coefficients of every term on [a, b], c[q][i] for term i: the corner plane first (c_0 =
/// coefficient l0, c_1 = coefficient l1), then per plane (end values g0, g1) the product by its square,
/// c_q <- g0^2 c_q + 2 g0 g1 c_{q-1} + g1^2 c_{q-2}, downwards in place. Every term takes the same steps.
CIP_VECTOR_CLONES void termBernstein(const Terms& terms, double a, double b, Row* __restrict c) {
  const double* cf = terms.coefficient.data();
  const double* lo = terms.linearOffset.data();
  const double* ls = terms.linearSlope.data();
  const int lanes = terms.lanes;
  for (int i = 0; i < lanes; ++i) {
    c[0][static_cast<std::size_t>(i)] = cf[i] * (lo[i] + ls[i] * a);
    c[1][static_cast<std::size_t>(i)] = cf[i] * (lo[i] + ls[i] * b);
  }
  for (int s = 0, k = 1; s < terms.faces; ++s, k += 2) {
    const double* fo = terms.faceOffset[static_cast<std::size_t>(s)].data();
    const double* fs = terms.faceSlope[static_cast<std::size_t>(s)].data();
    alignas(32) Row a0, a1, a2;
    for (int i = 0; i < lanes; ++i) {
      const double g0 = fo[i] + fs[i] * a, g1 = fo[i] + fs[i] * b;
      a0[static_cast<std::size_t>(i)] = g0 * g0;
      a1[static_cast<std::size_t>(i)] = 2 * g0 * g1;
      a2[static_cast<std::size_t>(i)] = g1 * g1;
    }
    // k is the degree before this step (k >= 1): the new coefficients k + 2 and k + 1 first, then down to 0.
    double* __restrict top = c[k + 2].data();
    double* __restrict next = c[k + 1].data();
    const double* ck = c[k].data();
    const double* ck1 = c[k - 1].data();
    for (int i = 0; i < lanes; ++i) {
      top[i] = a2[static_cast<std::size_t>(i)] * ck[i];
      next[i] = a1[static_cast<std::size_t>(i)] * ck[i] + a2[static_cast<std::size_t>(i)] * ck1[i];
    }
    for (int q = k; q >= 2; --q) {
      double* __restrict cq = c[q].data();
      const double* c1 = c[q - 1].data();
      const double* c2 = c[q - 2].data();
      for (int i = 0; i < lanes; ++i)
        cq[i] = a0[static_cast<std::size_t>(i)] * cq[i] + a1[static_cast<std::size_t>(i)] * c1[i] +
                a2[static_cast<std::size_t>(i)] * c2[i];
    }
    double* __restrict c1 = c[1].data();
    double* __restrict c0 = c[0].data();
    for (int i = 0; i < lanes; ++i) {
      c1[i] = a0[static_cast<std::size_t>(i)] * c1[i] + a1[static_cast<std::size_t>(i)] * c0[i];
      c0[i] = a0[static_cast<std::size_t>(i)] * c0[i];
    }
  }
}

/// Sum of values[0 .. count) in index order.
double sumInOrder(const double* values, int count) {
  double sum = 0;
  for (int i = 0; i < count; ++i) sum += values[i];
  return sum;
}

}  // namespace

PatchRayPolynomial::PatchRayPolynomial(const CornerPatch& patch, const Vec3& origin, const Vec3& direction) {
  Terms& t = terms_;
  // The bounding planes along the ray, in increasing face order, and each face's slot among them.
  std::array<double, kMaxFaces> planeOffset{}, planeSlope{};
  std::array<int, 6> slot{};
  for (int f = 0; f < 6; ++f) {
    if (!((patch.faceMask >> f) & 1)) continue;
    const int axis = f / 2;
    const auto s = static_cast<std::size_t>(t.faces);
    planeOffset[s] = (f & 1) ? 1.0 - origin[axis] : origin[axis];
    planeSlope[s] = (f & 1) ? -direction[axis] : direction[axis];
    slot[static_cast<std::size_t>(f)] = t.faces++;
  }
  degree_ = 1 + 2 * t.faces;
  // Per term the bounding planes it has, as bits of the slots.
  std::array<std::uint64_t, kMaxTerms> has{};
  auto slots = [&](unsigned faces) {
    std::uint64_t bits = 0;
    for (int f = 0; f < 6; ++f)
      if ((faces >> f) & 1) bits |= std::uint64_t{1} << slot[static_cast<std::size_t>(f)];
    return bits;
  };
  auto addTerm = [&](double coefficient, double offset, double slope, double rounding, std::uint64_t planes) {
    const auto i = static_cast<std::size_t>(numTerms_++);
    t.coefficient[i] = coefficient;
    t.linearOffset[i] = offset;
    t.linearSlope[i] = slope;
    t.linearRounding[i] = rounding;
    has[i] = planes;
  };
  const unsigned faces = patch.faceMask;
  const std::uint64_t all = slots(faces);
  for (int c = 0; c < patch.numCorners; ++c) {
    if (patch.weight[c] == 0) continue;
    const Vec3& n = patch.normal[c];
    const auto ef = cube::edgeFaces(patch.edge[c]);
    addTerm(patch.weight[c], n.dot(origin - patch.point[c]), n.dot(direction), 2 * kEps,
            slots(faces & ~((1u << ef[0]) | (1u << ef[1]))));
  }
  for (int f = 0; f < 6; ++f)
    if (((faces >> f) & 1) && patch.faceCoefficient[f] != 0)
      addTerm(patch.faceCoefficient[f], 1.0, 0.0, 0.0,
              all & ~(std::uint64_t{1} << slot[static_cast<std::size_t>(f)]));
  if (patch.central != 0) addTerm(patch.central, 1.0, 0.0, 0.0, all);
  t.lanes = (numTerms_ + kLanes - 1) / kLanes * kLanes;
  for (auto i = static_cast<std::size_t>(numTerms_); i < static_cast<std::size_t>(t.lanes); ++i) {
    t.coefficient[i] = 0;
    t.linearOffset[i] = 1;
    t.linearSlope[i] = 0;
    t.linearRounding[i] = 0;
    has[i] = 0;
  }
  fillFaceRows(t, planeOffset.data(), planeSlope.data(), has.data());
}

double PatchRayPolynomial::value(double t) const {
  alignas(32) Row v;
  termValues(terms_, t, v.data());
  return sumInOrder(v.data(), terms_.lanes);
}

void PatchRayPolynomial::valueDerivativeAndBound(double t, double& value, double& derivative,
                                                 double& bound) const {
  alignas(32) Row v, d, exact, perturbed;
  termValueDerivativeAndMagnitudes(terms_, t, v.data(), d.data(), exact.data(), perturbed.data());
  value = sumInOrder(v.data(), terms_.lanes);
  derivative = sumInOrder(d.data(), terms_.lanes);
  double spread = 0, size = 0;
  for (std::size_t i = 0; i < static_cast<std::size_t>(terms_.lanes); ++i) {
    spread += perturbed[i] - exact[i];
    size += perturbed[i];
  }
  bound = 4.0 * (spread + (degree_ + numTerms_ + 2) * kEps * size);
}

double PatchRayPolynomial::roundingBound(double t) const {
  double value = 0, derivative = 0, bound = 0;
  valueDerivativeAndBound(t, value, derivative, bound);
  return bound;
}

bool PatchRayPolynomial::excludesZero(double a, double b) const {
  alignas(32) Row lo, hi;
  termRanges(terms_, a, b, lo.data(), hi.data());
  double sumLo = 0, sumHi = 0, size = 0;
  for (std::size_t i = 0; i < static_cast<std::size_t>(terms_.lanes); ++i) {
    sumLo += lo[i];
    sumHi += hi[i];
    size += std::max(-lo[i], hi[i]);
  }
  const double margin = 1e-12 * size;
  return size > 0 && (sumLo > margin || sumHi < -margin);
}

int PatchRayPolynomial::scaledBernstein(double a, double b, Coefficients& out) const {
  const int n = degree_;
  alignas(32) std::array<Row, kMaxDegree + 1> c;
  termBernstein(terms_, a, b, c.data());
  // Each coefficient summed in term order: the ends are then value(a) and value(b), bit for bit.
  for (int q = 0; q <= n; ++q)
    out[static_cast<std::size_t>(q)] = sumInOrder(c[static_cast<std::size_t>(q)].data(), terms_.lanes);
  return n;
}

}  // namespace cip
