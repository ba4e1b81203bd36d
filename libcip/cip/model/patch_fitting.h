/// @file patch_fitting.h
/// @brief The fitted corner-patch construction (PatchMethod::Fitted) over a whole model: side and central
/// coefficients fitted to a reference surface (the analytic field, or the tricubic interpolant of the
/// samples) under sign constraints, so that the patch has no extra branches where the reference has none,
/// with corner-plane normals blended towards the edge direction only where a face or cell cannot be made
/// sign-correct. Each number is decided from data that all the cells sharing it see identically (a side
/// coefficient once per face, copied to both cells), so the joins between cells stay continuous, and the
/// result does not depend on the number of threads. docs/method.md ("`fitted`", "The construction") has the
/// construction step by step and its measurements; patch/face_fit.h and patch/cell_fit.h fit one face and one
/// cell, model/fitting_rounds.h runs the passes over the model.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "cip/core/collective.h"
#include "cip/model/model.h"
#include "cip/reference/reconstruction_choice.h"
#include "cip/reference/tricubic_reference.h"

namespace cip {

struct FittingStats {
  int rounds = 0;                   ///< rounds run (1 = no face or cell needed a blended normal)
  bool lastRoundUndone = false;     ///< the last round did not reduce the unresolved cells and was undone
  std::size_t blendedVertices = 0;  ///< isovertices whose normal left the gradient
  std::size_t failedFaces = 0;      ///< faces still without a sign-correct coefficient at the last level
  std::size_t failedCells = 0;      ///< cells still without a sign-correct central coefficient
  std::array<std::size_t, 5> levelCount{};  ///< isovertices per final blend level
  /// Cells (model indices, ascending) that end without a sign-correct central coefficient or touch a face
  /// that ends without a sign-correct side coefficient: where the checks could not be met.
  std::vector<std::uint32_t> unresolvedCells;
  /// Faces left by the rounds whose side coefficient cannot keep an uncrossed edge next to an open face at
  /// its vertices' sign (a hole), and how many of them a local blend of their isovertices' normals closed.
  std::size_t holes = 0, holesClosed = 0;
  /// Set by buildModel unless normals are exact: the reconstruction of the reference (Reconstruction::Auto
  /// resolved) and, for Auto, the estimate it was resolved from (reconstruction_choice.h).
  Reconstruction reconstruction = Reconstruction::Monotone;
  SamplingEstimate sampling;
  /// Set by buildModel: how far it raised the isovalue over integer samples (build_passes.h,
  /// integerRaise; the model's isovalue is the raised one); 0 when it did not.
  double isovalueRaise = 0;
};

/// Replaces the side and central coefficients and the corner-plane normals of a model built with the paper's
/// construction (loops, pairings and isovertex positions are kept). `loops[c]` are the loops of cell c
/// (model.loops(c); the builder has them already). `reference(c, ref)` sets `ref` to the reference of cell c
/// (the fitting keeps a block of them in place); it is called concurrently. Runs in the caller's TBB arena.
/// The cells must be in grid order (by z, then y, then x, each once), as the builder makes them; otherwise
/// throws cip::Error. `progress` (if set) is called from the calling thread with the fraction of the rounds
/// done, between blocks of cells; an exception it throws ends the fitting (the model is then left partly
/// fitted). With `collective` (every rank calling with the same model), the first round's per-face and
/// per-cell fits are split between the ranks by rankShare of the cells and exchanged; the result is the
/// same on every rank and the same as without it.
FittingStats fitModelPatches(Model& model, const std::vector<CellLoops>& loops,
                             const std::function<void(std::size_t, CellReference&)>& reference,
                             const std::function<void(double)>& progress = {},
                             const Collective* collective = nullptr);

}  // namespace cip
