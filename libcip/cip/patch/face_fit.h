/// @file face_fit.h
/// @brief The side coefficient of one grid face of the fitted construction (docs/method.md, "The
/// construction", steps 2, 4 and 7): the face restriction fitted to the reference's face curve and clamped
/// under sign constraints on a face lattice and along the face's uncrossed edges. Computed once per face, by
/// its first cell; model/patch_fitting.h runs it model-wide and copies the result to both cells.
#pragma once
#include <cstdint>

#include "cip/patch/corner_patch.h"
#include "cip/reference/tricubic_reference.h"

namespace cip {

/// A face's side coefficient and whether it meets the samples that count.
struct FaceResult {
  double coefficient = 0;
  bool ok = true;
  /// Canonical edges (bit k) without a crossing that the reference keeps at the vertices' sign, where the
  /// edge's samples cannot be met together with the lattice's and, with the lattice's coefficient, the face
  /// restriction has the other sign at one of the edge's points inside (not only at an end or at a ridge
  /// point next to a crossing). Where such an edge lies on a face that is open in one of the face's cells,
  /// the patch's zero set ends there: a hole (closed where it can be by the local blends of docs/method.md,
  /// step 7).
  std::uint8_t holeEdges = 0;
};

/// The side coefficient of face f of a cell (its first cell) with corner data `patch` (coefficients unused),
/// ambiguous-face pairings `pairing03`, configuration `config` and reference `ref`. Where no value meets
/// every counting sample, the result is not ok and the coefficient is the fit, or with
/// `fallBackToLeastContradicted` the value the fewest counting samples contradict, nearest to the fit (for
/// the faces still failed after the fallback rounds). Where the samples of the uncrossed edges cannot be met
/// together with the lattice's, the lattice's alone decide.
FaceResult fitFace(const CornerPatch& patch, std::uint8_t config, std::uint8_t pairing03, int f,
                   const CellReference& ref, bool fallBackToLeastContradicted = false);

}  // namespace cip
