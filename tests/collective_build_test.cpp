// A build split between ranks (BuildOptions::collective, docs/mpi.md) gives every rank the model one process
// builds, byte for byte once written. The ranks here are threads of one process exchanging through memory,
// so libcip's side of the split is tested without MPI; tests/mpi_extract_check.py runs extract under mpirun.
#include <gtest/gtest.h>

#include <condition_variable>
#include <functional>
#include <initializer_list>
#include <limits>
#include <mutex>
#include <string>
#include <thread>

#include "cip/core/collective.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
#include "cip/model/streamed_build.h"
#include "cip/reference/mask_reference.h"
#include "cip/volume/analytic_field.h"

namespace cip {
namespace {

/// Version 1 keeps every number in full precision: equal bytes are equal models, to the bit.
ModelFileOptions fullPrecision() {
  ModelFileOptions o;
  o.version = 1;
  return o;
}

/// `size` ranks as threads: allgather waits for every rank, then hands each the others' bytes.
class ThreadRanks {
 public:
  explicit ThreadRanks(int size) : size_(size), slots_(static_cast<std::size_t>(size)) {}

  class Rank : public Collective {
   public:
    Rank(ThreadRanks& all, int rank) : all_(all), rank_(rank) {}
    int rank() const override { return rank_; }
    int size() const override { return all_.size_; }
    std::vector<std::vector<std::uint8_t>> allgather(const std::vector<std::uint8_t>& mine) const override {
      {
        std::lock_guard<std::mutex> lock(all_.mutex_);
        all_.slots_[static_cast<std::size_t>(rank_)] = mine;
      }
      all_.wait();  // every slot filled
      std::vector<std::vector<std::uint8_t>> out;
      {
        std::lock_guard<std::mutex> lock(all_.mutex_);
        out = all_.slots_;
      }
      all_.wait();  // every rank copied them before any overwrites its slot again
      return out;
    }

   private:
    ThreadRanks& all_;
    int rank_;
  };

  /// A rank failed: the others' exchanges throw instead of waiting for it for ever (as MPI_Abort ends them).
  void fail() {
    std::lock_guard<std::mutex> lock(mutex_);
    failed_ = true;
    cv_.notify_all();
  }

 private:
  void wait() {
    std::unique_lock<std::mutex> lock(mutex_);
    const std::uint64_t generation = generation_;
    if (failed_) throw Error("another rank failed");
    if (++arrived_ == size_) {
      arrived_ = 0;
      ++generation_;
      cv_.notify_all();
    } else {
      cv_.wait(lock, [&] { return generation_ != generation || failed_; });
      if (generation_ == generation) throw Error("another rank failed");
    }
  }

