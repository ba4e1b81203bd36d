// The fitted patch construction (PatchMethod::Fitted): no spurious sheets on analytic fields, fidelity
// against the paper's construction, model file round trip, the cubic edge root on sampled data, signs on CT
// data against the reference and the samples (thread independence where the fallbacks run:
// fitting_fallbacks_test.cpp).
#include "cip/model/patch_fitting.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <tuple>
#include <vector>

#include "cip/core/error.h"
#include "cip/measure/continuity_check.h"
#include "cip/measure/surface_fidelity.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/readers/volume_reader.h"
#include "cip/reference/tricubic_reference.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "support/join_tolerances.h"
#include "support/sanitized_build.h"
#include "support/volume_blocks.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

Model build(const AnalyticField& field, const DenseGrid& grid, NormalMode mode, PatchMethod method) {
  BuildOptions o;
  o.isovalue = field.defaultIsovalue();
  o.normals = mode;
  o.method = method;
  o.exactField = &field;
  return buildModel(grid, o);
}

}  // namespace

using FieldAndMode = std::tuple<std::string, NormalMode>;

class FittedPatches : public ::testing::TestWithParam<FieldAndMode> {};

// Zero cells with a wrong sign more than half a voxel from the true surface (8^3 and 16^3 lattices), and a
// surface at least as close and with better normals than the paper's construction on the same grid.
TEST_P(FittedPatches, NoSpuriousCellsAndBetterThanPaper) {
  auto field = makeAnalyticField(std::get<0>(GetParam()));
  ASSERT_TRUE(field);
  DenseGrid g = sampleField(*field, 32, field->name());
  const NormalMode mode = std::get<1>(GetParam());
  Model fitted = build(*field, g, mode, PatchMethod::Fitted);
  Model paper = build(*field, g, mode, PatchMethod::Paper);
  EXPECT_EQ(fitted.method, PatchMethod::Fitted);
  ASSERT_EQ(fitted.cells.size(), paper.cells.size());
  EXPECT_EQ(countSpuriousCells(fitted, *field, 8, 0.5), 0);
  if (!test::kSanitizedBuild) {  // 4,096 points a cell: in the Release run
    EXPECT_EQ(countSpuriousCells(fitted, *field, 16, 0.5), 0);
  }

  const double voxel = g.geometry.spacing.minCoeff();
  const double iso = field->defaultIsovalue();
  const int lines = test::kSanitizedBuild ? 2 : 4;  // the sampling is most of this test's time
  FidelityMeasures f = measureFidelity(samplePatchSurface(fitted, lines), *field, iso, voxel, false);
  FidelityMeasures p = measureFidelity(samplePatchSurface(paper, lines), *field, iso, voxel, false);
  EXPECT_LT(f.distanceVoxels.mean, p.distanceVoxels.mean);
  EXPECT_LT(f.normalDegrees.mean, p.normalDegrees.mean);
  // Measured (docs/method.md): at most 0.006 voxel and 2.2 degrees on these fields at N = 32.
  EXPECT_LT(f.distanceVoxels.mean, 0.01);
  EXPECT_LT(f.normalDegrees.mean, 3.0);
}

INSTANTIATE_TEST_SUITE_P(AnalyticFields, FittedPatches,
                         ::testing::Combine(::testing::Values("sphere", "torus", "gyroid"),
                                            ::testing::Values(NormalMode::Gradient, NormalMode::Exact)),
                         [](const ::testing::TestParamInfo<FieldAndMode>& param) {
                           return std::get<0>(param.param) + "_" + toString(std::get<1>(param.param));
                         });

