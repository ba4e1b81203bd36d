#include "cip/model/fitting_rounds.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <cstring>
#include <limits>
#include <numeric>

#include "cip/core/error.h"
#include "cip/patch/cell_fit.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

/// Blend levels of a corner-plane normal: n = normalize((1 - beta) n_gradient + beta e_edge).
constexpr std::array<double, 5> kBlend{0.0, 0.25, 0.5, 0.75, 1.0};
constexpr int kMaxLevel = static_cast<int>(kBlend.size()) - 1;
/// Cells per block of the fitting rounds and worker thread (references kept for one block at a time). A
/// block's references (about 300 KB per thread) then stay in cache from its face fits to its cell fits:
/// against 4096, gyroid at N = 32 fits about 4 % faster. Blocks grow with the threads so that each block
/// gives every thread as much work between two waits. The block size does not change the model: a face is
/// fitted by the first of its two cells, in a block before or with the second.
constexpr std::size_t kBlockCells = 512;

std::size_t blockCells() {
  return kBlockCells * static_cast<std::size_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
}

/// The edges of face f, as bits of the cell's edges.
std::uint16_t faceEdgeMask(int f) {
  std::uint16_t mask = 0;
  for (int k = 0; k < 4; ++k) mask = static_cast<std::uint16_t>(mask | (1u << cube::faceEdge(f, k)));
  return mask;
}

/// Sorts `v` and removes repeated entries.
void sortUnique(std::vector<std::uint32_t>& v) {
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
}

}  // namespace

FaceTable buildFaceTable(const Model& model, const std::vector<CellLoops>& loops) {
  const std::size_t numCells = model.cells.size();
  const auto& dims = model.geometry.dims;
  const std::array<std::uint64_t, 3> step{1, static_cast<std::uint64_t>(dims[0]),
                                          static_cast<std::uint64_t>(dims[0] * dims[1])};
  auto key = [&](std::size_t c) {
    const auto& p = model.cells[c].index;
    return p[0] * step[0] + p[1] * step[1] + p[2] * step[2];
  };
  // In three parallel passes over chunks of cells, numbering the faces as one pass in raster order would:
  // (1) each cell's new faces (ownedFaces) and, for each near face it shares, the cell below (one cursor per
  // axis and chunk); (2) the first index of each cell's new faces (a prefix sum); (3) the new faces; (4) the
  // shared ones, each written by its second cell alone.
  constexpr std::size_t kChunk = 4096;
  FaceTable table;
  table.ownedFaces.resize(numCells);
  std::vector<std::array<std::uint32_t, 3>> below(numCells);
  std::atomic<bool> ordered{true};
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, numCells, kChunk), [&](const tbb::blocked_range<std::size_t>& r) {
        std::array<std::size_t, 3> cursor;
        for (int a = 0; a < 3; ++a) {  // the first cell at or after the first cell's neighbour below
          const std::uint64_t k = key(r.begin());
          const std::uint64_t target = k >= step[a] ? k - step[a] : 0;
          std::size_t lo = 0, hi = r.begin();
          while (lo < hi) {
            const std::size_t mid = (lo + hi) / 2;
            if (key(mid) < target)
              lo = mid + 1;
            else
              hi = mid;
          }
          cursor[a] = lo;
        }
        for (std::size_t c = r.begin(); c != r.end(); ++c) {
          const std::uint64_t k = key(c);
          if (c > 0 && k <= key(c - 1)) ordered = false;
          std::uint8_t owned = 0;
          for (int f = 0; f < 6; ++f) {
            if (!((loops[c].faceMask >> f) & 1)) continue;
            const int axis = cube::faceAxis(f);
            if (cube::faceSide(f) == 0 && model.cells[c].index[axis] > 0) {
              const std::uint64_t down = k - step[axis];
              std::size_t& at = cursor[static_cast<std::size_t>(axis)];
              while (at < c && key(at) < down) ++at;
              if (at < c && key(at) == down && ((loops[at].faceMask >> (f + 1)) & 1)) {
                below[c][static_cast<std::size_t>(axis)] = static_cast<std::uint32_t>(at);
                continue;
              }
            }
            owned = static_cast<std::uint8_t>(owned | (1u << f));
          }
          table.ownedFaces[c] = owned;
        }
      });
  if (!ordered) throw Error("fitModelPatches: cells must be in grid order (by z, y, x), each once");
  std::vector<std::uint32_t> first(numCells);
  std::size_t total = 0;
  for (std::size_t c = 0; c < numCells; ++c) {
    first[c] = static_cast<std::uint32_t>(total);
    total += static_cast<std::size_t>(__builtin_popcount(table.ownedFaces[c]));
  }
  if (total > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max()))
    throw Error("fitModelPatches: too many faces");
  table.faces.resize(total);
  table.cellFaces.resize(numCells);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numCells, kChunk),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t c = r.begin(); c != r.end(); ++c) {
                        auto& cf = table.cellFaces[c];
                        cf.fill(-1);
                        std::uint32_t i = first[c];
                        for (int f = 0; f < 6; ++f) {
                          if (!((table.ownedFaces[c] >> f) & 1)) continue;
                          FaceEntry& e = table.faces[i];
                          e.cell[0] = static_cast<std::uint32_t>(c);
                          e.face[0] = static_cast<std::int8_t>(f);
                          e.count = 1;
                          cf[static_cast<std::size_t>(f)] = static_cast<std::int32_t>(i++);
                        }
                      }
                    });
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, numCells, kChunk),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t c = r.begin(); c != r.end(); ++c) {
                        const unsigned shared = loops[c].faceMask & ~table.ownedFaces[c];
                        for (int f = 0; f < 6; ++f) {
                          if (!((shared >> f) & 1)) continue;
                          const std::uint32_t at = below[c][static_cast<std::size_t>(cube::faceAxis(f))];
                          const std::int32_t i = table.cellFaces[at][static_cast<std::size_t>(f + 1)];
                          FaceEntry& e = table.faces[static_cast<std::size_t>(i)];
                          e.cell[1] = static_cast<std::uint32_t>(c);
                          e.face[1] = static_cast<std::int8_t>(f);
                          e.count = 2;
                          table.cellFaces[c][static_cast<std::size_t>(f)] = i;
                        }
                      }
                    });
  return table;
}

