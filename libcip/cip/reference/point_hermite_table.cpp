#include "cip/reference/point_hermite_table.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cstring>
#include <utility>

#include "cip/core/error.h"
#include "cip/core/huge_pages.h"

namespace cip {

namespace {

/// Tiles of PointHermiteTable, in grid points per axis: long along x (lines of the passes), a few reaches
/// along y and z so that the box grown by the reach is not mostly margin.
constexpr std::array<std::int64_t, 3> kTile{32, 16, 16};

}  // namespace

PointHermiteTable::PointHermiteTable(const DenseGrid& grid, const std::vector<std::int64_t>& cells,
                                     Reconstruction kind, const Collective* ranks)
    : dims_(grid.geometry.dims) {
  const auto& dims = grid.geometry.dims;
  const std::int64_t dx = dims[0], dxy = dims[0] * dims[1];
  present_.assign(static_cast<std::size_t>((grid.geometry.pointCount() + 63) / 64), 0);
  // The corners of the cells, marked in parallel (bits of one word may come from several threads).
  auto mark = [&](std::int64_t index) {
    __atomic_fetch_or(&present_[static_cast<std::size_t>(index >> 6)], std::uint64_t(1) << (index & 63),
                      __ATOMIC_RELAXED);
  };
  tbb::parallel_for(std::size_t(0), cells.size(), [&](std::size_t n) {
    const std::int64_t c = cells[n];
    for (std::int64_t corner : {c, c + dx, c + dxy, c + dx + dxy}) {
      mark(corner);
      mark(corner + 1);
    }
  });
  before_.resize(present_.size());
  std::uint64_t total = 0;
  for (std::size_t w = 0; w < present_.size(); ++w) {
    before_[w] = static_cast<std::uint32_t>(total);
    total += static_cast<std::uint64_t>(__builtin_popcountll(present_[w]));
  }
  if (total > 0xFFFFFFFFu) throw Error("too many grid points for one reference table");
  resizeHuge(data_, static_cast<std::size_t>(total));

  // The points of one tile: their box-local positions over the tile's bounding box of points.
  std::array<std::int64_t, 3> tiles;
  for (int a = 0; a < 3; ++a) tiles[a] = (dims[a] + kTile[a] - 1) / kTile[a];
  // Split between ranks: rank r computes the r-th run of z-layers of tiles, whose points are a run of data_.
  const std::int64_t layer = tiles[0] * tiles[1];
  auto layers = [&](int r) {
    const auto share = rankShare(static_cast<std::size_t>(tiles[2]), r, ranks ? ranks->size() : 1);
    return std::make_pair(static_cast<std::int64_t>(share.first), static_cast<std::int64_t>(share.second));
  };
  const auto [z0, z1] = layers(ranks ? ranks->rank() : 0);
  tbb::parallel_for(z0 * layer, z1 * layer, [&](std::int64_t t) {
    const std::array<std::int64_t, 3> begin{(t % tiles[0]) * kTile[0], (t / tiles[0] % tiles[1]) * kTile[1],
                                            t / (tiles[0] * tiles[1]) * kTile[2]};
    std::array<std::int64_t, 3> end, lo = dims, hi{-1, -1, -1};
    for (int a = 0; a < 3; ++a) end[a] = std::min(begin[a] + kTile[a], dims[a]);
    thread_local std::vector<std::array<std::int64_t, 3>> points;
    points.clear();
    for (std::int64_t k = begin[2]; k < end[2]; ++k)
      for (std::int64_t j = begin[1]; j < end[1]; ++j) {
        const std::int64_t row = grid.index(0, j, k);
        for (std::int64_t i = begin[0]; i < end[0]; ++i) {
          const std::int64_t index = row + i;
          const std::uint64_t word = present_[static_cast<std::size_t>(index >> 6)];
          if (word == 0) {  // skip the rest of the word
            i += 63 - (index & 63);
            continue;
          }
          if (!((word >> (index & 63)) & 1)) continue;
          points.push_back({i, j, k});
          lo = {std::min(lo[0], i), std::min(lo[1], j), std::min(lo[2], k)};
          hi = {std::max(hi[0], i), std::max(hi[1], j), std::max(hi[2], k)};
        }
      }
    if (points.empty()) return;
    thread_local std::vector<std::array<int, 3>> local;
    thread_local std::vector<PointHermite> values;
    local.resize(points.size());
    values.resize(points.size());
    for (std::size_t n = 0; n < points.size(); ++n)
      for (int a = 0; a < 3; ++a) local[n][a] = static_cast<int>(points[n][a] - lo[a]);
    hermiteInBox(grid, kind, lo,
                 {static_cast<int>(hi[0] - lo[0] + 1), static_cast<int>(hi[1] - lo[1] + 1),
                  static_cast<int>(hi[2] - lo[2] + 1)},
                 local.data(), local.size(), values.data());
    for (std::size_t n = 0; n < points.size(); ++n)
      data_[rank(grid.index(points[n][0], points[n][1], points[n][2]))] = values[n];
  });
  if (!ranks || ranks->size() < 2) return;
  exchangeRanges(
      *ranks, sizeof(PointHermite),
      [&](int r) {
        const auto [k0, k1] = layers(r);
        auto below = [&](std::int64_t k) { return heldBelow(std::min(k * kTile[2], dims[2]) * dxy); };
        return std::make_pair(below(k0), below(k1));
      },
      [&](std::size_t n, std::vector<std::uint8_t>& out) {
        appendBytes(out, data_[n].data(), data_[n].size());
      },
      [&](std::size_t n, const std::uint8_t* p) { std::memcpy(data_[n].data(), p, sizeof(PointHermite)); });
}

std::size_t PointHermiteTable::heldBelow(std::int64_t index) const {
  const std::size_t w = static_cast<std::size_t>(index >> 6);
  if (w >= present_.size()) return data_.size();
  return rank(index);
}

void PointHermiteTable::compact() {
  if (compact_) return;
  std::vector<std::uint64_t> words, present;
  std::vector<std::uint32_t> before;
  for (std::size_t w = 0; w < present_.size(); ++w) {
    if (present_[w] == 0) continue;
    words.push_back(w);
    present.push_back(present_[w]);
    before.push_back(before_[w]);
  }
  words_ = std::move(words);
  present_ = std::move(present);
  before_ = std::move(before);
  compact_ = true;
}

void PointHermiteTable::appendTo(std::vector<std::uint8_t>& out) const {
  appendBytes(out, dims_.data(), dims_.size());
  const std::uint8_t compact = compact_;
  appendBytes(out, &compact, 1);
  appendVector(out, present_);
  appendVector(out, words_);
  appendVector(out, before_);
  appendVector(out, data_);
}

PointHermiteTable PointHermiteTable::readFrom(ByteReader& in) {
  PointHermiteTable t;
  in.read(t.dims_.data(), t.dims_.size());
  t.compact_ = in.value<std::uint8_t>() != 0;
  t.present_ = in.vector<std::uint64_t>();
  t.words_ = in.vector<std::uint64_t>();
  t.before_ = in.vector<std::uint32_t>();
  t.data_ = in.vector<PointHermite>();
  const std::size_t words = t.compact_ ? t.words_.size() : t.present_.size();
  if (t.present_.size() != words || t.before_.size() != words)
    throw Error("a reference table's bytes do not agree with themselves");
  return t;
}

std::ptrdiff_t PointHermiteTable::wordOf(std::int64_t index) const {
  if (index < 0) return -1;
  const auto w = static_cast<std::uint64_t>(index >> 6);
  if (!compact_) return w < present_.size() ? static_cast<std::ptrdiff_t>(w) : -1;
  const auto it = std::lower_bound(words_.begin(), words_.end(), w);
  return it != words_.end() && *it == w ? it - words_.begin() : -1;
}

bool PointHermiteTable::holds(std::int64_t index) const {
  const std::ptrdiff_t w = wordOf(index);
  return w >= 0 && (present_[static_cast<std::size_t>(w)] >> (index & 63)) & 1;
}

std::size_t PointHermiteTable::rank(std::int64_t index) const {
  const auto w = static_cast<std::size_t>(wordOf(index));
  const std::uint64_t below = (std::uint64_t(1) << (index & 63)) - 1;
  return before_[w] + static_cast<std::size_t>(__builtin_popcountll(present_[w] & below));
}

const PointHermite& PointHermiteTable::at(std::int64_t index) const {
  if (!holds(index)) throw Error("grid point not in the reference table");
  return data_[rank(index)];
}

void PointHermiteTable::setReference(const std::array<std::int64_t, 3>& cell, double isovalue,
                                     CellReference& ref) const {
  ref.field = nullptr;
  ref.geometry = nullptr;
  ref.origin = Vec3::Zero();
  ref.isovalue = isovalue;
  ref.metric = Vec3::Ones();
  const std::int64_t dx = dims_[0], dxy = dx * dims_[1];
  const std::int64_t base = cell[0] + dx * cell[1] + dxy * cell[2];
  const std::int64_t rows[4] = {base, base + dx, base + dxy, base + dx + dxy};
  bool held = true;
  for (std::int64_t row : rows) held = held && holds(row) && holds(row + 1);
  if (!held) throw Error("cell not in the reference table");
  std::array<const PointHermite*, 8> corners;
  for (int r = 0; r < 4; ++r) {
    const std::size_t n = rank(rows[r]);  // x + 1 is the next point held
    corners[static_cast<std::size_t>(2 * r)] = &data_[n];
    corners[static_cast<std::size_t>(2 * r + 1)] = &data_[n + 1];
  }
  cellHermite(corners, ref.hermite);
}

}  // namespace cip