// Marschner-Lobb at N = 32 has about 2.7 cells per ripple: 32 cells have sign structure inside that their
// loops cannot follow, and blending their normals only spreads the failures (more unresolved cells after each
// round). Near samples are confirmed near by a lattice neighbour of the other sign before Newton steps are
// tried; with Newton steps alone, which miss some surfaces within reach in these ripples, 120 cells stayed
// unresolved. The first fallback round is undone (none of the unresolved cells resolves when refitted
// alone, so it ends before refitting the rest), the model is the unblended one, and it has no wrong-sign cell
// at half a voxel, while ten rounds used to leave 1.1 % of the cells wrong-sign.
TEST(FittedPatches, FallbackRoundThatSpreadsFailuresIsUndone) {
  auto field = makeAnalyticField("marschner-lobb");
  DenseGrid g = sampleField(*field, 32, field->name());
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  o.normals = NormalMode::Exact;
  o.exactField = field.get();
  FittingStats stats;
  o.fittingStats = &stats;
  Model m = buildModel(g, o);
  EXPECT_TRUE(stats.lastRoundUndone);
  // Open faces' samples never fail a cell (docs/method.md, step 7): when they could, 48 cells stayed
  // unresolved and a fallback round was kept before the next one was undone.
  EXPECT_LE(stats.rounds, 2);
  EXPECT_GT(stats.unresolvedCells.size(), 0u);
  EXPECT_LT(stats.unresolvedCells.size(), 40u);
  EXPECT_EQ(countSpuriousCells(m, *field, 8, 0.5), 0);
  // The undone round restored the normals: the isovertices off the exact gradient are the ones the kept
  // rounds blended, no more.
  std::size_t blended = 0;
  for (const IsoVertex& v : m.vertices) {
    const Vec3 exact = field->gradient(g.geometry.indexToWorld(v.position)).cwiseProduct(g.geometry.spacing);
    blended += v.normal.dot(exact.normalized()) < 0.999999;
  }
  EXPECT_EQ(blended, stats.blendedVertices);
  EXPECT_LT(stats.blendedVertices, m.vertices.size() / 20);
}

// fitModelPatches pairs the cells across each face by walking them in grid order, which the builder gives;
// a model in another order is refused rather than fitted with unpaired faces.
TEST(FittedPatches, CellsOutOfGridOrderAreRefused) {
  auto field = makeAnalyticField("sphere");
  DenseGrid g = sampleField(*field, 8, "sphere");
  Model m = build(*field, g, NormalMode::Gradient, PatchMethod::Paper);
  ASSERT_GT(m.cells.size(), 2u);
  std::vector<CellLoops> loops;
  for (std::size_t c = 0; c < m.cells.size(); ++c) loops.push_back(m.loops(c));
  auto reference = [&](std::size_t c, CellReference& ref) {
    const auto& i = m.cells[c].index;
    ref = tricubicReference(g, {i[0], i[1], i[2]}, field->defaultIsovalue());
  };
  Model swapped = m;
  std::swap(swapped.cells[0], swapped.cells[1]);
  std::swap(loops[0], loops[1]);
  EXPECT_THROW(fitModelPatches(swapped, loops, reference), Error);
  std::swap(loops[0], loops[1]);
  EXPECT_NO_THROW(fitModelPatches(m, loops, reference));
}

TEST(FittedPatches, ModelFileRoundTripKeepsMethod) {
  auto field = makeAnalyticField("torus");
  DenseGrid g = sampleField(*field, 12, "torus");
  Model m = build(*field, g, NormalMode::Gradient, PatchMethod::Fitted);
  auto bytes = serializeModel(m);
  Model back = parseModel(bytes.data(), bytes.size());
  EXPECT_EQ(back.method, PatchMethod::Fitted);
  EXPECT_EQ(serializeModel(back), bytes);
}

