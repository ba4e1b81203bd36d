#include "cip/model/model_file_v2.h"

#include <tbb/parallel_for.h>
#include <zstd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <optional>

#include "cip/core/checksum.h"
#include "cip/core/error.h"
#include "cip/core/huge_pages.h"
#include "cip/model/model_file_header.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

constexpr std::uint32_t kVersion = 2;
constexpr std::size_t kDirectoryEntryBytes = 6 * 4 + 8 + 4;

/// The streams of a chunk, in file order (docs/model-format.md, "Chunk").
enum Stream : int {
  kRows,         ///< per point row of the sign region: (transitions << 1 | first sign) varint, then positions
  kExceptions,   ///< cells whose signs say crossed but which the model leaves out: count, index deltas
  kPairings,     ///< one byte (0/1) per ambiguous owned face
  kPositionsLo,  ///< crossing parameter codes, low bytes
  kPositionsHi,  ///< high bytes (only when positionBits > 8)
  kNormals,      ///< zigzag varints: normal residual (u, v) per owned vertex
  kSides,        ///< zigzag varints: side coefficient codes per owned face (when stored)
  kCentrals,     ///< zigzag varints: central coefficient codes per cell (when stored)
  kWeights,      ///< raw f64 corner coefficients per owned vertex (when stored)
  kZeroMasks,    ///< one byte per vertex on a grid point: which of its normal's cross components are zero
  kExact,        ///< vertices kept in full precision: count; per vertex index delta, f64 t, 3 f64 normal
  kNumStreams
};

enum Flags : std::uint8_t { kSidesStored = 1, kCentralsStored = 2, kWeightsStored = 4 };

// ---- small byte helpers -------------------------------------------------------------------------------

void putVarint(std::vector<std::uint8_t>& out, std::uint64_t v) {
  while (v >= 0x80) {
    out.push_back(static_cast<std::uint8_t>(v | 0x80));
    v >>= 7;
  }
  out.push_back(static_cast<std::uint8_t>(v));
}
std::uint64_t zigzag(std::int64_t v) {
  return (static_cast<std::uint64_t>(v) << 1) ^ static_cast<std::uint64_t>(v >> 63);
}
std::int64_t unzigzag(std::uint64_t v) {
  return static_cast<std::int64_t>(v >> 1) ^ -static_cast<std::int64_t>(v & 1);
}
template <class T>
void putRaw(std::vector<std::uint8_t>& out, T v) {
  const auto* p = reinterpret_cast<const std::uint8_t*>(&v);
  out.insert(out.end(), p, p + sizeof(T));
}

/// Reads one decompressed stream; every read is bounds-checked and a failure names the chunk and stream.
class StreamReader {
 public:
  StreamReader() = default;
  StreamReader(const std::vector<std::uint8_t>* bytes, std::string where)
      : b_(bytes), where_(std::move(where)) {}
  std::uint64_t varint() {
    std::uint64_t v = 0;
    for (int shift = 0; shift < 64; shift += 7) {
      if (pos_ >= b_->size()) fail("ends early");
      const std::uint8_t byte = (*b_)[pos_++];
      v |= static_cast<std::uint64_t>(byte & 0x7F) << shift;
      if (!(byte & 0x80)) return v;
    }
    fail("has an over-long number");
  }
  /// A signed number; none beyond 2^62 in magnitude is valid anywhere (and negating one must be safe).
  std::int64_t svarint() {
    const std::uint64_t v = varint();
    if (v >> 63) fail("has a number out of range");
    return unzigzag(v);
  }
  std::uint8_t byte() {
    if (pos_ >= b_->size()) fail("ends early");
    return (*b_)[pos_++];
  }
  double f64() {
    if (b_->size() - pos_ < 8) fail("ends early");
    double v;
    std::memcpy(&v, b_->data() + pos_, 8);
    pos_ += 8;
    return v;
  }
  void expectEnd() const {
    if (b_ && pos_ != b_->size()) fail("has " + std::to_string(b_->size() - pos_) + " bytes too many");
  }
  [[noreturn]] void fail(const std::string& why) const { throw Error(where_ + " " + why); }

 private:
  const std::vector<std::uint8_t>* b_ = nullptr;
  std::size_t pos_ = 0;
  std::string where_;
};

std::uint32_t crc(const std::uint8_t* data, std::size_t size) {
  return crc32Of(data, size);
}

// ---- quantisers (shared by writer and reader: the reader's values are the writer's, bit for bit) ---------

/// A float-like code: linear steps of `step` up to 2^m steps, then m bits of relative precision.
std::int64_t coefficientCode(double w, double step, int m) {
  const double v = w / step;
  const double a = std::abs(v);
  const std::int64_t lim = std::int64_t(1) << m;
  std::int64_t code;
  if (a < static_cast<double>(lim)) {
    code = std::llround(a);
  } else {
    int ex;
    const double fr = std::frexp(a, &ex);  // a = fr 2^ex, fr in [0.5, 1)
    std::int64_t r = std::llround(std::ldexp(fr, m + 1));
    if (r == 2 * lim) {
      r = lim;
      ++ex;
    }
    const std::int64_t block = ex - 1 - m;  // >= 0
    code = lim + block * lim + (r - lim);
  }
  return v < 0 ? -code : code;
}
double coefficientValue(std::int64_t code, double step, int m) {
  const std::int64_t lim = std::int64_t(1) << m;
  const std::int64_t c = code < 0 ? -code : code;
  double a;
  if (c < lim) {
    a = static_cast<double>(c);
  } else {
    const std::int64_t block = (c - lim) / lim, rem = (c - lim) % lim;
    a = std::ldexp(static_cast<double>(lim + rem), static_cast<int>(std::min<std::int64_t>(block, 4000)));
  }
  return (code < 0 ? -a : a) * step;
}

