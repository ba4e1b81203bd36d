#include "cip/model/streamed_build.h"

#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <chrono>
#include <cstring>
#include <limits>
#include <numeric>
#include <optional>

#include "cip/core/error.h"
#include "cip/model/build_passes.h"
#include "cip/model/patch_fitting.h"
#include "cip/model/slab_exchange.h"
#include "cip/reference/mask_reference.h"
#include "cip/reference/point_hermite.h"

namespace cip {

namespace {

using Clock = std::chrono::steady_clock;

double secondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

/// The slabs of a volume: slab s owns the cell layers [starts[s], starts[s + 1]) along z and holds the points
/// `halo` beyond them on either side, where the volume has them. A label map's field is computed in blocks
/// whose result depends on the classes within the kernel's radius (smoothLabel): its slabs hold, around their
/// points and `halo`, the whole blocks of kMaskBlock slices (placed as in the volume) and the kernel's radius
/// beyond them. Split between ranks, rank r owns slabs [rankFirst[r], rankFirst[r + 1]): its rankShare of the
/// cell layers, cut into slabs of at most `cells` layers.
struct SlabPlan {
  std::array<std::int64_t, 3> dims{};
  std::int64_t cells = 1;  ///< most cell layers a slab owns
  std::vector<std::int64_t> starts;
  std::vector<std::int64_t> rankFirst;
  int rank = 0;
  int halo = 0;
  int blockRadius = -1;  ///< label maps: the kernel's radius; -1: no blocks to hold whole

