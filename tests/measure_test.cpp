// The measures of libcip/cip/measure/ find the defects they measure: each test plants one in a model (or a
// sample list) whose measure is 0 before, and expects it found with the count or value an independent
// computation in the test gives (closed forms where the field allows: the sphere's field is its signed
// distance, the plane is reproduced exactly).
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <vector>

#include "cip/core/bisection.h"
#include "cip/measure/continuity_check.h"
#include "cip/measure/surface_fidelity.h"
#include "cip/model/model_builder.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "support/join_tolerances.h"

using namespace cip;

namespace {

constexpr double kRadToDeg = 180 / M_PI;

Model fieldModel(const AnalyticField& field, int n, NormalMode mode) {
  BuildOptions o;
  o.isovalue = field.defaultIsovalue();
  o.normals = mode;
  o.exactField = &field;
  return buildModel(sampleField(field, n, field.name()), o);
}

/// The model with only the cells `keep` (model indices, ascending): the same vertex table and corners.
Model onlyCells(const Model& m, const std::vector<std::size_t>& keep) {
  Model out = m;
  out.cells.clear();
  for (std::size_t c : keep) out.cells.push_back(m.cells[c]);
  return out;
}

Model withoutCell(const Model& m, std::size_t cell) {
  Model out = m;
  out.cells.erase(out.cells.begin() + static_cast<std::ptrdiff_t>(cell));
  return out;
}

/// A cell whose upper face along `axis` is a bounding plane with a non-empty cell across it (that one's
/// index in `upper`), the first in grid order.
std::size_t cellWithUpperNeighbour(const Model& m, int axis, std::size_t& upper) {
  for (std::size_t c = 0; c < m.cells.size(); ++c) {
    if (!((m.patch(c).faceMask >> (2 * axis + 1)) & 1)) continue;
    std::int64_t i[3] = {m.cells[c].index[0], m.cells[c].index[1], m.cells[c].index[2]};
    ++i[axis];
    const std::int64_t b = m.findCell(i[0], i[1], i[2]);
    if (b < 0) continue;
    upper = static_cast<std::size_t>(b);
    return c;
  }
  ADD_FAILURE() << "no face pair along axis " << axis;
  return 0;
}

/// Largest gap and normal angle over the zeros of the lower cell's patch on the face it shares with the upper
/// cell (along `axis`), on the lines measureContinuity samples (u = (i + 1/2) / (samples + 1)), each
/// scanned in 2048 steps between its first and last sample and the roots bisected to rounding: what
/// measureContinuity should find there, by another search for the zeros.
struct FaceMismatch {
  double gap = 0, angle = 0;
};
FaceMismatch mismatchOnFace(const Model& m, std::size_t lower, std::size_t upper, int axis, int samples) {
  const CornerPatch a = m.patch(lower), b = m.patch(upper);
  const auto uv = cube::otherAxes(axis);
  FaceMismatch out;
  const double first = 0.5 / (samples + 1), last = (samples + 0.5) / (samples + 1);
  for (int i = 0; i <= samples; ++i) {
    auto at = [&](double v) {
      Vec3 x;
      x[axis] = 1;
      x[uv[0]] = (i + 0.5) / (samples + 1);
      x[uv[1]] = v;
      return x;
    };
    auto valueA = [&](double v) { return a.value(at(v)); };
    constexpr int kSteps = 2048;
    double v0 = first, f0 = valueA(v0);
    for (int s = 1; s <= kSteps; ++s) {
      const double v1 = first + (last - first) * s / kSteps, f1 = valueA(v1);
      if ((f0 > 0) != (f1 > 0)) {
        Vec3 x = at(bisectSignChange(valueA, v0, v1, f0, 200));
        const PatchDerivatives da = a.derivatives(x);
        x[axis] = 0;
        const PatchDerivatives db = b.derivatives(x);
        out.gap = std::max(out.gap, std::abs(db.value) / db.gradient.norm());
        out.angle = std::max(
            out.angle,
            std::acos(std::clamp(da.gradient.normalized().dot(db.gradient.normalized()), -1.0, 1.0)));
      }
      v0 = v1;
      f0 = f1;
    }
  }
  return out;
}

}  // namespace

// measureContinuity before any change: the joins are exact to rounding (support/join_tolerances.h).
using test::kJoinAngle;
using test::kJoinGap;
constexpr int kFaceSamples = 8;