FittingRounds::FittingRounds(Model& model, const std::vector<CellLoops>& loops, const Reference& reference,
                             const Progress& progress, const Collective* collective)
    : model_(model),
      loops_(loops),
      reference_(reference),
      progress_(progress),
      collective_(collective && collective->size() > 1 ? collective : nullptr),
      numCells_(model.cells.size()),
      numVertices_(model.vertices.size()),
      baseNormal_(numVertices_),
      edgeAxis_(numVertices_, 0),
      table_(buildFaceTable(model, loops)),
      level_(numVertices_, 0),
      bump_(numVertices_, 0),
      faceDirty_(table_.faces.size(), 1),
      cellDirty_(numCells_, 1),
      faceOk_(table_.faces.size(), 1),
      cellOk_(numCells_, 1),
      faceHole_(table_.faces.size(), 0),
      faceCoefficient_(table_.faces.size(), 0.0),
      dirtyCells_(numCells_),
      blockReference_(std::min(numCells_, blockCells())) {
  for (std::size_t v = 0; v < numVertices_; ++v) baseNormal_[v] = model.vertices[v].normal;
  for (std::size_t c = 0; c < numCells_; ++c) {
    const ModelCell& cell = model.cells[c];
    for (int k = 0; k < cell.numCorners(); ++k)
      edgeAxis_[model.corners[cell.firstCorner + k]] =
          static_cast<std::uint8_t>(cube::edgeAxis(loops[c].edges[k]));
  }
  for (std::size_t c = 0; c < numCells_; ++c) dirtyCells_[c] = static_cast<std::uint32_t>(c);
}

// ---- Normals and isovertices ----

/// The edge direction of an isovertex, towards the positive vertex.
Vec3 FittingRounds::edgeDirection(std::size_t v) const {
  const int axis = edgeAxis_[v];
  return Vec3(Vec3::Unit(axis) * (baseNormal_[v][axis] >= 0 ? 1.0 : -1.0));
}

/// The normal of isovertex v at its blend level.
void FittingRounds::setNormal(std::size_t v) {
  double beta = kBlend[level_[v]];
  const Vec3 edge = edgeDirection(v);
  Vec3 n = (1 - beta) * baseNormal_[v] + beta * edge;
  model_.vertices[v].normal = n.norm() > 1e-12 ? Vec3(n.normalized()) : edge;
}

