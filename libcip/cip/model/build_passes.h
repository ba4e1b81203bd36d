/// @file build_passes.h
/// @brief The passes of buildModel (model_builder.h), in the order it runs them: scan the cells, prepare the
/// reference, place the isovertices, assemble the cells, fit the coefficients. What one pass hands the next
/// is a struct here, so the data flow is in the signatures. Tables are ordered by grid keys (the scan's by
/// brick and row), never by completion order: the model is the same for any number of threads. Internal to
/// the builder; the passes run in its TBB arena.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <mutex>
#include <vector>

#include "cip/model/model.h"
#include "cip/model/model_builder.h"
#include "cip/reference/mask_reference.h"
#include "cip/reference/point_hermite_table.h"
#include "cip/reference/reconstruction_choice.h"

namespace cip::build {

/// A grid point or grid edge of the global grid as one number: point keys in x-fastest order, edge keys as
/// point key * 3 + axis (the edge from the point towards +axis).
using Key = std::uint64_t;

struct GridKeys {
  std::array<std::int64_t, 3> dims;
  Key point(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return static_cast<Key>(i + dims[0] * (j + dims[1] * k));
  }
  std::array<std::int64_t, 3> coords(Key p) const {
    std::int64_t v = static_cast<std::int64_t>(p);
    return {v % dims[0], (v / dims[0]) % dims[1], v / (dims[0] * dims[1])};
  }
  /// The key of edge `e` (cube_topology.h numbering) of the cell whose lowest point is `cell`.
  Key cellEdge(const std::array<std::int64_t, 3>& cell, int e) const;
};

/// A crossed grid edge, seen from a brick that owns one of its cells.
struct EdgeRef {
  Key key;
  std::uint32_t brick;
  bool operator<(const EdgeRef& o) const { return key != o.key ? key < o.key : brick < o.brick; }
};

/// A crossed cell (corners on both sides of the isovalue), its owning brick and sign configuration.
struct CellRef {
  Key key;
  std::uint32_t brick;
  std::uint8_t config;
  bool operator<(const CellRef& o) const { return key < o.key; }
};

/// Reports the fraction done to BuildOptions::progress in steps of at least 0.005, never concurrently.
class Progress {
 public:
  explicit Progress(const std::function<void(double)>& fn) : fn_(fn) {}
  void set(double fraction) {
    if (!fn_) return;
    std::lock_guard<std::mutex> lock(mutex_);
    if (fraction < last_ + 0.005 && fraction < 1.0) return;
    last_ = fraction;
    fn_(fraction);
  }

 private:
  const std::function<void(double)>& fn_;
  std::mutex mutex_;
  double last_ = -1;
};

/// Whether a build follows the smoothed indicator of a mask or label (mask_reference.h) instead of the
/// samples: never, always (asked for: a label, or Reconstruction::Mask), or when the samples next to the
/// surface take two values in every brick (Auto on sampled data: detect it).
enum class MaskRule : std::uint8_t { Samples, Mask, Detect };
/// The rule of `options`; throws cip::Error when the mask is asked for without the fitted construction's
/// reference of the samples.
MaskRule maskRule(const BuildOptions& options);

/// MaskRule::Detect's verdict over bricks, told each brick's detectTwoValued in turn: the mask when some
/// brick saw the surface and every such brick saw the same two values. Also whether the samples are integers
/// at an integer isovalue (integerSamples()).
class TwoValuedVerdict {
 public:
  void add(const TwoValuedSamples& t) {
    if (t.points == 0) return;
    integral_ = integral_ && t.integral;
    crossedEdges_ += t.crossedEdges;
    if (failed_) return;
    if (!t.twoValued || (seen_ && (below_ != t.below || above_ != t.above))) {
      failed_ = true;
      return;
    }
    seen_ = true;
    below_ = t.below;
    above_ = t.above;
  }
  bool mask() const { return seen_ && !failed_; }
  /// The samples of the crossed grid edges counted are integers, and so is the isovalue: 8- and 16-bit data
  /// (CT, MRI, quantised fields), where samples equal the isovalue next to the surface. The monotone and
  /// central8 interpolants are zero on plateaus around such samples where the data climbs by a level or two
  /// per voxel (terraces: nearly every cell then failed its fit, and the fallback rounds and hole blends
  /// refitted each many times, docs/performance.md, "Why 1024³ blobs take minutes"), and isovertices on or
  /// next to grid points leave holes where a corner plane tilts across an uncrossed grid edge
  /// (docs/method.md, "Integer samples at an integer isovalue").
  bool integerSamples() const { return integral_ && crossedEdges_ > 0; }
  /// No further brick can change mask() or integerSamples().
  bool decided() const { return failed_ && !integral_; }

