/// @file fitting_rounds.h
/// @brief The passes of fitModelPatches (patch_fitting.h) over a whole model and the state they share: the
/// table of grid faces with crossings, each face's and cell's last fit, the blend level of every isovertex's
/// normal, and what a round or a local blend saved to undo it. The fits themselves are patch/face_fit.h and
/// patch/cell_fit.h. Internal to model/.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <vector>

#include "cip/core/collective.h"
#include "cip/model/model.h"
#include "cip/model/patch_fitting.h"
#include "cip/patch/face_fit.h"
#include "cip/reference/tricubic_reference.h"

namespace cip {

/// A grid face with crossings and its one or two cells (the first has the lower index and fits it).
struct FaceEntry {
  std::array<std::uint32_t, 2> cell{};
  std::array<std::int8_t, 2> face{};
  int count = 0;
};

/// Grid faces with crossings, each with its (one or two) cells, and per cell the index of each of its faces
/// in that table (-1: not a bounding plane).
struct FaceTable {
  std::vector<FaceEntry> faces;
  std::vector<std::array<std::int32_t, 6>> cellFaces;
  std::vector<std::uint8_t> ownedFaces;  ///< per cell, bit f: the cell is its face f's first cell
};

/// The first cell of a face (lowest index) computes it. Faces are listed as the cells meet them in grid
/// (raster) order: a cell's far face along an axis (side 1) is new, its near face (side 0) is the far face
/// of the cell below if that cell has it. The cells below along an axis come in raster order too, so one
/// cursor per axis finds them. Throws cip::Error if the cells are not in that order.
FaceTable buildFaceTable(const Model& model, const std::vector<CellLoops>& loops);

/// The model-wide fitting of docs/method.md, "The construction", steps 5 to 7, one method per pass. Each pass
/// decides from the state the previous one left, in index order, so the model does not depend on the number
/// of threads.
class FittingRounds {
 public:
  using Reference = std::function<void(std::size_t, CellReference&)>;
  using Progress = std::function<void(double)>;
  /// As fitModelPatches: `loops[c]` are the loops of cell c, `reference(c, ref)` sets the reference of cell
  /// c, `progress` (if set) hears the rounds' fraction done. The cells must be in grid order
  /// (buildFaceTable); the model must have at least one cell. With `collective` (more than one rank), every
  /// rank holds the same model and the first round's fits are split between the ranks (fitSharedRound).
  FittingRounds(Model& model, const std::vector<CellLoops>& loops, const Reference& reference,
                const Progress& progress = {}, const Collective* collective = nullptr);

  /// Step 5: every face and cell fitted with gradient normals, then rounds that blend the normals of the
  /// failed ones one level towards the edge direction and refit what they touch, while that reduces the
  /// unresolved cells.
  void runRounds(FittingStats& stats);
  /// Step 7: faces left with a hole at an uncrossed edge next to an open face get their isovertices' normals
  /// blended alone, kept where that closes the hole without harm around it.
  void closeHoles(FittingStats& stats);
  /// Step 6: faces left without a sign-correct side coefficient take the one the fewest counting samples
  /// contradict, and their cells' central coefficients are fitted again; returns those cells as flags.
  std::vector<std::uint8_t> settleFailedFaces();
  /// Step 6: cells left without a sign-correct central coefficient (or flagged in `refit`) are fitted again,
  /// taking the coefficient the fewest counting samples contradict where none is sign-correct.
  void settleFailedCells(const std::vector<std::uint8_t>& refit);
  /// The blend levels, the failures and the unresolved cells left.
  void report(FittingStats& stats) const;

 private:
  /// What a round or a local blend overwrites, to undo it: per cell its coefficients and result, per face
  /// its result.
  struct SavedCell {
    double central;
    std::array<double, 6> faceCoefficient;
    std::uint8_t ok;
  };
  struct SavedFace {
    std::size_t index;
    double coefficient;
    std::uint8_t ok, hole;
  };
  /// The isovertices of a hole's face and the faces and cells a local blend of their normals refits.
  struct HoleRegion {
    std::vector<std::uint32_t> vertices, cells, faces;
    std::vector<std::uint8_t> startLevel;  ///< of `vertices`
  };
  /// The cells of each isovertex (at most 4): those of v are cells[first[v]] up to cells[first[v + 1]].
  struct VertexCells {
    std::vector<std::uint32_t> first, cells;
  };