  std::int64_t count() const { return static_cast<std::int64_t>(starts.size()) - 1; }
  /// This rank's slabs [first, second).
  std::pair<std::int64_t, std::int64_t> mine() const {
    return {rankFirst[static_cast<std::size_t>(rank)], rankFirst[static_cast<std::size_t>(rank) + 1]};
  }
  /// The points [lo, hi] along z slab s holds.
  std::pair<std::int64_t, std::int64_t> points(std::int64_t s) const {
    const std::int64_t c0 = starts[static_cast<std::size_t>(s)], c1 = starts[static_cast<std::size_t>(s) + 1];
    std::int64_t lo = c0 - halo, hi = c1 + halo;
    if (blockRadius >= 0) {
      lo = std::max<std::int64_t>(lo, 0) / kMaskBlock * kMaskBlock - blockRadius;
      hi = std::min(hi, dims[2] - 1) / kMaskBlock * kMaskBlock + kMaskBlock - 1 + blockRadius;
    }
    return {std::max<std::int64_t>(0, lo), std::min(dims[2] - 1, hi)};
  }
  /// Slab s as a brick of the volume (its grid not set).
  GridBrick brick(std::int64_t s) const {
    const std::int64_t c0 = starts[static_cast<std::size_t>(s)], c1 = starts[static_cast<std::size_t>(s) + 1];
    const std::int64_t lo = points(s).first;
    GridBrick b;
    b.offset = {0, 0, lo};
    b.cellBegin = {0, 0, c0 - lo};
    b.cellEnd = {dims[0] - 1, dims[1] - 1, c1 - lo};
    return b;
  }
};

/// Points the first pass's slabs hold beyond their cells: the 3 along each axis that Auto's estimate reads
/// (SamplingEstimator::addCell); the two-valued detection needs 1.
constexpr int kEstimateHalo = 3;

/// Points the building pass's slabs hold beyond their cells: what the reference resolved to reaches (the
/// mask's field: maskReach).
int buildHalo(const BuildOptions& options, bool mask, Reconstruction kind) {
  if (mask) return maskReach();
  BuildOptions resolved = options;
  resolved.reconstruction = kind;
  return brickApron(resolved);
}

SlabPlan planSlabs(const GridGeometry& geometry, int halo, int blockRadius, const StreamOptions& stream,
                   const Collective* ranks) {
  SlabPlan plan;
  plan.dims = geometry.dims;
  plan.halo = halo;
  plan.blockRadius = blockRadius;
  const std::int64_t cellsZ = geometry.dims[2] - 1;
  const auto sliceBytes = static_cast<std::size_t>(geometry.dims[0] * geometry.dims[1]) * sizeof(double);
  std::int64_t cells = stream.slabCells;
  if (cells <= 0) {
    const auto slices = static_cast<std::int64_t>(stream.slabBytes / std::max<std::size_t>(1, sliceBytes));
    const std::int64_t around = 2 * halo + (blockRadius >= 0 ? 2 * (kMaskBlock + blockRadius) : 0);
    // At least half as many cells as slices around them: a slab moves the slices it shares with the one
    // before and recomputes the reference (or the mask's field) on its halo, so slabs much thinner than
    // their halo repeat that work many times per cell (wide slices: a 2048² slice of doubles is 32 MiB,
    // and the 64 MiB budget would leave one cell per slab under a halo of 49 slices). The window may then
    // exceed the budget.
    cells = std::max<std::int64_t>({1, slices - 1 - around, (around + 1) / 2});
  }
  plan.cells = std::min(cells, std::max<std::int64_t>(1, cellsZ));
  const int size = ranks ? ranks->size() : 1;
  plan.rank = ranks ? ranks->rank() : 0;
  for (int r = 0; r < size; ++r) {
    plan.rankFirst.push_back(static_cast<std::int64_t>(plan.starts.size()));
    const auto [first, end] = rankShare(static_cast<std::size_t>(std::max<std::int64_t>(0, cellsZ)), r, size);
    for (auto c = static_cast<std::int64_t>(first); c < static_cast<std::int64_t>(end); c += plan.cells)
      plan.starts.push_back(c);
  }
  plan.rankFirst.push_back(static_cast<std::int64_t>(plan.starts.size()));
  plan.starts.push_back(std::max<std::int64_t>(0, cellsZ));
  return plan;
}

/// The samples of the current slab, read through the source; the slices a slab shares with the one before
/// are kept rather than read again (compressed files are decompressed once per pass).
class SlabWindow {
 public:
  SlabWindow(const GridGeometry& geometry, const SliceSource& read, StreamStats& stats)
      : read_(read), stats_(stats) {
    grid_.geometry = geometry;
    slice_ = geometry.dims[0] * geometry.dims[1];
  }
  /// The samples of points [lo, hi] along z, as a grid of dims (nx, ny, hi - lo + 1).
  const DenseGrid& load(std::int64_t lo, std::int64_t hi) {
    const auto start = Clock::now();
    std::int64_t have = 0;  // slices kept from the previous slab
    if (lo_ >= 0 && lo >= lo_ && lo <= hi_ && hi >= hi_) {
      have = hi_ - lo + 1;
      std::memmove(grid_.values.data(), grid_.values.data() + (lo - lo_) * slice_,
                   static_cast<std::size_t>(have * slice_) * sizeof(double));
    }
    const auto size = static_cast<std::size_t>((hi - lo + 1) * slice_);
    if (size > grid_.values.capacity()) grid_.values.reserve(size);  // exactly: resize alone may double it
    grid_.values.resize(size);
    if (lo + have <= hi) {
      read_(lo + have, hi + 1, grid_.values.data() + have * slice_);
      if (reading_.slicesRead == 0) reading_.firstSlice = lo + have;
      reading_.firstSlice = std::min(reading_.firstSlice, lo + have);
      reading_.endSlice = std::max(reading_.endSlice, hi + 1);
      reading_.slicesRead += hi + 1 - lo - have;
    }
    grid_.geometry.dims[2] = hi - lo + 1;
    lo_ = lo;
    hi_ = hi;
    stats_.readSeconds += secondsSince(start);
    return grid_;
  }
  std::size_t bytes() const { return grid_.values.capacity() * sizeof(double); }
  /// The slices read so far.
  RankSlices& reading() { return reading_; }
  void restart() { lo_ = hi_ = -1; }