TEST(CubicEdgeVertex, ExactRootAndGradientOfAQuadraticField) {
  // Quadratic along x, linear across: central differences are exact for quadratics (and the limiter does not
  // act: the samples increase along x with no difference more than 5 times another), so the Hermite cubic
  // along the edge reproduces the quadratic, and the root and the normal are exact.
  DenseGrid g;
  g.allocate({6, 4, 4});
  auto f = [](double x, double y, double z) { return 0.1 * (x - 2.3) * (x + 1.0) + 0.05 * y - 0.02 * z; };
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 4; ++j)
      for (int i = 0; i < 6; ++i) g.at(i, j, k) = f(i, j, k);
  // Edge from (2,1,1) to (3,1,1): f goes from -0.06 to 0.31.
  Vec3 normal;
  double t = cubicEdgeVertex(g, {2, 1, 1}, 0, 0.0, normal);
  double x = 2 + t;
  EXPECT_NEAR(f(x, 1, 1), 0.0, 1e-12);
  Vec3 grad(0.1 * (2 * x - 1.3), 0.05, -0.02);
  EXPECT_NEAR(normal.dot(grad.normalized()), 1.0, 1e-12);
}

// Bricks sharing a plane of points: isovertices, faces and cells at the brick border are decided once, so the
// joins stay continuous. The reference's stencil is extended linearly at brick borders (no stencil across
// bricks); the sign checks still hold there (docs/method.md).
// The central8 reconstruction (tricubic_reference.h) on smooth data: no wrong-sign cells, the same continuity
// between cells, and patch normals closer to the true ones than with the monotone reference (torus at N = 32:
// 0.80 against 1.03 degrees, docs/method.md).
TEST(FittedPatches, Central8ReferenceOnSmoothData) {
  auto field = makeAnalyticField("torus");
  DenseGrid g = sampleField(*field, 32, "torus");
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  o.reconstruction = Reconstruction::Monotone;
  Model monotone = buildModel(g, o);
  o.reconstruction = Reconstruction::Central8;
  Model central8 = buildModel(g, o);
  ASSERT_EQ(central8.cells.size(), monotone.cells.size());
  EXPECT_EQ(countSpuriousCells(central8, *field, 8, 0.5), 0);
  if (!test::kSanitizedBuild) {  // 4,096 points a cell: in the Release run
    EXPECT_EQ(countSpuriousCells(central8, *field, 16, 0.5), 0);
  }
  const ContinuityStats s = measureContinuity(central8, test::kSanitizedBuild ? 8 : 12);
  EXPECT_LT(s.maxGap, test::kJoinGap);
  EXPECT_LT(s.maxAngle, test::kJoinAngle);
  EXPECT_EQ(s.signDisagreements, 0);
  const double voxel = g.geometry.spacing.minCoeff(), iso = field->defaultIsovalue();
  const int lines = test::kSanitizedBuild ? 2 : 4;  // the sampling is most of this test's time
  const FidelityMeasures c = measureFidelity(samplePatchSurface(central8, lines), *field, iso, voxel, false);
  const FidelityMeasures m = measureFidelity(samplePatchSurface(monotone, lines), *field, iso, voxel, false);
  EXPECT_LT(c.normalDegrees.mean, 0.9 * m.normalDegrees.mean);
  EXPECT_LT(c.distanceVoxels.mean, m.distanceVoxels.mean);
}