void octEncode(const Vec3& n, double& u, double& v) {
  const double s = std::abs(n.x()) + std::abs(n.y()) + std::abs(n.z());
  u = n.x() / s;
  v = n.y() / s;
  if (n.z() < 0) {
    const double uu = (1 - std::abs(v)) * (u >= 0 ? 1 : -1), vv = (1 - std::abs(u)) * (v >= 0 ? 1 : -1);
    u = uu;
    v = vv;
  }
}
Vec3 octDecode(double u, double v) {
  Vec3 n(u, v, 1 - std::abs(u) - std::abs(v));
  if (n.z() < 0) {
    const double x = (1 - std::abs(v)) * (u >= 0 ? 1 : -1), y = (1 - std::abs(u)) * (v >= 0 ? 1 : -1);
    n.x() = x;
    n.y() = y;
  }
  return n.normalized();
}
/// An orthonormal frame whose third axis is `p` (unit).
void frameOf(const Vec3& p, Vec3& b1, Vec3& b2) {
  b1 = (std::abs(p.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY()).cross(p).normalized();
  b2 = p.cross(b1);
}

// ---- brick geometry ------------------------------------------------------------------------------------

using I3 = std::array<std::int64_t, 3>;

struct Layout {
  I3 dims{};
  std::int64_t B = 64;
  I3 nb{};  ///< bricks per axis
  std::int64_t key(const I3& b) const { return b[0] + nb[0] * (b[1] + nb[1] * b[2]); }
  /// The brick that owns grid point p (the last brick also owns the grid's last point layer).
  I3 pointBrick(const I3& p) const {
    I3 b;
    for (int a = 0; a < 3; ++a) b[a] = std::min(p[a] / B, nb[a] - 1);
    return b;
  }
};

/// The points a chunk stores signs for: its brick's points, one more layer below and two above, inside the
/// grid.
struct Region {
  I3 lo{}, n{};
  std::int64_t rowIndex(std::int64_t y, std::int64_t z) const { return (y - lo[1]) + n[1] * (z - lo[2]); }
  std::int64_t index(const I3& p) const { return (p[0] - lo[0]) + n[0] * rowIndex(p[1], p[2]); }
  bool contains(const I3& p) const {
    for (int a = 0; a < 3; ++a)
      if (p[a] < lo[a] || p[a] >= lo[a] + n[a]) return false;
    return true;
  }
};

/// What a chunk holds, decoded: the topology every later step (and the writer's own prediction) needs.
struct ChunkTopology {
  I3 brick{};
  I3 origin{};      ///< first cell and first owned point
  I3 cellCount{};   ///< cells of the brick per axis
  I3 ownedCount{};  ///< owned points per axis (the last brick also owns the last point layer)
  Region region;
  std::vector<std::uint8_t> sign;        ///< per region point: 1 above the isovalue
  std::vector<std::uint8_t> rowUniform;  ///< per region row: 1 if all its points share a sign
  std::vector<std::uint32_t> cells;      ///< present cells: lx + B (ly + B lz), increasing
  std::vector<std::uint8_t> config;
  std::vector<std::uint32_t> vertexKey;  ///< owned crossed edges: (lx + (B+1)(ly + (B+1) lz)) 3 + axis
  std::vector<std::uint16_t> tCode;
  std::vector<std::uint8_t> vertexFlags;  ///< bit 0, 1: normal component along the first, second other axis
                                          ///< is zero (grid-point vertices); 5: edge start above; 6: on a
                                          ///< grid point
  std::vector<std::uint32_t> faceKey;     ///< owned crossed faces: point key 3 + normal axis
  std::vector<std::uint32_t> vertexRow,
      faceRow;                            ///< per owned point row: its first entry of vertexKey, faceKey
  std::vector<std::uint8_t> facePairing;  ///< 1: pairs around canonical vertices 0 and 3 (ambiguous faces)
  std::uint64_t vertexBase = 0, faceBase = 0;
  std::vector<std::vector<std::uint8_t>> streams;  ///< the reader keeps the decompressed streams
  std::vector<std::uint32_t> exact;                ///< owned vertices kept in full precision, increasing
  std::vector<double> exactT;
  std::vector<Vec3> exactNormal;
};

std::uint32_t pointKey(const ChunkTopology& ch, std::int64_t B, const I3& p) {
  return static_cast<std::uint32_t>((p[0] - ch.origin[0]) +
                                    (B + 1) * ((p[1] - ch.origin[1]) + (B + 1) * (p[2] - ch.origin[2])));
}

void setupChunk(const Layout& L, const I3& brick, ChunkTopology& ch) {
  ch.brick = brick;
  for (int a = 0; a < 3; ++a) {
    ch.origin[a] = brick[a] * L.B;
    ch.cellCount[a] = std::min(L.B, L.dims[a] - 1 - ch.origin[a]);
    ch.ownedCount[a] = brick[a] == L.nb[a] - 1 ? L.dims[a] - ch.origin[a] : L.B;
    ch.region.lo[a] = std::max<std::int64_t>(0, ch.origin[a] - 1);
    ch.region.n[a] = std::min(L.dims[a] - 1, ch.origin[a] + L.B + 1) - ch.region.lo[a] + 1;
  }
}

/// 1 if grid point p (inside the chunk's region) is above the isovalue.
std::uint8_t signAt(const ChunkTopology& ch, const I3& p) {
  return ch.sign[static_cast<std::size_t>(ch.region.index(p))];
}

/// The corners of the face at grid point p across `axis`: p, p + b, p + c, p + b + c (b, c: the other axes).
std::array<I3, 4> faceCorners(const I3& p, int axis) {
  const auto o = cube::otherAxes(axis);
  std::array<I3, 4> q{p, p, p, p};
  ++q[1][o[0]];
  ++q[2][o[1]];
  ++q[3][o[0]];
  ++q[3][o[1]];
  return q;
}

std::uint8_t cellConfig(const ChunkTopology& ch, const I3& c) {
  std::uint8_t config = 0;
  for (int v = 0; v < 8; ++v) {
    const auto o = cube::vertexCoords(v);
    const I3 p{c[0] + o[0], c[1] + o[1], c[2] + o[2]};
    config = static_cast<std::uint8_t>(config | (signAt(ch, p) << v));
  }
  return config;
}

/// Whether the point rows (y..y+1, z..z+1) that exist are all uniform with one sign: nothing crosses there.
bool quietRows(const ChunkTopology& ch, std::int64_t y, std::int64_t z) {
  const Region& r = ch.region;
  int s = -1;
  for (int dz = 0; dz < 2; ++dz)
    for (int dy = 0; dy < 2; ++dy) {
      const std::int64_t yy = y + dy, zz = z + dz;
      if (yy >= r.lo[1] + r.n[1] || zz >= r.lo[2] + r.n[2]) continue;
      const std::int64_t row = r.rowIndex(yy, zz);
      if (!ch.rowUniform[static_cast<std::size_t>(row)]) return false;
      const int rs = ch.sign[static_cast<std::size_t>(row * r.n[0])];
      if (s >= 0 && rs != s) return false;
      s = rs;
    }
  return true;
}

/// Present cells from signs and exceptions (reader), or the check that they agree (writer).
void cellsFromSigns(const Layout& L, ChunkTopology& ch, std::vector<std::uint32_t>& nontrivial) {
  nontrivial.clear();
  for (std::int64_t lz = 0; lz < ch.cellCount[2]; ++lz)
    for (std::int64_t ly = 0; ly < ch.cellCount[1]; ++ly) {
      const std::int64_t y = ch.origin[1] + ly, z = ch.origin[2] + lz;
      if (quietRows(ch, y, z)) continue;
      for (std::int64_t lx = 0; lx < ch.cellCount[0]; ++lx) {
        const std::uint8_t c = cellConfig(ch, {ch.origin[0] + lx, y, z});
        if (c != 0 && c != 0xFF) nontrivial.push_back(static_cast<std::uint32_t>(lx + L.B * (ly + L.B * lz)));
      }
    }
}

/// The owned crossed edges and faces in file order, with the sign-derived flags of each vertex.
void ownedItems(const Layout& L, ChunkTopology& ch) {
  ch.vertexKey.clear();
  ch.vertexFlags.clear();
  ch.faceKey.clear();
  auto s = [&](const I3& p) { return signAt(ch, p); };
  auto inGrid = [&](const I3& p) {
    return p[0] < L.dims[0] && p[1] < L.dims[1] && p[2] < L.dims[2] && p[0] >= 0 && p[1] >= 0 && p[2] >= 0;
  };
  for (std::int64_t lz = 0; lz < ch.ownedCount[2]; ++lz)
    for (std::int64_t ly = 0; ly < ch.ownedCount[1]; ++ly) {
      const std::int64_t y = ch.origin[1] + ly, z = ch.origin[2] + lz;
      if (quietRows(ch, y, z)) continue;
      // The four point rows (y..y+1, z..z+1) this row's edges and faces reach; a missing one (beyond the
      // grid) stands in as this row, and the checks below leave out what would use it.
      const Region& r = ch.region;
      const std::uint8_t* row[4];
      for (int d = 0; d < 4; ++d) {
        const std::int64_t yy = y + (d & 1), zz = z + (d >> 1);
        const bool in = yy < r.lo[1] + r.n[1] && zz < r.lo[2] + r.n[2];
        row[d] = &ch.sign[static_cast<std::size_t>(r.rowIndex(in ? yy : y, in ? zz : z) * r.n[0])];
      }
      const std::int64_t xEnd = r.lo[0] + r.n[0] - 1;  // last point of the row
      for (std::int64_t lx = 0; lx < ch.ownedCount[0]; ++lx) {
        const std::int64_t x = ch.origin[0] + lx, i = x - r.lo[0], i1 = std::min(x + 1, xEnd) - r.lo[0];
        const std::uint8_t v = row[0][i];
        if (row[0][i1] == v && row[1][i] == v && row[1][i1] == v && row[2][i] == v && row[2][i1] == v &&
            row[3][i] == v && row[3][i1] == v)
          continue;  // nothing crosses from this point
        const I3 p{x, y, z};
        const std::uint32_t key = static_cast<std::uint32_t>(lx + (L.B + 1) * (ly + (L.B + 1) * lz));
        const int sp = s(p);
        for (int a = 0; a < 3; ++a) {
          I3 q = p;
          ++q[a];
          if (!inGrid(q) || s(q) == sp) continue;
          std::uint8_t flags = static_cast<std::uint8_t>(sp << 5);
          ch.vertexKey.push_back(key * 3 + static_cast<std::uint32_t>(a));
          ch.vertexFlags.push_back(flags);
        }
        for (int a = 0; a < 3; ++a) {
          const std::array<I3, 4> q = faceCorners(p, a);
          if (!inGrid(q[3])) continue;
          if (s(q[1]) == sp && s(q[2]) == sp && s(q[3]) == sp) continue;
          ch.faceKey.push_back(key * 3 + static_cast<std::uint32_t>(a));
        }
      }
    }
  // Where each point row's entries start, for lookups by point.
  const auto rows = static_cast<std::size_t>((L.B + 1) * (L.B + 1));
  auto index = [&](const std::vector<std::uint32_t>& keys, std::vector<std::uint32_t>& start) {
    start.assign(rows + 1, 0);
    for (std::uint32_t k : keys) ++start[k / 3 / static_cast<std::uint32_t>(L.B + 1) + 1];
    for (std::size_t r = 0; r < rows; ++r) start[r + 1] += start[r];
  };
  index(ch.vertexKey, ch.vertexRow);
  index(ch.faceKey, ch.faceRow);
}

/// Whether the face at grid point p across `axis` has its four crossings (diagonal points share a sign).
bool ambiguousFace(const ChunkTopology& ch, const I3& p, int axis) {
  const std::array<I3, 4> q = faceCorners(p, axis);
  const int s0 = signAt(ch, q[0]), s1 = signAt(ch, q[1]);
  return s0 == signAt(ch, q[3]) && s1 == signAt(ch, q[2]) && s0 != s1;
}

I3 keyPoint(const ChunkTopology& ch, std::int64_t B, std::uint32_t pointKeyValue) {
  const std::int64_t k = pointKeyValue;
  return {ch.origin[0] + k % (B + 1), ch.origin[1] + (k / (B + 1)) % (B + 1),
          ch.origin[2] + k / ((B + 1) * (B + 1))};
}

std::uint16_t maxTCode(int bits) {
  return static_cast<std::uint16_t>((1u << bits) - 1);
}

/// Marks the vertices whose code puts them on a grid point (flag 64): their normals keep the components the
/// file says are exactly zero (the builder removes the ones that would tilt the corner plane across an
/// uncrossed grid edge: normalClearOfUncrossedEdges).
void gridPointVertexFlags(ChunkTopology& ch, int positionBits) {
  for (std::size_t v = 0; v < ch.vertexKey.size(); ++v)
    if (ch.tCode[v] == 0 || ch.tCode[v] == maxTCode(positionBits))
      ch.vertexFlags[v] = static_cast<std::uint8_t>(ch.vertexFlags[v] | 64);
}

// ---- chunk lookup and assembly (shared) ---------------------------------------------------------------

struct Chunks {
  Layout L;
  std::vector<ChunkTopology> list;  ///< in increasing brick key order
  std::vector<std::int64_t> keys;
  const ChunkTopology* find(const I3& brick) const {
    const std::int64_t k = L.key(brick);
    auto it = std::lower_bound(keys.begin(), keys.end(), k);
    if (it == keys.end() || *it != k) return nullptr;
    return &list[static_cast<std::size_t>(it - keys.begin())];
  }
  /// The chunk that owns grid point p; `hint` (the asking cell's chunk) is tried first.
  const ChunkTopology* owner(const I3& p, const ChunkTopology* hint) const {
    const I3 b = L.pointBrick(p);
    return hint && hint->brick == b ? hint : find(b);
  }
  /// Global index of the vertex on the edge from grid point p along `axis`, or -1.
  std::int64_t vertexOf(const I3& p, int axis, const ChunkTopology* hint) const {
    const ChunkTopology* ch = owner(p, hint);
    if (!ch) return -1;
    const std::int64_t i = rowSearch(ch->vertexKey, ch->vertexRow, pointKey(*ch, L.B, p), axis);
    return i < 0 ? -1 : static_cast<std::int64_t>(ch->vertexBase) + i;
  }
  std::int64_t faceOf(const I3& p, int axis, std::uint8_t* pairing, const ChunkTopology* hint) const {
    const ChunkTopology* ch = owner(p, hint);
    if (!ch) return -1;
    const std::int64_t i = rowSearch(ch->faceKey, ch->faceRow, pointKey(*ch, L.B, p), axis);
    if (i < 0) return -1;
    if (pairing) *pairing = ch->facePairing[static_cast<std::size_t>(i)];
    return static_cast<std::int64_t>(ch->faceBase) + i;
  }

 private:
  /// Position of key (point, axis) in `keys`, looked for among its point row's entries only.
  std::int64_t rowSearch(const std::vector<std::uint32_t>& entries,
                         const std::vector<std::uint32_t>& rowStart, std::uint32_t point, int axis) const {
    const std::uint32_t key = point * 3 + static_cast<std::uint32_t>(axis);
    const std::size_t row = point / static_cast<std::uint32_t>(L.B + 1);
    if (row + 1 >= rowStart.size()) return -1;
    for (std::uint32_t i = rowStart[row]; i < rowStart[row + 1]; ++i)
      if (entries[i] == key) return i;
    return -1;
  }
};

/// Where each model cell came from.
struct CellOrigin {
  std::uint32_t chunk, local;
};

/// The model's cells (global order), corners, vertex positions and, per cell face, the global face index.
struct Skeleton {
  std::vector<CellOrigin> origin;
  std::vector<std::array<std::int64_t, 6>> face;
  std::vector<std::uint8_t> vertexAxis;
};

Skeleton assemble(const Chunks& chunks, int positionBits, Model& m, const std::string& name) {
  const Layout& L = chunks.L;
  Skeleton sk;
  std::vector<std::pair<std::uint64_t, CellOrigin>> order;
  std::size_t total = 0;
  for (const ChunkTopology& ch : chunks.list) total += ch.cells.size();
  order.reserve(total);
  const std::uint64_t dx = static_cast<std::uint64_t>(L.dims[0]), dy = static_cast<std::uint64_t>(L.dims[1]);
  for (std::uint32_t c = 0; c < chunks.list.size(); ++c) {
    const ChunkTopology& ch = chunks.list[c];
    for (std::uint32_t i = 0; i < ch.cells.size(); ++i) {
      const std::uint64_t lx = ch.cells[i] % L.B, ly = (ch.cells[i] / L.B) % L.B,
                          lz = ch.cells[i] / (L.B * L.B);
      const std::uint64_t key = (ch.origin[0] + lx) + dx * ((ch.origin[1] + ly) + dy * (ch.origin[2] + lz));
      order.push_back({key, {c, i}});
    }
  }
  std::sort(order.begin(), order.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  resizeHuge(m.cells, total);
  sk.origin.resize(total);
  sk.face.resize(total);
  std::vector<std::uint32_t> cornerCount(total);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, total), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const CellOrigin o = order[i].second;
      sk.origin[i] = o;
      const ChunkTopology& ch = chunks.list[o.chunk];
      const std::uint32_t local = ch.cells[o.local];
      ModelCell& cell = m.cells[i];
      const I3 idx{ch.origin[0] + local % L.B, ch.origin[1] + (local / L.B) % L.B,
                   ch.origin[2] + local / (L.B * L.B)};
      for (int a = 0; a < 3; ++a)
        cell.index[static_cast<std::size_t>(a)] = static_cast<std::uint32_t>(idx[a]);
      cell.config = ch.config[o.local];
      cell.pairing03 = 0;
      const std::uint8_t faces = cube::crossedFaces(cell.config);
      for (int f = 0; f < 6; ++f) {
        sk.face[i][static_cast<std::size_t>(f)] = -1;
        if (!((faces >> f) & 1)) continue;
        I3 p = idx;
        p[f / 2] += f & 1;
        std::uint8_t pairing = 0;
        const std::int64_t fi = chunks.faceOf(p, f / 2, &pairing, &ch);
        if (fi < 0)
          throw Error(name + ": damaged model file: a crossed face of cell " + std::to_string(i) +
                      " is missing");
        sk.face[i][static_cast<std::size_t>(f)] = fi;
        if (cube::isAmbiguousFace(cell.config, f) && pairing)
          cell.pairing03 = static_cast<std::uint8_t>(cell.pairing03 | (1u << f));
      }
      const CellLoops loops = buildCellLoops(cell.config, cell.pairing03);
      cell.numLoops = static_cast<std::uint8_t>(loops.numLoops);
      cell.loopSize = loops.loopSize;
      cornerCount[i] = static_cast<std::uint32_t>(loops.numCorners());
    }
  });
  std::uint64_t corners = 0;
  for (std::size_t i = 0; i < total; ++i) {
    m.cells[i].firstCorner = static_cast<std::uint32_t>(corners);
    corners += cornerCount[i];
  }
  if (corners > std::numeric_limits<std::uint32_t>::max()) throw Error(name + ": too many corners");
  resizeHuge(m.corners, corners);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, total), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t i = r.begin(); i < r.end(); ++i) {
      const ModelCell& cell = m.cells[i];
      const ChunkTopology* hint = &chunks.list[sk.origin[i].chunk];
      const CellLoops loops = buildCellLoops(cell.config, cell.pairing03);
      for (int k = 0; k < loops.numCorners(); ++k) {
        const int e = loops.edges[static_cast<std::size_t>(k)];
        const auto s = cube::vertexCoords(cube::edgeVertex(e, 0));
        const I3 p{cell.index[0] + static_cast<std::int64_t>(s[0]),
                   cell.index[1] + static_cast<std::int64_t>(s[1]),
                   cell.index[2] + static_cast<std::int64_t>(s[2])};
        const std::int64_t v = chunks.vertexOf(p, cube::edgeAxis(e), hint);
        if (v < 0)
          throw Error(name + ": damaged model file: a crossed edge of cell " + std::to_string(i) +
                      " has no vertex");
        m.corners[cell.firstCorner + static_cast<std::uint32_t>(k)] = static_cast<std::uint32_t>(v);
      }
    }
  });
  // Vertex positions from the crossing parameters.
  std::uint64_t vertices = 0;
  for (const ChunkTopology& ch : chunks.list) vertices += ch.vertexKey.size();
  resizeHuge(m.vertices, vertices);
  sk.vertexAxis.resize(vertices);
  const double scale = 1.0 / maxTCode(positionBits);
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t c) {
    const ChunkTopology& ch = chunks.list[c];
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
      const int axis = static_cast<int>(ch.vertexKey[v] % 3);
      const I3 p = keyPoint(ch, L.B, ch.vertexKey[v] / 3);
      IsoVertex& vx = m.vertices[ch.vertexBase + v];
      vx.position = Vec3(static_cast<double>(p[0]), static_cast<double>(p[1]), static_cast<double>(p[2]));
      vx.position[axis] += ch.tCode[v] * scale;
      vx.weight = 1.0;
      sk.vertexAxis[ch.vertexBase + v] = static_cast<std::uint8_t>(axis);
    }
  });
  return sk;
}

