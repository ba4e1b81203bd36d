#include "cip/patch/corner_patch.h"

#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

/// Forward-mode accumulation of value, gradient and (if kHessian) Hessian through a product of linear
/// factors. The value and gradient do not depend on the Hessian, so they are the same either way.
template <bool kHessian>
struct Jet {
  double v = 1;
  Vec3 g = Vec3::Zero();
  Mat3 h = Mat3::Zero();
  // this *= (a . x + value) where `value` is the factor's value at x and `a` its gradient.
  void multiply(double value, const Vec3& a) {
    if constexpr (kHessian)
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) h(r, c) = h(r, c) * value + g[r] * a[c] + a[r] * g[c];
    for (int r = 0; r < 3; ++r) g[r] = g[r] * value + v * a[r];
    v *= value;
  }
  // this *= b^2 for a face plane b of axis k (gradient +-e_k, `slope`): the square's gradient is 2 b slope
  // e_k and its Hessian 2 e_k e_k^T, so only row and column k gain terms. One such step replaces two general
  // products; written with Eigen expressions, those took 86 % of the continuity tests under the sanitizers.
  void multiplyFaceSquare(double b, int k, double slope) {
    const double q = b * b, d = 2 * b * slope;
    if constexpr (kHessian) {
      h *= q;
      for (int r = 0; r < 3; ++r) {
        h(r, k) += d * g[r];
        h(k, r) += d * g[r];
      }
      h(k, k) += 2 * v;
    }
    g *= q;
    g[k] += d * v;
    v *= q;
  }
};

double productOfSquares(std::uint8_t mask, const std::array<double, 6>& b) {
  double r = 1;
  for (int f = 0; f < 6; ++f)
    if ((mask >> f) & 1) r *= b[f] * b[f];
  return r;
}

}  // namespace

Vec3 CornerPatch::facePlaneGradient(int f) {
  Vec3 g = Vec3::Zero();
  g[f / 2] = (f & 1) ? -1.0 : 1.0;
  return g;
}

int CornerPatch::terms(std::array<PatchTerm, kMaxTerms>& out) const {
  int n = 0;
  for (int c = 0; c < numCorners; ++c) {
    if (weight[c] == 0) continue;
    auto ef = cube::edgeFaces(edge[c]);
    std::uint8_t mask = static_cast<std::uint8_t>(faceMask & ~((1u << ef[0]) | (1u << ef[1])));
    out[n++] = PatchTerm{weight[c], c, mask};
  }
  for (int f = 0; f < 6; ++f)
    if (((faceMask >> f) & 1) && faceCoefficient[f] != 0)
      out[n++] = PatchTerm{faceCoefficient[f], -1, static_cast<std::uint8_t>(faceMask & ~(1u << f))};
  if (central != 0) out[n++] = PatchTerm{central, -1, faceMask};
  return n;
}

double CornerPatch::valueWithoutCentral(const Vec3& x) const {
  std::array<double, 6> b;
  for (int f = 0; f < 6; ++f) b[f] = facePlane(f, x);
  double sum = 0;
  for (int c = 0; c < numCorners; ++c) {
    auto ef = cube::edgeFaces(edge[c]);
    std::uint8_t mask = static_cast<std::uint8_t>(faceMask & ~((1u << ef[0]) | (1u << ef[1])));
    sum += weight[c] * cornerPlane(c, x) * productOfSquares(mask, b);
  }
  for (int f = 0; f < 6; ++f)
    if ((faceMask >> f) & 1)
      sum += faceCoefficient[f] * productOfSquares(static_cast<std::uint8_t>(faceMask & ~(1u << f)), b);
  return sum;
}

double CornerPatch::centralBasis(const Vec3& x) const {
  std::array<double, 6> b;
  for (int f = 0; f < 6; ++f) b[f] = facePlane(f, x);
  return productOfSquares(faceMask, b);
}

