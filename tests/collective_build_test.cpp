// A build split between ranks (BuildOptions::collective, docs/mpi.md) gives every rank the model one process
// builds, byte for byte once written. The ranks here are threads of one process exchanging through memory,
// so libcip's side of the split is tested without MPI; tests/mpi_extract_check.py runs extract under mpirun.
#include <gtest/gtest.h>

#include <condition_variable>
#include <functional>
#include <limits>
#include <mutex>
#include <thread>

#include "cip/core/collective.h"
#include "cip/model/model_builder.h"
#include "cip/model/model_file.h"
#include "cip/model/patch_fitting.h"
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
      all_.slots_[static_cast<std::size_t>(rank_)] = mine;
      all_.wait();  // every slot filled
      std::vector<std::vector<std::uint8_t>> out = all_.slots_;
      all_.wait();  // every rank copied them before any overwrites its slot again
      return out;
    }

   private:
    ThreadRanks& all_;
    int rank_;
  };

 private:
  void wait() {
    std::unique_lock<std::mutex> lock(mutex_);
    const std::uint64_t generation = generation_;
    if (++arrived_ == size_) {
      arrived_ = 0;
      ++generation_;
      cv_.notify_all();
    } else {
      cv_.wait(lock, [&] { return generation_ != generation; });
    }
  }

  int size_;
  std::vector<std::vector<std::uint8_t>> slots_;
  std::mutex mutex_;
  std::condition_variable cv_;
  int arrived_ = 0;
  std::uint64_t generation_ = 0;
};

/// The file bytes of `build(options)` run by `ranks` threads as ranks, one per rank.
std::vector<std::vector<std::uint8_t>> rankModels(const std::function<Model(const BuildOptions&)>& build,
                                                  BuildOptions options, int ranks,
                                                  std::vector<FittingStats>* stats = nullptr) {
  ThreadRanks all(ranks);
  std::vector<std::vector<std::uint8_t>> bytes(static_cast<std::size_t>(ranks));
  std::vector<FittingStats> fitting(static_cast<std::size_t>(ranks));
  std::vector<std::thread> threads;
  for (int r = 0; r < ranks; ++r)
    threads.emplace_back([&, r] {
      ThreadRanks::Rank rank(all, r);
      BuildOptions o = options;
      o.collective = &rank;
      o.threads = 1;
      o.fittingStats = &fitting[static_cast<std::size_t>(r)];
      bytes[static_cast<std::size_t>(r)] = serializeModel(build(o), fullPrecision());
    });
  for (auto& t : threads) t.join();
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
