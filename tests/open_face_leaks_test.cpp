// countOpenFaceLeaks (surface_fidelity.h): cells whose patch crosses a face that no neighbouring patch
// continues, where the surface has a hole. It finds a leak made on purpose and none where there is none; the
// paper construction leaks in many cells of the bundled volume, the fitted one in a few.
#include <gtest/gtest.h>

#include "cip/measure/surface_fidelity.h"
#include "cip/model/model_builder.h"
#include "cip/readers/volume_reader.h"
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

TEST(OpenFaceLeaks, FindsACellWhosePatchCrossesAnOpenFace) {
  Model model = sphere32(PatchMethod::Fitted);
  const OpenFace open = firstOpenFace(model);
  ASSERT_GE(open.face, 0);
  // The central term is positive inside every open face (its planes are the bounding ones), so a huge central
  // coefficient of the sign opposite to the face's corners turns the face's middle to that sign.
  model.cells[open.cell].central = open.positive ? -1e9 : 1e9;
  Vec3 middle = Vec3::Constant(0.5);
  middle[cube::faceAxis(open.face)] = cube::faceSide(open.face);
  ASSERT_NE(model.patch(open.cell).value(middle) > 0, open.positive);
  EXPECT_EQ(countOpenFaceLeaks(model), 1);
}

TEST(OpenFaceLeaks, FewOnTheBundledVolumeWithTheFittedConstruction) {
  const SparseVolume volume = readVolume(test::sourceFile("data/blobs.nrrd"));
  BuildOptions o;
  o.isovalue = 128;
  o.method = PatchMethod::Paper;
  const std::int64_t paper = countOpenFaceLeaks(buildModel(*volume.dense(), o));
  o.method = PatchMethod::Fitted;
  const std::int64_t fitted = countOpenFaceLeaks(buildModel(*volume.dense(), o));
  // The paper's construction leaks in 667 of the 4,380 cells (docs/method.md); the fitted one keeps the
  // corners' sign on open faces and on the uncrossed edges of bounding faces, and its isovertices that lie on
  // grid points (the volume has samples equal to the isovalue) keep their corner planes off uncrossed edges.
  // It leaked in 52 cells before; 6 are left, where its reference itself crosses an uncrossed edge.
  EXPECT_GT(paper, 300);
  EXPECT_LE(fitted, 6);
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