TEST(FittedPatches, BricksJoinContinuously) {
  auto field = makeAnalyticField("gyroid");
  // N = 16 under the sanitizers: under half the cells, and the seam at 11 still crosses the surface.
  DenseGrid g = sampleField(*field, test::kSanitizedBuild ? 16 : 24, "gyroid");
  const auto dims = g.geometry.dims;
  const std::int64_t split = 11;
  DenseGrid a, b;
  a.geometry = b.geometry = g.geometry;
  a.allocate({split + 1, dims[1], dims[2]});
  b.allocate({dims[0] - split, dims[1], dims[2]});
  for (std::int64_t k = 0; k < dims[2]; ++k)
    for (std::int64_t j = 0; j < dims[1]; ++j) {
      for (std::int64_t i = 0; i <= split; ++i) a.at(i, j, k) = g.at(i, j, k);
      for (std::int64_t i = split; i < dims[0]; ++i) b.at(i - split, j, k) = g.at(i, j, k);
    }
  std::vector<GridBrick> bricks(2);
  bricks[0].grid = &a;
  bricks[0].cellEnd = {split, dims[1] - 1, dims[2] - 1};
  bricks[1].grid = &b;
  bricks[1].offset = {split, 0, 0};
  bricks[1].cellEnd = {dims[0] - 1 - split, dims[1] - 1, dims[2] - 1};
  for (Reconstruction kind : {Reconstruction::Monotone, Reconstruction::Central8}) {
    // These bricks keep a 1-point apron: central8 (reach 4) then extends each brick's samples at its border
    // rather than reading the other brick's, so the two references differ near the seam; the patches must
    // join all the same.
    BuildOptions o;
    o.method = PatchMethod::Fitted;
    o.normals = NormalMode::Gradient;
    o.reconstruction = kind;
    Model m = buildModel(g.geometry, bricks, o, "two bricks");
    EXPECT_EQ(m.cells.size(), buildModel(g, o).cells.size());
    // 12 x 12 lines per face (8 x 8 under the sanitizers, where they are most of this test's time).
    ContinuityStats s = measureContinuity(m, test::kSanitizedBuild ? 8 : 12);
    EXPECT_GT(s.curvePoints, 1000);
    EXPECT_LT(s.maxGap, test::kJoinGap) << toString(kind);
    EXPECT_LT(s.maxAngle, test::kJoinAngle) << toString(kind);
    EXPECT_EQ(s.signDisagreements, 0) << toString(kind);
    EXPECT_EQ(countSpuriousCells(m, *field, 8, 0.5), 0) << toString(kind);
  }
}

// Real CT data against its reference (the monotone tricubic interpolant): no cell with a wrong sign more than
// half a voxel from the reference surface. Blocks of the tooth and of headsq (anisotropic spacing) keep the
// test short; docs/method.md has the whole volumes.
namespace {

using test::crop;
using test::readVolumeDense;

/// Cells whose patch has the other sign than the samples, where those decide it without the reference: at a
/// grid point where the patch is not 0, or inside a cell edge whose two samples lie on one side of the
/// isovalue, at the 16 odd multiples of 1/32 (between the 9 points per edge the construction binds). The
/// monotone reference never overshoots the samples, so it keeps their sign along such an edge, and the
/// construction keeps it there too (on open faces, and on the uncrossed edges of bounding faces) except in an
/// unresolved cell or at a hole no blend closed; `skip` lists the unresolved cells (ascending).
std::int64_t cellsAgainstTheSamples(const Model& m, const DenseGrid& grid,
                                    const std::vector<std::uint32_t>& skip) {
  std::int64_t cells = 0;
  for (std::size_t c = 0; c < m.cells.size(); ++c) {
    if (std::binary_search(skip.begin(), skip.end(), static_cast<std::uint32_t>(c))) continue;
    const CornerPatch p = m.patch(c);
    const auto& at = m.cells[c].index;
    auto above = [&](int vertex) {
      const auto v = cube::vertexCoords(vertex);
      return grid.at(at[0] + v[0], at[1] + v[1], at[2] + v[2]) > m.isovalue;
    };
    auto against = [&](const Vec3& x, bool positive) {
      const double value = p.value(x);
      return value != 0 && (value > 0) != positive;
    };
    bool wrong = false;
    for (int v = 0; v < 8 && !wrong; ++v) {
      const auto corner = cube::vertexCoords(v);
      wrong = against(Vec3(corner[0], corner[1], corner[2]), above(v));
    }
    for (int e = 0; e < 12 && !wrong; ++e) {
      const int start = cube::edgeVertex(e, 0);
      if (above(start) != above(cube::edgeVertex(e, 1))) continue;
      const auto s = cube::vertexCoords(start);
      for (int i = 1; i < 32 && !wrong; i += 2) {
        Vec3 x(s[0], s[1], s[2]);
        x[cube::edgeAxis(e)] = i / 32.0;
        wrong = against(x, above(start));
      }
    }
    cells += wrong;
  }
  return cells;
}

/// Wrong-sign cells against the reference on an n^3 lattice per cell, for each n of `lattices`. Against the
/// samples themselves (data the construction does not fit), only the two cells of each hole left open may
/// have a wrong sign where the samples decide it.
std::vector<std::int64_t> wrongSignCells(const DenseGrid& grid, double isovalue,
                                         std::vector<int> lattices = {8}) {
  BuildOptions o;
  o.isovalue = isovalue;
  FittingStats stats;
  o.fittingStats = &stats;
  Model m = buildModel(grid, o);
  EXPECT_EQ(m.method, PatchMethod::Fitted);
  EXPECT_EQ(stats.reconstruction, Reconstruction::Monotone);
  EXPECT_GT(m.cells.size(), 500u);
  EXPECT_LE(cellsAgainstTheSamples(m, grid, stats.unresolvedCells),
            static_cast<std::int64_t>(2 * (stats.holes - stats.holesClosed)));
  const TricubicInterpolant reference(grid);
  std::vector<std::int64_t> out;
  for (int n : lattices) out.push_back(countSpuriousCells(m, reference, n, 0.5));
  return out;
}

}  // namespace