 private:
  bool seen_ = false, failed_ = false, integral_ = true;
  double below_ = 0, above_ = 0;
  std::int64_t crossedEdges_ = 0;
};

/// Where detectTwoValued counts a brick's crossed edges: its own cells, so that bricks and slabs that overlap
/// count what the whole volume counts.
inline CountedEdges countedEdgesOf(const GridBrick& brick) {
  CountedEdges count;
  count.begin = brick.cellBegin;
  count.end = brick.cellEnd;
  count.firstSliceZ = brick.offset[2];
  return count;
}

/// How far above the isovalue a fitted build of integer samples runs (integerRaise): 1/64 of a level. No
/// integer sample lies between the isovalue and it, so every sample keeps its side, every cell its
/// configuration; the crossings next to samples at the isovalue move 1/64 of a level off them (at most 1/64
/// voxel where the samples step by a level), and the interpolants are no longer zero on plateaus. On a
/// crop of the 1024³ blobs of benchmarks/streaming_memory.py the fit ran 100 times faster for a patch surface
/// as close to the true level set; on CT and MRI data it leaves fewer failed cells and holes
/// (docs/method.md, "Integer samples at an integer isovalue").
constexpr double kIntegerRaise = 1.0 / 64;
/// kIntegerRaise where `verdict` found integer samples and no mask (the mask's own field has no plateaus),
/// else 0; also 0 where `isovalue` is so large that adding it changes no bit (from about 2^47).
inline double integerRaise(const TwoValuedVerdict& verdict, double isovalue) {
  const bool raise = !verdict.mask() && verdict.integerSamples() && isovalue + kIntegerRaise != isovalue;
  return raise ? kIntegerRaise : 0.0;
}

/// The field a mask's model is built from, of one brick's samples: smoothMask, or smoothLabel of the label
/// (with its blocks placed along z as in the volume whose slice `firstSliceZ` is the brick's first).
DenseGrid maskField(const DenseGrid& samples, const BuildOptions& options, std::int64_t firstSliceZ = 0);
/// The options the mask's model is built with from maskField's bricks (Central8, the label's isovalue 0).
BuildOptions maskFieldOptions(const BuildOptions& options);

/// What every pass reads.
struct Input {
  const GridGeometry& geometry;  ///< the global grid
  const std::vector<GridBrick>& bricks;
  const BuildOptions& options;
  GridKeys keys;  ///< of the global grid
  Progress& progress;
  /// How far options.isovalue lies above the isovalue asked for (integerRaise, else 0): an isovertex next to
  /// a sample at the asked isovalue is treated as one on that grid point (normalClearOfUncrossedEdges).
  double raise;
};

/// Brick-local indices of the global grid point `global` in `brick`.
std::array<std::int64_t, 3> localPoint(const GridBrick& brick, const std::array<std::int64_t, 3>& global);

/// A model with no cells yet: the grid, isovalue, normal mode, method and source of the build.
Model emptyModel(const GridGeometry& geometry, const BuildOptions& options, const std::string& source);

/// Whether the coefficients are fitted model-wide (fitCoefficients below) rather than per cell.
inline bool fitsModelWide(const BuildOptions& options) {
  return options.fitCoefficients && options.method == PatchMethod::Fitted;
}

/// The ranks a build is split between (BuildOptions::collective with more than one rank), or null.
inline const Collective* sharedBuild(const BuildOptions& options) {
  return options.collective && options.collective->size() > 1 ? options.collective : nullptr;
}

/// Scan's result: the crossed cells and, per brick row, their crossed edges without repeats (an edge shared
/// by two bricks is listed by both), both brick by brick and row by row; for one brick of finite samples,
/// the edges sorted and unique (edgesUnique).
struct CellScan {
  std::vector<CellRef> cells;
  std::vector<EdgeRef> edges;
  bool edgesUnique = false;  ///< edges already sorted by key, each once (one brick of finite samples)
};

/// Pass 1, progress 0 to 0.3. Throws NonFiniteSampleError for a cell with a NaN or infinite corner value
/// unless options.skipNonFinite (then the cell is left out).
CellScan scanCells(const Input& in);

/// Pass 1 over brick `brick` alone (a streamed build scans one slab of the volume at a time): its crossed
/// cells in key order and their crossed edges sorted by key, each once (edgesUnique). Throws as scanCells.
CellScan scanBrickCells(const Input& in, std::uint32_t brick);

/// Adds `cells` (crossed cells, in scan order) to Auto's estimate, from the samples of their bricks.
void addToEstimate(const Input& in, const std::vector<CellRef>& cells, SamplingEstimator& estimator);

/// The reference's data (`kind`, resolved) at the corners of `cells`, crossed cells of one brick; with
/// `ranks`, each rank computes its share of the table and the ranks exchange them (PointHermiteTable).
PointHermiteTable brickReference(const Input& in, const std::vector<CellRef>& cells, Reconstruction kind,
                                 const Collective* ranks = nullptr);

/// The reference of the samples: with the fitted construction, unless exact, the reconstruction (Auto
/// resolved) and its Hermite data at the corners of the crossed cells, one table per brick.
struct SampledReference {
  bool sampled = false;
  Reconstruction kind = Reconstruction::Auto;
  SamplingEstimate sampling;              ///< what Auto was resolved from
  std::vector<PointHermiteTable> tables;  ///< per brick (empty without crossed cells or when not sampled)
};

/// Pass 2. `cells` in scan order (Auto's estimate adds them in that order).
SampledReference prepareReference(const Input& in, const std::vector<CellRef>& cells);

/// The scanned edges sorted by key, each once (from the first brick that lists it; `alreadyUnique`: they are,
/// CellScan::edgesUnique). Throws cip::Error when there are more than 2^32 - 1.
std::vector<EdgeRef> uniqueEdges(std::vector<EdgeRef> edges, bool alreadyUnique = false);

/// Pass 3: the isovertex of every edge of `edges` (uniqueEdges), in their order: the model's vertex table.
/// With sharedBuild, each rank places its share of the edges (rankShare) and the ranks exchange them.
std::vector<IsoVertex> placeIsovertices(const Input& in, const SampledReference& reference,
                                        const std::vector<EdgeRef>& edges);

/// Pass 4, progress 0.5 to 1 (to 0.6 when fitsModelWide): model.cells and model.corners from `cells` (sorted
/// by key) and the isovertices placed on `edges`: each cell's loops, corners and, with PatchMethod::Paper,
/// its coefficients. With sharedBuild, each rank assembles its share of the cells (rankShare) and the ranks
/// exchange them. Returns the cells' loops when fitsModelWide (for fitCoefficients), else nothing. Throws
/// cip::Error when the corners exceed 2^32 - 1.
std::vector<CellLoops> assembleCells(const Input& in, const std::vector<CellRef>& cells,
                                     const std::vector<EdgeRef>& edges, Model& model);

/// Pass 5 (progress 0.6 to 1), when fitsModelWide: the side and central coefficients of every cell
/// (fitModelPatches) against the reference (the analytic field in exact mode, else the tricubic interpolant
/// of the cell's brick); records the reconstruction in the model and options.fittingStats.
void fitCoefficients(const Input& in, const std::vector<CellRef>& cells, const SampledReference& reference,
                     const std::vector<CellLoops>& loops, Model& model);

}  // namespace cip::build