/// Undoes raiseFailedVertices.
void FittingRounds::lowerChangedVertices() {
  for (std::uint32_t v : changedVertices_) {
    --level_[v];
    setNormal(v);
  }
}

/// Marks the isovertices of cell c on the edges of `edgeMask` that can still be raised.
void FittingRounds::markVertices(std::size_t c, std::uint16_t edgeMask) {
  const ModelCell& cell = model_.cells[c];
  for (int k = 0; k < cell.numCorners(); ++k) {
    if (!((edgeMask >> loops_[c].edges[k]) & 1)) continue;
    const std::uint32_t v = cellVertex(c, k);
    if (level_[v] < kMaxLevel && !bump_[v]) {
      bump_[v] = 1;
      changedVertices_.push_back(v);
    }
  }
}

/// Isovertices of failed faces and cells move one blend level towards the edge direction (changedVertices_);
/// false where none can. Only this round's faces and cells can bump one: a failure left from an earlier
/// round that was not refitted has all its isovertices at the last level.
bool FittingRounds::raiseFailedVertices() {
  changedVertices_.clear();
  for (std::uint32_t c : dirtyCells_) {
    for (int f = 0; f < 6; ++f) {
      if (!ownedDirtyFace(c, f) || faceOk_[static_cast<std::size_t>(table_.cellFaces[c][f])]) continue;
      markVertices(c, faceEdgeMask(f));
    }
    if (!cellOk_[c]) markVertices(c, 0xFFF);
  }
  if (changedVertices_.empty()) return false;
  for (std::uint32_t v : changedVertices_) {
    ++level_[v];
    bump_[v] = 0;
    setNormal(v);
  }
  return true;
}

// ---- Fits of one face or cell ----

/// The fit of face f of cell c (with corner data `patch`), by the cell's configuration and pairings.
FaceResult FittingRounds::fitFaceOf(std::size_t c, const CornerPatch& patch, int f, const CellReference& ref,
                                    bool fallBack) const {
  return fitFace(patch, model_.cells[c].config, model_.cells[c].pairing03, f, ref, fallBack);
}

/// Whether the edges `holeEdges` of face i make a hole (faceHole_).
bool FittingRounds::opensAHole(std::size_t i, std::uint8_t holeEdges) const {
  const FaceEntry& face = table_.faces[i];
  for (int k = 0; k < 4; ++k) {
    if (!((holeEdges >> k) & 1)) continue;
    const auto both = cube::edgeFaces(cube::faceEdge(face.face[0], k));
    const int other = both[0] == face.face[0] ? both[1] : both[0];  // the same plane in both cells
    for (int s = 0; s < face.count; ++s)
      if (!((loops_[face.cell[s]].faceMask >> other) & 1)) return true;
  }
  return false;
}

// A face's fit recorded (by its first cell), then copied to both its cells; a cell's central coefficient
// fitted with the side coefficients it has. The rounds, the local blends and the last pass fit alike.

void FittingRounds::recordFace(std::size_t i, const FaceResult& fr) {
  faceCoefficient_[i] = fr.coefficient;
  faceOk_[i] = fr.ok;
  faceHole_[i] = opensAHole(i, fr.holeEdges);
}

void FittingRounds::shareFace(std::size_t i) {
  const FaceEntry& face = table_.faces[i];
  for (int s = 0; s < face.count; ++s)
    model_.cells[face.cell[s]].faceCoefficient[face.face[s]] = faceCoefficient_[i];
}

void FittingRounds::refitCell(std::size_t c, const CellReference& ref, bool fallBack) {
  model_.cells[c].central = 0;
  const CellResult cr = fitCell(model_.patch(c, loops_[c]), model_.cells[c].config, ref, fallBack);
  model_.cells[c].central = cr.central;
  cellOk_[c] = cr.ok;
}

/// Cells without a sign-correct central coefficient or with a face without a sign-correct side coefficient,
/// ascending. Failures are few: the flags are scanned, not every cell's faces.
std::vector<std::uint32_t> FittingRounds::unresolvedCells() const {
  std::vector<std::uint32_t> out;
  for (std::size_t c = 0; c < numCells_; ++c)
    if (!cellOk_[c]) out.push_back(static_cast<std::uint32_t>(c));
  for (std::size_t i = 0; i < table_.faces.size(); ++i)
    if (!faceOk_[i])
      for (int s = 0; s < table_.faces[i].count; ++s) out.push_back(table_.faces[i].cell[s]);
  sortUnique(out);
  return out;
}

