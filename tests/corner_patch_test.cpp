// Properties of single-cell corner patches over all 256 sign configurations, and the paper's coefficient
// rules checked on hand-computed cells.
#include "cip/patch/corner_patch.h"

#include <gtest/gtest.h>

#include <random>

#include "cip/model/model_builder.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/topology/cell_loops.h"
#include "cip/topology/cube_topology.h"
#include "support/random_volume.h"

using namespace cip;

namespace {

// Face-frame point (u,v) of face f to cell-local coordinates.
Vec3 facePointToCell(int f, const Vec2& q) {
  auto uv = cube::otherAxes(cube::faceAxis(f));
  Vec3 x;
  x[cube::faceAxis(f)] = cube::faceSide(f);
  x[uv[0]] = q.x();
  x[uv[1]] = q.y();
  return x;
}

}  // namespace

TEST(CornerPatch, AllConfigurationsVanishAtIsoverticesInterpolateSidesAndFollowCornerPlanes) {
  std::mt19937 rng(7);
  int sidesChecked = 0, ambiguousFaces = 0;
  for (int config = 1; config < 255; ++config) {
    for (int trial = 0; trial < 4; ++trial) {
      auto vx = test::randomCellVertices(static_cast<std::uint8_t>(config), rng);
      std::uint8_t pairing;
      CellLoops loops;
      CornerPatch p = buildCellPatch(static_cast<std::uint8_t>(config), vx, &pairing, &loops);
      ASSERT_EQ(p.numCorners, __builtin_popcount(cube::crossedEdges(static_cast<std::uint8_t>(config))));
      EXPECT_LE(p.degree(), 12);
      for (int c = 0; c < p.numCorners; ++c) {
        // Vanishes at the isovertex (exactly: every term has a zero factor there).
        EXPECT_NEAR(p.value(p.point[c]), 0.0, 1e-14) << "config " << config << " corner " << c;
        // Gradient parallel to the corner plane's normal, same direction.
        PatchDerivatives d = p.derivatives(p.point[c]);
        ASSERT_GT(d.gradient.norm(), 0) << "config " << config;
        Vec3 g = d.gradient.normalized();
        EXPECT_NEAR(g.dot(p.normal[c]), 1.0, 1e-12) << "config " << config << " corner " << c;
      }
      for (int f = 0; f < 6; ++f) {
        if (!((p.faceMask >> f) & 1)) continue;
        FaceCrossings face = faceCrossingsOf(p, f, (pairing >> f) & 1);
        std::array<std::array<int, 2>, 2> segs;
        int n = faceSegments(face, segs);
        ASSERT_GE(n, 1);
        if (n == 1) {
          Vec3 s = facePointToCell(f, sidePoint(face, segs[0][0], segs[0][1]));
          // The patch interpolates the side point: relative to the size of its terms there.
          double scale = std::abs(p.valueWithoutCentral(s) - p.faceCoefficient[f] * 0) + 1e-3;
          EXPECT_NEAR(p.value(s), 0.0, 1e-12 * scale) << "config " << config << " face " << f;
          ++sidesChecked;
        } else {
          // Ambiguous face: one coefficient, two side points: least squares -> residuals orthogonal to the
          // basis.
          ++ambiguousFaces;
          double normal = 0, size = 0;
          for (int k = 0; k < 2; ++k) {
            Vec2 q = sidePoint(face, segs[k][0], segs[k][1]);
            FaceRestriction r = faceRestriction(face, q);
            double residual = r.cornerPart + p.faceCoefficient[f] * r.sideBasis;
            normal += residual * r.sideBasis;
            size += std::abs(r.cornerPart * r.sideBasis);
            // And the cell's function agrees with the face restriction's sign there.
            double cellValue = p.value(facePointToCell(f, q));
            if (std::abs(residual) > 1e-12) {
              EXPECT_EQ(cellValue > 0, residual > 0);
            }
          }
          EXPECT_NEAR(normal, 0.0, 1e-12 * (size + 1e-12));
        }
      }
    }
  }
  EXPECT_GT(sidesChecked, 1000);
  EXPECT_GT(ambiguousFaces, 10);
}

