#include "streamed_input.h"

#include <algorithm>
#include <cmath>
#include <set>

#include "cip/core/collective.h"
#include "cip/core/error.h"
#include "cip/volume/sparse_volume.h"

namespace cip {

StreamMode parseStreamMode(const std::string& text) {
  if (text == "auto") return StreamMode::Auto;
  if (text == "on") return StreamMode::On;
  if (text == "off") return StreamMode::Off;
  throw Error("unknown --stream mode '" + text + "' (expected auto, on or off)");
}

std::optional<DenseDataLayout> streamedLayout(const std::string& path, const VolumeReadOptions& read,
                                              const BuildOptions& build, StreamMode mode, int ranks) {
  if (mode == StreamMode::Off) return std::nullopt;
  std::string why = whyNotStreamed(build);
  DenseVolumeProbe probe;
  if (why.empty()) {
    probe = probeDenseVolume(path, read);
    why = probe.whyNot;
  }
  if (!why.empty()) {
    if (mode == StreamMode::On) throw Error(path + ": --stream on: cannot build slab by slab: " + why);
    return std::nullopt;
  }
  const auto& d = probe.layout->geometry.dims;
  const double doubles =
      static_cast<double>(d[0]) * static_cast<double>(d[1]) * static_cast<double>(d[2]) * 8;
  if (mode == StreamMode::Auto && ranks <= 1 && doubles < static_cast<double>(kStreamAutoBytes))
    return std::nullopt;
  return probe.layout;
}

SliceSource StreamedVolume::source() {
  return [this](std::int64_t z0, std::int64_t z1, double* out) {
    reader_.readInto(z0, z1, out);
    // A build reads the volume in each of its passes: only the slices outside the run of slices already taken
    // into the range are scanned (seeing a sample again does not change the range).
    const auto perSlice = static_cast<std::size_t>(reader_.sliceSamples());
    auto scan = [&](std::int64_t from, std::int64_t to) {
      if (from >= to) return;
      addToRange(out + static_cast<std::size_t>(from - z0) * perSlice,
                 static_cast<std::size_t>(to - from) * perSlice);
    };
    if (z0 > rangedEnd_ || z1 < rangedBegin_ || rangedBegin_ == rangedEnd_) {  // not joined to that run
      scan(z0, z1);
      rangedBegin_ = z0;
      rangedEnd_ = z1;
      return;
    }
    scan(z0, std::min(z1, rangedBegin_));
    scan(std::max(z0, rangedEnd_), z1);
    rangedBegin_ = std::min(rangedBegin_, z0);
    rangedEnd_ = std::max(rangedEnd_, z1);
  };
}

void StreamedVolume::addToRange(const double* v, std::size_t n) {
  const auto [lo, hi] = finiteRange(v, n);
  if (!(lo <= hi)) return;  // no finite sample
  lo_ = any_ ? std::min(lo_, lo) : lo;
  hi_ = any_ ? std::max(hi_, hi) : hi;
  any_ = true;
}

std::pair<double, double> StreamedVolume::range(const Collective* ranks) const {
  if (!ranks || ranks->size() <= 1) return {lo_, hi_};
  std::vector<std::uint8_t> mine;
  const double d[3] = {any_ ? 1.0 : 0.0, lo_, hi_};
  appendBytes(mine, d, 3);
  bool any = false;
  double lo = 0, hi = 0;
  for (const std::vector<std::uint8_t>& theirs : ranks->allgather(mine)) {
    double t[3];
    ByteReader(theirs).read(t, 3);
    if (t[0] == 0) continue;
    lo = any ? std::min(lo, t[1]) : t[1];
    hi = any ? std::max(hi, t[2]) : t[2];
    any = true;
  }
  return {lo, hi};
}

std::vector<std::int64_t> StreamedVolume::labels(const Collective* ranks) {
  const auto& d = layout().geometry.dims;
  const std::int64_t slices =
      std::max<std::int64_t>(1, (std::int64_t(64) << 20) / std::max<std::int64_t>(1, 8 * d[0] * d[1]));
  const int size = ranks ? ranks->size() : 1;
  const auto [first, end] = rankShare(static_cast<std::size_t>(d[2]), ranks ? ranks->rank() : 0, size);
  std::set<std::int64_t> all;
  const SliceSource read = source();
  for (auto z0 = static_cast<std::int64_t>(first); z0 < static_cast<std::int64_t>(end); z0 += slices) {
    const std::int64_t z1 = std::min(static_cast<std::int64_t>(end), z0 + slices);
    DenseGrid slab;
    slab.allocate({d[0], d[1], z1 - z0}, static_cast<std::size_t>(-1));
    read(z0, z1, slab.values.data());
    for (const std::int64_t l : labelsOf(fromDense(std::move(slab)))) all.insert(l);
  }
  if (size > 1) {
    const std::vector<std::int64_t> mine(all.begin(), all.end());
    std::vector<std::uint8_t> bytes;
    appendVector(bytes, mine);
    for (const std::vector<std::uint8_t>& theirs : ranks->allgather(bytes)) {
      ByteReader in(theirs);
      for (const std::int64_t l : in.vector<std::int64_t>()) all.insert(l);
    }
  }
  return {all.begin(), all.end()};
}

}  // namespace cip
