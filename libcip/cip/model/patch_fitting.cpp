#include "cip/model/patch_fitting.h"

#include "cip/core/error.h"
#include "cip/model/fitting_rounds.h"

namespace cip {

FittingStats fitModelPatches(Model& model, const std::vector<CellLoops>& loops,
                             const std::function<void(std::size_t, CellReference&)>& reference,
                             const std::function<void(double)>& progress, const Collective* collective) {
  FittingStats stats;
  if (loops.size() != model.cells.size()) throw Error("fitModelPatches: one CellLoops per cell expected");
  if (model.cells.empty()) return stats;
  // The faces with crossings and their cells (throws unless the cells are in grid order), gradient normals.
  FittingRounds fitting(model, loops, reference, progress, collective);
  // Every face, then every cell, fitted; rounds of blended normals where they fail (docs/method.md, step 5).
  fitting.runRounds(stats);
  // Holes at uncrossed edges next to open faces, closed by blends of their isovertices alone (step 7).
  fitting.closeHoles(stats);
  // Faces, then cells, still failed take the coefficient the fewest counting samples contradict (step 6).
  const std::vector<std::uint8_t> refit = fitting.settleFailedFaces();
  fitting.settleFailedCells(refit);
  fitting.report(stats);
  return stats;
}

}  // namespace cip