// A side coefficient changed in the lower cell of a face only, on one face along each axis.
TEST(ContinuityMeasure, FindsASideCoefficientChangedInOneCellOfAFace) {
  const auto field = makeAnalyticField("gyroid");
  const Model m = fieldModel(*field, 5, NormalMode::Exact);
  const ContinuityStats before = measureContinuity(m, kFaceSamples);
  ASSERT_LT(before.maxGap, kJoinGap);
  ASSERT_LT(before.maxAngle, kJoinAngle);
  ASSERT_EQ(before.signDisagreements, 0);
  std::array<std::size_t, 3> lower{}, upper{};
  for (int axis = 0; axis < 3; ++axis) lower[axis] = cellWithUpperNeighbour(m, axis, upper[axis]);
  auto changed = [&](auto&& coefficient) {
    Model out = m;
    for (int axis = 0; axis < 3; ++axis) {
      double& w = out.cells[lower[axis]].faceCoefficient[static_cast<std::size_t>(2 * axis + 1)];
      w = coefficient(axis, w);
    }
    return out;
  };

  // A small change: the face curves of the two cells part, by first order delta * (side basis) / |grad|. The
  // side term of a face vanishes on the cell's other faces, so each change shows on its face alone.
  const Model shifted = changed([](int, double w) { return w + 0.05; });
  const ContinuityStats s = measureContinuity(shifted, kFaceSamples);
  FaceMismatch largest;
  for (int axis = 0; axis < 3; ++axis) {
    const FaceMismatch expected = mismatchOnFace(shifted, lower[axis], upper[axis], axis, kFaceSamples);
    EXPECT_GT(expected.gap, 1e3 * kJoinGap) << "axis " << axis;
    // Both bisect the same zeros to rounding, and the gap changes by O(1) per unit along the face, so they
    // agree to ~1e-15 voxel; kJoinGap plus 1e-9 of the gap leaves a wide margin (a gap off by a few percent,
    // or taken at another point, fails).
    const ContinuityStats pair =
        measureContinuity(onlyCells(shifted, {lower[axis], upper[axis]}), kFaceSamples);
    EXPECT_EQ(pair.facePairs, 1);
    EXPECT_NEAR(pair.maxGap, expected.gap, kJoinGap + 1e-9 * expected.gap) << "axis " << axis;
    EXPECT_NEAR(pair.maxAngle, expected.angle, kJoinAngle) << "axis " << axis;
    largest.gap = std::max(largest.gap, expected.gap);
    largest.angle = std::max(largest.angle, expected.angle);
  }
  EXPECT_EQ(s.facePairs, before.facePairs);
  EXPECT_NEAR(s.maxGap, largest.gap, kJoinGap + 1e-9 * largest.gap);
  EXPECT_NEAR(s.maxAngle, largest.angle, kJoinAngle);
  // Nowhere else: without the changed cells the model is exact again.
  Model rest = shifted;
  std::vector<std::size_t> changedCells(lower.begin(), lower.end());
  std::sort(changedCells.begin(), changedCells.end());
  changedCells.erase(std::unique(changedCells.begin(), changedCells.end()), changedCells.end());
  for (auto c = changedCells.rbegin(); c != changedCells.rend(); ++c) rest = withoutCell(rest, *c);
  EXPECT_LT(measureContinuity(rest, kFaceSamples).maxGap, kJoinGap);

  // A large coefficient makes the lower cell's face take its sign at every sample inside the face (its side
  // basis, the product of the other faces' squared planes, is at least (1/18)^8 = 1e-10 at the samples, which
  // lie 1/18 of a cell or more inside; times 1e30 it outweighs the other terms, which are O(1)): each sample
  // where the upper cell has the other sign is a disagreement. Signs alternate over the axes, then swap.
  for (double first : {1.0, -1.0}) {
    auto sign = [&](int axis) { return axis == 1 ? -first : first; };
    int disagreements = 0;
    for (int axis = 0; axis < 3; ++axis) {
      const CornerPatch p = m.patch(upper[axis]);
      const auto uv = cube::otherAxes(axis);
      for (int i = 0; i <= kFaceSamples; ++i)
        for (int j = 0; j <= kFaceSamples; ++j) {
          Vec3 x;
          x[axis] = 0;
          x[uv[0]] = (i + 0.5) / (kFaceSamples + 1);
          x[uv[1]] = (j + 0.5) / (kFaceSamples + 1);
          disagreements += (p.value(x) > 0) != (sign(axis) > 0);
        }
    }
    EXPECT_GT(disagreements, 0);
    const Model flipped = changed([&](int axis, double) { return sign(axis) * 1e30; });
    EXPECT_EQ(measureContinuity(flipped, kFaceSamples).signDisagreements, disagreements) << "sign " << first;
  }
}

