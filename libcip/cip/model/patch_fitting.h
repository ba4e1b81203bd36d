/// @file patch_fitting.h
/// @brief The fitted corner-patch construction (PatchMethod::Fitted): side and central coefficients fitted to
/// a reference surface under sign constraints, with corner-plane normals blended towards the edge direction
/// only where a face or cell cannot be made sign-correct.
///
/// Reference: the analytic field (NormalMode::Exact), else a tricubic Hermite interpolant of the samples
/// (tricubic_reference.h; BuildOptions::reconstruction chooses its derivatives). Every decision uses data
/// that all cells sharing it see identically:
///  - isovertex (NormalMode::Gradient): root of the reference along the grid edge, normal = its gradient
///  there
///    (a function of the grid edge's neighbourhood only, shared by its 4 cells);
///  - side coefficient w_f: computed once per grid face from the reference on that face, in the face's
///    canonical frame (faceCrossingsOf), and copied to both cells;
///  - central coefficient: per cell.
/// On each face, w_f is the least-squares fit of the face curve to reference face-curve points, clamped into
/// the interval of w for which the face restriction has the reference's sign at every face sample lying more
/// than a margin from the reference surface, and, where that value fails them, the sign of the vertices
/// along the face's edges without a crossing (unless the reference itself crosses such an edge). In each cell
/// the central coefficient is fitted to interior reference surface points and clamped into the interval that
/// keeps the reference's sign at interior lattice points away from the surface and, where that value fails
/// them, the corners' sign on the cell's faces that are not bounding planes. Those edges and faces are
/// continued by no neighbouring patch, so a wrong sign there would be a hole; where they cannot be met with
/// the lattice, the lattice decides (for a cell, after trying the open-face points where the reference agrees
/// with the corners), and they never make a face or cell fail (docs/method.md, step 7); after the rounds,
/// a face whose uncrossed edge next to an open face stays crossed that way has the normals of its isovertices
/// blended alone, kept only where that closes the hole and no face or cell around it fails or gets one.
/// Samples (of faces and cells) the first-order distance estimate calls near the surface are checked by
/// Newton steps on the reference where the patch gives them the wrong sign. When an interval is empty, the
/// face or cell fails, and the normals of all its isovertices move one step from the gradient towards the
/// edge direction (blend levels, shared per isovertex); the affected faces and cells are recomputed. A round
/// that does not reduce the cells left unresolved is undone and ends the rounds (blending cannot fix a cell
/// whose field has structure inside that its loops do not follow, and there it spreads failures). A cell left
/// without a sign-correct central coefficient takes the one the fewest counting samples contradict. Rounds
/// are deterministic (decisions of a round depend only on the previous round's state), so the result does not
/// depend on the number of threads. docs/method.md has the details and the measurements.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

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
};

/// Replaces the side and central coefficients and the corner-plane normals of a model built with the paper's
/// construction (loops, pairings and isovertex positions are kept). `loops[c]` are the loops of cell c
/// (model.loops(c); the builder has them already). `reference(c, ref)` sets `ref` to the reference of cell c
/// (the fitting keeps a block of them in place); it is called concurrently. Runs in the caller's TBB arena.
/// The cells must be in grid order (by z, then y, then x, each once), as the builder makes them; otherwise
/// throws cip::Error.
FittingStats fitModelPatches(Model& model, const std::vector<CellLoops>& loops,
                             const std::function<void(std::size_t, CellReference&)>& reference);

}  // namespace cip