/// Whether cell c gets sign-correct side coefficients on all its faces and a sign-correct central
/// coefficient when fitted alone with the current normals, exactly as a round would fit it (each face by its
/// first cell). The model is not changed.
bool FittingRounds::resolvesAlone(std::size_t c) const {
  CornerPatch patch = model_.patch(c, loops_[c]);
  CellReference ref, firstRef;
  reference_(c, ref);
  for (int f = 0; f < 6; ++f) {
    const std::int32_t i = table_.cellFaces[c][f];
    if (i < 0) continue;
    const FaceEntry& face = table_.faces[static_cast<std::size_t>(i)];
    const std::size_t first = face.cell[0];
    if (first != c) reference_(first, firstRef);
    const FaceResult fr = first == c
                              ? fitFaceOf(c, patch, face.face[0], ref)
                              : fitFaceOf(first, model_.patch(first, loops_[first]), face.face[0], firstRef);
    if (!fr.ok) return false;
    patch.faceCoefficient[static_cast<std::size_t>(f)] = fr.coefficient;
  }
  patch.central = 0;
  return fitCell(patch, model_.cells[c].config, ref).ok;
}

/// Whether one of `cells` resolves alone (resolvesAlone).
bool FittingRounds::someCellResolves(const std::vector<std::uint32_t>& cells) const {
  std::atomic<bool> found{false};
  tbb::parallel_for(std::size_t(0), cells.size(), [&](std::size_t j) {
    if (found.load(std::memory_order_relaxed)) return;
    if (resolvesAlone(cells[j])) found.store(true, std::memory_order_relaxed);
  });
  return found.load();
}

// ---- Saving and undoing ----

void FittingRounds::saveCell(std::uint32_t c) {
  savedCells_.push_back({model_.cells[c].central, model_.cells[c].faceCoefficient, cellOk_[c]});
}

void FittingRounds::saveFace(std::size_t i) {
  savedFaces_.push_back({i, faceCoefficient_[i], faceOk_[i], faceHole_[i]});
}

/// What a round overwrites: per dirty cell its coefficients and result, per face it fits its result.
void FittingRounds::saveRound() {
  savedCells_.clear();
  savedFaces_.clear();
  for (std::uint32_t c : dirtyCells_) {
    saveCell(c);
    for (int f = 0; f < 6; ++f)
      if (ownedDirtyFace(c, f)) saveFace(static_cast<std::size_t>(table_.cellFaces[c][f]));
  }
}

/// Puts back what savedFaces_ and savedCells_ (one per cell of `cells`) hold.
void FittingRounds::restoreSaved(const std::vector<std::uint32_t>& cells) {
  for (std::size_t j = 0; j < cells.size(); ++j) {
    ModelCell& cell = model_.cells[cells[j]];
    cell.central = savedCells_[j].central;
    cell.faceCoefficient = savedCells_[j].faceCoefficient;
    cellOk_[cells[j]] = savedCells_[j].ok;
  }
  for (const SavedFace& saved : savedFaces_) {
    faceCoefficient_[saved.index] = saved.coefficient;
    faceOk_[saved.index] = saved.ok;
    faceHole_[saved.index] = saved.hole;
  }
}

// ---- The rounds ----

void FittingRounds::runRounds(FittingStats& stats) {
  std::size_t bestUnresolved = 0;
  for (int round = 0;; ++round) {
    stats.rounds = round + 1;
    if (round > 0) saveRound();
    if (round == 0)
      tbb::parallel_for(std::size_t(0), numVertices_, [&](std::size_t v) { setNormal(v); });
    else
      for (std::uint32_t v : changedVertices_) setNormal(v);
    // Progress: the first round (every cell) to 0.85, each later one (fewer cells) part of what is left.
    if (round == 0 && collective_)
      fitSharedRound(0.0, 0.85);
    else
      fitDirtyCells(round == 0 ? 0.0 : 1.0 - 0.15 / round, 1.0 - 0.15 / (round + 1));
    // A fallback round that does not reduce the unresolved cells is undone, and the rounds end: blending
    // normals cannot make a cell follow sign structure its loops do not have (a field with detail inside
    // cells), and there it only spreads failures to the neighbours (Marschner-Lobb at N = 32, exact: 160
    // unresolved cells after the first round, 280 after ten).
    const std::size_t unresolved = unresolvedCells().size();
    if (round > 0 && unresolved >= bestUnresolved) {
      restoreSaved(dirtyCells_);
      lowerChangedVertices();
      stats.lastRoundUndone = true;
      return;
    }
    bestUnresolved = unresolved;
    if (!raiseFailedVertices()) return;
    // The next round can lower the count of unresolved cells only if one of them resolves, and what a round
    // gives a cell depends on its own isovertices alone. If none resolves when fitted alone, the round would
    // be undone: end here with the same result, without refitting the cells around them.
    if (!someCellResolves(unresolvedCells())) {
      lowerChangedVertices();
      stats.rounds = round + 2;
      stats.lastRoundUndone = true;
      return;
    }
    findNextDirtyCells();
  }
}