// The check against the samples sees wrong signs: the paper's construction has them in many cells.
TEST(FittedPatches, CheckAgainstTheSamplesSeesThePapersWrongSigns) {
  const DenseGrid nucleon = readVolumeDense(test::sharedData("nucleon.nhdr"));
  BuildOptions o;
  o.isovalue = 128;
  o.method = PatchMethod::Paper;
  EXPECT_GT(cellsAgainstTheSamples(buildModel(nucleon, o), nucleon, {}), 0);
}

/// The lattices of the cases below that check on 16^3 points a cell as well as 8^3: 8^3 alone under the
/// sanitizers, where the 4,096 points a cell are most of these tests' time (the builds are the same).
const std::vector<int> kBothLattices = test::kSanitizedBuild ? std::vector<int>{8} : std::vector<int>{8, 16};
const std::vector<std::int64_t> kNoneOnBoth(kBothLattices.size(), 0);

TEST(FittedPatches, NoWrongSignCellsOnCtData) {
  const std::vector<std::int64_t> none{0};
  // The sanitizer run takes the same path on the tooth's block (CT, uint8, isotropic).
  if (!test::kSanitizedBuild) {
    EXPECT_EQ(wrongSignCells(readVolumeDense(test::sharedData("nucleon.nhdr")), 128), none);
  }
  DenseGrid tooth = readVolumeDense(test::sharedData("tooth.nhdr"));
  EXPECT_EQ(wrongSignCells(crop(tooth, {30, 30, 60}, {40, 40, 40}), 120), none);
  DenseGrid headsq = readVolumeDense(test::sharedData("headsq.nhdr"));
  EXPECT_EQ(wrongSignCells(crop(headsq, {10, 10, 30}, {40, 40, 30}), 500), none);
  // Bone at 1150: 2 wrong-sign cells in this block on the 8^3 lattice with a 5 % clamp margin and unverified
  // face exemptions; on the 16^3 lattice 2 while the staggered second look of the cell fit could not fail a
  // cell (docs/method.md, step 3).
  EXPECT_EQ(wrongSignCells(crop(headsq, {20, 20, 4}, {24, 32, 28}), 1150, kBothLattices), kNoneOnBoth);
}

// The OpenVDB smoke (a fog volume) at 0.1, in two blocks of its grid read as one brick.
TEST(FittedPatches, NoWrongSignCellsOnFogData) {
  DenseGrid smoke = readVolumeDense(test::sharedData("vdb/smoke.vdb"));
  // A face without a sign-correct side coefficient (its reference dips 4 % below the isovalue from one vertex
  // to its middle, and its opposite vertex is a sample well above): with the fit kept, its two cells were
  // wrong-sign on the 16^3 lattice; the coefficient the fewest samples contradict, the least reference value
  // among ties, keeps the vertex (docs/method.md, step 6).
  EXPECT_EQ(wrongSignCells(crop(smoke, {40, 72, 52}, {16, 16, 16}), 0.1, kBothLattices), kNoneOnBoth);
  // A cell whose wrong-sign points lie 0.07 voxel from a reference surface that Newton steps reach only in 37
  // (they zig-zag across a cell face near a shallow minimum): one cell while the measure stopped at 30.
  EXPECT_EQ(wrongSignCells(crop(smoke, {61, 23, 56}, {16, 16, 16}), 0.1, kBothLattices), kNoneOnBoth);
}

