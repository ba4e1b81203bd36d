// countOpenFaceLeaks (surface_fidelity.h): cells whose patch crosses a face that no neighbouring patch
// continues, where the surface has a hole. It counts the leaks made on purpose and finds none where there is
// none; on the bundled volume it agrees with a search from the samples.
#include <gtest/gtest.h>

#include <algorithm>

#include "cip/measure/surface_fidelity.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/readers/volume_reader.h"
#include "cip/reference/tricubic_reference.h"
#include "cip/topology/cube_topology.h"
#include "cip/volume/analytic_field.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

Model sphere32(PatchMethod method) {
  const auto field = makeAnalyticField("sphere");
  const DenseGrid grid = sampleField(*field, 32, "sphere");
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  o.method = method;
  return buildModel(grid, o);
}

/// The first cell with an open face (not a bounding plane), that face, and whether its corners are positive.
struct OpenFace {
  std::size_t cell = 0;
  int face = -1;
  bool positive = false;
};
OpenFace firstOpenFace(const Model& model) {
  for (std::size_t c = 0; c < model.cells.size(); ++c) {
    const CornerPatch p = model.patch(c);
    for (int f = 0; f < 6; ++f) {
      if ((p.faceMask >> f) & 1) continue;
      return {c, f, ((model.cells[c].config >> cube::faceVertex(f, 0)) & 1) != 0};
    }
  }
  return {};
}

}  // namespace

TEST(OpenFaceLeaks, NoneOnTheFittedSphere) {
  const Model model = sphere32(PatchMethod::Fitted);
  ASSERT_GE(firstOpenFace(model).face, 0) << "the measure needs open faces to look at";
  EXPECT_EQ(countOpenFaceLeaks(model), 0);
}

// The central term is positive inside every open face (its planes are the bounding ones), so a huge central
// coefficient (1e30, against terms of order 1 and a central basis of at least (1/32)^8 = 1e-12 at the lattice
// points inside the face) gives the face's inside its sign. Planted in every 41st cell with an open face:
// with the sign opposite to an open face's corners in half of them (they leak), and with the sign all of the
// cell's open faces share in the others (they do not).
TEST(OpenFaceLeaks, CountsTheCellsWhosePatchCrossesAnOpenFace) {
  Model model = sphere32(PatchMethod::Fitted);
  std::int64_t leaking = 0, kept = 0;
  for (std::size_t c = 0; c < model.cells.size(); c += 41) {
    const std::uint8_t open = static_cast<std::uint8_t>(~model.patch(c).faceMask & 0x3f);
    if (!open) continue;
    // The corners' sign shared by all the open faces: +1, -1, or 2 when they differ.
    int shared = 0;
    for (int f = 0; f < 6; ++f) {
      if (!((open >> f) & 1)) continue;
      const int sign = ((model.cells[c].config >> cube::faceVertex(f, 0)) & 1) ? 1 : -1;
      shared = shared == 0 || shared == sign ? sign : 2;
    }
    if ((leaking + kept) % 2 == 0 || shared == 2) {  // the other sign than the first open face's corners
      const int first = __builtin_ctz(open);
      model.cells[c].central = ((model.cells[c].config >> cube::faceVertex(first, 0)) & 1) ? -1e30 : 1e30;
      ++leaking;
    } else {
      model.cells[c].central = shared * 1e30;
      ++kept;
    }
  }
  ASSERT_GT(kept, 0);
  EXPECT_EQ(countOpenFaceLeaks(model), leaking);
}