/// The faces and cells of the round. Cells in blocks of index order. A face is fitted by its first cell (the
/// lowest index), so when a block's cells are fitted, every face they touch has been fitted in this block or
/// an earlier one, and each cell's reference is built once per round for its faces and itself.
void FittingRounds::fitDirtyCells(double from, double to) {
  const std::size_t block = std::max<std::size_t>(1, blockReference_.size());
  for (std::size_t b0 = 0; b0 < dirtyCells_.size(); b0 += block) {
    if (progress_)
      progress_(from + (to - from) * static_cast<double>(b0) / static_cast<double>(dirtyCells_.size()));
    const std::size_t b1 = std::min(dirtyCells_.size(), b0 + block);
    fitBlockFaces(b0, b1);
    for (std::size_t j = b0; j < b1; ++j)
      for (int f = 0; f < 6; ++f) {
        const std::size_t c = dirtyCells_[j];
        if (ownedDirtyFace(c, f)) shareFace(static_cast<std::size_t>(table_.cellFaces[c][f]));
      }
    fitBlockCells(b0, b1);
  }
}

/// The first round (every cell) split between the ranks of collective_: each rank fits the faces its share
/// of the cells (rankShare) owns, the ranks exchange them and every rank shares every face with its cells,
/// then each rank fits its share's central coefficients and the ranks exchange those. Each fit reads what
/// it reads in fitDirtyCells (a face its first cell's corners, a cell its faces' coefficients, fitted before
/// it by a cell with a lower index), so every rank ends with the state one process computes, to the bit.
void FittingRounds::fitSharedRound(double from, double to) {
  const int rank = collective_->rank(), ranks = collective_->size();
  // The faces owned by the cells c0 .. c1 (numbered in the order of their first cells).
  auto facesOf = [&](std::size_t c0, std::size_t c1) {
    auto byCell = [](const FaceEntry& e, std::size_t c) { return e.cell[0] < c; };
    const auto begin = std::lower_bound(table_.faces.begin(), table_.faces.end(), c0, byCell);
    const auto end = std::lower_bound(begin, table_.faces.end(), c1, byCell);
    return std::pair<std::size_t, std::size_t>(static_cast<std::size_t>(begin - table_.faces.begin()),
                                               static_cast<std::size_t>(end - table_.faces.begin()));
  };
  const auto [c0, c1] = rankShare(numCells_, rank, ranks);
  const std::size_t block = std::max<std::size_t>(1, blockReference_.size());
  const double mid = from + 0.5 * (to - from);
  for (std::size_t b0 = c0; b0 < c1; b0 += block) {
    if (progress_)
      progress_(from + (mid - from) * static_cast<double>(b0 - c0) / static_cast<double>(c1 - c0));
    fitBlockFaces(b0, std::min(c1, b0 + block));
  }
  constexpr std::size_t kFaceRecord = sizeof(double) + 2, kCellRecord = sizeof(double) + 1;
  exchangeRanges(
      *collective_, kFaceRecord,
      [&](int r) {
        const auto [d0, d1] = rankShare(numCells_, r, ranks);
        return facesOf(d0, d1);
      },
      [&](std::size_t i, std::vector<std::uint8_t>& out) {
        appendBytes(out, &faceCoefficient_[i], 1);
        out.push_back(faceOk_[i]);
        out.push_back(faceHole_[i]);
      },
      [&](std::size_t i, const std::uint8_t* p) {
        std::memcpy(&faceCoefficient_[i], p, sizeof(double));
        faceOk_[i] = p[sizeof(double)];
        faceHole_[i] = p[sizeof(double) + 1];
      });
  tbb::parallel_for(std::size_t(0), table_.faces.size(), [&](std::size_t i) { shareFace(i); });
  for (std::size_t b0 = c0; b0 < c1; b0 += block) {
    if (progress_) progress_(mid + (to - mid) * static_cast<double>(b0 - c0) / static_cast<double>(c1 - c0));
    const std::size_t b1 = std::min(c1, b0 + block);
    tbb::parallel_for(tbb::blocked_range<std::size_t>(b0, b1, 32),
                      [&](const tbb::blocked_range<std::size_t>& r) {
                        for (std::size_t j = r.begin(); j != r.end(); ++j)
                          reference_(j, blockReference_[j - b0]);
                      });
    fitBlockCells(b0, b1);
  }
  exchangeRanges(
      *collective_, kCellRecord, [&](int r) { return rankShare(numCells_, r, ranks); },
      [&](std::size_t c, std::vector<std::uint8_t>& out) {
        appendBytes(out, &model_.cells[c].central, 1);
        out.push_back(cellOk_[c]);
      },
      [&](std::size_t c, const std::uint8_t* p) {
        std::memcpy(&model_.cells[c].central, p, sizeof(double));
        cellOk_[c] = p[sizeof(double)];
      });
}

