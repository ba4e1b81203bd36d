#include "cip/model/model_builder.h"

#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>

#include "cip/core/error.h"
#include "cip/model/build_passes.h"
#include "cip/model/patch_fitting.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/reference/mask_reference.h"
#include "cip/reference/point_hermite.h"
#include "cip/topology/cube_topology.h"

namespace cip {

CornerPatch buildCellPatch(std::uint8_t config, const std::array<IsoVertex, 12>& vertexData,
                           std::uint8_t* pairing03Out, CellLoops* loopsOut, bool fitCoefficients) {
  std::uint8_t pairing = 0;
  for (int f = 0; f < 6; ++f) {
    if (!cube::isAmbiguousFace(config, f)) continue;
    std::array<double, 4> t;
    for (int k = 0; k < 4; ++k) {
      int e = cube::faceEdge(f, k);
      t[k] = vertexData[e].position[cube::edgeAxis(e)];
    }
    bool v0Positive = (config >> cube::faceVertex(f, 0)) & 1;
    if (cutsOffDiagonal03(t, v0Positive)) pairing = static_cast<std::uint8_t>(pairing | (1u << f));
  }
  CellLoops loops = buildCellLoops(config, pairing);
  CornerPatch patch;
  patch.numCorners = loops.numCorners();
  for (int c = 0; c < patch.numCorners; ++c) {
    const IsoVertex& v = vertexData[loops.edges[c]];
    patch.point[c] = v.position;
    patch.normal[c] = v.normal;
    patch.weight[c] = v.weight;
    patch.edge[c] = loops.edges[c];
  }
  patch.faceMask = loops.faceMask;
  for (int f = 0; f < 6 && fitCoefficients; ++f)
    if ((loops.faceMask >> f) & 1)
      patch.faceCoefficient[f] = fitFaceCoefficient(faceCrossingsOf(patch, f, (pairing >> f) & 1));
  if (pairing03Out) *pairing03Out = pairing;
  if (loopsOut) *loopsOut = loops;
  return patch;
}

int brickApron(const BuildOptions& options) {
  if (options.method == PatchMethod::Fitted && options.normals != NormalMode::Exact)
    return options.reconstruction == Reconstruction::Mask || options.label
               ? maskReach()
               : referenceReach(options.reconstruction);
  return 1;
}

namespace {

Model buildSampled(const GridGeometry& geometry, const std::vector<GridBrick>& bricks,
                   const BuildOptions& options, const std::string& source, double raise = 0);

/// What the samples decide (build::maskRule; Detect: from every brick's detectTwoValued): whether the build
/// follows the smoothed indicator of a mask or label, and how far it raises the isovalue over integer
/// samples (build::integerRaise).
struct SampleChoice {
  bool mask = false;
  double raise = 0;
};

SampleChoice chooseFromSamples(const std::vector<GridBrick>& bricks, const BuildOptions& options) {
  const build::MaskRule rule = build::maskRule(options);
  if (rule != build::MaskRule::Detect) return {rule == build::MaskRule::Mask, 0.0};
  build::TwoValuedVerdict verdict;
  for (const GridBrick& b : bricks) {
    verdict.add(detectTwoValued(*b.grid, options.isovalue, build::countedEdgesOf(b)));
    if (verdict.decided()) break;
  }
  return {verdict.mask(), build::integerRaise(verdict, options.isovalue)};
}

/// The model of the smoothed indicator: each brick's field (build::maskField), built with Central8
/// derivatives and recorded as Reconstruction::Mask.
Model buildMask(const GridGeometry& geometry, const std::vector<GridBrick>& bricks,
                const BuildOptions& options, const std::string& source) {
  const auto start = std::chrono::steady_clock::now();
  std::vector<DenseGrid> fields(bricks.size());
  std::vector<GridBrick> fieldBricks = bricks;
  for (std::size_t b = 0; b < bricks.size(); ++b) {
    fields[b] = build::maskField(*bricks[b].grid, options);
    fieldBricks[b].grid = &fields[b];
  }
  const double smoothing = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  Model model = buildSampled(geometry, fieldBricks, build::maskFieldOptions(options), source);
  model.reconstruction = Reconstruction::Mask;
  if (options.fittingStats) options.fittingStats->reconstruction = Reconstruction::Mask;
  if (options.timings) options.timings->reference += smoothing;
  return model;
}

}  // namespace

Model buildModel(const DenseGrid& grid, const BuildOptions& options) {
  GridBrick brick;
  brick.grid = &grid;
  for (int a = 0; a < 3; ++a) brick.cellEnd[a] = std::max<std::int64_t>(0, grid.geometry.dims[a] - 1);
  return buildModel(grid.geometry, {brick}, options, grid.description);
}

Model buildModel(const GridGeometry& geometry, const std::vector<GridBrick>& bricks,
                 const BuildOptions& options, const std::string& source) {
  // The detection and the mask's field run in parallel too, bounded as the passes are.
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  return arena.execute([&] {
    const SampleChoice choice = chooseFromSamples(bricks, options);
    if (choice.mask) return buildMask(geometry, bricks, options, source);
    if (choice.raise == 0) return buildSampled(geometry, bricks, options, source);
    BuildOptions raised = options;
    raised.isovalue += choice.raise;
    Model model = buildSampled(geometry, bricks, raised, source, choice.raise);
    if (options.fittingStats) options.fittingStats->isovalueRaise = choice.raise;
    return model;
  });
}

namespace {

/// buildModel of the samples as they are, at options.isovalue, which lies `raise` above the isovalue asked
/// for (build::Input::raise).
Model buildSampled(const GridGeometry& geometry, const std::vector<GridBrick>& bricks,
                   const BuildOptions& options, const std::string& source, double raise) {
  if (options.normals == NormalMode::Exact && !options.exactField) {
    throw Error("exact normals need an analytic field; sampled volumes take gradient or edge normals");
  }
  build::Progress progress(options.progress);
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  Model model = build::emptyModel(geometry, options, source);

  BuildTimings timings;
  using Clock = std::chrono::steady_clock;
  auto mark = Clock::now();
  auto lap = [&](double& seconds) {
    const auto now = Clock::now();
    seconds = std::chrono::duration<double>(now - mark).count();
    mark = now;
  };
  arena.execute([&] {
    const build::Input in{geometry, bricks, options, build::GridKeys{geometry.dims}, progress, raise};
    // Scan (progress to 0.3): the crossed cells and their crossed edges, brick by brick, row by row.
    build::CellScan scan = build::scanCells(in);
    lap(timings.scan);
    // Reference: the reconstruction of the samples, Auto resolved from the crossed cells in scan order, and
    // its data at their corners.
    const build::SampledReference reference = build::prepareReference(in, scan.cells);
    lap(timings.reference);
    // Isovertices: one per crossed grid edge, ordered by edge key.
    const std::vector<build::EdgeRef> edges = build::uniqueEdges(std::move(scan.edges), scan.edgesUnique);
    model.vertices = build::placeIsovertices(in, reference, edges);
    lap(timings.isovertices);
    progress.set(0.5);
    // Assemble (progress to 1): the cells in cell-key order, with their loops and corners.
    if (!std::is_sorted(scan.cells.begin(), scan.cells.end()))  // one brick's scan is in key order already
      std::stable_sort(scan.cells.begin(), scan.cells.end());
    const std::vector<CellLoops> loops = build::assembleCells(in, scan.cells, edges, model);
    lap(timings.assemble);
    // Coefficients (PatchMethod::Fitted): fitted model-wide, one per face for its two cells (the paper's
    // construction set them per cell while assembling).
    if (build::fitsModelWide(options)) build::fitCoefficients(in, scan.cells, reference, loops, model);
    lap(timings.fit);
  });
  if (options.timings) *options.timings = timings;
  progress.set(1.0);
  return model;
}

}  // namespace

}  // namespace cip