 private:
  const SliceSource& read_;
  StreamStats& stats_;
  DenseGrid grid_;
  RankSlices reading_;
  std::int64_t slice_ = 0, lo_ = -1, hi_ = -1;
};

/// What the first pass decides from all slabs: whether the build follows the mask's field, and Auto's
/// estimate (over the crossed cells of the samples, in the whole-volume build's scan order).
struct GlobalChoice {
  bool mask = false;
  double raise = 0;  ///< build::integerRaise
  std::optional<SamplingEstimate> sampling;
};

GlobalChoice choose(const GridGeometry& geometry, const BuildOptions& options, const SlabPlan& plan,
                    SlabWindow& window, build::Progress& progress) {
  GlobalChoice choice;
  const build::MaskRule rule = build::maskRule(options);
  choice.mask = rule == build::MaskRule::Mask;
  if (rule != build::MaskRule::Detect) return choice;
  // Cells with non-finite corners are left out of the estimate: the build that follows stops at them anyway
  // unless they are to be skipped.
  BuildOptions scanOptions = options;
  scanOptions.skipNonFinite = true;
  const Collective* ranks = build::sharedBuild(options);
  build::TwoValuedVerdict verdict;
  build::FirstPassRecord record;  // split between ranks: what this rank's slabs measured
  SamplingEstimator estimator(ranks ? &record.terms : nullptr);
  std::vector<GridBrick> bricks(static_cast<std::size_t>(plan.count()));
  const auto [first, end] = plan.mine();
  for (std::int64_t s = first; s < end; ++s) {
    const auto [lo, hi] = plan.points(s);
    const DenseGrid& samples = window.load(lo, hi);
    bricks[static_cast<std::size_t>(s)] = plan.brick(s);
    bricks[static_cast<std::size_t>(s)].grid = &samples;
    const TwoValuedSamples twoValued = detectTwoValued(
        samples, options.isovalue, build::countedEdgesOf(bricks[static_cast<std::size_t>(s)]));
    if (ranks) record.twoValued.push_back(twoValued);
    verdict.add(twoValued);
    const build::Input in{geometry, bricks, scanOptions, build::GridKeys{geometry.dims}, progress, 0.0};
    build::addToEstimate(in, build::scanBrickCells(in, static_cast<std::uint32_t>(s)).cells, estimator);
    bricks[static_cast<std::size_t>(s)].grid = nullptr;
  }
  if (ranks) {  // every rank's measurements, in slab order, as one process takes them
    record.cells = estimator.cells();
    verdict = build::TwoValuedVerdict();
    estimator = SamplingEstimator();
    build::gatherFirstPass(*ranks, record, verdict, estimator);
  }
  choice.mask = verdict.mask();
  choice.raise = build::integerRaise(verdict, options.isovalue);
  choice.sampling = estimator.estimate();
  return choice;
}

/// The slab's scan, reference and isovertices into `out`. An edge on the plane two slabs share is placed
/// from the lower slab, as uniqueEdges keeps the lower brick's.
void harvestSlab(const build::Input& in, std::uint32_t s, const SlabPlan& plan, build::SlabHarvest& out,
                 BuildTimings& timings) {
  auto mark = Clock::now();
  build::CellScan scan = build::scanBrickCells(in, s);
  timings.scan += secondsSince(mark);
  mark = Clock::now();
  if (out.reference.sampled)
    out.reference.tables[s] = build::brickReference(in, scan.cells, out.reference.kind);
  timings.reference += secondsSince(mark);
  mark = Clock::now();
  const GridBrick& b = in.bricks[s];
  const build::Key topPlane =
      in.keys.point(0, 0, b.offset[2] + b.cellEnd[2]) * 3;  // first edge key of the slab's last plane
  std::vector<build::Key> top;
  std::vector<build::EdgeRef> fresh;
  fresh.reserve(scan.edges.size());
  for (const build::EdgeRef& e : scan.edges) {
    if (e.key >= topPlane && s + 1 < plan.count()) top.push_back(e.key);
    if (!std::binary_search(out.sharedPlane.begin(), out.sharedPlane.end(), e.key)) fresh.push_back(e);
  }
  const std::vector<IsoVertex> vertices = build::placeIsovertices(in, out.reference, fresh);
  if (out.reference.sampled) out.reference.tables[s].compact();
  out.sharedPlane = std::move(top);
  out.edges.insert(out.edges.end(), fresh.begin(), fresh.end());
  out.vertices.insert(out.vertices.end(), vertices.begin(), vertices.end());
  out.cells.insert(out.cells.end(), scan.cells.begin(), scan.cells.end());
  timings.isovertices += secondsSince(mark);
}

/// The building pass: this rank's slabs (all of them in one process) harvested into `harvest`, whose
/// reference is set; split between ranks, then every rank's harvest joined in slab order. `in` reads
/// `bricks`, the plan's slabs; `mask`: the slabs' samples are replaced by maskField(samples, `options`).
void harvestSlabs(const build::Input& in, std::vector<GridBrick>& bricks, const SlabPlan& plan,
                  SlabWindow& window, bool mask, const BuildOptions& options, build::SlabHarvest& harvest,
                  StreamStats& stats, BuildTimings& timings) {
  // The slabs are this rank's alone: nothing in them is split between ranks.
  BuildOptions own = in.options;
  own.collective = nullptr;
  const build::Input local{in.geometry, bricks, own, in.keys, in.progress, in.raise};
  DenseGrid field;
  const auto [first, end] = plan.mine();
  for (std::int64_t s = first; s < end; ++s) {
    const auto [lo, hi] = plan.points(s);
    const DenseGrid* samples = &window.load(lo, hi);
    if (mask) {
      const auto mark = Clock::now();
      field = build::maskField(*samples, options, lo);
      samples = &field;
      timings.reference += secondsSince(mark);
    }
    stats.windowBytes =
        std::max(stats.windowBytes, window.bytes() + field.values.capacity() * sizeof(double));
    bricks[static_cast<std::size_t>(s)].grid = samples;
    harvestSlab(local, static_cast<std::uint32_t>(s), plan, harvest, timings);
    bricks[static_cast<std::size_t>(s)].grid = nullptr;  // the passes below read no samples
  }
  RankSlices reading = window.reading();
  reading.cellBegin = plan.starts[static_cast<std::size_t>(first)];
  reading.cellEnd = plan.starts[static_cast<std::size_t>(end)];
  reading.slabs = end - first;
  stats.ranks = {reading};
  if (const Collective* ranks = build::sharedBuild(in.options)) {
    const auto mark = Clock::now();
    stats.ranks = build::gatherHarvests(*ranks, harvest, plan.rankFirst, reading);
    timings.isovertices += secondsSince(mark);
  }
}

Model streamSlabs(const GridGeometry& geometry, const SliceSource& read, const BuildOptions& options,
                  const std::string& source, const StreamOptions& stream, StreamStats& stats) {
  build::Progress progress(options.progress);
  SlabWindow window(geometry, read, stats);
  const Collective* ranks = build::sharedBuild(options);
  const auto start = Clock::now();
  const GlobalChoice choice =
      choose(geometry, options, planSlabs(geometry, kEstimateHalo, -1, stream, ranks), window, progress);
  stats.passes = choice.sampling ? 2 : 1;
  BuildOptions o = choice.mask ? build::maskFieldOptions(options) : options;
  o.isovalue += choice.raise;
  BuildTimings timings;
  timings.reference = secondsSince(start);
  build::SlabHarvest harvest;
  harvest.reference.sampled = o.method == PatchMethod::Fitted && o.normals != NormalMode::Exact;
  harvest.reference.kind = o.reconstruction;
  if (harvest.reference.sampled && o.reconstruction == Reconstruction::Auto) {
    harvest.reference.sampling = *choice.sampling;
    harvest.reference.kind = chooseReconstruction(*choice.sampling);
  }
  const SlabPlan plan = planSlabs(geometry, buildHalo(o, choice.mask, harvest.reference.kind),
                                  options.label ? maskKernelRadius() : -1, stream, ranks);
  stats.slabs = plan.count();
  stats.slabCells = plan.cells;
  stats.halo = plan.halo;
  harvest.reference.tables.resize(static_cast<std::size_t>(plan.count()));
  std::vector<GridBrick> bricks(static_cast<std::size_t>(plan.count()));
  for (std::int64_t s = 0; s < plan.count(); ++s) bricks[static_cast<std::size_t>(s)] = plan.brick(s);
  const build::Input in{geometry, bricks, o, build::GridKeys{geometry.dims}, progress, choice.raise};
  window.restart();
  harvestSlabs(in, bricks, plan, window, choice.mask, options, harvest, stats, timings);
  auto mark = Clock::now();
  if (harvest.edges.size() > std::numeric_limits<std::uint32_t>::max())
    throw Error("too many isovertices for one model");
  build::sortEdges(harvest);
  if (!std::is_sorted(harvest.cells.begin(), harvest.cells.end()))  // slabs in z order give key order
    std::stable_sort(harvest.cells.begin(), harvest.cells.end());
  timings.isovertices += secondsSince(mark);
  progress.set(0.5);
  Model model = build::emptyModel(geometry, o, source);
  model.vertices = std::move(harvest.vertices);
  harvest.sharedPlane.clear();
  mark = Clock::now();
  const std::vector<CellLoops> loops = build::assembleCells(in, harvest.cells, harvest.edges, model);
  harvest.edges = std::vector<build::EdgeRef>();  // the fitting needs the cells, not the edges
  timings.assemble = secondsSince(mark);
  mark = Clock::now();
  if (build::fitsModelWide(o)) build::fitCoefficients(in, harvest.cells, harvest.reference, loops, model);
  timings.fit = secondsSince(mark);
  if (options.fittingStats) options.fittingStats->isovalueRaise = choice.raise;
  if (choice.mask) {
    model.reconstruction = Reconstruction::Mask;
    if (options.fittingStats) options.fittingStats->reconstruction = Reconstruction::Mask;
  }
  if (options.timings) *options.timings = timings;
  progress.set(1.0);
  return model;
}

}  // namespace

std::string whyNotStreamed(const BuildOptions& options) {
  if (options.normals == NormalMode::Exact || options.exactField)
    return "exact normals take an analytic field, not samples";
  if (options.method == PatchMethod::Paper && options.central == CentralRule::Interior &&
      options.fitCoefficients)
    return "the paper's interior central rule reads the samples of each cell after the scan";
  return {};
}

Model buildModelStreamed(const GridGeometry& geometry, const SliceSource& read, const BuildOptions& options,
                         const std::string& source, const StreamOptions& stream, StreamStats* stats) {
  if (const std::string why = whyNotStreamed(options); !why.empty())
    throw Error("cannot build slab by slab: " + why);
  StreamStats local;
  StreamStats& st = stats ? *stats : local;
  st = StreamStats();
  tbb::task_arena arena(options.threads > 0 ? options.threads : tbb::task_arena::automatic);
  return arena.execute([&] {
    if (geometry.dims[0] < 2 || geometry.dims[1] < 2 || geometry.dims[2] < 2) {
      // No cells: the whole (flat) volume is one slab.
      DenseGrid grid;
      grid.geometry = geometry;
      grid.values.resize(static_cast<std::size_t>(geometry.pointCount()));
      if (!grid.values.empty()) read(0, geometry.dims[2], grid.values.data());
      grid.description = source;
      st.passes = 1;
      st.windowBytes = grid.values.size() * sizeof(double);
      return buildModel(grid, options);
    }
    return streamSlabs(geometry, read, options, source, stream, st);
  });
}

}  // namespace cip