/// The faces that the cells b0 .. b1 of the round fit, each cell's reference kept in blockReference_.
void FittingRounds::fitBlockFaces(std::size_t b0, std::size_t b1) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(b0, b1, 32),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t j = r.begin(); j != r.end(); ++j) {
                        const std::size_t c = dirtyCells_[j];
                        CellReference& ref = blockReference_[j - b0];
                        reference_(c, ref);
                        unsigned fits = 0;  // the faces this cell fits now
                        for (int f = 0; f < 6; ++f) fits |= unsigned{ownedDirtyFace(c, f)} << f;
                        if (!fits) continue;
                        const CornerPatch patch = model_.patch(c, loops_[c]);
                        for (int f = 0; f < 6; ++f) {
                          if (!((fits >> f) & 1)) continue;
                          const auto i = static_cast<std::size_t>(table_.cellFaces[c][f]);
                          recordFace(i, fitFaceOf(c, patch, f, ref));
                        }
                      }
                    });
}

/// The central coefficients of the cells b0 .. b1 of the round, with the references fitBlockFaces kept.
void FittingRounds::fitBlockCells(std::size_t b0, std::size_t b1) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(b0, b1, 32),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t j = r.begin(); j != r.end(); ++j)
                        refitCell(dirtyCells_[j], blockReference_[j - b0]);
                    });
}

/// Next round: the cells of changed isovertices (found by a pass over the corners; there are few rounds),
/// all their faces, and the other cells of those faces.
void FittingRounds::findNextDirtyCells() {
  const auto& faces = table_.faces;
  const auto& cellFaces = table_.cellFaces;
  if (dirtyCells_.size() == numCells_) {
    std::fill(cellDirty_.begin(), cellDirty_.end(), 0);
    std::fill(faceDirty_.begin(), faceDirty_.end(), 0);
  } else {
    for (std::uint32_t c : dirtyCells_) {
      cellDirty_[c] = 0;
      for (int f = 0; f < 6; ++f)
        if (cellFaces[c][f] >= 0) faceDirty_[static_cast<std::size_t>(cellFaces[c][f])] = 0;
    }
  }
  dirtyCells_.clear();
  vertexChanged_.resize(numVertices_, 0);
  for (std::uint32_t v : changedVertices_) vertexChanged_[v] = 1;
  for (std::size_t c = 0; c < numCells_; ++c)
    for (int k = 0; k < model_.cells[c].numCorners(); ++k)
      if (vertexChanged_[cellVertex(c, k)]) {
        cellDirty_[c] = 1;
        dirtyCells_.push_back(static_cast<std::uint32_t>(c));
        break;
      }
  for (std::uint32_t v : changedVertices_) vertexChanged_[v] = 0;
  const std::size_t touched = dirtyCells_.size();
  for (std::size_t j = 0; j < touched; ++j)
    for (int f = 0; f < 6; ++f) {
      const std::int32_t i = cellFaces[dirtyCells_[j]][f];
      if (i < 0) continue;
      faceDirty_[static_cast<std::size_t>(i)] = 1;
      const FaceEntry& face = faces[static_cast<std::size_t>(i)];
      for (int s = 0; s < face.count; ++s)
        if (!cellDirty_[face.cell[s]]) {
          cellDirty_[face.cell[s]] = 1;
          dirtyCells_.push_back(face.cell[s]);
        }
    }
  std::sort(dirtyCells_.begin(), dirtyCells_.end());
}