/// The predicted normal of every vertex: the normal of the marching-cubes polygons around it (the sum of
/// cross products of its loop neighbours, cells in grid order), pointing to the positive side.
std::vector<Vec3> predictNormals(const Model& m, const Skeleton& sk,
                                 const std::vector<std::uint8_t>& startAbove) {
  const std::size_t V = m.vertices.size();
  std::vector<Vec3> pred(V, Vec3::Zero());
  // Corners per vertex in cell order (a counting sort of the corner table keeps it).
  std::vector<std::uint32_t> start(V + 1, 0);
  for (std::uint32_t v : m.corners) ++start[v + 1];
  for (std::size_t v = 0; v < V; ++v) start[v + 1] += start[v];
  std::vector<Vec3> contribution(m.corners.size());
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, m.cells.size()), [&](const tbb::blocked_range<std::size_t>& r) {
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
          const ModelCell& cell = m.cells[i];
          const CellLoops loops = buildCellLoops(cell.config, cell.pairing03);
          std::array<int, 12> prev{};
          for (int k = 0; k < loops.numCorners(); ++k)
            prev[static_cast<std::size_t>(loops.nextCorner(k))] = k;
          for (int k = 0; k < loops.numCorners(); ++k) {
            const Vec3& p = m.vertices[m.corners[cell.firstCorner + static_cast<std::uint32_t>(k)]].position;
            const Vec3& a =
                m.vertices[m.corners[cell.firstCorner + static_cast<std::uint32_t>(loops.nextCorner(k))]]
                    .position;
            const Vec3& b = m.vertices[m.corners[cell.firstCorner + static_cast<std::uint32_t>(
                                                                        prev[static_cast<std::size_t>(k)])]]
                                .position;
            contribution[cell.firstCorner + static_cast<std::uint32_t>(k)] = (a - p).cross(b - p);
          }
        }
      });
  std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
  std::vector<std::uint32_t> byVertex(m.corners.size());
  for (std::uint32_t c = 0; c < m.corners.size(); ++c) byVertex[fill[m.corners[c]]++] = c;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, V), [&](const tbb::blocked_range<std::size_t>& r) {
    for (std::size_t v = r.begin(); v < r.end(); ++v) {
      Vec3 sum = Vec3::Zero();
      for (std::uint32_t j = start[v]; j < start[v + 1]; ++j) sum += contribution[byVertex[j]];
      Vec3 towards = Vec3::Zero();
      towards[sk.vertexAxis[v]] = startAbove[v] ? -1.0 : 1.0;
      const double len = sum.norm();
      Vec3 n = (len > 0 && std::isfinite(len)) ? Vec3(sum / len) : towards;
      if (n.dot(towards) < 0) n = -n;
      pred[v] = n;
    }
  });
  return pred;
}

/// The stored normal of a vertex from its prediction and residual code.
Vec3 normalFromCode(const Vec3& pred, std::int64_t qu, std::int64_t qv, double step, int axis,
                    std::uint8_t flags) {
  Vec3 b1, b2;
  frameOf(pred, b1, b2);
  const Vec3 local = octDecode(static_cast<double>(qu) * step, static_cast<double>(qv) * step);
  Vec3 n = (b1 * local.x() + b2 * local.y() + pred * local.z()).normalized();
  Vec3 towards = Vec3::Zero();
  towards[axis] = (flags & 32) ? -1.0 : 1.0;
  if (flags & 64) {  // on a grid point: the components that are exactly zero stay so
    const auto o = cube::otherAxes(axis);
    for (int oi = 0; oi < 2; ++oi)
      if ((flags >> oi) & 1) n[o[oi]] = 0;
  }
  return orientCornerNormal(n, towards);
}

