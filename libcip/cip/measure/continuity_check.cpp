#include "cip/measure/continuity_check.h"

#include <algorithm>
#include <cmath>

#include "cip/core/bisection.h"
#include "cip/topology/cube_topology.h"

namespace cip {

ContinuityStats measureContinuity(const Model& m, int kSamples) {
  ContinuityStats s;
  for (std::size_t a = 0; a < m.cells.size(); ++a) {
    const ModelCell& ca = m.cells[a];
    CornerPatch pa = m.patch(a);
    for (int axis = 0; axis < 3; ++axis) {
      std::int64_t nb[3] = {ca.index[0], ca.index[1], ca.index[2]};
      nb[axis] += 1;
      std::int64_t b = m.findCell(nb[0], nb[1], nb[2]);
      if (b < 0) continue;
      int faceA = 2 * axis + 1;
      if (!((pa.faceMask >> faceA) & 1)) continue;  // no crossings on the shared face
      CornerPatch pb = m.patch(static_cast<std::size_t>(b));
      ++s.facePairs;
      auto uv = cube::otherAxes(axis);
      auto onA = [&](double u, double v) {
        Vec3 x;
        x[axis] = 1;
        x[uv[0]] = u;
        x[uv[1]] = v;
        return x;
      };
      auto toB = [&](Vec3 x) {
        x[axis] -= 1;
        return x;
      };
      for (int iu = 0; iu <= kSamples; ++iu) {
        double u = (iu + 0.5) / (kSamples + 1);
        double prevV = 0.5 / (kSamples + 1), prevF = pa.value(onA(u, prevV));
        for (int iv = 0; iv <= kSamples; ++iv) {
          double v = (iv + 0.5) / (kSamples + 1);
          double fa = pa.value(onA(u, v)), fb = pb.value(toB(onA(u, v)));
          double ga = pa.derivatives(onA(u, v)).gradient.norm();
          if (std::abs(fa) > 1e-9 * ga && (fa > 0) != (fb > 0)) ++s.signDisagreements;
          if ((fa > 0) != (prevF > 0)) {
            Vec3 x =
                onA(u, bisectSignChange([&](double t) { return pa.value(onA(u, t)); }, prevV, v, prevF, 80));
            PatchDerivatives da = pa.derivatives(x), db = pb.derivatives(toB(x));
            if (da.gradient.norm() > 0 && db.gradient.norm() > 0) {
              s.maxGap = std::max(s.maxGap, std::abs(db.value) / db.gradient.norm());
              double c = da.gradient.normalized().dot(db.gradient.normalized());
              s.maxAngle = std::max(s.maxAngle, std::acos(std::clamp(c, -1.0, 1.0)));
              ++s.curvePoints;
            }
          }
          prevV = v;
          prevF = fa;
        }
      }
    }
  }
  return s;
}

}  // namespace cip