double CornerPatch::value(const Vec3& x) const {
  double v = valueWithoutCentral(x);
  return central != 0 ? v + central * centralBasis(x) : v;
}

namespace {

template <bool kHessian>
PatchDerivatives derivativesOf(const CornerPatch& patch, const Vec3& x) {
  std::array<PatchTerm, CornerPatch::kMaxTerms> ts;
  int n = patch.terms(ts);
  PatchDerivatives out;
  for (int i = 0; i < n; ++i) {
    Jet<kHessian> j;
    if (ts[i].corner >= 0) j.multiply(patch.cornerPlane(ts[i].corner, x), patch.normal[ts[i].corner]);
    for (int f = 0; f < 6; ++f) {
      if (!((ts[i].faceSquares >> f) & 1)) continue;
      j.multiplyFaceSquare(CornerPatch::facePlane(f, x), f / 2, CornerPatch::facePlaneGradient(f)[f / 2]);
    }
    out.value += ts[i].coefficient * j.v;
    out.gradient += ts[i].coefficient * j.g;
    if constexpr (kHessian) out.hessian += ts[i].coefficient * j.h;
  }
  return out;
}

}  // namespace

PatchDerivatives CornerPatch::derivatives(const Vec3& x) const {
  return derivativesOf<true>(*this, x);
}

PatchDerivatives CornerPatch::valueAndGradient(const Vec3& x) const {
  // Every term is coefficient * [S_c] * q_x q_y q_z, q_a the product of the squared face planes of axis a in
  // the term (none, the low face, the high face or both): all four of each axis and their derivatives along
  // the axis are tabulated once, so a term costs a few products instead of one Jet step per factor.
  std::array<std::array<double, 4>, 3> q, dq;
  for (int a = 0; a < 3; ++a) {
    const double lo = x[a], hi = 1.0 - x[a];  // B_{2a} and B_{2a+1}; derivatives +1 and -1
    q[a] = {1.0, lo * lo, hi * hi, lo * lo * (hi * hi)};
    dq[a] = {0.0, 2 * lo, -2 * hi, 2 * lo * hi * (hi - lo)};
  }
  PatchDerivatives out;
  auto add = [&](double coefficient, int corner, unsigned mask) {
    const unsigned sx = mask & 3, sy = (mask >> 2) & 3, sz = (mask >> 4) & 3;
    const double qyz = q[1][sy] * q[2][sz], value = q[0][sx] * qyz;
    const Vec3 gradient(dq[0][sx] * qyz, q[0][sx] * dq[1][sy] * q[2][sz], q[0][sx] * q[1][sy] * dq[2][sz]);
    if (corner < 0) {
      out.value += coefficient * value;
      out.gradient += coefficient * gradient;
      return;
    }
    const double s = cornerPlane(corner, x);
    out.value += coefficient * (s * value);
    out.gradient += coefficient * (value * normal[corner] + s * gradient);
  };
  for (int c = 0; c < numCorners; ++c) {
    if (weight[c] == 0) continue;
    const auto ef = cube::edgeFaces(edge[c]);
    add(weight[c], c, faceMask & ~((1u << ef[0]) | (1u << ef[1])));
  }
  for (int f = 0; f < 6; ++f)
    if (((faceMask >> f) & 1) && faceCoefficient[f] != 0) add(faceCoefficient[f], -1, faceMask & ~(1u << f));
  if (central != 0) add(central, -1, faceMask);
  return out;
}

int CornerPatch::degree() const {
  std::array<PatchTerm, kMaxTerms> ts;
  int n = terms(ts), d = 0;
  for (int i = 0; i < n; ++i) {
    int k = (ts[i].corner >= 0 ? 1 : 0);
    for (int f = 0; f < 6; ++f) k += 2 * ((ts[i].faceSquares >> f) & 1);
    d = std::max(d, k);
  }
  return d;
}

}  // namespace cip