  // Normals and isovertices.
  std::uint32_t cellVertex(std::size_t c, int k) const {
    return model_.corners[model_.cells[c].firstCorner + k];
  }
  Vec3 edgeDirection(std::size_t v) const;
  void setNormal(std::size_t v);
  void lowerChangedVertices();
  void markVertices(std::size_t c, std::uint16_t edgeMask);
  bool raiseFailedVertices();

  // Fits of one face or cell, and their results.
  bool ownedDirtyFace(std::size_t c, int f) const {
    return ((table_.ownedFaces[c] >> f) & 1) && faceDirty_[static_cast<std::size_t>(table_.cellFaces[c][f])];
  }
  FaceResult fitFaceOf(std::size_t c, const CornerPatch& patch, int f, const CellReference& ref,
                       bool fallBack = false) const;
  bool opensAHole(std::size_t i, std::uint8_t holeEdges) const;
  void recordFace(std::size_t i, const FaceResult& fr);
  void shareFace(std::size_t i);
  void refitCell(std::size_t c, const CellReference& ref, bool fallBack = false);
  std::vector<std::uint32_t> unresolvedCells() const;
  bool resolvesAlone(std::size_t c) const;
  bool someCellResolves(const std::vector<std::uint32_t>& cells) const;

  // Saving and undoing.
  void saveCell(std::uint32_t c);
  void saveFace(std::size_t i);
  void saveRound();
  void restoreSaved(const std::vector<std::uint32_t>& cells);

  // The rounds.
  void fitDirtyCells(double from, double to);
  void fitSharedRound(double from, double to);
  void fitBlockFaces(std::size_t b0, std::size_t b1);
  void fitBlockCells(std::size_t b0, std::size_t b1);
  void findNextDirtyCells();

  // The local blends at holes.
  VertexCells cellsOfVertices() const;
  void findRegion(std::uint32_t target, const VertexCells& vertexCells, HoleRegion& region) const;
  void refitRegion(const HoleRegion& region, CellReference& ref);
  bool regionWorse(const HoleRegion& region) const;
  bool blendUntilClosed(std::uint32_t target, const HoleRegion& region, CellReference& ref);

  Model& model_;
  const std::vector<CellLoops>& loops_;
  const Reference& reference_;
  Progress progress_;
  const Collective* collective_;
  const std::size_t numCells_, numVertices_;
  std::vector<Vec3> baseNormal_;        ///< gradient normal of every isovertex
  std::vector<std::uint8_t> edgeAxis_;  ///< edge axis of every isovertex (a byte: most cells write theirs)
  const FaceTable table_;
  std::vector<std::uint8_t> level_, bump_;  ///< per isovertex: blend level, raised this round
  std::vector<std::uint8_t> faceDirty_, cellDirty_, faceOk_, cellOk_;
  /// Per face, whether FaceResult::holeEdges has an edge on a face that is open in one of its cells (a cell
  /// face without a crossing, which no patch continues): there the patch's zero set ends, a hole. Where both
  /// cells have a bounding plane through the edge instead, their zero sets meet along it (a crease).
  std::vector<std::uint8_t> faceHole_;
  std::vector<double> faceCoefficient_;
  /// The round's cells, ascending: all of them first, then the cells of the faces touched by an isovertex
  /// whose blend level changed (a dirty face's cells are both dirty, so its first cell fits it).
  std::vector<std::uint32_t> dirtyCells_, changedVertices_;
  std::vector<std::uint8_t> vertexChanged_;  ///< flags of changedVertices_ while the next cells are found
  std::vector<CellReference> blockReference_;
  std::vector<SavedCell> savedCells_;
  std::vector<SavedFace> savedFaces_;
};

}  // namespace cip