// Bounding faces carry the joins between cells, where a wrong sign is a sheet spanning two cells. The side
// coefficients are checked on a 7 x 7 face lattice; a sample that the first-order distance estimate calls
// near the surface but that the coefficient gives the wrong sign is verified by Newton steps on the
// reference (steep CT gradients far from the surface fool the estimate) and counts unless they reach the
// surface within 0.3 voxel. So no sample of that lattice on a face of a resolved cell has the wrong sign more
// than 0.3 voxel from the reference surface; without the verification, 30 faces of this crop of headsq at
// 1150 had one. Between the samples the face curve can stray a little: on a 16 x 16 lattice, wrong signs
// stay within 0.6 voxel here (2 faces have one beyond 0.5 voxel, 14 without the verification).
TEST(FittedPatches, BoundingFacesHaveTheReferenceSignOnCtData) {
  DenseGrid headsq = crop(readVolumeDense(test::sharedData("headsq.nhdr")), {20, 20, 4}, {24, 32, 28});
  BuildOptions o;
  o.isovalue = 1150;
  FittingStats stats;
  o.fittingStats = &stats;
  Model m = buildModel(headsq, o);
  ASSERT_GT(m.cells.size(), 1000u);
  EXPECT_LT(stats.unresolvedCells.size(), m.cells.size() / 100);
  const TricubicInterpolant reference(headsq);
  std::vector<double> faceLattice;  // the face fit's lattice: 7 samples, a quarter step inset from the edges
  for (int i = 0; i < 7; ++i) faceLattice.push_back((i + 0.25) / 6.5);
  EXPECT_EQ(countWrongSignFaces(m, reference, faceLattice, 0.3, stats.unresolvedCells), 0);
  EXPECT_EQ(countWrongSignFaces(m, reference, 16, 0.6, stats.unresolvedCells), 0);
}

namespace {

/// Points of the uncrossed edges of bounding faces where the face restriction (so the patch next to the edge)
/// has the other sign than the edge's vertices: 255 points inside each such edge of every cell, on the edges
/// along which the reference `truth` keeps the vertices' sign (at 15 points; where it does not, the
/// reference surface itself crosses the edge, and the construction follows it). It is 0 along an edge both
/// of whose ends lie on the isovalue, with both isovertices there: the surface touches the edge, it does not
/// cross it.
std::int64_t uncrossedEdgeViolations(const Model& m, const ScalarField& truth) {
  constexpr int kFirstVertex[4] = {0, 2, 0, 1};  // the canonical vertex at the start of canonical edge k
  std::int64_t violations = 0;
  for (std::size_t c = 0; c < m.cells.size(); ++c) {
    const CornerPatch p = m.patch(c);
    for (int f = 0; f < 6; ++f) {
      if (!((p.faceMask >> f) & 1)) continue;
      const FaceCrossings fc = faceCrossingsOf(p, f, (m.cells[c].pairing03 >> f) & 1);
      const auto uv = cube::otherAxes(cube::faceAxis(f));
      for (int k = 0; k < 4; ++k) {
        if ((fc.crossed >> k) & 1) continue;
        const bool positive = (m.cells[c].config >> cube::faceVertex(f, kFirstVertex[k])) & 1;
        auto local = [&](double t) {
          const double fixed = k & 1;
          return k < 2 ? Vec2(t, fixed) : Vec2(fixed, t);
        };
        bool referenceKeeps = true;
        for (int i = 1; i < 16 && referenceKeeps; ++i) {
          const Vec2 q = local(i / 16.0);
          Vec3 x;
          x[cube::faceAxis(f)] = cube::faceSide(f);
          x[uv[0]] = q.x();
          x[uv[1]] = q.y();
          referenceKeeps =
              (truth.value(m.geometry.indexToWorld(m.cellOrigin(c) + x)) > m.isovalue) == positive;
        }
        if (!referenceKeeps) continue;
        for (int i = 1; i < 256; ++i) {
          const FaceRestriction fr = faceRestriction(fc, local(i / 256.0));
          const double v = fr.cornerPart + p.faceCoefficient[static_cast<std::size_t>(f)] * fr.sideBasis;
          violations += positive ? v < 0 : v > 0;
        }
      }
    }
  }
  return violations;
}

}  // namespace

