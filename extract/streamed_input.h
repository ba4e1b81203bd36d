// extract's streamed input: a dense volume file built slab by slab (model/streamed_build.h) instead of read
// whole, when --stream asks for it or the volume is large, and what the run needs of it without holding it:
// its range (for the isovalue warning) and its labels (--labels).
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "cip/model/streamed_build.h"
#include "cip/readers/slab_reader.h"

namespace cip {

/// --stream: always (on), never (off), or when the volume's samples as doubles take at least
/// kStreamAutoBytes (auto).
enum class StreamMode : std::uint8_t { Auto, On, Off };
StreamMode parseStreamMode(const std::string& text);

/// The size from which --stream auto streams: the samples of the whole volume as doubles.
constexpr std::uint64_t kStreamAutoBytes = std::uint64_t(1) << 30;

/// The layout of `path` when the run streams it: the file can be read in slabs (probeDenseVolume), the build
/// can be streamed (whyNotStreamed) and `mode` says so (for On, a file or build that cannot be streamed is an
/// error saying why; Auto streams a large volume, and any volume the run splits between `ranks` > 1, so that
/// each rank reads only its slabs: docs/mpi.md). Otherwise nothing: the volume is read whole.
std::optional<DenseDataLayout> streamedLayout(const std::string& path, const VolumeReadOptions& read,
                                              const BuildOptions& build, StreamMode mode, int ranks = 1);

/// A dense volume file read slab by slab: the slice source of buildModelStreamed, which also records the
/// range of the finite samples read.
class StreamedVolume {
 public:
  explicit StreamedVolume(DenseDataLayout layout) : reader_(std::move(layout)) {}
  const DenseDataLayout& layout() const { return reader_.layout(); }
  SliceSource source();
  /// Smallest and largest finite sample read so far (every sample once a build has run); with `ranks`, of
  /// the samples every rank read (every rank calls it).
  std::pair<double, double> range(const Collective* ranks = nullptr) const;
  /// labelsOf of the whole volume, reading it slab by slab; with `ranks`, each rank reads its rankShare of
  /// the slices and the ranks exchange their labels (every rank calls it).
  std::vector<std::int64_t> labels(const Collective* ranks = nullptr);

 private:
  /// Takes the finite ones of `n` samples into the range.
  void addToRange(const double* v, std::size_t n);

  SlabReader reader_;
  double lo_ = 0, hi_ = 0;
  bool any_ = false;
  std::int64_t rangedBegin_ = 0, rangedEnd_ = 0;  ///< the run of slices whose samples range() has seen
};

}  // namespace cip