  int size_;
  std::vector<std::vector<std::uint8_t>> slots_;
  std::mutex mutex_;
  std::condition_variable cv_;
  int arrived_ = 0;
  std::uint64_t generation_ = 0;
  bool failed_ = false;
};

/// The file bytes of `build(options)` run by `ranks` threads as ranks, one per rank.
std::vector<std::vector<std::uint8_t>> rankModels(const std::function<Model(const BuildOptions&)>& build,
                                                  BuildOptions options, int ranks,
                                                  std::vector<FittingStats>* stats = nullptr) {
  ThreadRanks all(ranks);
  std::vector<std::vector<std::uint8_t>> bytes(static_cast<std::size_t>(ranks));
  std::vector<FittingStats> fitting(static_cast<std::size_t>(ranks));
  std::vector<std::thread> threads;
  std::vector<std::string> errors(static_cast<std::size_t>(ranks));
  for (int r = 0; r < ranks; ++r)
    threads.emplace_back([&, r] {
      ThreadRanks::Rank rank(all, r);
      BuildOptions o = options;
      o.collective = &rank;
      o.threads = 1;
      o.fittingStats = &fitting[static_cast<std::size_t>(r)];
      try {
        bytes[static_cast<std::size_t>(r)] = serializeModel(build(o), fullPrecision());
      } catch (const std::exception& e) {
        errors[static_cast<std::size_t>(r)] = e.what();
        all.fail();
      }
    });
  for (auto& t : threads) t.join();
  for (int r = 0; r < ranks; ++r)
    EXPECT_EQ(errors[static_cast<std::size_t>(r)], "") << "rank " << r << " of " << ranks;
  if (stats) *stats = fitting;
  return bytes;
}

/// The same of a dense grid.
std::vector<std::vector<std::uint8_t>> rankModels(const DenseGrid& grid, BuildOptions options, int ranks,
                                                  std::vector<FittingStats>* stats = nullptr) {
  return rankModels([&](const BuildOptions& o) { return buildModel(grid, o); }, options, ranks, stats);
}

struct Case {
  const char* field;
  int n;
  PatchMethod method;
  bool exact = false;  ///< exact normals from the field
};

class CollectiveBuild : public ::testing::TestWithParam<Case> {};

TEST_P(CollectiveBuild, EveryRankHoldsTheSingleProcessModel) {
  const Case c = GetParam();
  const auto field = makeAnalyticField(c.field);
  const DenseGrid grid = sampleField(*field, c.n, c.field);
  BuildOptions options;
  options.isovalue = field->defaultIsovalue();
  options.method = c.method;
  if (c.exact) {
    options.normals = NormalMode::Exact;
    options.exactField = field.get();
  }
  FittingStats single;
  options.fittingStats = &single;
  const std::vector<std::uint8_t> one = serializeModel(buildModel(grid, options), fullPrecision());
  options.fittingStats = nullptr;
  if (c.exact) {
    EXPECT_GT(single.rounds, 1);  // the rounds after the split one run too
  }
  for (int ranks : {2, 3, 5}) {
    std::vector<FittingStats> stats;
    const auto models = rankModels(grid, options, ranks, &stats);
    for (int r = 0; r < ranks; ++r) {
      EXPECT_TRUE(models[static_cast<std::size_t>(r)] == one) << ranks << " ranks, rank " << r;
      if (c.method == PatchMethod::Fitted) {
        EXPECT_EQ(stats[static_cast<std::size_t>(r)].rounds, single.rounds);
        EXPECT_EQ(stats[static_cast<std::size_t>(r)].unresolvedCells, single.unresolvedCells);
      }
    }
  }
}

// Marschner-Lobb with exact normals leaves failed cells after the first round, so the later (unsplit) rounds
// run on the split round's results; the gyroid has many ambiguous faces.
INSTANTIATE_TEST_SUITE_P(Fields, CollectiveBuild,
                         ::testing::Values(Case{"sphere", 20, PatchMethod::Fitted},
                                           Case{"gyroid", 24, PatchMethod::Fitted},
                                           Case{"marschner-lobb", 32, PatchMethod::Fitted, true},
                                           Case{"gyroid", 24, PatchMethod::Paper}));

TEST(CollectiveBuild, MoreRanksThanCells) {
  const auto field = makeAnalyticField("sphere");
  const DenseGrid grid = sampleField(*field, 3, "sphere");
  BuildOptions options;
  options.isovalue = field->defaultIsovalue();
  const std::vector<std::uint8_t> one = serializeModel(buildModel(grid, options), fullPrecision());
  for (const auto& bytes : rankModels(grid, options, 40)) EXPECT_TRUE(bytes == one);
}

// A non-finite sample in one slab only (cells around it skipped): the slabs' ranks together list the cells
// and edges one process lists for a grid that is not finite everywhere.
TEST(CollectiveBuild, NonFiniteSampleInOneSlab) {
  const auto field = makeAnalyticField("sphere");
  DenseGrid grid = sampleField(*field, 20, "sphere");
  BuildOptions options;
  options.isovalue = field->defaultIsovalue();
  // On the positive side, where a NaN (never > the isovalue) differs in sign from its neighbours: edges that
  // a scan of the point rows alone would list.
  const std::array<std::int64_t, 3> at = grid.at(10, 10, 17) > options.isovalue
                                             ? std::array<std::int64_t, 3>{10, 10, 17}
                                             : std::array<std::int64_t, 3>{1, 1, 17};
  ASSERT_GT(grid.at(at[0], at[1], at[2]), options.isovalue);
  grid.at(at[0], at[1], at[2]) = std::numeric_limits<double>::quiet_NaN();
  options.skipNonFinite = true;
  const std::vector<std::uint8_t> one = serializeModel(buildModel(grid, options), fullPrecision());
  for (int ranks : {2, 3})
    for (const auto& bytes : rankModels(grid, options, ranks)) EXPECT_TRUE(bytes == one) << ranks << " ranks";
}

// Several bricks (as a sparse volume's): the ranks scan their share of the bricks.
TEST(CollectiveBuild, Bricks) {
  const auto field = makeAnalyticField("gyroid");
  const DenseGrid grid = sampleField(*field, 24, "gyroid");
  std::vector<GridBrick> bricks;
  const std::array<std::int64_t, 5> layers{0, 5, 11, 18, 24};  // each brick's cell layers of the whole grid
  for (std::size_t i = 0; i + 1 < layers.size(); ++i) {
    GridBrick b;
    b.grid = &grid;
    b.cellBegin = {0, 0, layers[i]};
    b.cellEnd = {24, 24, layers[i + 1]};
    bricks.push_back(b);
  }
  BuildOptions options;
  options.isovalue = field->defaultIsovalue();
  auto build = [&](const BuildOptions& o) { return buildModel(grid.geometry, bricks, o, "bricks"); };
  const std::vector<std::uint8_t> one = serializeModel(build(options), fullPrecision());
  for (int ranks : {2, 3, 6})
    for (const auto& bytes : rankModels(build, options, ranks))
      EXPECT_TRUE(bytes == one) << ranks << " ranks";
}

// Streamed builds split between ranks (docs/mpi.md): each rank reads only the slices of its share of the
// cell layers and their halo. Its slice source throws when asked for any other slice, so a rank that read
// more (the whole volume, say) fails the test.

/// The slices rank `rank` of `ranks` may read: its rankShare of the cell layers along z, widened by the
/// furthest any reference reaches (Auto's estimate 3, brickApron, maskReach) and, for a label map, by a
/// block of the label's field and its kernel.
std::pair<std::int64_t, std::int64_t> allowedSlices(const GridGeometry& g, const BuildOptions& options,
                                                    int rank, int ranks) {
  const auto [c0, c1] = rankShare(static_cast<std::size_t>(g.dims[2] - 1), rank, ranks);
  std::int64_t reach = std::max({3, brickApron(options), maskReach()});
  if (options.label) reach += kMaskBlock + maskKernelRadius();
  return {std::max<std::int64_t>(0, static_cast<std::int64_t>(c0) - reach),
          std::min<std::int64_t>(g.dims[2], static_cast<std::int64_t>(c1) + 1 + reach)};
}

/// Expects every rank of a streamed build split between `rankCounts` ranks, reading only its allowed slices,
/// to end with the single-process streamed model, byte for byte, which is also the whole-volume model; and
/// the stream statistics to say what each rank read.
void expectRankSlabs(const DenseGrid& grid, BuildOptions options, std::int64_t slabCells,
                     std::initializer_list<int> rankCounts = {2, 3, 4}) {
  const std::vector<std::uint8_t> whole = serializeModel(buildModel(grid, options), fullPrecision());
  const auto& g = grid.geometry;
  const std::int64_t slice = g.dims[0] * g.dims[1];
  StreamOptions stream;
  stream.slabCells = slabCells;
  auto streamed = [&](const BuildOptions& o, const std::pair<std::int64_t, std::int64_t>& allowed,
                      StreamStats* stats) {
    const SliceSource read = [&, allowed](std::int64_t z0, std::int64_t z1, double* out) {
      if (z0 < allowed.first || z1 > allowed.second)
        throw Error("slices [" + std::to_string(z0) + ", " + std::to_string(z1) + ") asked for, outside [" +
                    std::to_string(allowed.first) + ", " + std::to_string(allowed.second) + ")");
      std::copy(grid.values.begin() + z0 * slice, grid.values.begin() + z1 * slice, out);
    };
    return buildModelStreamed(g, read, o, grid.description, stream, stats);
  };
  StreamStats single;
  EXPECT_TRUE(serializeModel(streamed(options, {0, g.dims[2]}, &single), fullPrecision()) == whole);
  ASSERT_EQ(single.ranks.size(), 1u);
  EXPECT_EQ(single.ranks[0].cellEnd, g.dims[2] - 1);
  for (int ranks : rankCounts) {
    std::vector<StreamStats> stats(static_cast<std::size_t>(ranks));
    const auto models = rankModels(
        [&](const BuildOptions& o) {
          const int r = o.collective->rank();
          return streamed(o, allowedSlices(g, o, r, ranks), &stats[static_cast<std::size_t>(r)]);
        },
        options, ranks);
    std::int64_t layers = 0;
    for (int r = 0; r < ranks; ++r) {
      EXPECT_TRUE(models[static_cast<std::size_t>(r)] == whole) << ranks << " ranks, rank " << r;
      const auto& all = stats[static_cast<std::size_t>(r)].ranks;
      ASSERT_EQ(all.size(), static_cast<std::size_t>(ranks));
      const RankSlices& mine = all[static_cast<std::size_t>(r)];
      const auto [c0, c1] = rankShare(static_cast<std::size_t>(g.dims[2] - 1), r, ranks);
      EXPECT_EQ(mine.cellBegin, static_cast<std::int64_t>(c0));
      EXPECT_EQ(mine.cellEnd, static_cast<std::int64_t>(c1));
      const auto allowed = allowedSlices(g, options, r, ranks);
      EXPECT_GE(mine.firstSlice, allowed.first);
      EXPECT_LE(mine.endSlice, allowed.second);
      EXPECT_LT(mine.endSlice - mine.firstSlice, g.dims[2]) << "rank " << r << " read every slice";
      EXPECT_GE(mine.slicesRead, mine.endSlice - mine.firstSlice);
      layers += mine.cellEnd - mine.cellBegin;
    }
    EXPECT_EQ(layers, g.dims[2] - 1);
  }
}

DenseGrid fieldGrid(const char* name, int n) {
  return sampleField(*makeAnalyticField(name), n, name);
}

/// `copies` of the samples of `grid` stacked along z, each value v as `value(v, n)` (n: its index in the
/// copy): a volume tall enough for the ranks' slabs to hold fewer slices than it has, even with the mask's
/// halo and blocks.
DenseGrid stacked(const DenseGrid& grid, int copies,
                  const std::function<double(double, std::size_t)>& value) {
  DenseGrid out = grid;
  out.geometry.dims[2] *= copies;
  out.values.clear();
  for (int copy = 0; copy < copies; ++copy)
    for (std::size_t n = 0; n < grid.values.size(); ++n) out.values.push_back(value(grid.values[n], n));
  return out;
}

TEST(CollectiveStreamedBuild, EachRankReadsItsSlabs) {
  const auto gyroid = makeAnalyticField("gyroid");
  BuildOptions options;
  options.isovalue = gyroid->defaultIsovalue();
  const DenseGrid grid = fieldGrid("gyroid", 24);
  expectRankSlabs(grid, options, 0);  // Auto: the first pass's estimate over every rank's cells
  options.reconstruction = Reconstruction::Monotone;
  expectRankSlabs(grid, options, 3);  // several slabs per rank
  options.method = PatchMethod::Paper;
  expectRankSlabs(grid, options, 0);
}

// More ranks than cell layers: the ranks without layers read nothing and still end with the model.
TEST(CollectiveStreamedBuild, MoreRanksThanLayers) {
  const DenseGrid grid = fieldGrid("sphere", 3);
  BuildOptions options;
  options.isovalue = makeAnalyticField("sphere")->defaultIsovalue();
  const std::vector<std::uint8_t> whole = serializeModel(buildModel(grid, options), fullPrecision());
  const std::int64_t slice = grid.geometry.dims[0] * grid.geometry.dims[1];
  std::vector<StreamStats> stats(6);
  const auto models = rankModels(
      [&](const BuildOptions& o) {
        const SliceSource read = [&](std::int64_t z0, std::int64_t z1, double* out) {
          std::copy(grid.values.begin() + z0 * slice, grid.values.begin() + z1 * slice, out);
        };
        return buildModelStreamed(grid.geometry, read, o, grid.description, {},
                                  &stats[static_cast<std::size_t>(o.collective->rank())]);
      },
      options, 6);
  for (std::size_t r = 0; r < models.size(); ++r) {
    EXPECT_TRUE(models[r] == whole) << "rank " << r;
    const RankSlices& mine = stats[r].ranks.at(r);
    EXPECT_EQ(mine.slicesRead > 0, r < 3) << "rank " << r;  // 3 cell layers for 6 ranks
  }
}

// NaN samples on the planes that ranks' slabs share (z = 8 between 3 ranks' layers, 12 between 2 ranks'),
// their cells skipped: the edges there that both ranks list, or only the upper one, are each kept once.
TEST(CollectiveStreamedBuild, NonFiniteSamplesOnSharedPlanes) {
  DenseGrid grid = fieldGrid("gyroid", 24);
  BuildOptions options;
  options.isovalue = makeAnalyticField("gyroid")->defaultIsovalue();
  options.reconstruction = Reconstruction::Monotone;
  options.skipNonFinite = true;
  for (const std::array<std::int64_t, 3>& at :
       {std::array<std::int64_t, 3>{5, 5, 12}, {7, 3, 8}, {11, 20, 16}})
    grid.at(at[0], at[1], at[2]) = std::numeric_limits<double>::quiet_NaN();
  expectRankSlabs(grid, options, 0);
}

// Two values only: Auto detects the mask in the first pass (every rank's slabs must agree).
TEST(CollectiveStreamedBuild, DetectedMask) {
  const double iso = makeAnalyticField("sphere")->defaultIsovalue();
  const DenseGrid grid =
      stacked(fieldGrid("sphere", 14), 6, [&](double v, std::size_t) { return v > iso ? 1.0 : 0.0; });
  BuildOptions options;
  options.isovalue = 0.5;
  FittingStats fitting;
  options.fittingStats = &fitting;
  buildModel(grid, options);
  EXPECT_EQ(fitting.reconstruction, Reconstruction::Mask);
  options.fittingStats = nullptr;
  expectRankSlabs(grid, options, 4, {2, 3});
}

// A label map: the label's field is computed in blocks along z, which the ranks' slabs hold whole.
TEST(CollectiveStreamedBuild, LabelMap) {
  const double iso = makeAnalyticField("sphere")->defaultIsovalue();
  // Labels 1 and 2 interleaved inside the balls.
  // The label's field reaches maskReach() + kMaskBlock + maskKernelRadius() (51 here) beyond a slab's cells:
  // many small balls, 143 slices.
  const DenseGrid grid = stacked(fieldGrid("sphere", 10), 13, [&](double v, std::size_t n) {
    return v > iso ? (n % 3 == 0 && v > iso + 0.2 ? 2.0 : 1.0) : 0.0;
  });
  BuildOptions options;
  options.label = 1;
  expectRankSlabs(grid, options, 0, {3});
}

TEST(RankShare, CoversTheItemsInOrderWithinOne) {
  for (std::size_t count : {0, 1, 7, 100, 101}) {
    for (int size : {1, 2, 3, 8}) {
      std::size_t next = 0, lo = count, hi = 0;
      for (int r = 0; r < size; ++r) {
        const auto [first, end] = rankShare(count, r, size);
        EXPECT_EQ(first, next);
        EXPECT_LE(first, end);
        lo = std::min(lo, end - first);
        hi = std::max(hi, end - first);
        next = end;
      }
      EXPECT_EQ(next, count);
      EXPECT_LE(hi - lo, 1u);
    }
  }
}

}  // namespace
}  // namespace cip