/// The residual code of normal n against its prediction. Where the reader's corrections (normalFromCode: the
/// grid-point rule, the minimal angle to the edge) may have moved a stored normal off its code's direction,
/// the codes around are searched for one that decodes to n exactly, so that writing a model read from a file
/// gives the same file.
void normalCode(const Vec3& pred, const Vec3& n, double step, int axis, std::uint8_t flags, std::int64_t& qu,
                std::int64_t& qv) {
  Vec3 b1, b2;
  frameOf(pred, b1, b2);
  double u, v;
  octEncode(Vec3(n.dot(b1), n.dot(b2), n.dot(pred)), u, v);
  qu = std::llround(u / step);
  qv = std::llround(v / step);
  const double towards = (flags & 32) ? -n[axis] : n[axis];
  if (!(flags & 64) && towards > 0.0501) return;
  if (normalFromCode(pred, qu, qv, step, axis, flags) == n) return;
  for (std::int64_t du = -2; du <= 2; ++du)
    for (std::int64_t dv = -2; dv <= 2; ++dv)
      if (normalFromCode(pred, qu + du, qv + dv, step, axis, flags) == n) {
        qu += du;
        qv += dv;
        return;
      }
}

std::vector<std::uint8_t> startAboveFlags(const Chunks& chunks, std::size_t V) {
  std::vector<std::uint8_t> out(V);
  for (const ChunkTopology& ch : chunks.list)
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v)
      out[ch.vertexBase + v] = (ch.vertexFlags[v] >> 5) & 1;
  return out;
}

using NormalCodes = std::vector<std::array<std::int64_t, 2>>;

/// Sets every vertex normal from its prediction and residual code (both in file order).
void applyNormalCodes(Model& m, const Chunks& chunks, const Skeleton& sk, const std::vector<Vec3>& pred,
                      const NormalCodes& codes, double step) {
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const ChunkTopology& ch = chunks.list[i];
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
      const std::size_t g = ch.vertexBase + v;
      m.vertices[g].normal =
          normalFromCode(pred[g], codes[g][0], codes[g][1], step, sk.vertexAxis[g], ch.vertexFlags[v]);
    }
  });
}

/// Vertices kept in full precision: their crossing parameters (before normals are predicted) ...
void applyExactPositions(Model& m, const Chunks& chunks, const Skeleton& sk) {
  for (const ChunkTopology& ch : chunks.list)
    for (std::size_t k = 0; k < ch.exact.size(); ++k) {
      const std::size_t g = ch.vertexBase + ch.exact[k];
      const int axis = sk.vertexAxis[g];
      const I3 p = keyPoint(ch, chunks.L.B, ch.vertexKey[ch.exact[k]] / 3);
      m.vertices[g].position[axis] = static_cast<double>(p[axis]) + ch.exactT[k];
    }
}
/// ... and their normals (after the others are decoded).
void applyExactNormals(Model& m, const Chunks& chunks) {
  for (const ChunkTopology& ch : chunks.list)
    for (std::size_t k = 0; k < ch.exact.size(); ++k)
      m.vertices[ch.vertexBase + ch.exact[k]].normal = ch.exactNormal[k];
}

/// The paper's side coefficient of every face (global face order) from the model's corners as stored: what
/// the file codes the paper method's side coefficients against (a well-conditioned face then costs a zero).
/// Each face is computed once, by the cell it bounds from below if that cell is in the model, else by the
/// other (both would compute the same value: patch_coefficients.h).
std::vector<double> paperSidePrediction(const Model& m, const Skeleton& sk, std::size_t faces) {
  std::vector<double> pred(faces, 0.0);
  std::vector<std::uint8_t> done(faces, 0);
  for (int pass = 0; pass < 2; ++pass)
    tbb::parallel_for(
        tbb::blocked_range<std::size_t>(0, m.cells.size()), [&](const tbb::blocked_range<std::size_t>& r) {
          for (std::size_t c = r.begin(); c < r.end(); ++c) {
            const ModelCell& cell = m.cells[c];
            const CellLoops loops = buildCellLoops(cell.config, cell.pairing03);
            std::optional<CornerPatch> patch;
            for (int f = pass; f < 6; f += 2) {
              if (!((loops.faceMask >> f) & 1)) continue;
              const auto fi = static_cast<std::size_t>(sk.face[c][static_cast<std::size_t>(f)]);
              if (pass == 1 && done[fi]) continue;
              if (!patch) patch = m.patch(c, loops);
              pred[fi] = fitFaceCoefficient(faceCrossingsOf(*patch, f, (cell.pairing03 >> f) & 1));
              if (pass == 0) done[fi] = 1;
            }
          }
        });
  return pred;
}
}  // namespace

// =========================================================================================================
// Writer
// =========================================================================================================

namespace {

/// The model's cells around one chunk (indices from the region's first point - 1 to its last), by grid index:
/// the writer's lookups, filled while the chunk's signs are.
struct CellFinder {
  I3 lo{}, n{};
  std::vector<std::int64_t> cell;  ///< model cell, or -1
  void reset(const Region& r) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = r.lo[a] - 1;
      n[a] = r.n[a] + 1;
    }
    cell.assign(static_cast<std::size_t>(n[0] * n[1] * n[2]), -1);
  }
  std::int64_t& at(const I3& c) {
    return cell[static_cast<std::size_t>((c[0] - lo[0]) + n[0] * ((c[1] - lo[1]) + n[1] * (c[2] - lo[2])))];
  }
  std::int64_t find(const I3& c) const {
    for (int a = 0; a < 3; ++a)
      if (c[a] < lo[a] || c[a] >= lo[a] + n[a]) return -1;
    return cell[static_cast<std::size_t>((c[0] - lo[0]) + n[0] * ((c[1] - lo[1]) + n[1] * (c[2] - lo[2])))];
  }
};

void encodeRows(const ChunkTopology& ch, std::vector<std::uint8_t>& out) {
  const Region& r = ch.region;
  for (std::int64_t row = 0; row < r.n[1] * r.n[2]; ++row) {
    const std::uint8_t* s = &ch.sign[static_cast<std::size_t>(row * r.n[0])];
    std::uint64_t transitions = 0;
    for (std::int64_t x = 1; x < r.n[0]; ++x) transitions += s[x] != s[x - 1];
    putVarint(out, (transitions << 1) | s[0]);
    for (std::int64_t x = 1; x < r.n[0]; ++x)
      if (s[x] != s[x - 1]) out.push_back(static_cast<std::uint8_t>(x));
  }
}

void markUniformRows(ChunkTopology& ch) {
  const Region& r = ch.region;
  ch.rowUniform.assign(static_cast<std::size_t>(r.n[1] * r.n[2]), 1);
  for (std::int64_t row = 0; row < r.n[1] * r.n[2]; ++row) {
    const std::uint8_t* s = &ch.sign[static_cast<std::size_t>(row * r.n[0])];
    for (std::int64_t x = 1; x < r.n[0]; ++x)
      if (s[x] != s[0]) {
        ch.rowUniform[static_cast<std::size_t>(row)] = 0;
        break;
      }
  }
}

/// Signs of the region's points from the model's cells; points no cell decides take the sign of their row's
/// decided neighbour, and rows with none that of an adjacent row (exactly the volume's own signs when every
/// crossed cell is in the model).
void signsFromModel(const Model& m, ChunkTopology& ch, CellFinder& finder, const std::string& name) {
  const Region& r = ch.region;
  finder.reset(r);
  const std::size_t n = static_cast<std::size_t>(r.n[0] * r.n[1] * r.n[2]);
  std::vector<std::int8_t> s(n, -1);
  auto rowKey = [](std::uint32_t i, std::uint32_t j, std::uint32_t k) {
    return std::array<std::uint32_t, 3>{k, j, i};
  };
  const std::int64_t iFirst = std::max<std::int64_t>(0, r.lo[0] - 1), iEnd = r.lo[0] + r.n[0];
  for (std::int64_t k = std::max<std::int64_t>(0, r.lo[2] - 1); k < r.lo[2] + r.n[2]; ++k)
    for (std::int64_t j = std::max<std::int64_t>(0, r.lo[1] - 1); j < r.lo[1] + r.n[1]; ++j) {
      const auto target = rowKey(static_cast<std::uint32_t>(iFirst), static_cast<std::uint32_t>(j),
                                 static_cast<std::uint32_t>(k));
      auto it = std::lower_bound(
          m.cells.begin(), m.cells.end(), target,
          [&](const ModelCell& a, const auto& t) { return rowKey(a.index[0], a.index[1], a.index[2]) < t; });
      for (; it != m.cells.end() && it->index[1] == j && it->index[2] == k && it->index[0] < iEnd; ++it) {
        const ModelCell& cell = *it;
        const std::int64_t i = cell.index[0];
        finder.at({i, j, k}) = it - m.cells.begin();
        for (int v = 0; v < 8; ++v) {
          const auto o = cube::vertexCoords(v);
          const I3 p{i + o[0], j + o[1], k + o[2]};
          if (!r.contains(p)) continue;
          std::int8_t& t = s[static_cast<std::size_t>(r.index(p))];
          const std::int8_t sv = static_cast<std::int8_t>((cell.config >> v) & 1);
          if (t >= 0 && t != sv)
            throw Error(
                name +
                ": the model cannot be written in format 2: cells disagree on the sign of grid point (" +
                std::to_string(p[0]) + "," + std::to_string(p[1]) + "," + std::to_string(p[2]) + ")");
          t = sv;
        }
      }
    }
  // Fill rows from their decided points; rows without any from adjacent rows (breadth first).
  const std::int64_t rows = r.n[1] * r.n[2];
  std::vector<std::int8_t> rowSign(static_cast<std::size_t>(rows), -1);
  std::vector<std::int64_t> queue;
  for (std::int64_t row = 0; row < rows; ++row) {
    std::int8_t* x = &s[static_cast<std::size_t>(row * r.n[0])];
    std::int8_t last = -1;
    for (std::int64_t i = 0; i < r.n[0]; ++i)
      if (x[i] >= 0) {
        last = x[i];
        break;
      }
    if (last < 0) continue;
    for (std::int64_t i = 0; i < r.n[0]; ++i) {
      if (x[i] < 0) x[i] = last;
      last = x[i];
    }
    rowSign[static_cast<std::size_t>(row)] = x[0];
    queue.push_back(row);
  }
  for (std::size_t head = 0; head < queue.size(); ++head) {
    const std::int64_t row = queue[head], y = row % r.n[1], z = row / r.n[1];
    const std::int64_t nbr[4][2] = {{y - 1, z}, {y + 1, z}, {y, z - 1}, {y, z + 1}};
    for (const auto& q : nbr) {
      if (q[0] < 0 || q[1] < 0 || q[0] >= r.n[1] || q[1] >= r.n[2]) continue;
      const std::int64_t qr = q[0] + r.n[1] * q[1];
      if (rowSign[static_cast<std::size_t>(qr)] >= 0) continue;
      rowSign[static_cast<std::size_t>(qr)] = rowSign[static_cast<std::size_t>(row)];
      std::fill_n(&s[static_cast<std::size_t>(qr * r.n[0])], r.n[0], rowSign[static_cast<std::size_t>(row)]);
      queue.push_back(qr);
    }
  }
  ch.sign.resize(n);
  for (std::size_t i = 0; i < n; ++i) ch.sign[i] = static_cast<std::uint8_t>(std::max<std::int8_t>(s[i], 0));
  markUniformRows(ch);
}