// A corner plane moved in one cell only (the cell's corner pointed at a copy of the shared isovertex, moved
// along its edge): the two faces of the cell through that edge no longer meet their neighbours.
TEST(ContinuityMeasure, FindsAnIsovertexMovedInOneCell) {
  const auto field = makeAnalyticField("gyroid");
  Model m = fieldModel(*field, 5, NormalMode::Exact);
  std::size_t b = 0;
  const std::size_t a = cellWithUpperNeighbour(m, 0, b);
  // A corner of cell a on an edge of its upper x face (shared with b).
  const CornerPatch pa = m.patch(a);
  int corner = -1;
  for (int k = 0; k < pa.numCorners && corner < 0; ++k) {
    const auto faces = cube::edgeFaces(pa.edge[static_cast<std::size_t>(k)]);
    if (faces[0] == 1 || faces[1] == 1) corner = k;
  }
  ASSERT_GE(corner, 0);
  const std::size_t slot = m.cells[a].firstCorner + static_cast<std::size_t>(corner);
  IsoVertex moved = m.vertices[m.corners[slot]];
  const int edgeAxis = cube::edgeAxis(pa.edge[static_cast<std::size_t>(corner)]);
  const double local = moved.position[edgeAxis] - m.cellOrigin(a)[edgeAxis];
  moved.position[edgeAxis] += local < 0.5 ? 0.05 : -0.05;  // stays on the edge
  m.corners[slot] = static_cast<std::uint32_t>(m.vertices.size());
  m.vertices.push_back(moved);

  const ContinuityStats s = measureContinuity(m, kFaceSamples);
  const FaceMismatch expected = mismatchOnFace(m, a, b, 0, kFaceSamples);
  EXPECT_GT(expected.gap, 1e3 * kJoinGap);
  // The largest gap is at least the one on the face shared with b (the other face through the edge may have
  // a larger one), and it is all in cell a.
  EXPECT_GE(s.maxGap, expected.gap * (1 - 1e-9));
  EXPECT_GE(s.maxAngle, expected.angle - kJoinAngle);
  EXPECT_LT(measureContinuity(withoutCell(m, a), kFaceSamples).maxGap, kJoinGap);
  EXPECT_NEAR(measureContinuity(onlyCells(m, {a, b}), kFaceSamples).maxGap, expected.gap,
              kJoinGap + 1e-9 * expected.gap);
}

namespace {

/// The sphere's field is its signed distance (|p| - 0.75, world units): a point of the wrong sign counts for
/// countSpuriousCells and countWrongSignFaces exactly when |field| exceeds the margin. Points within 1e-9 of
/// the margin would be decided by rounding; the tests check there are none.
struct SignCount {
  bool wrongBeyondMargin = false;
  bool atMargin = false;
};
template <class Points>
SignCount wrongSignBeyond(const Model& m, std::size_t cell, const ScalarField& sphere, double margin,
                          Points&& points) {
  const CornerPatch p = m.patch(cell);
  SignCount out;
  points([&](const Vec3& local) {
    const double distance = sphere.value(m.geometry.indexToWorld(m.cellOrigin(cell) + local));
    const double v = p.value(local);
    if (v == 0 || (v > 0) == (distance > 0)) return;
    out.atMargin = out.atMargin || std::abs(std::abs(distance) - margin) < 1e-9;
    out.wrongBeyondMargin = out.wrongBeyondMargin || std::abs(distance) > margin;
  });
  return out;
}

/// The sphere sampled at N = 16 with gradient normals, and half a voxel (world units): the margin.
struct Sphere16 {
  std::unique_ptr<AnalyticField> field = makeAnalyticField("sphere");
  Model model = fieldModel(*field, 16, NormalMode::Gradient);
  double margin = 0.5 * model.geometry.spacing.minCoeff();
};

}  // namespace

// Huge central coefficients (of alternating sign) in every 23rd cell of the sphere make those cells take that
// sign at every interior lattice point (the central basis is at least 16^-12 there, so 1e30 outweighs the
// other terms). A cell counts when one of its lattice points on the other side of the sphere lies more than
// half a voxel from it; cells the sphere cuts near a corner or a face have none, and do not count.
TEST(SpuriousCellsMeasure, CountsTheCellsGivenAWrongSignRegion) {
  Sphere16 sphere;
  Model& m = sphere.model;
  constexpr int kLattice = 8;
  ASSERT_EQ(countSpuriousCells(m, *sphere.field, kLattice, 0.5), 0);
  auto lattice = [](auto&& visit) {
    for (int a = 0; a < kLattice; ++a)
      for (int b = 0; b < kLattice; ++b)
        for (int d = 0; d < kLattice; ++d)
          visit(Vec3((a + 0.5) / kLattice, (b + 0.5) / kLattice, (d + 0.5) / kLattice));
  };
  std::int64_t expected = 0, planted = 0;
  for (std::size_t c = 0; c < m.cells.size(); c += 23, ++planted) {
    m.cells[c].central = planted % 2 ? -1e30 : 1e30;
    const SignCount s = wrongSignBeyond(m, c, *sphere.field, sphere.margin, lattice);
    ASSERT_FALSE(s.atMargin) << "cell " << c;
    expected += s.wrongBeyondMargin;
  }
  EXPECT_GT(expected, 0);
  EXPECT_LT(expected, planted);
  EXPECT_EQ(countSpuriousCells(m, *sphere.field, kLattice, 0.5), expected);
}