// ---- The local blends at holes ----

/// Holes the rounds leave: faces whose uncrossed edges their side coefficient cannot keep at the vertices'
/// sign together with the face lattice, where the reference keeps that sign, next to an open face
/// (faceHole_). The corner planes of the face's isovertices stand in the way, so they move towards the edge
/// direction one level at a time, here alone: the faces and cells around them are fitted again, and the
/// blend is kept at the first level where the hole closes and no face or cell around it fails or gets a hole
/// it did not have; otherwise it is undone. As failures, holes would spread to the neighbours through the
/// rounds (docs/method.md, step 7). One hole at a time, in index order, so the model does not depend on the
/// number of threads.
void FittingRounds::closeHoles(FittingStats& stats) {
  std::vector<std::uint32_t> holes;
  for (std::size_t i = 0; i < table_.faces.size(); ++i)
    if (faceHole_[i] && faceOk_[i]) holes.push_back(static_cast<std::uint32_t>(i));
  stats.holes = holes.size();
  if (holes.empty()) return;
  const VertexCells vertexCells = cellsOfVertices();
  HoleRegion region;
  CellReference ref;
  for (std::uint32_t target : holes) {
    if (!faceHole_[target]) continue;  // closed by an earlier blend
    findRegion(target, vertexCells, region);
    savedFaces_.clear();
    savedCells_.clear();
    for (std::uint32_t i : region.faces) saveFace(i);
    for (std::uint32_t c : region.cells) saveCell(c);
    if (blendUntilClosed(target, region, ref)) {
      ++stats.holesClosed;
      continue;
    }
    for (std::size_t j = 0; j < region.vertices.size(); ++j) {
      level_[region.vertices[j]] = region.startLevel[j];
      setNormal(region.vertices[j]);
    }
    restoreSaved(region.cells);
  }
}

/// The cells of each isovertex, as offsets into one array.
FittingRounds::VertexCells FittingRounds::cellsOfVertices() const {
  VertexCells out;
  out.first.assign(numVertices_ + 1, 0);
  for (std::size_t c = 0; c < numCells_; ++c)
    for (int k = 0; k < model_.cells[c].numCorners(); ++k) ++out.first[cellVertex(c, k) + 1];
  std::partial_sum(out.first.begin(), out.first.end(), out.first.begin());
  out.cells.resize(out.first[numVertices_]);
  std::vector<std::uint32_t> next(out.first.begin(), out.first.end() - 1);
  for (std::size_t c = 0; c < numCells_; ++c)
    for (int k = 0; k < model_.cells[c].numCorners(); ++k)
      out.cells[next[cellVertex(c, k)]++] = static_cast<std::uint32_t>(c);
  return out;
}

/// The isovertices on the edges of face `target` (from its first cell), the faces of the cells around them
/// and all those faces' cells, as a round would fit them, and the isovertices' blend levels now.
void FittingRounds::findRegion(std::uint32_t target, const VertexCells& vertexCells,
                               HoleRegion& region) const {
  const auto& faces = table_.faces;
  const std::size_t owner = faces[target].cell[0];
  const std::uint16_t edgeMask = faceEdgeMask(faces[target].face[0]);
  region.vertices.clear();
  for (int k = 0; k < model_.cells[owner].numCorners(); ++k)
    if ((edgeMask >> loops_[owner].edges[k]) & 1) region.vertices.push_back(cellVertex(owner, k));
  region.cells.clear();
  region.faces.clear();
  for (std::uint32_t v : region.vertices)
    for (std::uint32_t j = vertexCells.first[v]; j < vertexCells.first[v + 1]; ++j)
      for (int f = 0; f < 6; ++f)
        if (table_.cellFaces[vertexCells.cells[j]][f] >= 0)
          region.faces.push_back(static_cast<std::uint32_t>(table_.cellFaces[vertexCells.cells[j]][f]));
  sortUnique(region.faces);
  for (std::uint32_t i : region.faces)
    for (int s = 0; s < faces[i].count; ++s) region.cells.push_back(faces[i].cell[s]);
  sortUnique(region.cells);
  region.startLevel.clear();
  for (std::uint32_t v : region.vertices) region.startLevel.push_back(level_[v]);
}