/// The model vertex on the edge from grid point p along `axis`, from any present cell that has it, or -1
/// (a crossing no present cell uses); all present cells must agree.
std::int64_t modelVertexOn(const Model& m, const CellFinder& finder, const I3& p, int axis,
                           const std::string& name) {
  const auto o = cube::otherAxes(axis);
  std::int64_t found = -1;
  for (int db = 0; db < 2; ++db)
    for (int dc = 0; dc < 2; ++dc) {
      I3 c = p;
      c[o[0]] -= db;
      c[o[1]] -= dc;
      const std::int64_t ci = finder.find(c);
      if (ci < 0) continue;
      const int e = cube::edgeIndex(axis, db, dc);
      const ModelCell& cell = m.cells[static_cast<std::size_t>(ci)];
      const CellLoops loops = buildCellLoops(cell.config, cell.pairing03);
      for (int k = 0; k < loops.numCorners(); ++k)
        if (loops.edges[static_cast<std::size_t>(k)] == e) {
          const std::int64_t v = m.corners[cell.firstCorner + static_cast<std::uint32_t>(k)];
          if (found >= 0 && found != v)
            throw Error(
                name +
                ": the model cannot be written in format 2: cells around a grid edge use different vertices");
          found = v;
        }
    }
  return found;
}

struct ChunkSource {
  std::vector<std::int64_t> vertex;  ///< model vertex per owned vertex, or -1
  std::vector<double> side;          ///< model side coefficient per owned face
  std::vector<std::int64_t> cell;    ///< model cell per present cell
};

void buildChunkFromModel(const Model& m, const Layout& L, const ModelFileV2Options& q, ChunkTopology& ch,
                         ChunkSource& src, const std::string& name) {
  CellFinder finder;
  signsFromModel(m, ch, finder, name);
  ch.streams.assign(kNumStreams, {});
  encodeRows(ch, ch.streams[kRows]);
  // Present cells and the crossed ones the model leaves out.
  std::vector<std::uint32_t> nontrivial;
  cellsFromSigns(L, ch, nontrivial);
  std::vector<std::uint32_t> exceptions;
  for (std::uint32_t local : nontrivial) {
    const I3 c{ch.origin[0] + local % L.B, ch.origin[1] + (local / L.B) % L.B,
               ch.origin[2] + local / (L.B * L.B)};
    const std::int64_t ci = finder.find(c);
    if (ci < 0) {
      exceptions.push_back(local);
      continue;
    }
    ch.cells.push_back(local);
    ch.config.push_back(m.cells[static_cast<std::size_t>(ci)].config);
    src.cell.push_back(ci);
  }
  putVarint(ch.streams[kExceptions], exceptions.size());
  std::uint32_t prev = 0;
  for (std::uint32_t e : exceptions) {
    putVarint(ch.streams[kExceptions], e - prev);
    prev = e + 1;
  }
  ownedItems(L, ch);
  // Vertices: crossing parameters.
  const std::uint16_t tMax = maxTCode(q.positionBits);
  ch.tCode.resize(ch.vertexKey.size());
  src.vertex.resize(ch.vertexKey.size());
  for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
    const int axis = static_cast<int>(ch.vertexKey[v] % 3);
    const I3 p = keyPoint(ch, L.B, ch.vertexKey[v] / 3);
    const std::int64_t mv = modelVertexOn(m, finder, p, axis, name);
    src.vertex[v] = mv;
    double t = 0.5;
    if (mv >= 0) {
      const Vec3& pos = m.vertices[static_cast<std::size_t>(mv)].position;
      t = pos[axis] - static_cast<double>(p[axis]);
      if (!(t >= 0 && t <= 1))
        throw Error(name + ": the model cannot be written in format 2: a vertex is not on its grid edge");
    }
    ch.tCode[v] = static_cast<std::uint16_t>(std::clamp<long long>(std::llround(t * tMax), 0, tMax));
    ch.streams[kPositionsLo].push_back(static_cast<std::uint8_t>(ch.tCode[v] & 0xFF));
    if (q.positionBits > 8) ch.streams[kPositionsHi].push_back(static_cast<std::uint8_t>(ch.tCode[v] >> 8));
  }
  gridPointVertexFlags(ch, q.positionBits);
  for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
    if (!(ch.vertexFlags[v] & 64)) continue;
    std::uint8_t mask = 0;
    if (src.vertex[v] >= 0) {
      const Vec3& n = m.vertices[static_cast<std::size_t>(src.vertex[v])].normal;
      const auto o = cube::otherAxes(static_cast<int>(ch.vertexKey[v] % 3));
      mask = static_cast<std::uint8_t>((n[o[0]] == 0.0) | ((n[o[1]] == 0.0) << 1));
    }
    ch.vertexFlags[v] = static_cast<std::uint8_t>(ch.vertexFlags[v] | mask);
    ch.streams[kZeroMasks].push_back(mask);
  }
  // Faces: pairings and side coefficients.
  ch.facePairing.resize(ch.faceKey.size());
  src.side.resize(ch.faceKey.size());
  for (std::size_t f = 0; f < ch.faceKey.size(); ++f) {
    const int axis = static_cast<int>(ch.faceKey[f] % 3);
    const I3 p = keyPoint(ch, L.B, ch.faceKey[f] / 3);
    bool seen = false;
    const bool ambiguous = ambiguousFace(ch, p, axis);
    std::uint8_t pairing = 0;
    double side = 0;
    for (int s = 0; s < 2; ++s) {
      I3 c = p;
      c[axis] -= s;
      const std::int64_t ci = finder.find(c);
      if (ci < 0) continue;
      const ModelCell& cell = m.cells[static_cast<std::size_t>(ci)];
      const int face = 2 * axis + s;
      const std::uint8_t pr = (cell.pairing03 >> face) & 1;
      if (seen &&
          (cell.faceCoefficient[static_cast<std::size_t>(face)] != side || (ambiguous && pr != pairing)))
        throw Error(name +
                    ": the model cannot be written in format 2: the two cells of a face disagree on it");
      side = cell.faceCoefficient[static_cast<std::size_t>(face)];
      pairing = pr;
      seen = true;
    }
    src.side[f] = side;
    ch.facePairing[f] = ambiguous ? pairing : 0;
    if (ambiguous) ch.streams[kPairings].push_back(pairing);
  }
}

/// The paper's side coefficients are recomputed from the stored corners; where a face's coefficient is
/// ill-conditioned (the one from quantised corners differs from the built one by more than 1 %), the corners
/// of the cells around that face are kept in full precision instead, so that the recomputed coefficients and
/// the cells' corner planes are the built ones. Returns whether any vertex is kept.
bool keepIllConditionedCells(const Model& m, const Model& sk, const Skeleton& skel, Chunks& chunks,
                             const std::vector<ChunkSource>& sources, const std::vector<double>& prediction) {
  std::vector<std::uint8_t> badFace(prediction.size(), 0);
  for (std::size_t i = 0; i < chunks.list.size(); ++i)
    for (std::size_t f = 0; f < sources[i].side.size(); ++f) {
      const double w = sources[i].side[f], p = prediction[chunks.list[i].faceBase + f];
      if (!(std::abs(w - p) <= 1.0 * (1.0 + std::abs(w)))) badFace[chunks.list[i].faceBase + f] = 1;
    }
  std::vector<std::uint8_t> keep(sk.vertices.size(), 0);
  bool any = false;
  for (std::size_t c = 0; c < sk.cells.size(); ++c) {
    bool bad = false;
    for (std::int64_t fi : skel.face[c])
      if (fi >= 0 && badFace[static_cast<std::size_t>(fi)]) bad = true;
    if (!bad) continue;
    const ModelCell& cell = sk.cells[c];
    for (int k = 0; k < cell.numCorners(); ++k)
      keep[sk.corners[cell.firstCorner + static_cast<std::uint32_t>(k)]] = 1;
    any = true;
  }
  if (!any) return false;
  for (std::size_t i = 0; i < chunks.list.size(); ++i) {
    ChunkTopology& ch = chunks.list[i];
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
      if (!keep[ch.vertexBase + v] || sources[i].vertex[v] < 0) continue;
      const IsoVertex& mv = m.vertices[static_cast<std::size_t>(sources[i].vertex[v])];
      const int axis = skel.vertexAxis[ch.vertexBase + v];
      ch.exact.push_back(static_cast<std::uint32_t>(v));
      ch.exactT.push_back(mv.position[axis] -
                          static_cast<double>(keyPoint(ch, chunks.L.B, ch.vertexKey[v] / 3)[axis]));
      ch.exactNormal.push_back(mv.normal);
    }
  }
  return true;
}

