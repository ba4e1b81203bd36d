#include "cip/reference/isovertex.h"

#include <algorithm>
#include <cmath>

#include "cip/core/error.h"

namespace cip {

const char* toString(NormalMode mode) {
  switch (mode) {
    case NormalMode::Edge:
      return "edge";
    case NormalMode::Gradient:
      return "gradient";
    case NormalMode::Exact:
      return "exact";
  }
  return "unknown";
}

NormalMode parseNormalMode(const std::string& text) {
  if (text == "edge") return NormalMode::Edge;
  if (text == "gradient") return NormalMode::Gradient;
  if (text == "exact") return NormalMode::Exact;
  throw Error("unknown normal mode '" + text + "' (expected edge, gradient or exact)");
}

double linearCrossing(double v0, double v1, double isovalue) {
  double den = v1 - v0;
  if (den == 0) return 0.5;
  double t = (isovalue - v0) / den;
  return std::clamp(t, 0.0, 1.0);
}

double exactCrossing(const ScalarField& field, const Vec3& a, const Vec3& b, double isovalue) {
  double lo = 0, hi = 1;
  double flo = field.value(a) - isovalue, fhi = field.value(b) - isovalue;
  if (flo == 0) return 0;
  if (fhi == 0) return 1;
  int side = 0;
  for (int it = 0; it < 200 && hi - lo > 1e-16; ++it) {
    double t = (lo * fhi - hi * flo) / (fhi - flo);
    if (!(t > lo && t < hi) || it % 8 == 7) t = 0.5 * (lo + hi);  // bisection safeguard
    double ft = field.value(a + t * (b - a)) - isovalue;
    if (ft == 0) return t;
    if ((ft > 0) == (fhi > 0)) {
      hi = t;
      fhi = ft;
      if (side == -1) flo *= 0.5;  // Illinois step
      side = -1;
    } else {
      lo = t;
      flo = ft;
      if (side == 1) fhi *= 0.5;
      side = 1;
    }
  }
  return 0.5 * (lo + hi);
}

Vec3 orientCornerNormal(const Vec3& normal, const Vec3& towardsPositive) {
  constexpr double kMinCos = 0.05;  // about 87 degrees from the edge at most
  double len = normal.norm();
  if (!(len > 0) || !std::isfinite(len)) return towardsPositive;
  Vec3 n = normal / len;
  double c = n.dot(towardsPositive);
  if (c < kMinCos) {
    n += (kMinCos - c) * towardsPositive;
    n.normalize();
  }
  return n;
}

Vec3 normalClearOfUncrossedEdges(const DenseGrid& grid, const std::array<std::int64_t, 3>& p, int axis,
                                 double isovalue, const Vec3& normal, const Vec3& towardsPositive) {
  const bool above = grid.at(p[0], p[1], p[2]) > isovalue;
  Vec3 n = normal;
  for (int other = 0; other < 3; ++other) {
    if (other == axis) continue;
    for (int step : {-1, 1}) {
      auto q = p;
      q[other] += step;
      if (q[other] < 0 || q[other] >= grid.geometry.dims[other]) continue;
      if ((grid.at(q[0], q[1], q[2]) > isovalue) != above) continue;  // a crossed edge
      // Along the edge the plane changes by n[other] * step per unit; it must not move towards the other
      // sign.
      const double along = n[other] * step;
      if (above ? along < 0 : along > 0) n[other] = 0;
    }
  }
  return orientCornerNormal(n, towardsPositive);
}

}  // namespace cip