// Huge side coefficients (1e30) on one bounding face of every 19th cell (and on both cells of one shared
// face) make those faces take their sign at every point of the 16 x 16 face lattice (the side basis there is
// at least (1/32)^8 = 1e-12); each (cell, face) whose lattice has a point of the other sign more than half a
// voxel from the sphere counts once. Skipped cells' faces do not count.
TEST(WrongSignFacesMeasure, CountsTheFacesGivenAWrongSign) {
  Sphere16 sphere;
  Model& m = sphere.model;
  constexpr int kLattice = 16;
  ASSERT_EQ(countWrongSignFaces(m, *sphere.field, kLattice, 0.5), 0);
  std::vector<std::int64_t> counted(m.cells.size(), 0);
  auto plant = [&](std::size_t c, int f, double sign) {
    m.cells[c].faceCoefficient[static_cast<std::size_t>(f)] = sign * 1e30;
    const int axis = cube::faceAxis(f);
    const SignCount s = wrongSignBeyond(m, c, *sphere.field, sphere.margin, [&](auto&& visit) {
      for (int a = 0; a < kLattice; ++a)
        for (int b = 0; b < kLattice; ++b) {
          Vec3 x;
          x[axis] = cube::faceSide(f);
          x[(axis + 1) % 3] = (a + 0.5) / kLattice;
          x[(axis + 2) % 3] = (b + 0.5) / kLattice;
          visit(x);
        }
    });
    ASSERT_FALSE(s.atMargin) << "cell " << c << " face " << f;
    counted[c] += s.wrongBeyondMargin;
  };
  int planted = 0;
  for (std::size_t c = 0; c < m.cells.size(); c += 19, ++planted) {
    const std::uint8_t mask = m.patch(c).faceMask;
    int f = 0;
    while (!((mask >> f) & 1)) ++f;
    plant(c, f, planted % 2 ? -1.0 : 1.0);
  }
  std::size_t upper = 0;
  const std::size_t lower = cellWithUpperNeighbour(m, 2, upper);
  plant(lower, 5, -1.0);  // the shared face, from both sides
  plant(upper, 4, -1.0);
  std::int64_t expected = 0;
  for (std::int64_t n : counted) expected += n;
  EXPECT_GT(expected, 0);
  EXPECT_LT(expected, planted + 2);
  EXPECT_EQ(countWrongSignFaces(m, *sphere.field, kLattice, 0.5), expected);
  std::vector<std::uint32_t> skip;
  std::int64_t skipped = 0;
  for (std::size_t c = 0; c < m.cells.size() && skip.size() < 3; ++c)
    if (counted[c] > 0) {
      skip.push_back(static_cast<std::uint32_t>(c));
      skipped += counted[c];
    }
  EXPECT_EQ(countWrongSignFaces(m, *sphere.field, kLattice, 0.5, skip), expected - skipped);
}