void compressStreams(ChunkTopology& ch, int level, std::vector<std::uint8_t>& out) {
  for (auto& s : ch.streams) {
    putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(s.size()));
    if (s.empty()) {
      putRaw<std::uint32_t>(out, 0);
      continue;
    }
    std::vector<std::uint8_t> z(ZSTD_compressBound(s.size()));
    const std::size_t n = ZSTD_compress(z.data(), z.size(), s.data(), s.size(), level);
    if (ZSTD_isError(n)) throw Error(std::string("zstd: ") + ZSTD_getErrorName(n));
    if (n >= s.size()) {  // stored as is
      putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(s.size()));
      out.insert(out.end(), s.begin(), s.end());
      continue;
    }
    putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(n));
    out.insert(out.end(), z.begin(), z.begin() + static_cast<std::ptrdiff_t>(n));
  }
}

void checkOptions(const ModelFileV2Options& q) {
  if (q.brick < 8 || q.brick > 128) throw Error("model format 2: brick size must be in 8..128");
  if (q.positionBits < 4 || q.positionBits > 16)
    throw Error("model format 2: position bits must be in 4..16");
  if (q.normalBits < 6 || q.normalBits > 16) throw Error("model format 2: normal bits must be in 6..16");
  if (!(q.sideStep > 0) || !(q.centralStep > 0) || !std::isfinite(q.sideStep) ||
      !std::isfinite(q.centralStep))
    throw Error("model format 2: coefficient steps must be positive");
  if (q.sideMantissa < 1 || q.sideMantissa > 24 || q.centralMantissa < 1 || q.centralMantissa > 24)
    throw Error("model format 2: mantissa bits must be in 1..24");
}

}  // namespace

ModelFileV2Options ModelFileV2Options::forMethod(PatchMethod method) {
  ModelFileV2Options o;
  if (method == PatchMethod::Paper) o.normalBits = 10;
  return o;
}

std::vector<std::uint8_t> serializeModelV2(const Model& m, const ModelFileV2Options& q) {
  checkOptions(q);
  const std::string name = "model";
  Chunks chunks;
  Layout& L = chunks.L;
  L.dims = m.geometry.dims;
  L.B = q.brick;
  for (int a = 0; a < 3; ++a) L.nb[a] = (L.dims[a] - 1 + L.B - 1) / L.B;
  for (double v : {m.geometry.origin[0], m.geometry.origin[1], m.geometry.origin[2], m.isovalue})
    if (!std::isfinite(v)) throw Error("model format 2: the header has a non-finite number");
  // Bricks with cells, and the bricks above them that own their upper edges and faces.
  std::vector<std::int64_t> keys;
  for (const ModelCell& c : m.cells) {
    const I3 idx{c.index[0], c.index[1], c.index[2]};
    const I3 b{idx[0] / L.B, idx[1] / L.B, idx[2] / L.B};
    for (int d = 0; d < 8; ++d) {
      const auto o = cube::vertexCoords(d);
      if ((o[0] && idx[0] % L.B != L.B - 1) || (o[1] && idx[1] % L.B != L.B - 1) ||
          (o[2] && idx[2] % L.B != L.B - 1))
        continue;
      const I3 p{idx[0] + o[0], idx[1] + o[1], idx[2] + o[2]};
      const I3 pb = L.pointBrick(p);
      if (pb != b || d == 0) keys.push_back(L.key(pb));
    }
  }
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  chunks.keys = keys;
  chunks.list.resize(keys.size());
  for (std::size_t i = 0; i < keys.size(); ++i) {
    const std::int64_t k = keys[i];
    setupChunk(L, {k % L.nb[0], (k / L.nb[0]) % L.nb[1], k / (L.nb[0] * L.nb[1])}, chunks.list[i]);
  }
  std::vector<ChunkSource> sources(chunks.list.size());
  tbb::parallel_for(std::size_t(0), chunks.list.size(),
                    [&](std::size_t i) { buildChunkFromModel(m, L, q, chunks.list[i], sources[i], name); });
  std::uint64_t vb = 0, fb = 0;
  for (ChunkTopology& ch : chunks.list) {
    ch.vertexBase = vb;
    ch.faceBase = fb;
    vb += ch.vertexKey.size();
    fb += ch.faceKey.size();
  }
  // The reader's skeleton and prediction, to code the normals against.
  Model sk;
  sk.geometry = m.geometry;
  sk.method = m.method;
  const Skeleton skel = assemble(chunks, q.positionBits, sk, name);
  if (sk.cells.size() != m.cells.size())
    throw Error(name + ": the model cannot be written in format 2: its cells do not follow from its signs");
  const std::vector<Vec3> pred = predictNormals(sk, skel, startAboveFlags(chunks, sk.vertices.size()));
  const double nStep = std::ldexp(1.0, -q.normalBits);
  std::uint8_t flags = kSidesStored;
  for (const ModelCell& c : m.cells)
    if (c.central != 0) flags |= kCentralsStored;
  if (m.method == PatchMethod::Fitted) flags |= kCentralsStored;
  for (const IsoVertex& v : m.vertices)
    if (v.weight != 1.0) flags |= kWeightsStored;
  // Normal codes against the prediction, and the normals (and weights) a reader will have.
  NormalCodes codes(sk.vertices.size(), {0, 0});
  auto codeNormals = [&](const std::vector<Vec3>& prediction) {
    tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
      const ChunkTopology& ch = chunks.list[i];
      const ChunkSource& src = sources[i];
      for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
        if (src.vertex[v] < 0) continue;
        const IsoVertex& mv = m.vertices[static_cast<std::size_t>(src.vertex[v])];
        normalCode(prediction[ch.vertexBase + v], mv.normal, nStep, skel.vertexAxis[ch.vertexBase + v],
                   ch.vertexFlags[v], codes[ch.vertexBase + v][0], codes[ch.vertexBase + v][1]);
        sk.vertices[ch.vertexBase + v].weight = (flags & kWeightsStored) ? mv.weight : 1.0;
      }
    });
    applyNormalCodes(sk, chunks, skel, prediction, codes, nStep);
    applyExactNormals(sk, chunks);
  };
  codeNormals(pred);
  std::vector<double> sidePrediction =
      m.method == PatchMethod::Paper ? paperSidePrediction(sk, skel, fb) : std::vector<double>(fb, 0.0);
  if (m.method == PatchMethod::Paper &&
      keepIllConditionedCells(m, sk, skel, chunks, sources, sidePrediction)) {
    applyExactPositions(sk, chunks, skel);
    codeNormals(predictNormals(sk, skel, startAboveFlags(chunks, sk.vertices.size())));
    sidePrediction = paperSidePrediction(sk, skel, fb);
  }
  std::vector<std::vector<std::uint8_t>> chunkBytes(chunks.list.size());
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    ChunkTopology& ch = chunks.list[i];
    const ChunkSource& src = sources[i];
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
      putVarint(ch.streams[kNormals], zigzag(codes[ch.vertexBase + v][0]));
      putVarint(ch.streams[kNormals], zigzag(codes[ch.vertexBase + v][1]));
      if (flags & kWeightsStored) putRaw<double>(ch.streams[kWeights], sk.vertices[ch.vertexBase + v].weight);
    }
    putVarint(ch.streams[kExact], ch.exact.size());
    for (std::size_t k = 0; k < ch.exact.size(); ++k) {
      putVarint(ch.streams[kExact], ch.exact[k] - (k ? ch.exact[k - 1] + 1 : 0));
      putRaw<double>(ch.streams[kExact], ch.exactT[k]);
      for (int a = 0; a < 3; ++a) putRaw<double>(ch.streams[kExact], ch.exactNormal[k][a]);
    }
    for (std::size_t f = 0; f < src.side.size(); ++f)
      putVarint(ch.streams[kSides], zigzag(coefficientCode(src.side[f] - sidePrediction[ch.faceBase + f],
                                                           q.sideStep, q.sideMantissa)));
    if (flags & kCentralsStored)
      for (std::int64_t c : src.cell)
        putVarint(ch.streams[kCentrals], zigzag(coefficientCode(m.cells[static_cast<std::size_t>(c)].central,
                                                                q.centralStep, q.centralMantissa)));
    compressStreams(ch, q.zstdLevel, chunkBytes[i]);
  });
  // Header, directory, chunks.
  std::vector<std::uint8_t> out;
  std::size_t total = 0;
  for (const auto& b : chunkBytes) total += b.size();
  out.reserve(200 + std::min(m.source.size(), kMaxModelSourceBytes) +
              chunks.list.size() * kDirectoryEntryBytes + total);
  appendModelHeader(out, m, kVersion, flags);
  putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(q.brick));
  out.push_back(static_cast<std::uint8_t>(q.positionBits));
  out.push_back(static_cast<std::uint8_t>(q.normalBits));
  out.push_back(static_cast<std::uint8_t>(q.sideMantissa));
  out.push_back(static_cast<std::uint8_t>(q.centralMantissa));
  putRaw<double>(out, q.sideStep);
  putRaw<double>(out, q.centralStep);
  putRaw<std::uint64_t>(out, m.cells.size());
  putRaw<std::uint64_t>(out, chunks.list.size());
  for (std::size_t i = 0; i < chunks.list.size(); ++i) {
    const ChunkTopology& ch = chunks.list[i];
    for (int a = 0; a < 3; ++a) putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(ch.brick[a]));
    putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(ch.cells.size()));
    putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(ch.vertexKey.size()));
    putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(ch.faceKey.size()));
    putRaw<std::uint64_t>(out, chunkBytes[i].size());
    putRaw<std::uint32_t>(out, crc(chunkBytes[i].data(), chunkBytes[i].size()));
  }
  putRaw<std::uint32_t>(out, crc(out.data(), out.size()));
  for (const auto& b : chunkBytes) out.insert(out.end(), b.begin(), b.end());
  return out;
}

// =========================================================================================================
// Reader
// =========================================================================================================