/// The region's faces and cells fitted again, as a round fits them.
void FittingRounds::refitRegion(const HoleRegion& region, CellReference& ref) {
  for (std::uint32_t i : region.faces) {
    const std::size_t c = table_.faces[i].cell[0];
    reference_(c, ref);
    recordFace(i, fitFaceOf(c, model_.patch(c, loops_[c]), table_.faces[i].face[0], ref));
    shareFace(i);
  }
  for (std::uint32_t c : region.cells) {
    reference_(c, ref);
    refitCell(c, ref);
  }
}

/// Whether a face or cell of the region fails now where it did not before the blend (savedFaces_,
/// savedCells_), or a face got a hole.
bool FittingRounds::regionWorse(const HoleRegion& region) const {
  bool worse = false;
  for (const SavedFace& saved : savedFaces_)
    worse |= (saved.ok && !faceOk_[saved.index]) || (!saved.hole && faceHole_[saved.index]);
  for (std::size_t j = 0; j < region.cells.size(); ++j)
    worse |= savedCells_[j].ok && !cellOk_[region.cells[j]];
  return worse;
}

/// Raises the blend level of the region's isovertices one step at a time and refits the region, until the
/// hole at face `target` closes (true) or the levels end or the region gets worse (false; the caller undoes
/// the blend).
bool FittingRounds::blendUntilClosed(std::uint32_t target, const HoleRegion& region, CellReference& ref) {
  for (;;) {
    bool moved = false;
    for (std::uint32_t v : region.vertices)
      if (level_[v] < kMaxLevel) {
        ++level_[v];
        setNormal(v);
        moved = true;
      }
    if (!moved) return false;
    refitRegion(region, ref);
    if (regionWorse(region)) return false;
    if (!faceHole_[target]) return true;
  }
}

// ---- The last pass ----

/// Faces left without a sign-correct side coefficient take the one the fewest counting samples contradict
/// (nearest to the fit) instead of the fit; their cells are flagged to be fitted again.
std::vector<std::uint8_t> FittingRounds::settleFailedFaces() {
  const auto& faces = table_.faces;
  std::vector<std::uint32_t> failedFaces;
  for (std::size_t i = 0; i < faces.size(); ++i)
    if (!faceOk_[i]) failedFaces.push_back(static_cast<std::uint32_t>(i));
  tbb::parallel_for(std::size_t(0), failedFaces.size(), [&](std::size_t j) {
    const FaceEntry& face = faces[failedFaces[j]];
    const std::size_t c = face.cell[0];
    CellReference ref;
    reference_(c, ref);
    faceCoefficient_[failedFaces[j]] =
        fitFaceOf(c, model_.patch(c, loops_[c]), face.face[0], ref, true).coefficient;
  });
  std::vector<std::uint8_t> refit(numCells_, 0);
  for (std::uint32_t i : failedFaces) {
    shareFace(i);
    for (int s = 0; s < faces[i].count; ++s) refit[faces[i].cell[s]] = 1;
  }
  return refit;
}

/// Cells left without a sign-correct central coefficient take the one the fewest counting samples
/// contradict (nearest to 0) instead of 0; the cells of settled faces are fitted again.
void FittingRounds::settleFailedCells(const std::vector<std::uint8_t>& refit) {
  std::vector<std::uint32_t> lastCells;
  for (std::size_t c = 0; c < numCells_; ++c)
    if (!cellOk_[c] || refit[c]) lastCells.push_back(static_cast<std::uint32_t>(c));
  tbb::parallel_for(std::size_t(0), lastCells.size(), [&](std::size_t j) {
    CellReference ref;
    reference_(lastCells[j], ref);
    refitCell(lastCells[j], ref, true);
  });
}

void FittingRounds::report(FittingStats& stats) const {
  for (std::size_t v = 0; v < numVertices_; ++v) {
    stats.blendedVertices += level_[v] > 0;
    ++stats.levelCount[level_[v]];
  }
  for (auto ok : faceOk_) stats.failedFaces += !ok;
  for (auto ok : cellOk_) stats.failedCells += !ok;
  stats.unresolvedCells = unresolvedCells();
}

}  // namespace cip