// An uncrossed edge shared by a bounding face f and an open face: f's side term is positive on the open face
// but for its border planes, so a huge side coefficient of the sign opposite to the edge's vertices turns the
// edge and the open face beside it: a hole in that cell only (the cell across f keeps its own coefficient).
TEST(OpenFaceLeaks, FindsAnUncrossedEdgeTurnedByASideCoefficient) {
  Model model = sphere32(PatchMethod::Fitted);
  for (std::size_t c = 0; c < model.cells.size(); ++c) {
    const std::uint8_t mask = model.patch(c).faceMask;
    const std::uint16_t crossed = cube::crossedEdges(model.cells[c].config);
    for (int e = 0; e < 12; ++e) {
      const auto faces = cube::edgeFaces(e);
      const bool bounding0 = (mask >> faces[0]) & 1, bounding1 = (mask >> faces[1]) & 1;
      if (((crossed >> e) & 1) || bounding0 == bounding1) continue;
      const int f = bounding0 ? faces[0] : faces[1];
      const bool positive = (model.cells[c].config >> cube::edgeVertex(e, 0)) & 1;
      model.cells[c].faceCoefficient[static_cast<std::size_t>(f)] = positive ? -1e30 : 1e30;
      EXPECT_EQ(countOpenFaceLeaks(model), 1) << "cell " << c << " edge " << e;
      return;
    }
  }
  FAIL() << "no uncrossed edge between a bounding and an open face";
}

namespace {

/// The cells whose patch, at a point of the 33 x 33 lattice (border included) on one of their faces whose
/// four samples lie on one side of the isovalue, has the other sign: countOpenFaceLeaks from the samples
/// themselves rather than from the cells' loops.
std::vector<std::size_t> leakingCells(const Model& model, const DenseGrid& grid) {
  std::vector<std::size_t> out;
  for (std::size_t c = 0; c < model.cells.size(); ++c) {
    const CornerPatch patch = model.patch(c);
    const auto& cell = model.cells[c].index;
    bool leaks = false;
    for (int f = 0; f < 6 && !leaks; ++f) {
      const int axis = cube::faceAxis(f), u = (axis + 1) % 3, v = (axis + 2) % 3;
      int above = 0;
      for (int k = 0; k < 4; ++k) {
        std::array<std::int64_t, 3> at{cell[0], cell[1], cell[2]};
        at[axis] += cube::faceSide(f);
        at[u] += k & 1;
        at[v] += k >> 1;
        above += grid.at(at[0], at[1], at[2]) > model.isovalue;
      }
      if (above != 0 && above != 4) continue;
      for (int a = 0; a <= 32 && !leaks; ++a)
        for (int b = 0; b <= 32 && !leaks; ++b) {
          Vec3 x;
          x[axis] = cube::faceSide(f);
          x[u] = a / 32.0;
          x[v] = b / 32.0;
          const double value = patch.value(x);
          leaks = value != 0 && (value > 0) != (above == 4);
        }
    }
    if (leaks) out.push_back(c);
  }
  return out;
}

/// Whether the reference takes the other sign than the samples somewhere along an edge of the cell whose two
/// samples lie on one side of the isovalue (63 points inside each such edge).
bool referenceCrossesAnUncrossedEdge(const Model& model, std::size_t c, const DenseGrid& grid,
                                     const ScalarField& reference) {
  const Vec3 origin = model.cellOrigin(c);
  for (int e = 0; e < 12; ++e) {
    const auto a = cube::vertexCoords(cube::edgeVertex(e, 0));
    const Vec3 start = origin + Vec3(a[0], a[1], a[2]);
    const bool above = grid.at(static_cast<std::int64_t>(start.x()), static_cast<std::int64_t>(start.y()),
                               static_cast<std::int64_t>(start.z())) > model.isovalue;
    Vec3 end = start;
    end[cube::edgeAxis(e)] += 1;
    if ((grid.at(static_cast<std::int64_t>(end.x()), static_cast<std::int64_t>(end.y()),
                 static_cast<std::int64_t>(end.z())) > model.isovalue) != above)
      continue;
    for (int i = 1; i < 64; ++i) {
      const Vec3 x = start + (end - start) * (i / 64.0);
      if ((reference.value(model.geometry.indexToWorld(x)) > model.isovalue) != above) return true;
    }
  }
  return false;
}

}  // namespace