// An edge of a bounding face without a crossing is shared with a face that no patch continues (a face that
// is not a bounding plane, of this cell or of the cell across), or lies on a second bounding plane, where the
// patch next to it takes the sign of both faces' restrictions on it. A wrong sign there is a hole. The side
// coefficients keep the vertices' sign along such edges, also between the points that bind them, unless
// the reference itself crosses the edge.
TEST(FittedPatches, UncrossedEdgesOfBoundingFacesKeepTheirVerticesSign) {
  const SparseVolume blobs = readVolume(test::sourceFile("data/blobs.nrrd"));
  BuildOptions o;
  o.isovalue = 128;
  o.reconstruction = Reconstruction::Central8;  // what auto picks for these samples
  const TricubicInterpolant reference(*blobs.dense(), Reconstruction::Central8);
  EXPECT_EQ(uncrossedEdgeViolations(buildModel(*blobs.dense(), o), reference), 0);
  o.method = PatchMethod::Paper;
  EXPECT_GT(uncrossedEdgeViolations(buildModel(*blobs.dense(), o), reference), 1000)
      << "the check sees no wrong sign";
  const auto torus = makeAnalyticField("torus");
  EXPECT_EQ(
      uncrossedEdgeViolations(
          build(*torus, sampleField(*torus, 32, "torus"), NormalMode::Exact, PatchMethod::Fitted), *torus),
      0);
}

// Where the uncrossed edges of a face cannot keep their vertices' sign together with the face lattice, the
// corner planes of the face's isovertices stand in the way: a local blend of those normals closes the hole
// when it makes no face or cell around it fail. In this block of the OpenVDB smoke at 0.1, two cells sharing
// such a face had wrong signs 0.63 voxel from the reference surface next to its uncrossed edge while the
// lattice's coefficient was kept (2 wrong-sign cells on the 16^3 lattice, 14 wrong points along the edges;
// docs/method.md, step 7). The blends are made one hole at a time, so the model is the same for any number
// of threads.
TEST(FittedPatches, HolesAtUncrossedEdgesCloseByLocalBlends) {
  const DenseGrid smoke =
      crop(readVolumeDense(test::sharedData("vdb/smoke.vdb")), {24, 148, 36}, {16, 16, 16});
  BuildOptions o;
  o.isovalue = 0.1;
  FittingStats stats;
  o.fittingStats = &stats;
  o.threads = 1;
  const Model m = buildModel(smoke, o);
  ASSERT_GT(m.cells.size(), 500u);
  EXPECT_GE(stats.holes, 1u);
  EXPECT_EQ(stats.holesClosed, stats.holes);
  EXPECT_TRUE(stats.unresolvedCells.empty());
  const TricubicInterpolant reference(smoke);
  EXPECT_EQ(uncrossedEdgeViolations(m, reference), 0);
  EXPECT_EQ(countSpuriousCells(m, reference, 8, 0.5), 0);
  EXPECT_EQ(countSpuriousCells(m, reference, 16, 0.5), 0);
  o.threads = 2;
  EXPECT_EQ(serializeModel(buildModel(smoke, o)), serializeModel(m));
}
