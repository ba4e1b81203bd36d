#include "cip/core/collective.h"

#include <string>

#include "cip/core/error.h"

namespace cip {

std::pair<std::size_t, std::size_t> rankShare(std::size_t count, int rank, int size) {
  const auto n = static_cast<std::size_t>(size > 0 ? size : 1);
  const auto r = static_cast<std::size_t>(rank);
  const std::size_t base = count / n, extra = count % n;
  const std::size_t first = r * base + (r < extra ? r : extra);
  return {first, first + base + (r < extra ? 1 : 0)};
}

void ByteReader::need(std::uint64_t n, std::size_t bytes) const {
  const auto left = static_cast<std::uint64_t>(end_ - p_);
  if (bytes > 0 && n > left / bytes) throw Error("a rank's bytes end before the values they announce");
}

bool allRanks(const Collective& collective, bool mine) {
  const std::vector<std::vector<std::uint8_t>> all =
      collective.allgather(std::vector<std::uint8_t>{static_cast<std::uint8_t>(mine)});
  for (const auto& r : all)
    if (r.size() != 1 || !r[0]) return false;
  return true;
}

void exchangeRanges(const Collective& collective, std::size_t recordBytes,
                    const std::function<std::pair<std::size_t, std::size_t>(int)>& range,
                    const std::function<void(std::size_t, std::vector<std::uint8_t>&)>& pack,
                    const std::function<void(std::size_t, const std::uint8_t*)>& unpack) {
  const int rank = collective.rank();
  const auto [first, end] = range(rank);
  std::vector<std::uint8_t> mine;
  mine.reserve((end - first) * recordBytes);
  for (std::size_t i = first; i < end; ++i) pack(i, mine);
  if (mine.size() != (end - first) * recordBytes) throw Error("exchangeRanges: a record of another size");
  const std::vector<std::vector<std::uint8_t>> all = collective.allgather(mine);
  for (int r = 0; r < collective.size(); ++r) {
    if (r == rank) continue;
    const auto [from, to] = range(r);
    const std::vector<std::uint8_t>& theirs = all[static_cast<std::size_t>(r)];
    if (theirs.size() != (to - from) * recordBytes)
      throw Error("rank " + std::to_string(r) + " sent " + std::to_string(theirs.size()) + " bytes for " +
                  std::to_string(to - from) + " records of " + std::to_string(recordBytes));
    for (std::size_t i = from; i < to; ++i) unpack(i, theirs.data() + (i - from) * recordBytes);
  }
}

}  // namespace cip