namespace {

struct DirectoryEntry {
  I3 brick{};
  std::uint32_t cells = 0, vertices = 0, faces = 0, crc = 0;
  std::uint64_t offset = 0, bytes = 0;
};

std::string chunkName(const std::string& name, std::size_t i, const DirectoryEntry& e, std::int64_t B) {
  return name + ": damaged model file: chunk " + std::to_string(i) + " (brick " + std::to_string(e.brick[0]) +
         "," + std::to_string(e.brick[1]) + "," + std::to_string(e.brick[2]) + ", cells from (" +
         std::to_string(e.brick[0] * B) + "," + std::to_string(e.brick[1] * B) + "," +
         std::to_string(e.brick[2] * B) + "))";
}

void decodeRows(ChunkTopology& ch, StreamReader& in) {
  const Region& r = ch.region;
  ch.sign.resize(static_cast<std::size_t>(r.n[0] * r.n[1] * r.n[2]));
  ch.rowUniform.resize(static_cast<std::size_t>(r.n[1] * r.n[2]));
  for (std::int64_t row = 0; row < r.n[1] * r.n[2]; ++row) {
    const std::uint64_t code = in.varint();
    const std::uint64_t transitions = code >> 1;
    if (transitions >= static_cast<std::uint64_t>(r.n[0])) in.fail("has a row with too many sign changes");
    std::uint8_t s = static_cast<std::uint8_t>(code & 1);
    std::uint8_t* out = &ch.sign[static_cast<std::size_t>(row * r.n[0])];
    std::int64_t x = 0;
    for (std::uint64_t t = 0; t < transitions; ++t) {
      const std::int64_t at = in.byte();
      if (at <= x || at >= r.n[0]) in.fail("has sign changes out of order");
      std::fill(out + x, out + at, s);
      x = at;
      s ^= 1;
    }
    std::fill(out + x, out + r.n[0], s);
    ch.rowUniform[static_cast<std::size_t>(row)] = transitions == 0;
  }
  in.expectEnd();
}

std::vector<std::uint8_t> decompress(const std::uint8_t*& at, const std::uint8_t* end, std::size_t cap,
                                     const std::string& where) {
  if (end - at < 8) throw Error(where + " is truncated");
  std::uint32_t raw, stored;
  std::memcpy(&raw, at, 4);
  std::memcpy(&stored, at + 4, 4);
  at += 8;
  if (raw > cap)
    throw Error(where + " declares " + std::to_string(raw) + " bytes, more than its counts can need");
  if (stored > static_cast<std::size_t>(end - at)) throw Error(where + " is truncated");
  std::vector<std::uint8_t> out(raw);
  if (raw == 0) {
    if (stored != 0) throw Error(where + " has bytes but declares none");
    return out;
  }
  if (stored == raw) {  // stored as is: compression would not have made it smaller
    std::memcpy(out.data(), at, raw);
    at += stored;
    return out;
  }
  const std::size_t n = ZSTD_decompress(out.data(), raw, at, stored);
  if (ZSTD_isError(n) || n != raw) throw Error(where + " does not decompress to its declared size");
  at += stored;
  return out;
}

}  // namespace

namespace {

/// The header and directory of a version 2 file: the model's scalar fields, the quantisation, the chunks.
struct FileHeader {
  ModelFileV2Options q;
  std::uint8_t flags = 0;
  std::vector<DirectoryEntry> dir;
};

FileHeader readHeader(const std::uint8_t* data, std::size_t size, const std::string& name, Model& m,
                      Layout& L) {
  ModelFileReader r(data, size, name);
  r.skip(12);  // magic and version, checked by the caller
  FileHeader h;
  h.flags = readModelHeader(r, m);
  if (h.flags > 7) r.fail("unknown flags");
  // Point and brick keys are 64-bit: at most 2^62 points (each dimension is at most 2^31).
  const std::int64_t plane = m.geometry.dims[0] * m.geometry.dims[1];
  if (m.geometry.dims[2] > (std::int64_t(1) << 62) / plane)
    r.fail("grid of " + std::to_string(m.geometry.dims[0]) + " x " + std::to_string(m.geometry.dims[1]) +
           " x " + std::to_string(m.geometry.dims[2]) + " points is too large");
  ModelFileV2Options& q = h.q;
  q.brick = static_cast<int>(r.get<std::uint32_t>("brick size"));
  q.positionBits = r.get<std::uint8_t>("position bits");
  q.normalBits = r.get<std::uint8_t>("normal bits");
  q.sideMantissa = r.get<std::uint8_t>("side mantissa");
  q.centralMantissa = r.get<std::uint8_t>("central mantissa");
  q.sideStep = r.getFinite("side step");
  q.centralStep = r.getFinite("central step");
  try {
    checkOptions(q);
  } catch (const Error& e) {
    r.fail(e.what());
  }
  L.dims = m.geometry.dims;
  L.B = q.brick;
  for (int a = 0; a < 3; ++a) L.nb[a] = (L.dims[a] - 1 + L.B - 1) / L.B;
  const auto cellCount = r.get<std::uint64_t>("cell count");
  const auto chunkCount = r.get<std::uint64_t>("chunk count");
  if (chunkCount > r.remaining() / kDirectoryEntryBytes)
    r.fail("chunk count " + std::to_string(chunkCount) + " exceeds the file");
  h.dir.resize(chunkCount);
  const auto B3 = static_cast<std::uint64_t>(L.B * L.B * L.B);
  const auto P3 = static_cast<std::uint64_t>(3 * (L.B + 1) * (L.B + 1) * (L.B + 1));
  std::uint64_t cellsInChunks = 0;
  for (std::size_t i = 0; i < chunkCount; ++i) {
    DirectoryEntry& e = h.dir[i];
    for (int a = 0; a < 3; ++a) {
      e.brick[a] = r.get<std::uint32_t>("chunk brick");
      if (e.brick[a] >= L.nb[a]) r.fail("chunk " + std::to_string(i) + " lies outside the grid");
    }
    if (i > 0 && L.key(e.brick) <= L.key(h.dir[i - 1].brick))
      r.fail("chunks are not in increasing brick order");
    e.cells = r.get<std::uint32_t>("chunk cell count");
    e.vertices = r.get<std::uint32_t>("chunk vertex count");
    e.faces = r.get<std::uint32_t>("chunk face count");
    if (e.cells > B3 || e.vertices > P3 || e.faces > P3)
      r.fail("chunk " + std::to_string(i) + " has impossible counts");
    e.bytes = r.get<std::uint64_t>("chunk size");
    e.crc = r.get<std::uint32_t>("chunk checksum");
    cellsInChunks += e.cells;
  }
  if (cellsInChunks != cellCount) r.fail("the chunks' cell counts do not add up to the cell count");
  const std::size_t headerEnd = r.pos();
  if (r.get<std::uint32_t>("header checksum") != crc(data, headerEnd)) r.fail("header checksum mismatch");
  std::uint64_t offset = r.pos();
  for (DirectoryEntry& e : h.dir) {
    if (e.bytes > size - offset) r.fail("truncated (a chunk runs past the end of the file)");
    e.offset = offset;
    offset += e.bytes;
  }
  if (offset != size) r.fail(std::to_string(size - offset) + " unexpected bytes after the last chunk");
  return h;
}

/// Phase 1 of reading a chunk, independent of all others: checksum, streams, signs, cells, owned vertices and
/// faces.
void readChunk(const std::uint8_t* data, const Layout& L, const FileHeader& h, std::size_t i,
               ChunkTopology& ch, const std::string& name) {
  const DirectoryEntry& e = h.dir[i];
  const std::string where = chunkName(name, i, e, L.B);
  const std::uint8_t* at = data + e.offset;
  const std::uint8_t* end = at + e.bytes;
  if (crc(at, e.bytes) != e.crc) throw Error(where + ": checksum mismatch");
  setupChunk(L, e.brick, ch);
  // The most bytes each stream can need for the chunk's counts (a writer never exceeds them; a reader
  // allocates no more).
  const std::size_t R = static_cast<std::size_t>(L.B + 3), V = e.vertices, F = e.faces, C = e.cells;
  const std::size_t cap[kNumStreams] = {R * R * (R + 3),
                                        10 + 5 * static_cast<std::size_t>(L.B * L.B * L.B),
                                        F,
                                        V,
                                        V,
                                        20 * V,
                                        10 * F,
                                        10 * C,
                                        8 * V,
                                        V,
                                        10 + 42 * V};
  ch.streams.resize(kNumStreams);
  for (int s = 0; s < kNumStreams; ++s)
    ch.streams[s] = decompress(at, end, cap[s], where + ", stream " + std::to_string(s) + ",");
  if (at != end) throw Error(where + ": bytes after its last stream");
  StreamReader rows(&ch.streams[kRows], where + ": sign rows");
  decodeRows(ch, rows);
  std::vector<std::uint32_t> nontrivial;
  cellsFromSigns(L, ch, nontrivial);
  StreamReader ex(&ch.streams[kExceptions], where + ": cell exceptions");
  const std::uint64_t nEx = ex.varint();
  if (nEx > nontrivial.size()) ex.fail("lists more cells than are crossed");
  std::vector<std::uint32_t> skip(nEx);
  std::uint64_t next = 0;
  for (auto& x : skip) {
    next += ex.varint();
    if (next >= static_cast<std::uint64_t>(L.B * L.B * L.B)) ex.fail("lists a cell outside the brick");
    x = static_cast<std::uint32_t>(next++);
  }
  ex.expectEnd();
  std::size_t k = 0;
  for (std::uint32_t local : nontrivial) {
    while (k < skip.size() && skip[k] < local) ++k;
    if (k < skip.size() && skip[k] == local) continue;
    ch.cells.push_back(local);
    ch.config.push_back(cellConfig(ch, {ch.origin[0] + local % L.B, ch.origin[1] + (local / L.B) % L.B,
                                        ch.origin[2] + local / (L.B * L.B)}));
  }
  if (ch.cells.size() != e.cells)
    throw Error(where + ": its signs give " + std::to_string(ch.cells.size()) +
                " cells, the directory says " + std::to_string(e.cells));
  ownedItems(L, ch);
  if (ch.vertexKey.size() != e.vertices || ch.faceKey.size() != e.faces)
    throw Error(where + ": its signs do not give the directory's vertex and face counts");
  StreamReader lo(&ch.streams[kPositionsLo], where + ": positions");
  StreamReader hi(&ch.streams[kPositionsHi], where + ": positions");
  const std::uint16_t tMax = maxTCode(h.q.positionBits);
  ch.tCode.resize(ch.vertexKey.size());
  for (auto& t : ch.tCode) {
    std::uint32_t v = lo.byte();
    if (h.q.positionBits > 8) v |= static_cast<std::uint32_t>(hi.byte()) << 8;
    if (v > tMax) lo.fail("has a crossing parameter out of range");
    t = static_cast<std::uint16_t>(v);
  }
  lo.expectEnd();
  hi.expectEnd();
  gridPointVertexFlags(ch, h.q.positionBits);
  StreamReader zr(&ch.streams[kZeroMasks], where + ": zero normal components");
  for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
    if (!(ch.vertexFlags[v] & 64)) continue;
    const std::uint8_t mask = zr.byte();
    if (mask > 3) zr.fail("has a mask out of range");
    ch.vertexFlags[v] = static_cast<std::uint8_t>(ch.vertexFlags[v] | mask);
  }
  zr.expectEnd();
  StreamReader pr(&ch.streams[kPairings], where + ": face pairings");
  ch.facePairing.assign(ch.faceKey.size(), 0);
  for (std::size_t f = 0; f < ch.faceKey.size(); ++f) {
    if (!ambiguousFace(ch, keyPoint(ch, L.B, ch.faceKey[f] / 3), static_cast<int>(ch.faceKey[f] % 3)))
      continue;
    const std::uint8_t b = pr.byte();
    if (b > 1) pr.fail("has a pairing that is not 0 or 1");
    ch.facePairing[f] = b;
  }
  pr.expectEnd();
  StreamReader xr(&ch.streams[kExact], where + ": full-precision vertices");
  const std::uint64_t nExact = xr.varint();
  if (nExact > ch.vertexKey.size()) xr.fail("lists more vertices than the chunk has");
  std::uint64_t nextVertex = 0;
  for (std::uint64_t x = 0; x < nExact; ++x) {
    nextVertex += xr.varint();
    if (nextVertex >= ch.vertexKey.size()) xr.fail("lists a vertex the chunk does not have");
    ch.exact.push_back(static_cast<std::uint32_t>(nextVertex++));
    const double t = xr.f64();
    if (!(t >= 0 && t <= 1)) xr.fail("has a crossing parameter outside its edge");
    ch.exactT.push_back(t);
    Vec3 n;
    for (int a = 0; a < 3; ++a) n[a] = xr.f64();
    if (!(std::abs(n.norm() - 1.0) <= 1e-6)) xr.fail("has a normal that is not a unit vector");
    ch.exactNormal.push_back(n);
  }
  xr.expectEnd();
  ch.sign = {};
  ch.rowUniform = {};
}