TEST(CornerPatch, DerivativesMatchFiniteDifferences) {
  // The analytic gradient and Hessian agree with central differences of the value (a check of the factored
  // derivative code, not how derivatives are computed).
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(0.05, 0.95);
  for (int config : {0x01, 0x17, 0x69, 0x5A, 0x3C}) {
    auto vx = test::randomCellVertices(static_cast<std::uint8_t>(config), rng);
    CornerPatch p = buildCellPatch(static_cast<std::uint8_t>(config), vx);
    p.central = 0.7;
    for (int s = 0; s < 20; ++s) {
      Vec3 x(u(rng), u(rng), u(rng));
      PatchDerivatives d = p.derivatives(x);
      EXPECT_NEAR(d.value, p.value(x), 1e-13);
      const double h = 1e-5;
      for (int a = 0; a < 3; ++a) {
        Vec3 e = Vec3::Unit(a) * h;
        double fd = (p.value(x + e) - p.value(x - e)) / (2 * h);
        EXPECT_NEAR(d.gradient[a], fd, 1e-7 * (1 + std::abs(fd)));
        PatchDerivatives dp = p.derivatives(x + e), dm = p.derivatives(x - e);
        for (int b = 0; b < 3; ++b) {
          double fdh = (dp.gradient[b] - dm.gradient[b]) / (2 * h);
          EXPECT_NEAR(d.hessian(a, b), fdh, 1e-6 * (1 + std::abs(fdh)));
        }
      }
      EXPECT_NEAR((d.hessian - d.hessian.transpose()).norm(), 0.0, 1e-12);
      // The renderer's normals: the tabulated value and gradient equal the Jet's to rounding, also on the
      // cell's faces and outside it.
      for (const Vec3& y : {x, Vec3(0, x.y(), x.z()), Vec3(x.x(), 1, 1), Vec3(-1e-9, 0.5, 1 + 1e-9)}) {
        const PatchDerivatives full = p.derivatives(y), fast = p.valueAndGradient(y);
        const double scale = 1 + full.gradient.norm();
        EXPECT_NEAR(fast.value, full.value, 1e-14 * scale);
        EXPECT_LT((fast.gradient - full.gradient).norm(), 1e-14 * scale);
        EXPECT_EQ(fast.hessian, Mat3::Zero());
      }
    }
  }
}

// Hand-computed cell: vertex 0 positive (configuration 0x01), crossings at the midpoints of the three edges
// at vertex 0, corner normals along the edges towards vertex 0 (the paper's section 7.1 normals):
//   p_x = (1/2,0,0), n_x = (-1,0,0);  p_y = (0,1/2,0), n_y = (0,-1,0);  p_z = (0,0,1/2), n_z = (0,0,-1).
// Bounding planes P = {x=0, y=0, z=0}: B = x, y, z.
namespace {
CornerPatch handCell() {
  std::array<IsoVertex, 12> vx;
  vx[cube::edgeIndex(0, 0, 0)] = IsoVertex{Vec3(0.5, 0, 0), Vec3(-1, 0, 0), 1.0};
  vx[cube::edgeIndex(1, 0, 0)] = IsoVertex{Vec3(0, 0.5, 0), Vec3(0, -1, 0), 1.0};
  vx[cube::edgeIndex(2, 0, 0)] = IsoVertex{Vec3(0, 0, 0.5), Vec3(0, 0, -1), 1.0};
  return buildCellPatch(0x01, vx);
}
}  // namespace

