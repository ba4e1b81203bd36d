// The AVX2 kernels (core/vector_clones.h: the tricubic reference's contraction, the fit lattice's sign bits,
// the sign constraints' sweep, the renderer's zero mask) against their baseline versions: the same models and
// the same zero masks, bit for bit, so that a processor without AVX2 computes what one with it does (which
// MPI runs across mixed nodes rely on, docs/mpi.md). Skipped where the processor has no AVX2.
#include <gtest/gtest.h>

#include <cstdint>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include "cip/core/vector_clones.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/ray/patch_bounds.h"
#include "cip/reference/tricubic_reference.h"
#include "support/field_model.h"
#include "support/volume_blocks.h"
#include "support/volume_files.h"

using namespace cip;

namespace {

struct Case {
  std::string name;
  std::function<Model()> build;
};

std::vector<Case> cases() {
  auto volume = [](Reconstruction reconstruction, PatchMethod method) {
    return [=] {
      BuildOptions o;
      o.isovalue = 128;
      o.method = method;
      o.reconstruction = reconstruction;
      return buildModel(test::readVolumeDense(test::sourceFile("data/blobs.nrrd")), o);
    };
  };
  return {
      {"blobs auto", volume(Reconstruction::Auto, PatchMethod::Fitted)},
      {"blobs central8", volume(Reconstruction::Central8, PatchMethod::Fitted)},
      {"blobs mask", volume(Reconstruction::Mask, PatchMethod::Fitted)},
      {"blobs paper", volume(Reconstruction::Auto, PatchMethod::Paper)},
      {"gyroid 20 gradient", [] { return test::fieldModel("gyroid", 20, NormalMode::Gradient); }},
      {"marschner-lobb 24 exact", [] { return test::fieldModel("marschner-lobb", 24, NormalMode::Exact); }},
  };
}

/// Restores the AVX2 kernels when a test ends, whatever it asserted.
struct KernelsBackOn {
  ~KernelsBackOn() { setAvx2Kernels(true); }
};

}  // namespace

TEST(Avx2Kernels, ModelsAndZeroMasksEqualTheBaselineBitForBit) {
  if (!hasAvx2()) GTEST_SKIP() << "this processor has no AVX2: only the baseline kernels run here";
  KernelsBackOn restore;
  for (const Case& c : cases()) {
    setAvx2Kernels(true);
    ASSERT_TRUE(hasAvx2());
    const Model withAvx2 = c.build();
    setAvx2Kernels(false);
    ASSERT_FALSE(hasAvx2());
    const Model baseline = c.build();
    ASSERT_GT(withAvx2.cells.size(), 300u) << c.name;
    ModelFileOptions fullPrecision;  // version 1 keeps every coefficient's bits
    fullPrecision.version = 1;
    EXPECT_EQ(serializeModel(withAvx2, fullPrecision), serializeModel(baseline, fullPrecision)) << c.name;

    std::int64_t differing = 0, marked = 0;
    for (std::size_t i = 0; i < baseline.cells.size(); ++i) {
      const CornerPatch patch = baseline.patch(i);
      std::uint64_t positiveBaseline = 0, positiveAvx2 = 0;
      setAvx2Kernels(false);
      const std::uint64_t maskBaseline = patchZeroMask(patch, &positiveBaseline);
      setAvx2Kernels(true);
      const std::uint64_t maskAvx2 = patchZeroMask(patch, &positiveAvx2);
      differing += maskBaseline != maskAvx2 || positiveBaseline != positiveAvx2;
      marked += __builtin_popcountll(maskBaseline);
    }
    EXPECT_EQ(differing, 0) << c.name << ": cells whose zero masks differ";
    EXPECT_GT(marked, 0) << c.name;
  }
}

// The sampled reference's value and gradient (TricubicInterpolant: the AVX2 contraction of its Hermite data)
// at random points of the bundled volume, with both references that have one.
TEST(Avx2Kernels, TricubicGradientsEqualTheBaselineBitForBit) {
  if (!hasAvx2()) GTEST_SKIP() << "this processor has no AVX2: only the baseline kernels run here";
  KernelsBackOn restore;
  const DenseGrid grid = test::readVolumeDense(test::sourceFile("data/blobs.nrrd"));
  for (Reconstruction kind : {Reconstruction::Monotone, Reconstruction::Central8}) {
    const TricubicInterpolant reference(grid, kind);
    std::mt19937_64 random(7);
    std::int64_t differing = 0;
    for (int n = 0; n < 20000; ++n) {
      Vec3 index;
      for (int a = 0; a < 3; ++a)
        index[a] =
            std::uniform_real_distribution<double>(0, static_cast<double>(grid.geometry.dims[a] - 1))(random);
      const Vec3 world = grid.geometry.indexToWorld(index);
      setAvx2Kernels(false);
      const Vec3 baseline = reference.gradient(world);
      setAvx2Kernels(true);
      const Vec3 withAvx2 = reference.gradient(world);
      differing += baseline != withAvx2;
    }
    EXPECT_EQ(differing, 0) << toString(kind) << ": points whose gradients differ";
  }
}