/// Normal codes (and corner coefficients, when stored) of every chunk, in file order.
NormalCodes readNormalCodes(const Chunks& chunks, const FileHeader& h, Model& m, const std::string& name) {
  NormalCodes codes(m.vertices.size());
  const std::int64_t limit = (std::int64_t(1) << h.q.normalBits) + 1;
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const ChunkTopology& ch = chunks.list[i];
    const std::string where = chunkName(name, i, h.dir[i], chunks.L.B);
    StreamReader nr(&ch.streams[kNormals], where + ": normals");
    StreamReader wr(&ch.streams[kWeights], where + ": corner coefficients");
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
      auto& c = codes[ch.vertexBase + v];
      c[0] = nr.svarint();
      c[1] = nr.svarint();
      if (std::abs(c[0]) > limit || std::abs(c[1]) > limit) nr.fail("has a normal code out of range");
      if (h.flags & kWeightsStored) {
        double& w = m.vertices[ch.vertexBase + v].weight;
        w = wr.f64();
        if (!std::isfinite(w)) wr.fail("has a non-finite corner coefficient");
      }
    }
    nr.expectEnd();
    wr.expectEnd();
  });
  return codes;
}

/// Side coefficients (prediction + stored residual, per face) and central coefficients (per cell).
void readCoefficients(const Chunks& chunks, const FileHeader& h, const Skeleton& sk, Model& m,
                      const std::string& name) {
  std::size_t faces = 0;
  for (const ChunkTopology& ch : chunks.list) faces += ch.faceKey.size();
  std::vector<double> side =
      m.method == PatchMethod::Paper ? paperSidePrediction(m, sk, faces) : std::vector<double>(faces, 0.0);
  std::vector<std::uint64_t> cellBase(chunks.list.size() + 1, 0);
  for (std::size_t i = 0; i < chunks.list.size(); ++i)
    cellBase[i + 1] = cellBase[i] + chunks.list[i].cells.size();
  std::vector<double> central(cellBase.back(), 0.0);
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const ChunkTopology& ch = chunks.list[i];
    const std::string where = chunkName(name, i, h.dir[i], chunks.L.B);
    StreamReader sr(&ch.streams[kSides], where + ": side coefficients");
    StreamReader cr(&ch.streams[kCentrals], where + ": central coefficients");
    if (h.flags & kSidesStored)
      for (std::size_t f = 0; f < ch.faceKey.size(); ++f) {
        side[ch.faceBase + f] += coefficientValue(sr.svarint(), h.q.sideStep, h.q.sideMantissa);
        if (!std::isfinite(side[ch.faceBase + f])) sr.fail("has a side coefficient out of range");
      }
    if (h.flags & kCentralsStored)
      for (std::size_t c = 0; c < ch.cells.size(); ++c) {
        central[cellBase[i] + c] = coefficientValue(cr.svarint(), h.q.centralStep, h.q.centralMantissa);
        if (!std::isfinite(central[cellBase[i] + c])) cr.fail("has a central coefficient out of range");
      }
    sr.expectEnd();
    cr.expectEnd();
  });
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, m.cells.size()),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t c = r.begin(); c < r.end(); ++c) {
                        ModelCell& cell = m.cells[c];
                        cell.central = central[cellBase[sk.origin[c].chunk] + sk.origin[c].local];
                        for (int f = 0; f < 6; ++f) {
                          const std::int64_t fi = sk.face[c][static_cast<std::size_t>(f)];
                          cell.faceCoefficient[static_cast<std::size_t>(f)] =
                              fi >= 0 ? side[static_cast<std::size_t>(fi)] : 0.0;
                        }
                      }
                    });
}

/// Drops vertices no cell uses (crossings next to cells the model leaves out).
void dropUnusedVertices(Model& m) {
  constexpr std::uint32_t kUnused = std::numeric_limits<std::uint32_t>::max();
  std::vector<std::uint32_t> remap(m.vertices.size(), kUnused);
  for (std::uint32_t v : m.corners) remap[v] = 0;
  std::uint32_t used = 0;
  for (auto& x : remap)
    if (x == 0) x = used++;
  if (used == m.vertices.size()) return;
  std::vector<IsoVertex> kept(used);
  for (std::size_t v = 0; v < m.vertices.size(); ++v)
    if (remap[v] != kUnused) kept[remap[v]] = m.vertices[v];
  m.vertices = std::move(kept);
  for (auto& c : m.corners) c = remap[c];
}

}  // namespace

std::vector<std::pair<std::string, std::size_t>> modelFileV2Streams(const std::vector<std::uint8_t>& file) {
  static const char* const kNames[kNumStreams] = {"sign rows",
                                                  "cell exceptions",
                                                  "face pairings",
                                                  "positions (low bytes)",
                                                  "positions (high bytes)",
                                                  "normals",
                                                  "side coefficients",
                                                  "central coefficients",
                                                  "corner coefficients",
                                                  "zero normal components",
                                                  "full-precision vertices"};
  Model m;
  Layout L;
  const FileHeader h = readHeader(file.data(), file.size(), "model", m, L);
  std::vector<std::pair<std::string, std::size_t>> out;
  for (const char* n : kNames) out.push_back({n, 0});
  std::size_t framing = 0;
  for (const DirectoryEntry& e : h.dir) {
    std::size_t at = e.offset;
    for (int s = 0; s < kNumStreams; ++s) {
      std::uint32_t stored;
      if (at + 8 > e.offset + e.bytes)
        throw Error("model: damaged model file: a chunk's streams are truncated");
      std::memcpy(&stored, file.data() + at + 4, 4);
      if (stored > e.offset + e.bytes - at - 8)
        throw Error("model: damaged model file: a stream is truncated");
      out[static_cast<std::size_t>(s)].second += stored;
      framing += 8;
      at += 8 + stored;
    }
  }
  out.push_back({"header", h.dir.empty() ? file.size() : h.dir.front().offset});
  out.push_back({"framing", framing});
  return out;
}

Model parseModelV2(const std::uint8_t* data, std::size_t size, const std::string& name) {
  Model m;
  Chunks chunks;
  const FileHeader h = readHeader(data, size, name, m, chunks.L);
  const std::size_t n = h.dir.size();
  chunks.list.resize(n);
  chunks.keys.resize(n);
  std::uint64_t vertices = 0, faces = 0;
  for (std::size_t i = 0; i < n; ++i) {
    chunks.keys[i] = chunks.L.key(h.dir[i].brick);
    chunks.list[i].vertexBase = vertices;
    chunks.list[i].faceBase = faces;
    vertices += h.dir[i].vertices;
    faces += h.dir[i].faces;
  }
  tbb::parallel_for(std::size_t(0), n,
                    [&](std::size_t i) { readChunk(data, chunks.L, h, i, chunks.list[i], name); });
  const Skeleton sk = assemble(chunks, h.q.positionBits, m, name);
  applyExactPositions(m, chunks, sk);
  const std::vector<Vec3> pred = predictNormals(m, sk, startAboveFlags(chunks, m.vertices.size()));
  const NormalCodes codes = readNormalCodes(chunks, h, m, name);
  applyNormalCodes(m, chunks, sk, pred, codes, std::ldexp(1.0, -h.q.normalBits));
  applyExactNormals(m, chunks);
  readCoefficients(chunks, h, sk, m, name);
  dropUnusedVertices(m);
  return m;
}

}  // namespace cip