// measureFidelity on samples of the sphere placed exactly on it, with its normals and mean curvature (1/r for
// an outward gradient): all errors vanish to rounding. Then one sample is moved off the sphere, one normal
// turned and one curvature changed, by known amounts: each maximum is that amount and each mean that amount
// over the sample count. The projection onto the sphere is exact in one Newton step (its field is the
// distance); the true curvature comes from central differences of the exact gradient with h = 1e-5, whose
// error (h^2 |f'''| / 6 plus rounding eps / h, about 1e-10 / voxel) stays below 1e-8 after the voxel factor.
TEST(FidelityMeasure, FindsAMovedSampleATurnedNormalAndAWrongCurvature) {
  const auto sphere = makeAnalyticField("sphere");
  constexpr double kRadius = 0.75, kVoxel = 0.05;
  std::vector<SurfaceSample> samples;
  constexpr int kCount = 200;
  for (int i = 0; i < kCount; ++i) {  // a Fibonacci spiral over the sphere
    const double z = 1 - (2 * i + 1.0) / kCount, phi = i * M_PI * (3 - std::sqrt(5.0));
    const Vec3 n(std::sqrt(1 - z * z) * std::cos(phi), std::sqrt(1 - z * z) * std::sin(phi), z);
    SurfaceSample s;
    s.world = kRadius * n;
    s.normal = i % 2 ? Vec3(-n) : n;  // unoriented
    s.meanCurvature = 1 / kRadius;
    samples.push_back(s);
  }
  FidelityMeasures f = measureFidelity(samples, *sphere, 0, kVoxel, true);
  EXPECT_EQ(f.distanceVoxels.count, static_cast<std::size_t>(kCount));
  EXPECT_LT(f.distanceVoxels.max, 1e-12);
  EXPECT_LT(f.normalDegrees.max, 1e-5);  // acos of a dot product that rounds to 1: sqrt(2 eps) rad
  EXPECT_LT(f.curvatureError.max, 1e-8);

  constexpr double kShift = 0.3, kTurn = 10, kCurvature = 0.5;  // voxels, degrees, per voxel
  samples[17].world *= (kRadius + kShift * kVoxel) / kRadius;
  const double t = kTurn / kRadToDeg;
  const Vec3 n = samples[40].normal, side = n.cross(Vec3::UnitZ()).normalized();
  samples[40].normal = std::cos(t) * n + std::sin(t) * side;
  samples[90].meanCurvature += kCurvature / kVoxel;
  f = measureFidelity(samples, *sphere, 0, kVoxel, true);
  EXPECT_NEAR(f.distanceVoxels.max, kShift, 1e-12);
  EXPECT_NEAR(f.distanceVoxels.mean, kShift / kCount, 1e-12);
  EXPECT_NEAR(f.normalDegrees.max, kTurn, 1e-9);
  EXPECT_NEAR(f.normalDegrees.mean, kTurn / kCount, 1e-5);
  EXPECT_NEAR(f.curvatureError.max, kCurvature, 1e-8);
  EXPECT_NEAR(f.curvatureError.mean, kCurvature / kCount, 1e-8);
  // One sample in 200 is off: the 99th percentile (the 198th of 200 sorted errors) is not it.
  EXPECT_LT(f.distanceVoxels.p99, 1e-12);
}

// The plane is reproduced exactly by every cell (continuity_test.cpp, LinearField): the patch surface's
// samples lie on it. Moving every corner plane of one cell (copies of its isovertices) by d along the plane's
// normal, with that cell's side and central coefficients zeroed, makes its patch the plane moved by d times a
// positive factor: exactly the samples of that cell are d voxels off.
TEST(FidelityMeasure, FindsTheSamplesOfACellWhoseCornerPlanesMoved) {
  const auto plane = makeAnalyticField("plane");
  Model m = fieldModel(*plane, 12, NormalMode::Exact);
  const double voxel = m.geometry.spacing.minCoeff();
  FidelityMeasures f = measureFidelity(samplePatchSurface(m, 4), *plane, 0, voxel, false);
  ASSERT_LT(f.distanceVoxels.max, 1e-12);
  const std::size_t cell = m.cells.size() / 2;
  constexpr double kShift = 0.1;  // voxels (index units: the spacing is the same along every axis)
  ModelCell& c = m.cells[cell];
  for (int k = 0; k < c.numCorners(); ++k) {
    IsoVertex v = m.vertices[m.corners[c.firstCorner + static_cast<std::size_t>(k)]];
    v.position += kShift * v.normal;
    m.corners[c.firstCorner + static_cast<std::size_t>(k)] = static_cast<std::uint32_t>(m.vertices.size());
    m.vertices.push_back(v);
  }
  c.faceCoefficient.fill(0);
  c.central = 0;
  const std::vector<SurfaceSample> samples = samplePatchSurface(m, 4);
  const std::size_t inCell =
      static_cast<std::size_t>(std::count_if(samples.begin(), samples.end(), [&](const SurfaceSample& s) {
        return s.cell == static_cast<std::int64_t>(cell);
      }));
  ASSERT_GT(inCell, 0u);
  f = measureFidelity(samples, *plane, 0, voxel, false);
  // Bisection along the sample lines places the roots to ~1e-15 of a cell.
  EXPECT_NEAR(f.distanceVoxels.max, kShift, 1e-12);
  EXPECT_NEAR(f.distanceVoxels.mean,
              kShift * static_cast<double>(inCell) / static_cast<double>(samples.size()), 1e-12);
  EXPECT_LT(f.normalDegrees.max, 1e-5);  // the moved plane keeps its normal
}
