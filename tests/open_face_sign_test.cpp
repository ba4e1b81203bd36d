// open_face_sign.h: the sign of a patch on the open faces of its cell, by separable sums checked against the
// patch's own value at every point, and the screen a writer runs before that check.
#include "cip/patch/open_face_sign.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include "cip/model/model_builder.h"
#include "cip/readers/volume_reader.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

/// The corners' sign of open face f, +1 or -1.
double cornerSign(const Model& model, std::size_t c, int f) {
  return ((model.cells[c].config >> cube::faceVertex(f, 0)) & 1) ? 1.0 : -1.0;
}

/// The patch's value at point (a, b) of an n x n lattice of face f, border included, as the measure of
/// holes has always taken it: CornerPatch::value at each point.
double faceValue(const CornerPatch& patch, int f, int n, int a, int b) {
  const int axis = cube::faceAxis(f);
  Vec3 x;
  x[axis] = cube::faceSide(f);
  x[(axis + 1) % 3] = static_cast<double>(a) / (n - 1);
  x[(axis + 2) % 3] = static_cast<double>(b) / (n - 1);
  return patch.value(x);
}

bool leaksPointByPoint(const CornerPatch& patch, double sign, int f, int n) {
  for (int a = 0; a < n; ++a)
    for (int b = 0; b < n; ++b) {
      const double v = faceValue(patch, f, n, a, b);
      if (v != 0 && (v > 0) != (sign > 0)) return true;
    }
  return false;
}

/// The bundled blobs built with the paper's rules (which leak through many open faces) and fitted, and the
/// fitted model with every side and central coefficient moved by up to 20 % at random (more faces near the
/// other sign, some across it).
std::vector<Model> models() {
  const SparseVolume volume = readVolume(test::sourceFile("data/blobs.nrrd"));
  BuildOptions o;
  o.isovalue = 128;
  o.method = PatchMethod::Paper;
  std::vector<Model> out;
  out.push_back(buildModel(*volume.dense(), o));
  o.method = PatchMethod::Fitted;
  out.push_back(buildModel(*volume.dense(), o));
  Model shaken = out.back();
  std::mt19937 random(7);
  std::uniform_real_distribution<double> factor(0.8, 1.2);
  for (ModelCell& cell : shaken.cells) {
    for (double& w : cell.faceCoefficient) w *= factor(random);
    cell.central *= factor(random);
  }
  out.push_back(std::move(shaken));
  return out;
}

}  // namespace

// The separable sums decide a point only where they keep the corners' sign by far more than any rounding;
// the verdict is the patch's value point by point, on every open face of these models and on lattices of
// 2, 9, 33 (the measure's) and 65 points (more than the sums keep on the stack).
TEST(OpenFaceSign, LeaksAsThePatchsValuePointByPoint) {
  int leaking = 0, faces = 0;
  for (const Model& model : models())
    for (std::size_t c = 0; c < model.cells.size(); ++c) {
      const CornerPatch patch = model.patch(c);
      for (int f = 0; f < 6; ++f) {
        if ((patch.faceMask >> f) & 1) continue;
        ++faces;
        for (int n : {2, 9, kOpenFaceLattice, 65}) {
          if (n == 65 && c % 16 != 0) continue;  // a sample of the cells: 65 x 65 points by value() is slow
          const bool expected = leaksPointByPoint(patch, cornerSign(model, c, f), f, n);
          ASSERT_EQ(openFaceLeaks(patch, model.cells[c].config, f, n), expected)
              << "cell " << c << " face " << f << " lattice " << n;
          leaking += expected && n == kOpenFaceLattice;
        }
      }
    }
  EXPECT_GT(faces, 1000);
  EXPECT_GT(leaking, 100) << "the models should leak through some faces, or the test shows little";
}

// The screen flags a face where, at a point inside its 9 x 9 lattice (1/8 apart), the value with the corners'
// sign is below `inside` times the largest magnitude inside, at a point on its edges (corners left out) below
// `border` times the largest magnitude of the lattice, or where a corner has the other sign, and no other
// face: checked against value() at those points, faces within 10^-9 of a threshold left out (the two sums
// round differently).
TEST(OpenFaceSign, ScreenFlagsTheFacesThatComeNearTheOtherSign) {
  int flagged = 0, clear = 0, byBorderOnly = 0;
  const std::array<std::array<double, 2>, 3> fractions{{{0.0, 0.0}, {0.05, 0.01}, {0.3, 0.1}}};
  for (const Model& model : models())
    for (std::size_t c = 0; c < model.cells.size(); ++c) {
      const CornerPatch patch = model.patch(c);
      for (const auto& [inside, border] : fractions) {
        const unsigned near = openFacesNearOtherSign(patch, model.cells[c].config, inside, border);
        EXPECT_EQ(near & patch.faceMask, 0u) << "a bounding plane is not an open face";
        for (int f = 0; f < 6; ++f) {
          if ((patch.faceMask >> f) & 1) continue;
          const double sign = cornerSign(model, c, f);
          double lowInside = INFINITY, highInside = 0, lowBorder = INFINITY, high = 0, lowCorner = INFINITY;
          for (int a = 0; a <= 8; ++a)
            for (int b = 0; b <= 8; ++b) {
              const bool edgeA = a == 0 || a == 8, edgeB = b == 0 || b == 8;
              const double v = faceValue(patch, f, 9, a, b);  // (a / 8, b / 8)
              high = std::max(high, std::abs(v));
              if (edgeA && edgeB) {
                lowCorner = std::min(lowCorner, sign * v);
              } else if (edgeA || edgeB) {
                lowBorder = std::min(lowBorder, sign * v);
              } else {
                lowInside = std::min(lowInside, sign * v);
                highInside = std::max(highInside, std::abs(v));
              }
            }
          if (std::abs(lowInside - inside * highInside) <= 1e-9 * high ||
              std::abs(lowBorder - border * high) <= 1e-9 * high || std::abs(lowCorner) <= 1e-9 * high)
            continue;
          const bool nearInside = !(lowInside > inside * highInside),
                     nearBorder = !(lowBorder > border * high) || lowCorner < 0;
          EXPECT_EQ(((near >> f) & 1) != 0, nearInside || nearBorder)
              << "cell " << c << " face " << f << " fractions " << inside << ", " << border;
          (nearInside || nearBorder ? flagged : clear)++;
          byBorderOnly += nearBorder && !nearInside;
        }
      }
    }
  EXPECT_GT(flagged, 100);
  EXPECT_GT(byBorderOnly, 10) << "the border's test should flag faces the inside's does not";
  EXPECT_GT(clear, 1000);
}