// On the bundled volume the measure finds the leaking cells an independent search from the samples finds: the
// paper's construction leaks in many (docs/method.md), the fitted one only in cells where its reference
// itself crosses an edge whose samples lie on one side (there it follows the reference; elsewhere it keeps
// the corners' sign on open faces and on the uncrossed edges of bounding faces).
TEST(OpenFaceLeaks, OnTheBundledVolumeOnlyWhereTheReferenceCrossesAnUncrossedEdge) {
  const SparseVolume volume = readVolume(test::sourceFile("data/blobs.nrrd"));
  const DenseGrid& grid = *volume.dense();
  BuildOptions o;
  o.isovalue = 128;
  o.method = PatchMethod::Paper;
  const Model paper = buildModel(grid, o);
  const std::vector<std::size_t> paperLeaks = leakingCells(paper, grid);
  EXPECT_GT(paperLeaks.size(), 0u);
  EXPECT_EQ(countOpenFaceLeaks(paper), static_cast<std::int64_t>(paperLeaks.size()));
  o.method = PatchMethod::Fitted;
  FittingStats stats;
  o.fittingStats = &stats;
  const Model fitted = buildModel(grid, o);
  const std::vector<std::size_t> fittedLeaks = leakingCells(fitted, grid);
  EXPECT_EQ(countOpenFaceLeaks(fitted), static_cast<std::int64_t>(fittedLeaks.size()));
  const TricubicInterpolant reference(grid, stats.reconstruction);
  for (std::size_t c : fittedLeaks)
    EXPECT_TRUE(referenceCrossesAnUncrossedEdge(fitted, c, grid, reference)) << "cell " << c;
}

TEST(OpenFaceLeaks, NoneOnTheFittedTorusInExactMode) {
  // The torus at N = 32 in exact mode had 96 leaking cells before the open faces were kept sign-correct.
  const auto field = makeAnalyticField("torus");
  const DenseGrid grid = sampleField(*field, 32, "torus");
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  o.normals = NormalMode::Exact;
  o.exactField = field.get();
  EXPECT_EQ(countOpenFaceLeaks(buildModel(grid, o), 65), 0);
}

// The torus at N = 64 (default options) had 16 leaking cells as built: patches that the cell lattice pulls
// towards an open face dipped through it between the face's samples, 1/3 apart. The fit now checks a value
// that comes close to an open face on the face's 17 x 17 lattice and adds the worst point as a sample.
TEST(OpenFaceLeaks, NoneOnTheFittedTorusAtN64) {
  const auto field = makeAnalyticField("torus");
  const DenseGrid grid = sampleField(*field, 64, "torus");
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  EXPECT_EQ(countOpenFaceLeaks(buildModel(grid, o)), 0);
}

// The same torus as stored (format 2) had 32 leaking cells: the rounding of corners and coefficients let the
// patch dip through open faces it kept clear by a few tenths of a percent of its magnitude there. The writer
// now refines the cells whose stored patch leaks where the built one does not (docs/model-format.md). On the
// bundled blobs, where the built model leaks in a few cells, the stored model leaks in none of the others.
TEST(OpenFaceLeaks, TheStoredModelLeaksOnlyWhereTheBuiltOneDoes) {
  const auto field = makeAnalyticField("torus");
  const DenseGrid grid = sampleField(*field, 64, "torus");
  BuildOptions o;
  o.isovalue = field->defaultIsovalue();
  EXPECT_EQ(countOpenFaceLeaks(storedModel(buildModel(grid, o))), 0);

  const SparseVolume volume = readVolume(test::sourceFile("data/blobs.nrrd"));
  o.isovalue = 128;
  const Model built = buildModel(*volume.dense(), o);
  const std::vector<std::uint32_t> builtLeaks = openFaceLeakCells(built);
  for (std::uint32_t c : openFaceLeakCells(storedModel(built)))
    EXPECT_TRUE(std::binary_search(builtLeaks.begin(), builtLeaks.end(), c)) << "cell " << c;
}