TEST(PatchCoefficients, TriangleRuleOnHandComputedFace) {
  CornerPatch p = handCell();
  // Face z=0 (f=4): u = x, v = y. Corner lines: -(u - 1/2) = 0 -> u = 1/2 and v = 1/2. They meet at
  // (1/2,1/2), inside the face: triangle (1/2,0), (0,1/2), (1/2,1/2) with centroid (1/3, 1/3).
  FaceCrossings face = faceCrossingsOf(p, 4, false);
  EXPECT_EQ(face.crossed, 0b0101);  // canonical edges 0 (x-edge at y=0) and 2 (y-edge at x=0)
  SideRule rule;
  Vec2 s = sidePoint(face, 0, 2, &rule);
  EXPECT_EQ(rule, SideRule::Triangle);
  EXPECT_NEAR(s.x(), 1.0 / 3, 1e-15);
  EXPECT_NEAR(s.y(), 1.0 / 3, 1e-15);
}

TEST(PatchCoefficients, TetragonRuleOnHandComputedFace) {
  // A face crossed on its two u-edges: (1/2, 0) on edge 0 and (1/2, 1) on edge 1, in-face normals (1,-2) and
  // (1,2). Lines: u - 2v = 1/2 and u + 2(v - 1) = 1/2 meet at u = 3/2 (outside the face): tetragon. Line 0
  // meets edge 1 (v = 1) at u = 5/2, clamped to (1,1); line 1 meets edge 0 (v = 0) at u = 5/2, clamped to
  // (1,0). Centroid of (1/2,0), (1,1), (1/2,1), (1,0) = (3/4, 1/2).
  FaceCrossings face;
  face.crossed = 0b0011;
  face.point[0] = Vec2(0.5, 0);
  face.point[1] = Vec2(0.5, 1);
  face.normal[0] = Vec2(1, -2);
  face.normal[1] = Vec2(1, 2);
  face.weight = {1, 1, 1, 1};
  SideRule rule;
  Vec2 s = sidePoint(face, 0, 1, &rule);
  EXPECT_EQ(rule, SideRule::Tetragon);
  EXPECT_NEAR(s.x(), 0.75, 1e-15);
  EXPECT_NEAR(s.y(), 0.5, 1e-15);
}

TEST(PatchCoefficients, Equation5OnHandComputedCell) {
  // Side point on z=0: q = (1/3, 1/3, 0). Eq. 5 there:
  //   corner x: S_x(q) = -(1/3 - 1/2) = 1/6, times B_{x=0}^2 = 1/9   -> 1/54
  //   corner y: S_y(q) = 1/6, times B_{y=0}^2 = 1/9                    -> 1/54
  //   corner z: has B_{z=0}^2 = 0                                     -> 0
  //   side basis: B_{x=0}^2 B_{y=0}^2 = 1/81
  //   w = -(1/54 + 1/54) / (1/81) = -3.   By symmetry all three side coefficients are -3.
  CornerPatch p = handCell();
  for (int f : {0, 2, 4}) EXPECT_NEAR(p.faceCoefficient[f], -3.0, 1e-13) << "face " << f;
  for (int f : {1, 3, 5}) EXPECT_EQ(p.faceCoefficient[f], 0.0);
  EXPECT_EQ(p.faceMask, 0b010101);
  EXPECT_NEAR(p.value(Vec3(1.0 / 3, 1.0 / 3, 0)), 0.0, 1e-15);
}

TEST(PatchCoefficients, Equation6OnHandComputedCell) {
  // Interior point p0 = (1/4, 1/4, 1/4):
  //   each corner: S = -(1/4 - 1/2) = 1/4, times one B^2 = 1/16   -> 1/64, three corners -> 3/64 = 12/256
  //   each side: w_f = -3 times two B^2 = 1/256                  -> -3/256, three sides -> -9/256
  //   central basis: (1/16)^3 = 1/4096
  //   w = -(12/256 - 9/256) / (1/4096) = -48.
  CornerPatch p = handCell();
  Vec3 p0(0.25, 0.25, 0.25);
  double w = fitCentralCoefficient(p, p0);
  EXPECT_NEAR(w, -48.0, 1e-11);
  p.central = w;
  EXPECT_NEAR(p.value(p0), 0.0, 1e-15);
  // A point on a bounding plane cannot fix the central coefficient.
  EXPECT_EQ(fitCentralCoefficient(p, Vec3(0, 0.3, 0.3)), 0.0);
}
