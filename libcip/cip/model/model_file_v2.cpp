#include "cip/model/model_file_v2.h"

#include <emmintrin.h>
#include <tbb/parallel_for.h>
#include <zstd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <optional>

#include "cip/core/checksum.h"
#include "cip/core/error.h"
#include "cip/core/huge_pages.h"
#include "cip/model/model_file_header.h"
#include "cip/patch/open_face_sign.h"
#include "cip/patch/patch_coefficients.h"
#include "cip/patch/surface_shift.h"
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
  kRefined,      ///< (flag bit 3) vertices with more bits: u8 bits, count; per vertex index delta, t, u, v
  kFineCoefficients,  ///< (flag bit 4) coefficients with more bits: u8 bits; cells, then faces: count,
                      ///< per item index delta and the finer residual
  kNumStreams
};
/// Streams of a chunk in files without refinements (written before they existed, and most fitted models).
constexpr int kStreamsBeforeRefinements = kRefined;
/// Streams of a chunk with refined vertices only (flag bit 3 without bit 4).
constexpr int kStreamsWithRefinedVertices = kFineCoefficients;

enum Flags : std::uint8_t {
  kSidesStored = 1,
  kCentralsStored = 2,
  kWeightsStored = 4,
  kRefinementsStored = 8,
  kFineCoefficientsStored = 16  ///< needs kRefinementsStored (its stream follows the refined vertices')
};

/// How many streams a chunk of a file with these flags has.
int chunkStreams(std::uint8_t flags) {
  return (flags & kFineCoefficientsStored) ? kNumStreams
         : (flags & kRefinementsStored)    ? kStreamsWithRefinedVertices
                                           : kStreamsBeforeRefinements;
}

/// Extra bits of a refined vertex's crossing parameter and normal code: their steps are 2^-8 of the
/// header's (docs/model-format.md, "Refined vertices").
constexpr int kRefineBits = 8;
/// Extra bits of a refined coefficient (docs/model-format.md, "Refined coefficients"): 4 keep the stored
/// surfaces of the cells that need them as close as 8 did, in 0.4-1 % fewer bytes of the whole file.
constexpr int kFineCoefficientBits = 4;

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
    if (pos_ < b_->size() && !((*b_)[pos_] & 0x80)) return (*b_)[pos_++];  // most numbers take one byte
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
  /// n signed numbers into out: svarint() n times, with the common one- and two-byte numbers read without a
  /// branch on their length.
  void svarints(std::size_t n, std::int64_t* out) {
    const std::uint8_t* data = b_->data();
    const std::size_t size = b_->size();
    std::size_t pos = pos_;
    for (std::size_t i = 0; i < n; ++i) {
      std::uint64_t v;
      const std::uint64_t b0 = pos < size ? data[pos] : 0x80, b1 = pos + 1 < size ? data[pos + 1] : 0x80;
      const std::uint64_t two = b0 >> 7;
      if (!(two & (b1 >> 7))) {
        v = (b0 & 0x7F) | ((b1 & (0 - two)) << 7);
        pos += 1 + two;
      } else {
        pos_ = pos;
        v = varint();
        if (v >> 63) fail("has a number out of range");
        pos = pos_;
      }
      out[i] = unzigzag(v);
    }
    pos_ = pos;
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

/// std::llround(x), without the library call where |x| < 2^52 (there x - trunc(x) is exact).
std::int64_t roundHalfAway(double x) {
  const double a = std::abs(x);
  if (!(a < 4503599627370496.0)) return std::llround(x);
  const auto i = static_cast<std::int64_t>(a);
  const std::int64_t r = i + (a - static_cast<double>(i) >= 0.5);
  return x < 0 ? -r : r;
}

/// A float-like code: linear steps of `step` up to 2^m steps, then m bits of relative precision.
std::int64_t coefficientCode(double w, double step, int m) {
  const double v = w / step;
  const double a = std::abs(v);
  const std::int64_t lim = std::int64_t(1) << m;
  std::uint64_t bits;
  std::memcpy(&bits, &a, 8);
  if ((bits >> 52) >= 0x7FF) {  // not finite: as frexp and llround take it
    int ex;
    const double fr = std::frexp(a, &ex);
    std::int64_t r = std::llround(std::ldexp(fr, m + 1));
    if (r == 2 * lim) {
      r = lim;
      ++ex;
    }
    const std::int64_t code = lim + (ex - 1 - m) * lim + (r - lim);
    return v < 0 ? -code : code;
  }
  // Both cases computed, one selected (which case a coefficient is in follows no pattern). Above lim steps,
  // a = fr 2^ex with fr in [0.5, 1) (frexp, from the exponent bits: a is normal there) and the mantissa
  // llround(ldexp(fr, m + 1)).
  const std::int64_t linear = roundHalfAway(a);
  int ex = static_cast<int>(bits >> 52) - 1022;
  const std::uint64_t frBits = (bits & ((std::uint64_t(1) << 52) - 1)) | (std::uint64_t(1022) << 52);
  double fr;
  std::memcpy(&fr, &frBits, 8);
  std::int64_t r = roundHalfAway(fr * static_cast<double>(2 * lim));
  const bool carry = r == 2 * lim;
  r = carry ? lim : r;
  ex += carry;
  const std::int64_t scaled = lim + (ex - 1 - m) * lim + (r - lim);
  const std::int64_t code = a < static_cast<double>(lim) ? linear : scaled;
  return v < 0 ? -code : code;
}

/// The block of a code (coefficientCode) of magnitude c: 0 in the linear range (c < 2^m), above it the
/// power of two its m-bit mantissa is scaled by.
std::int64_t codeBlock(std::int64_t c, int m) {
  const std::int64_t lim = std::int64_t(1) << m;
  return c < lim ? 0 : (c - lim) >> m;
}

double coefficientValue(std::int64_t code, double step, int m) {
  const std::int64_t lim = std::int64_t(1) << m;
  const std::int64_t c = code < 0 ? -code : code;
  // Below lim: c itself (times 2^0); above: lim + rem times 2^block. A product by a power of two is exact, as
  // ldexp is (the power is built from its exponent bits while it is a normal number). Selects, not branches:
  // which case a code is in follows no pattern.
  const bool linear = c < lim;
  const std::int64_t block = codeBlock(c, m);
  const std::int64_t mantissa = linear ? c : lim + ((c - lim) & (lim - 1));
  double a;
  if (block < 1000) {
    const std::uint64_t bits = static_cast<std::uint64_t>(1023 + block) << 52;
    double power;
    std::memcpy(&power, &bits, 8);
    a = static_cast<double>(mantissa) * power;
  } else {
    a = std::ldexp(static_cast<double>(mantissa), static_cast<int>(std::min<std::int64_t>(block, 4000)));
  }
  std::uint64_t bits;  // -a where the code is negative: its sign bit flipped
  std::memcpy(&bits, &a, 8);
  bits ^= static_cast<std::uint64_t>(code < 0) << 63;
  std::memcpy(&a, &bits, 8);
  return a * step;
}

/// The step between the values of the codes next to `code` (coefficientCode): `step` in the linear range,
/// step 2^block above it. A refined coefficient adds a residual in steps of this 2^-bits.
double codeStep(std::int64_t code, double step, int m) {
  const std::int64_t block = codeBlock(code < 0 ? -code : code, m);
  return std::ldexp(step, static_cast<int>(std::min<std::int64_t>(block, 4000)));
}

/// The value of a refined coefficient: its code's value plus `fine` steps of 2^-bits codeStep. The writer's
/// and the reader's expression, so both get the same bits.
double fineCoefficientValue(double coarse, std::int64_t fine, std::int64_t code, double step, int m,
                            int bits) {
  return coarse + static_cast<double>(fine) * std::ldexp(codeStep(code, step, m), -bits);
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

/// A cell of a brick by its packed local coordinates x + 256 (y + 256 z) (a brick is at most 128 cells a
/// side): in the order of the file's cell index x + B (y + B z), and taken apart with shifts.
constexpr std::uint32_t packCell(std::int64_t x, std::int64_t y, std::int64_t z) {
  return static_cast<std::uint32_t>(x | y << 8 | z << 16);
}
constexpr std::int64_t cellX(std::uint32_t c) {
  return c & 255;
}
constexpr std::int64_t cellY(std::uint32_t c) {
  return (c >> 8) & 255;
}
constexpr std::int64_t cellZ(std::uint32_t c) {
  return c >> 16;
}

/// What a chunk holds, decoded: the topology every later step (and the writer's own prediction) needs.
struct ChunkTopology {
  I3 brick{};
  I3 origin{};      ///< first cell and first owned point
  I3 cellCount{};   ///< cells of the brick per axis
  I3 ownedCount{};  ///< owned points per axis (the last brick also owns the last point layer)
  Region region;
  std::size_t words = 0;            ///< 64-bit words per sign row: one more than its points need
  std::vector<std::uint64_t> sign;  ///< per region row (y fastest, then z): bit i set = point lo[0] + i above
  std::vector<std::uint32_t> cells;  ///< present cells, packed (packCell), increasing
  std::vector<std::uint8_t> config;
  std::vector<std::uint32_t> rowFirstCell;  ///< per cell row (ly + cellCount[1] lz): its first entry of cells
  std::vector<std::uint64_t>
      rowCorners;  ///< per cell row: its corner count, then its model-wide first corner
  std::vector<std::uint64_t> rowModelCell;  ///< per cell row: the model-wide index of its first cell
  std::vector<std::uint32_t> vertexKey;     ///< owned crossed edges: (lx + (B+1)(ly + (B+1) lz)) 3 + axis
  std::vector<std::uint16_t> tCode;
  std::vector<std::uint8_t> vertexFlags;    ///< bit 0, 1: normal component along the first, second other axis
                                            ///< is zero (grid-point vertices); 5: edge start above; 6: on a
                                            ///< grid point
  std::vector<std::uint32_t> faceKey;       ///< owned crossed faces: point key 3 + normal axis
  std::vector<std::uint8_t> faceAmbiguous;  ///< 1: the face has four crossings
  std::vector<std::uint32_t> vertexRow,
      faceRow;                            ///< per owned point row: its first entry of vertexKey, faceKey
  std::vector<std::uint8_t> facePairing;  ///< 1: pairs around canonical vertices 0 and 3 (ambiguous faces)
  std::vector<double> side;               ///< reader: side coefficient per owned face (paper: its residual)
  std::vector<double> central;            ///< reader: central coefficient per cell
  std::uint64_t vertexBase = 0, faceBase = 0;
  std::vector<std::vector<std::uint8_t>> streams;  ///< the reader keeps the decompressed streams
  std::vector<std::uint32_t> exact;                ///< owned vertices kept in full precision, increasing
  std::vector<double> exactT;
  std::vector<Vec3> exactNormal;
  int refineBits = 0;                             ///< extra bits of the refined vertices
  std::vector<std::uint8_t> refined;              ///< per owned vertex (or empty): 1 = refined
  std::vector<std::array<std::int32_t, 3>> fine;  ///< per owned vertex (or empty): the finer parts of its
                                                  ///< t code and normal code (u, v), refined vertices only
  bool isRefined(std::size_t v) const { return !refined.empty() && refined[v]; }
  std::uint8_t refinedState(std::size_t v) const { return refined.empty() ? std::uint8_t(0) : refined[v]; }
};

void setupChunk(const Layout& L, const I3& brick, ChunkTopology& ch) {
  ch.brick = brick;
  for (int a = 0; a < 3; ++a) {
    ch.origin[a] = brick[a] * L.B;
    ch.cellCount[a] = std::min(L.B, L.dims[a] - 1 - ch.origin[a]);
    ch.ownedCount[a] = brick[a] == L.nb[a] - 1 ? L.dims[a] - ch.origin[a] : L.B;
    ch.region.lo[a] = std::max<std::int64_t>(0, ch.origin[a] - 1);
    ch.region.n[a] = std::min(L.dims[a] - 1, ch.origin[a] + L.B + 1) - ch.region.lo[a] + 1;
  }
  ch.words = static_cast<std::size_t>(ch.region.n[0] / 64 + 2);
}

// ---- sign rows as bits ---------------------------------------------------------------------------------
// A chunk's signs are kept one bit per point, a row in a few words, so that the cells and crossed items of
// a row come from a handful of word operations instead of a look at every point.

using Word = std::uint64_t;

const Word* signRow(const ChunkTopology& ch, std::int64_t y, std::int64_t z) {
  return &ch.sign[static_cast<std::size_t>(ch.region.rowIndex(y, z)) * ch.words];
}
int bitAt(const Word* row, std::int64_t i) {
  return static_cast<int>((row[i >> 6] >> (i & 63)) & 1);
}
/// Word w of the row moved down by one point (bit i = point i + 1).
Word nextBits(const Word* row, std::size_t w) {
  return (row[w] >> 1) | (row[w + 1] << 63);
}
/// Bits [from, to) of word w set.
Word bitRange(std::size_t w, std::int64_t from, std::int64_t to) {
  const std::int64_t lo = std::clamp<std::int64_t>(from - 64 * static_cast<std::int64_t>(w), 0, 64),
                     hi = std::clamp<std::int64_t>(to - 64 * static_cast<std::int64_t>(w), 0, 64);
  if (hi <= lo) return 0;
  const Word upto = hi == 64 ? ~Word(0) : (Word(1) << hi) - 1;
  return upto & ~((Word(1) << lo) - 1);
}
/// Bits where the four values are not all equal.
Word notAllEqual(Word a, Word b, Word c, Word d) {
  return (a | b | c | d) & ~(a & b & c & d);
}

/// Present cells from signs and exceptions (reader), or the check that they agree (writer): the cells of the
/// brick whose eight points do not all share a sign, in increasing (z, y, x), with their configurations.
void cellsFromSigns(const ChunkTopology& ch, std::vector<std::uint32_t>& nontrivial,
                    std::vector<std::uint8_t>& configs) {
  nontrivial.clear();
  configs.clear();
  const std::int64_t i0 = ch.origin[0] - ch.region.lo[0];
  const std::size_t used = static_cast<std::size_t>((i0 + ch.cellCount[0] + 63) / 64);
  for (std::int64_t lz = 0; lz < ch.cellCount[2]; ++lz)
    for (std::int64_t ly = 0; ly < ch.cellCount[1]; ++ly) {
      const std::int64_t y = ch.origin[1] + ly, z = ch.origin[2] + lz;
      const Word* r[4] = {signRow(ch, y, z), signRow(ch, y + 1, z), signRow(ch, y, z + 1),
                          signRow(ch, y + 1, z + 1)};
      for (std::size_t w = 0; w < used; ++w) {
        Word all = ~Word(0), any = 0;
        for (const Word* row : r) {
          const Word a = row[w], b = nextBits(row, w);
          all &= a & b;
          any |= a | b;
        }
        for (Word bits = any & ~all & bitRange(w, i0, i0 + ch.cellCount[0]); bits; bits &= bits - 1) {
          const std::int64_t i = 64 * static_cast<std::int64_t>(w) + __builtin_ctzll(bits);
          int config = 0;
          for (int d = 0; d < 4; ++d) config |= (bitAt(r[d], i) | bitAt(r[d], i + 1) << 1) << (2 * d);
          nontrivial.push_back(packCell(i - i0, ly, lz));
          configs.push_back(static_cast<std::uint8_t>(config));
        }
      }
    }
}

/// The owned crossed edges and faces in file order, with the sign-derived flags of each vertex and which
/// faces are ambiguous, and where each owned point row's entries start.
void ownedItems(const Layout& L, ChunkTopology& ch) {
  ch.vertexKey.clear();
  ch.vertexFlags.clear();
  ch.faceKey.clear();
  ch.faceAmbiguous.clear();
  const auto rows = static_cast<std::size_t>((L.B + 1) * (L.B + 1));
  ch.vertexRow.assign(rows + 1, 0);
  ch.faceRow.assign(rows + 1, 0);
  const Region& r = ch.region;
  const std::int64_t i0 = ch.origin[0] - r.lo[0], iEnd = i0 + ch.ownedCount[0];
  const std::int64_t lastX = L.dims[0] - 1 - r.lo[0];  // region index of the grid's last point along x
  const std::size_t used = static_cast<std::size_t>((iEnd + 63) / 64);
  for (std::int64_t lz = 0; lz < ch.ownedCount[2]; ++lz)
    for (std::int64_t ly = 0; ly < ch.ownedCount[1]; ++ly) {
      const std::int64_t y = ch.origin[1] + ly, z = ch.origin[2] + lz;
      const bool y1 = y + 1 < L.dims[1], z1 = z + 1 < L.dims[2];
      // The four point rows this row's edges and faces reach; one beyond the grid stands in as this row,
      // and the masks leave out what would use it.
      const Word* s = signRow(ch, y, z);
      const Word* sy = y1 ? signRow(ch, y + 1, z) : s;
      const Word* sz = z1 ? signRow(ch, y, z + 1) : s;
      const Word* syz = y1 && z1 ? signRow(ch, y + 1, z + 1) : s;
      const std::size_t row = static_cast<std::size_t>(ly + (L.B + 1) * lz);
      const std::uint32_t rowKey = static_cast<std::uint32_t>((L.B + 1) * (ly + (L.B + 1) * lz));
      for (std::size_t w = 0; w < used; ++w) {
        const Word owned = bitRange(w, i0, iEnd), x1 = bitRange(w, 0, lastX);
        const Word a = s[w], ax = nextBits(s, w), b = sy[w], bx = nextBits(sy, w), c = sz[w],
                   cx = nextBits(sz, w), d = syz[w];
        // Edges from each point along x, y, z; faces across x (spanning y, z), y (x, z), z (x, y).
        const Word e[3] = {(a ^ ax) & x1, y1 ? a ^ b : 0, z1 ? a ^ c : 0};
        const Word f[3] = {y1 && z1 ? notAllEqual(a, b, c, d) : 0, z1 ? notAllEqual(a, ax, c, cx) & x1 : 0,
                           y1 ? notAllEqual(a, ax, b, bx) & x1 : 0};
        // Ambiguous: the face's diagonal points share a sign, the two diagonals differ.
        const Word amb[3] = {~(a ^ d) & ~(b ^ c) & (a ^ b), ~(a ^ cx) & ~(ax ^ c) & (a ^ ax),
                             ~(a ^ bx) & ~(ax ^ b) & (a ^ ax)};
        for (Word bits = (e[0] | e[1] | e[2] | f[0] | f[1] | f[2]) & owned; bits; bits &= bits - 1) {
          const int bit = __builtin_ctzll(bits);
          const std::int64_t i = 64 * static_cast<std::int64_t>(w) + bit;
          const std::uint32_t key = rowKey + static_cast<std::uint32_t>(i - i0);
          const auto flags = static_cast<std::uint8_t>(((a >> bit) & 1) << 5);
          for (int axis = 0; axis < 3; ++axis)
            if ((e[axis] >> bit) & 1) {
              ch.vertexKey.push_back(key * 3 + static_cast<std::uint32_t>(axis));
              ch.vertexFlags.push_back(flags);
            }
          for (int axis = 0; axis < 3; ++axis)
            if ((f[axis] >> bit) & 1) {
              ch.faceKey.push_back(key * 3 + static_cast<std::uint32_t>(axis));
              ch.faceAmbiguous.push_back(static_cast<std::uint8_t>((amb[axis] >> bit) & 1));
            }
        }
      }
      ch.vertexRow[row + 1] = static_cast<std::uint32_t>(ch.vertexKey.size());
      ch.faceRow[row + 1] = static_cast<std::uint32_t>(ch.faceKey.size());
    }
  // Rows past the owned ones (ly beyond ownedCount) end where the row before them does.
  for (std::size_t row = 1; row <= rows; ++row) {
    ch.vertexRow[row] = std::max(ch.vertexRow[row], ch.vertexRow[row - 1]);
    ch.faceRow[row] = std::max(ch.faceRow[row], ch.faceRow[row - 1]);
  }
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

// ---- linking cells to the vertices and faces of the chunks that own them (shared) ----------------------

constexpr std::uint32_t kNone = std::numeric_limits<std::uint32_t>::max();

/// cube::crossedFaces of every configuration (looked up for every cell).
const std::array<std::uint8_t, 256> kCrossedFaces = [] {
  std::array<std::uint8_t, 256> t{};
  for (int c = 0; c < 256; ++c)
    t[static_cast<std::size_t>(c)] = cube::crossedFaces(static_cast<std::uint8_t>(c));
  return t;
}();

/// Per model cell, the model-wide index of the face of each of its cell faces (kNone: not crossed).
using CellFaces = std::vector<std::array<std::uint32_t, 6>>;

struct Chunks {
  Layout L;
  std::vector<ChunkTopology> list;  ///< in increasing brick key order
  std::vector<std::int64_t> keys;
  const ChunkTopology* find(const I3& brick) const {
    for (int a = 0; a < 3; ++a)
      if (brick[a] >= L.nb[a]) return nullptr;
    const std::int64_t k = L.key(brick);
    auto it = std::lower_bound(keys.begin(), keys.end(), k);
    if (it == keys.end() || *it != k) return nullptr;
    return &list[static_cast<std::size_t>(it - keys.begin())];
  }
};

/// Per cell row (ly + cellCount[1] lz) of a chunk: where its cells start, and how many corners they have.
void indexCellRows(ChunkTopology& ch) {
  const auto rows = static_cast<std::size_t>(ch.cellCount[1] * ch.cellCount[2]);
  ch.rowFirstCell.assign(rows + 1, 0);
  ch.rowCorners.assign(rows, 0);
  for (std::size_t j = 0; j < ch.cells.size(); ++j) {
    const auto row = static_cast<std::size_t>(cellY(ch.cells[j]) + ch.cellCount[1] * cellZ(ch.cells[j]));
    ++ch.rowFirstCell[row + 1];
    ch.rowCorners[row] += static_cast<std::uint64_t>(__builtin_popcount(cube::crossedEdges(ch.config[j])));
  }
  for (std::size_t r = 0; r < rows; ++r) ch.rowFirstCell[r + 1] += ch.rowFirstCell[r];
}

/// Model-wide positions of every chunk's cell rows: the model's cells are in grid order (z, y, x), so a
/// layer of cells (one z) runs through the brick rows of its slab of bricks (consecutive in the list), and
/// each row of cells through the chunks of its brick row in turn. Turns rowCorners into each row's first
/// corner; returns the cell count and sets `corners` to the corner count.
std::uint64_t placeCellRows(Chunks& chunks, std::uint64_t& corners) {
  std::uint64_t cells = 0;
  corners = 0;
  auto& list = chunks.list;
  for (std::size_t slab = 0; slab < list.size();) {
    std::size_t slabEnd = slab + 1;
    while (slabEnd < list.size() && list[slabEnd].brick[2] == list[slab].brick[2]) ++slabEnd;
    for (std::size_t i = slab; i < slabEnd; ++i) list[i].rowModelCell.resize(list[i].rowCorners.size());
    for (std::int64_t lz = 0; lz < list[slab].cellCount[2]; ++lz)
      for (std::size_t g = slab; g < slabEnd;) {
        std::size_t end = g + 1;
        while (end < slabEnd && list[end].brick[1] == list[g].brick[1]) ++end;
        for (std::int64_t ly = 0; ly < list[g].cellCount[1]; ++ly)
          for (std::size_t i = g; i < end; ++i) {
            ChunkTopology& ch = list[i];
            const auto r = static_cast<std::size_t>(ly + ch.cellCount[1] * lz);
            ch.rowModelCell[r] = cells;
            cells += ch.rowFirstCell[r + 1] - ch.rowFirstCell[r];
            const std::uint64_t n = ch.rowCorners[r];
            ch.rowCorners[r] = corners;
            corners += n;
          }
        g = end;
      }
    slab = slabEnd;
  }
  return cells;
}

/// The vertices and faces around a chunk's cells, looked up by point: for two point layers (z = lz and
/// lz + 1 of the chunk's cells), per point (x, y) of the cells' box and axis, the model-wide index of the
/// vertex on the crossed edge from there, and the face across it (the owning chunk's slot, see owner(), in
/// the top byte, its index there below), or kNone. Each layer is filled once from the point rows of the
/// chunks that own them (this one, or those above it), so a cell's items are one load each.
class LinkLayers {
 public:
  LinkLayers(const Chunks& chunks, std::size_t index) : ch_(chunks.list[index]), B_(chunks.L.B) {
    for (int d = 0; d < 8; ++d)
      nb_[d] =
          d ? chunks.find({ch_.brick[0] + (d & 1), ch_.brick[1] + ((d >> 1) & 1), ch_.brick[2] + (d >> 2)})
            : &ch_;
    P_ = static_cast<std::size_t>(ch_.cellCount[0] + 1);
    S_ = 3 * P_ * static_cast<std::size_t>(ch_.cellCount[1] + 1);
    vertex_.assign(2 * S_, kNone);
    face_.assign(2 * S_, kNone);
  }
  /// The chunk that owns an item whose face value is `value`.
  const ChunkTopology* owner(std::uint32_t value) const { return nb_[value >> 24]; }
  /// Makes point layers lz and lz + 1 present, and sets the bases of each cell edge's and face's lookup.
  void moveTo(std::int64_t lz) {
    for (std::int64_t pz = lz; pz <= lz + 1; ++pz) {
      const auto slot = static_cast<std::size_t>(pz & 1);
      if (held_[slot] == pz) continue;
      if (held_[slot] >= 0) fill(slot, held_[slot], true);
      fill(slot, pz, false);
      held_[slot] = pz;
    }
    for (int e = 0; e < 12; ++e) {
      const int axis = cube::edgeAxis(e), a = e & 1, b = (e >> 1) & 1;
      const auto o = cube::otherAxes(axis);
      int c[3] = {0, 0, 0};
      c[o[0]] = a;
      c[o[1]] = b;
      edge_[e] = vertex_.data() + offset(lz, c, axis);
    }
    for (int f = 0; f < 6; ++f) {
      int c[3] = {0, 0, 0};
      c[f / 2] = f & 1;
      faceAt_[f] = face_.data() + offset(lz, c, f / 2);
    }
  }
  /// The table position of cell (lx, ly) of the current layer.
  std::size_t cell(std::int64_t lx, std::int64_t ly) const {
    return 3 * (P_ * static_cast<std::size_t>(ly) + static_cast<std::size_t>(lx));
  }
  std::uint32_t vertexOn(int e, std::size_t at) const { return edge_[e][at]; }
  std::uint32_t faceOn(int f, std::size_t at) const { return faceAt_[f][at]; }

 private:
  std::size_t offset(std::int64_t lz, const int* c, int axis) const {
    return S_ * static_cast<std::size_t>((lz + c[2]) & 1) + 3 * (P_ * static_cast<std::size_t>(c[1]) + c[0]) +
           static_cast<std::size_t>(axis);
  }
  /// Writes (or clears) point layer pz into table slot `slot`.
  void fill(std::size_t slot, std::int64_t pz, bool clear) {
    const bool zUp = pz >= ch_.ownedCount[2];
    const std::int64_t oz = zUp ? 0 : pz;
    const bool xNext = ch_.ownedCount[0] <= ch_.cellCount[0];  // the last point column is the next brick's
    for (std::int64_t py = 0; py <= ch_.cellCount[1]; ++py) {
      const bool yUp = py >= ch_.ownedCount[1];
      const auto row = static_cast<std::size_t>((yUp ? 0 : py) + (B_ + 1) * oz);
      const auto keyBase = static_cast<std::uint32_t>(3 * (B_ + 1) * row);
      const std::size_t at = slot * S_ + 3 * P_ * static_cast<std::size_t>(py);
      for (int xUp = 0; xUp < (xNext ? 2 : 1); ++xUp) {
        const int d = xUp | (yUp ? 2 : 0) | (zUp ? 4 : 0);
        const ChunkTopology* o = nb_[d];
        if (!o) continue;
        // Entries of the owner's row: all of them, or (from the next brick) those of its first point.
        const std::uint32_t limit = xUp ? 3 : std::numeric_limits<std::uint32_t>::max();
        std::uint32_t* vt = &vertex_[at + (xUp ? 3 * (P_ - 1) : 0)];
        for (std::uint32_t j = o->vertexRow[row]; j < o->vertexRow[row + 1]; ++j) {
          const std::uint32_t k = o->vertexKey[j] - keyBase;
          if (k >= limit) break;
          vt[k] = clear ? kNone : static_cast<std::uint32_t>(o->vertexBase + j);
        }
        std::uint32_t* ft = &face_[at + (xUp ? 3 * (P_ - 1) : 0)];
        for (std::uint32_t j = o->faceRow[row]; j < o->faceRow[row + 1]; ++j) {
          const std::uint32_t k = o->faceKey[j] - keyBase;
          if (k >= limit) break;
          ft[k] = clear ? kNone : static_cast<std::uint32_t>(d) << 24 | j;
        }
      }
    }
  }

  const ChunkTopology& ch_;
  std::int64_t B_;
  const ChunkTopology* nb_[8];
  std::size_t P_ = 0, S_ = 0;  ///< points per table row, entries per layer
  std::vector<std::uint32_t> vertex_, face_;
  std::int64_t held_[2] = {-1, -1};
  const std::uint32_t* edge_[12] = {};
  const std::uint32_t* faceAt_[6] = {};
};

/// For every vertex and each of the four cells around its edge, in grid order, the vertices after and before
/// it in that cell's loop (kNone where the cell is not in the model): what its normal is predicted from.
struct LoopNeighbours {
  std::array<std::uint32_t, 8> v;
};
/// The grid-order place of the cell that has a vertex's edge as its edge e = 4 axis + a + 2 b: the cells
/// around an edge differ along its two other axes, the higher one the slower in grid order.
constexpr int aroundSlot(int e) {
  return 3 - (e & 3);
}

// ---- decoding a model from its chunks (shared: the writer decodes what it writes) ----------------------

/// A refined vertex's crossing parameter: the code tCode 2^bits + fine in steps of scale 2^-bits.
double refinedT(std::uint16_t tCode, std::int32_t fine, double scale, int bits) {
  return static_cast<double>((static_cast<std::int64_t>(tCode) << bits) + fine) * std::ldexp(scale, -bits);
}

bool sameBits(double a, double b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

/// The crossing parameter along its edge that vertex v's codes give: the plain code, or a refined vertex's
/// code with its finer part.
double codedT(const ChunkTopology& ch, double scale, std::size_t v) {
  return ch.isRefined(v) ? refinedT(ch.tCode[v], ch.fine[v][0], scale, ch.refineBits) : ch.tCode[v] * scale;
}

/// The vertices' positions (index coordinates) from their crossing parameters, or kept in full precision.
void placeVertices(const Chunks& chunks, int positionBits, Model& m) {
  const double scale = 1.0 / maxTCode(positionBits);
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const ChunkTopology& ch = chunks.list[i];
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
      const int axis = static_cast<int>(ch.vertexKey[v] % 3);
      const I3 p = keyPoint(ch, chunks.L.B, ch.vertexKey[v] / 3);
      IsoVertex& vx = m.vertices[ch.vertexBase + v];
      vx.position = Vec3(static_cast<double>(p[0]), static_cast<double>(p[1]), static_cast<double>(p[2]));
      vx.position[axis] += codedT(ch, scale, v);
      vx.weight = 1.0;
    }
    for (std::size_t k = 0; k < ch.exact.size(); ++k) {
      const std::uint32_t v = ch.exact[k];
      const int axis = static_cast<int>(ch.vertexKey[v] % 3);
      const I3 p = keyPoint(ch, chunks.L.B, ch.vertexKey[v] / 3);
      m.vertices[ch.vertexBase + v].position[axis] = static_cast<double>(p[axis]) + ch.exactT[k];
    }
  });
}

/// placeVertices for a model whose vertices were placed before and whose weights are set: puts only the
/// positions that the chunks' codes now give differently (a vertex refined since), leaves the weights, and
/// flags the vertices it moved in `moved` (global vertex order, sized by the caller).
void movePlacedVertices(const Chunks& chunks, int positionBits, Model& m, std::vector<std::uint8_t>& moved) {
  const double scale = 1.0 / maxTCode(positionBits);
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const ChunkTopology& ch = chunks.list[i];
    for (std::size_t v = 0, e = 0; v < ch.vertexKey.size(); ++v) {
      const int axis = static_cast<int>(ch.vertexKey[v] % 3);
      const I3 p = keyPoint(ch, chunks.L.B, ch.vertexKey[v] / 3);
      double t = static_cast<double>(p[axis]) + codedT(ch, scale, v);
      while (e < ch.exact.size() && ch.exact[e] < v) ++e;
      if (e < ch.exact.size() && ch.exact[e] == v) t = static_cast<double>(p[axis]) + ch.exactT[e];
      double& now = m.vertices[ch.vertexBase + v].position[axis];
      if (sameBits(now, t)) continue;
      now = t;
      moved[ch.vertexBase + v] = 1;
    }
  });
}

/// Which model vertex each vertex of the file is, and which model cells each face of the file bounds: per
/// vertex the model vertex of each cell around its edge (in grid order), per face the cell on each side.
struct ModelUse {
  std::vector<std::array<std::uint32_t, 4>> vertex;
  std::vector<std::array<std::uint32_t, 2>> face;
};

/// Fills the model's cells (index, configuration, pairings, loops, corners, and the coefficients the chunks
/// carry) and every vertex's loop neighbours, one pass per chunk; records each cell's faces (model-wide face
/// index per cell face, kNone) when asked, and (writer) which model vertex and cells each vertex and face of
/// the file carries (`use`). The model's tables are sized here; its cells and corners are kept only with
/// `cellTables` (a writer of a `fitted` model needs only the rest). The pairings are the chunks'
/// (reader), or those of `source`'s cells (writer), whose cells must then be the ones the signs give.
void fillCells(Chunks& chunks, Model& m, std::vector<LoopNeighbours>& around, CellFaces* cellFaces,
               const Model* source, ModelUse* use, bool cellTables, const std::string& name) {
  std::uint64_t corners = 0, vertices = 0;
  const std::uint64_t cells = placeCellRows(chunks, corners);
  if (corners > std::numeric_limits<std::uint32_t>::max()) throw Error(name + ": too many corners");
  if (source && source->cells.size() != cells)
    throw Error(name + ": the model cannot be written in format 2: its cells do not follow from its signs");
  for (const ChunkTopology& ch : chunks.list) vertices += ch.vertexKey.size();
  if (cellTables) {
    resizeHuge(m.cells, cells);
    resizeHuge(m.corners, corners);
  }
  resizeHuge(m.vertices, vertices);
  around.assign(vertices, LoopNeighbours{{kNone, kNone, kNone, kNone, kNone, kNone, kNone, kNone}});
  if (cellFaces) cellFaces->resize(cells);
  if (use) {
    std::uint64_t faces = 0;
    for (const ChunkTopology& ch : chunks.list) faces += ch.faceKey.size();
    use->vertex.assign(vertices, {kNone, kNone, kNone, kNone});
    use->face.assign(faces, {kNone, kNone});
  }
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const ChunkTopology& ch = chunks.list[i];
    LinkLayers links(chunks, i);
    std::uint32_t row = kNone;
    std::int64_t layer = -1;
    std::uint64_t cellAt = 0, cornerAt = 0;
    std::size_t rowAt = 0;
    for (std::size_t j = 0; j < ch.cells.size(); ++j) {
      const std::uint32_t local = ch.cells[j];
      const std::int64_t lx = cellX(local), ly = cellY(local), lz = cellZ(local);
      if (local >> 8 != row) {
        row = local >> 8;
        const auto r = static_cast<std::size_t>(ly + ch.cellCount[1] * lz);
        cellAt = ch.rowModelCell[r];
        cornerAt = ch.rowCorners[r];
        if (lz != layer) links.moveTo(layer = lz);
        rowAt = links.cell(0, ly);
      }
      const std::size_t at = rowAt + 3 * static_cast<std::size_t>(lx);
      const std::uint64_t c = cellAt++;
      ModelCell scratchCell;
      ModelCell& cell = cellTables ? m.cells[c] : scratchCell;
      cell.index = {static_cast<std::uint32_t>(ch.origin[0] + lx),
                    static_cast<std::uint32_t>(ch.origin[1] + ly),
                    static_cast<std::uint32_t>(ch.origin[2] + lz)};
      cell.config = ch.config[j];
      std::uint8_t pairing = 0;
      if (source &&
          (source->cells[c].index[0] != cell.index[0] || source->cells[c].index[1] != cell.index[1] ||
           source->cells[c].index[2] != cell.index[2] || source->cells[c].config != cell.config))
        throw Error(name +
                    ": the model cannot be written in format 2: its cells do not follow from its signs");
      const std::uint8_t faces = kCrossedFaces[cell.config];
      for (int f = 0; f < 6; ++f) {
        double w = 0;
        if ((faces >> f) & 1) {
          const std::uint32_t value = links.faceOn(f, at);
          if (value == kNone)
            throw Error(name + ": damaged model file: a crossed face of cell " + std::to_string(c) +
                        " is missing");
          const ChunkTopology* owner = links.owner(value);
          const std::uint32_t fl = value & 0xFFFFFF;
          const bool paired = source ? (source->cells[c].pairing03 >> f) & 1 : owner->facePairing[fl];
          if (paired && cube::isAmbiguousFace(cell.config, f))
            pairing = static_cast<std::uint8_t>(pairing | (1u << f));
          if (!owner->side.empty()) w = owner->side[fl];
          if (cellFaces)
            (*cellFaces)[c][static_cast<std::size_t>(f)] = static_cast<std::uint32_t>(owner->faceBase + fl);
          if (use)
            use->face[owner->faceBase + fl][static_cast<std::size_t>(f & 1)] = static_cast<std::uint32_t>(c);
        } else if (cellFaces) {
          (*cellFaces)[c][static_cast<std::size_t>(f)] = kNone;
        }
        cell.faceCoefficient[static_cast<std::size_t>(f)] = w;
      }
      cell.pairing03 = pairing;
      cell.central = ch.central.empty() ? 0.0 : ch.central[j];
      const CellLoops loops = buildCellLoops(cell.config, pairing);
      cell.numLoops = static_cast<std::uint8_t>(loops.numLoops);
      cell.loopSize = loops.loopSize;
      cell.firstCorner = static_cast<std::uint32_t>(cornerAt);
      const int n = loops.numCorners();
      std::uint32_t scratchCorners[12];
      std::uint32_t* corner = cellTables ? &m.corners[cornerAt] : scratchCorners;
      cornerAt += static_cast<std::uint64_t>(n);
      for (int k = 0; k < n; ++k) {
        corner[k] = links.vertexOn(loops.edges[static_cast<std::size_t>(k)], at);
        if (corner[k] == kNone)
          throw Error(name + ": damaged model file: a crossed edge of cell " + std::to_string(c) +
                      " has no vertex");
      }
      for (int l = 0, start = 0; l < loops.numLoops;
           start += loops.loopSize[static_cast<std::size_t>(l)], ++l) {
        const int size = loops.loopSize[static_cast<std::size_t>(l)];
        for (int k = 0; k < size; ++k) {
          const int e = loops.edges[static_cast<std::size_t>(start + k)];
          std::uint32_t* slot = &around[corner[start + k]].v[static_cast<std::size_t>(2 * aroundSlot(e))];
          slot[0] = corner[start + (k + 1 < size ? k + 1 : 0)];
          slot[1] = corner[start + (k > 0 ? k - 1 : size - 1)];
          if (use)
            use->vertex[corner[start + k]][static_cast<std::size_t>(aroundSlot(e))] =
                source->corners[source->cells[c].firstCorner + static_cast<std::uint32_t>(start + k)];
        }
      }
    }
  });
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

/// The residual code of normal n against its prediction (and its frame, frameOf). Where the reader's
/// corrections (normalFromCode: the grid-point rule, the minimal angle to the edge) may have moved a stored
/// normal off its code's direction, the codes around are searched for one that decodes to n exactly, so that
/// writing a model read from a file gives the same file.
void normalCode(const Vec3& pred, const Vec3& b1, const Vec3& b2, const Vec3& n, double step, int axis,
                std::uint8_t flags, std::int64_t& qu, std::int64_t& qv) {
  double u, v;
  octEncode(Vec3(n.dot(b1), n.dot(b2), n.dot(pred)), u, v);
  qu = roundHalfAway(u / step);
  qv = roundHalfAway(v / step);
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

// ---- normals, several vertices at a time ----------------------------------------------------------------
// A vertex's normal is predicted from its loop neighbours: the sum of the cross products (a - p) × (b - p) of
// the vectors to its two neighbours in each cell around its edge (cells in grid order), divided by its norm
// (the direction towards the positive side along the edge where that is not a positive finite number), and
// turned to the positive side. The predictions, their frames and the decoded normals of a block of a chunk's
// vertices are computed two vertices at a time (SSE2 lanes), with the same IEEE operations in the same order
// as the scalar Eigen expressions of frameOf, octDecode, normalFromCode and orientCornerNormal (Vec3::norm,
// normalized, cross, dot, ...): each lane's result is the scalar one bit for bit, so a file decodes to the
// same model on any machine as it did before these were vectorised.

using Lanes = double __attribute__((vector_size(16)));
using LaneMask = std::int64_t __attribute__((vector_size(16)));
constexpr std::size_t kLanes = 2;

Lanes load(const double* p) {
  Lanes v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
void store(double* p, Lanes v) {
  std::memcpy(p, &v, sizeof v);
}
Lanes splat(double x) {
  return Lanes{x, x};
}
Lanes sqrtLanes(Lanes x) {
  return _mm_sqrt_pd(x);
}
Lanes absLanes(Lanes x) {
  return _mm_andnot_pd(splat(-0.0), x);
}
/// Per lane: m ? a : b.
Lanes select(LaneMask m, Lanes a, Lanes b) {
  return m ? a : b;
}
/// (x, y, z) / sqrt(x² + y² + z²) where that square is positive (Vec3::normalized).
void normalizeLanes(Lanes& x, Lanes& y, Lanes& z) {
  const Lanes sq = (x * x + y * y) + z * z, len = sqrtLanes(sq);
  const LaneMask positive = sq > splat(0.0);
  x = select(positive, x / len, x);
  y = select(positive, y / len, y);
  z = select(positive, z / len, z);
}

/// Up to kSize vertices of one chunk on their way from their loop neighbours to their normals, one array per
/// coordinate.
struct NormalBlock {
  static constexpr std::size_t kSize = 64;
  std::size_t count = 0;
  alignas(16) double sx[kSize], sy[kSize], sz[kSize];  ///< the sum of the cross products
  alignas(16) double tx[kSize], ty[kSize], tz[kSize];  ///< towards the positive side along the edge
  alignas(16) double px[kSize], py[kSize], pz[kSize];  ///< the prediction
  alignas(16) double ax[kSize], ay[kSize], az[kSize];  ///< the frame's first axis
  alignas(16) double bx[kSize], by[kSize], bz[kSize];  ///< its second
  alignas(16) double u[kSize], v[kSize];               ///< the residual codes times the step
  alignas(16) std::int64_t keepX[kSize], keepY[kSize], keepZ[kSize];  ///< -1: keep, 0: a zero component
  alignas(16) double nx[kSize], ny[kSize], nz[kSize];                 ///< the normal
};

/// The block's sums of cross products (Eigen, cells in grid order) and the direction towards
/// the positive side, for the chunk's vertices first .. first + b.count - 1.
void sumBlock(const Model& m, const std::vector<LoopNeighbours>& around, const ChunkTopology& ch,
              std::size_t first, NormalBlock& b) {
  for (std::size_t k = 0; k < b.count; ++k) {
    const std::size_t v = first + k, g = ch.vertexBase + v;
    const Vec3& p = m.vertices[g].position;
    Vec3 sum = Vec3::Zero();
    const LoopNeighbours& nbr = around[g];
    for (int s = 0; s < 4; ++s) {
      const std::uint32_t next = nbr.v[static_cast<std::size_t>(2 * s)];
      if (next == kNone) continue;
      const Vec3& a = m.vertices[next].position;
      const Vec3& c = m.vertices[nbr.v[static_cast<std::size_t>(2 * s + 1)]].position;
      sum += (a - p).cross(c - p);
    }
    b.sx[k] = sum.x();
    b.sy[k] = sum.y();
    b.sz[k] = sum.z();
    const int axis = static_cast<int>(ch.vertexKey[v] % 3);
    const double towards = (ch.vertexFlags[v] & 32) ? -1.0 : 1.0;
    b.tx[k] = axis == 0 ? towards : 0.0;
    b.ty[k] = axis == 1 ? towards : 0.0;
    b.tz[k] = axis == 2 ? towards : 0.0;
  }
  for (std::size_t k = b.count; k < (b.count + kLanes - 1) / kLanes * kLanes; ++k) {  // a lane's padding
    b.sx[k] = b.sy[k] = b.sz[k] = b.ty[k] = b.tz[k] = 0.0;
    b.tx[k] = 1.0;
  }
}

/// Predictions from the sums and their frames (frameOf).
void predictBlock(NormalBlock& b) {
  for (std::size_t k = 0; k < b.count; k += kLanes) {
    const Lanes sx = load(b.sx + k), sy = load(b.sy + k), sz = load(b.sz + k);
    const Lanes tx = load(b.tx + k), ty = load(b.ty + k), tz = load(b.tz + k);
    const Lanes len = sqrtLanes((sx * sx + sy * sy) + sz * sz);
    const LaneMask ok = (len > splat(0.0)) & (len <= splat(std::numeric_limits<double>::max()));
    Lanes px = select(ok, sx / len, tx), py = select(ok, sy / len, ty), pz = select(ok, sz / len, tz);
    const LaneMask flip = ((px * tx + py * ty) + pz * tz) < splat(0.0);
    px = select(flip, -px, px);
    py = select(flip, -py, py);
    pz = select(flip, -pz, pz);
    store(b.px + k, px);
    store(b.py + k, py);
    store(b.pz + k, pz);
    // frameOf: (|p.x| < 0.9 ? unit x : unit y) × p, normalised; then p × that.
    const LaneMask useX = absLanes(px) < splat(0.9);
    const Lanes ex = select(useX, splat(1.0), splat(0.0)), ey = select(useX, splat(0.0), splat(1.0)),
                ez = splat(0.0);
    Lanes ax = ey * pz - ez * py, ay = ez * px - ex * pz, az = ex * py - ey * px;
    normalizeLanes(ax, ay, az);
    store(b.ax + k, ax);
    store(b.ay + k, ay);
    store(b.az + k, az);
    store(b.bx + k, py * az - pz * ay);
    store(b.by + k, pz * ax - px * az);
    store(b.bz + k, px * ay - py * ax);
  }
}

/// The normals from the predictions, frames and residuals (normalFromCode).
void decodeBlock(NormalBlock& b) {
  const Lanes one = splat(1.0), minCos = splat(0.05);
  for (std::size_t k = 0; k < b.count; k += kLanes) {
    // octDecode
    const Lanes u = load(b.u + k), v = load(b.v + k);
    const Lanes au = absLanes(u), av = absLanes(v);
    Lanes lx = u, ly = v, lz = (one - au) - av;
    const LaneMask folded = lz < splat(0.0);
    lx = select(folded, (one - av) * select(u >= splat(0.0), one, -one), lx);
    ly = select(folded, (one - au) * select(v >= splat(0.0), one, -one), ly);
    normalizeLanes(lx, ly, lz);
    // b1 local.x + b2 local.y + pred local.z, normalised
    const Lanes px = load(b.px + k), py = load(b.py + k), pz = load(b.pz + k);
    Lanes nx = (load(b.ax + k) * lx + load(b.bx + k) * ly) + px * lz;
    Lanes ny = (load(b.ay + k) * lx + load(b.by + k) * ly) + py * lz;
    Lanes nz = (load(b.az + k) * lx + load(b.bz + k) * ly) + pz * lz;
    normalizeLanes(nx, ny, nz);
    LaneMask keep;
    std::memcpy(&keep, b.keepX + k, sizeof keep);
    nx = select(keep, nx, splat(0.0));
    std::memcpy(&keep, b.keepY + k, sizeof keep);
    ny = select(keep, ny, splat(0.0));
    std::memcpy(&keep, b.keepZ + k, sizeof keep);
    nz = select(keep, nz, splat(0.0));
    // orientCornerNormal
    const Lanes tx = load(b.tx + k), ty = load(b.ty + k), tz = load(b.tz + k);
    const Lanes len = sqrtLanes((nx * nx + ny * ny) + nz * nz);
    const LaneMask ok = (len > splat(0.0)) & (len <= splat(std::numeric_limits<double>::max()));
    nx = nx / len;
    ny = ny / len;
    nz = nz / len;
    const Lanes c = (nx * tx + ny * ty) + nz * tz;
    const LaneMask tilt = c < minCos;
    Lanes mx = nx + (minCos - c) * tx, my = ny + (minCos - c) * ty, mz = nz + (minCos - c) * tz;
    normalizeLanes(mx, my, mz);
    store(b.nx + k, select(ok, select(tilt, mx, nx), tx));
    store(b.ny + k, select(ok, select(tilt, my, ny), ty));
    store(b.nz + k, select(ok, select(tilt, mz, nz), tz));
  }
}

/// Sets every vertex normal from its prediction and residual code, a block of each chunk's vertices at a
/// time: `codeOf(chunk)` returns a function of (first vertex of the block, block) that sets the block's
/// residuals (u, v: the codes times the step) from its predictions and frames (the reader reads the codes,
/// the writer chooses them). The normals are decoded when `decode` (a writer needs them only for `paper`
/// models); then the full-precision normals are put.
/// With `only` (global vertex order), the blocks with no flagged vertex are left as they are; with `changed`,
/// the vertices whose normal it changes are flagged there.
template <class CodeOf>
void decodeNormals(Model& m, const Chunks& chunks, const std::vector<LoopNeighbours>& around, bool decode,
                   CodeOf&& codeOf, const std::vector<std::uint8_t>* only = nullptr,
                   std::vector<std::uint8_t>* changed = nullptr) {
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const ChunkTopology& ch = chunks.list[i];
    auto code = codeOf(i);
    NormalBlock b;
    for (std::size_t first = 0; first < ch.vertexKey.size(); first += NormalBlock::kSize) {
      b.count = std::min(NormalBlock::kSize, ch.vertexKey.size() - first);
      if (only) {
        const auto from = only->begin() + static_cast<std::ptrdiff_t>(ch.vertexBase + first);
        if (std::find(from, from + static_cast<std::ptrdiff_t>(b.count), std::uint8_t{1}) ==
            from + static_cast<std::ptrdiff_t>(b.count))
          continue;
      }
      sumBlock(m, around, ch, first, b);
      predictBlock(b);
      code(first, b);
      if (!decode) continue;
      for (std::size_t k = 0; k < b.count; ++k) {
        const std::uint8_t flags = ch.vertexFlags[first + k];
        std::int64_t keep[3] = {-1, -1, -1};
        if (flags & 64) {  // on a grid point: the components that are exactly zero stay so
          const auto o = cube::otherAxes(static_cast<int>(ch.vertexKey[first + k] % 3));
          for (int oi = 0; oi < 2; ++oi)
            if ((flags >> oi) & 1) keep[o[oi]] = 0;
        }
        b.keepX[k] = keep[0];
        b.keepY[k] = keep[1];
        b.keepZ[k] = keep[2];
      }
      for (std::size_t k = b.count; k < (b.count + kLanes - 1) / kLanes * kLanes; ++k) {
        b.u[k] = b.v[k] = 0.0;
        b.keepX[k] = b.keepY[k] = b.keepZ[k] = -1;
      }
      decodeBlock(b);
      for (std::size_t k = 0; k < b.count; ++k) {
        Vec3& normal = m.vertices[ch.vertexBase + first + k].normal;
        if (changed && !(sameBits(normal.x(), b.nx[k]) && sameBits(normal.y(), b.ny[k]) &&
                         sameBits(normal.z(), b.nz[k])))
          (*changed)[ch.vertexBase + first + k] = 1;
        normal = Vec3(b.nx[k], b.ny[k], b.nz[k]);
      }
    }
    for (std::size_t k = 0; k < ch.exact.size(); ++k)
      m.vertices[ch.vertexBase + ch.exact[k]].normal = ch.exactNormal[k];
  });
}

/// The paper's side coefficient of every face (global face order) from the model's corners as stored: what
/// the file codes the paper method's side coefficients against (a well-conditioned face then costs a zero).
/// Each face is computed once, by the cell it bounds from below if that cell is in the model, else by the
/// other (both would compute the same value: patch_coefficients.h).
std::vector<double> paperSidePrediction(const Model& m, const CellFaces& cellFaces, std::size_t faces) {
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
              const std::uint32_t fi = cellFaces[c][static_cast<std::size_t>(f)];
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

/// The model's cells in the rows of cells around one chunk's region (y and z from the region's first point -
/// 1 to its last, x likewise): each row's range of Model::cells, found while the chunk's signs are.
struct ModelRows {
  std::int64_t y0 = 0, z0 = 0, ny = 0;
  std::vector<std::pair<std::size_t, std::size_t>> range;
  std::pair<std::size_t, std::size_t>& at(std::int64_t y, std::int64_t z) {
    return range[static_cast<std::size_t>((y - y0) + ny * (z - z0))];
  }
};

void encodeRows(const ChunkTopology& ch, std::vector<std::uint8_t>& out) {
  const Region& r = ch.region;
  const std::size_t used = static_cast<std::size_t>((r.n[0] + 63) / 64);
  for (std::int64_t row = 0; row < r.n[1] * r.n[2]; ++row) {
    const Word* s = &ch.sign[static_cast<std::size_t>(row) * ch.words];
    // Bit i: the sign changes between points i and i + 1.
    Word change[3] = {0, 0, 0};
    std::uint64_t transitions = 0;
    for (std::size_t w = 0; w < used; ++w) {
      change[w] = (s[w] ^ nextBits(s, w)) & bitRange(w, 0, r.n[0] - 1);
      transitions += static_cast<std::uint64_t>(__builtin_popcountll(change[w]));
    }
    putVarint(out, (transitions << 1) | (s[0] & 1));
    for (std::size_t w = 0; w < used; ++w)
      for (Word bits = change[w]; bits; bits &= bits - 1)
        out.push_back(
            static_cast<std::uint8_t>(64 * w + static_cast<std::size_t>(__builtin_ctzll(bits)) + 1));
  }
}

/// Signs of the region's points from the model's cells; points no cell decides take the sign of their row's
/// decided neighbour, and rows with none that of an adjacent row (exactly the volume's own signs when every
/// crossed cell is in the model).
void signsFromModel(const Model& m, ChunkTopology& ch, ModelRows& cellRows, const std::string& name) {
  const Region& r = ch.region;
  cellRows.y0 = r.lo[1] - 1;
  cellRows.z0 = r.lo[2] - 1;
  cellRows.ny = r.n[1] + 1;
  cellRows.range.assign(static_cast<std::size_t>(cellRows.ny * (r.n[2] + 1)), {0, 0});
  const std::int64_t rows = r.n[1] * r.n[2];
  const std::size_t W = ch.words;
  // Per row: which points some cell decides, and their signs (ch.sign).
  std::vector<Word> known(static_cast<std::size_t>(rows) * W, 0);
  ch.sign.assign(static_cast<std::size_t>(rows) * W, 0);
  auto before = [](const ModelCell& a, std::int64_t i, std::int64_t j, std::int64_t k) {
    if (a.index[2] != k) return a.index[2] < k;
    if (a.index[1] != j) return a.index[1] < j;
    return a.index[0] < i;
  };
  const std::int64_t iFirst = std::max<std::int64_t>(0, r.lo[0] - 1), iEnd = r.lo[0] + r.n[0];
  auto it = m.cells.begin();
  for (std::int64_t k = std::max<std::int64_t>(0, r.lo[2] - 1); k < r.lo[2] + r.n[2]; ++k)
    for (std::int64_t j = std::max<std::int64_t>(0, r.lo[1] - 1); j < r.lo[1] + r.n[1]; ++j) {
      // The row's first cell, searched forward from the last row's (galloping, then bisecting).
      if (it != m.cells.end() && before(*it, iFirst, j, k)) {
        auto lo = it, hi = it;
        for (std::ptrdiff_t step = 1; hi != m.cells.end() && before(*hi, iFirst, j, k); step *= 2) {
          lo = hi;
          hi = m.cells.end() - lo > step ? lo + step : m.cells.end();
        }
        it = std::lower_bound(lo, hi, 0, [&](const ModelCell& a, int) { return before(a, iFirst, j, k); });
      }
      auto& range = cellRows.at(j, k);
      range.first = range.second = static_cast<std::size_t>(it - m.cells.begin());
      // The four point rows of this row of cells (nullptr: outside the region): a cell's two points on each
      // are set with one word operation where both are inside the region and in the same word.
      Word* rowKnown[4];
      Word* rowSign[4];
      for (int d = 0; d < 4; ++d) {
        const std::int64_t y = j + (d & 1), z = k + (d >> 1);
        const bool inside = y >= r.lo[1] && y < r.lo[1] + r.n[1] && z >= r.lo[2] && z < r.lo[2] + r.n[2];
        const std::size_t at = inside ? static_cast<std::size_t>(r.rowIndex(y, z)) * W : 0;
        rowKnown[d] = inside ? &known[at] : nullptr;
        rowSign[d] = inside ? &ch.sign[at] : nullptr;
      }
      for (; it != m.cells.end() && it->index[1] == j && it->index[2] == k && it->index[0] < iEnd; ++it) {
        const ModelCell& cell = *it;
        const std::int64_t i = cell.index[0];
        range.second = static_cast<std::size_t>(it - m.cells.begin()) + 1;
        const std::int64_t lx = i - r.lo[0];
        if (lx >= 0 && lx + 1 < r.n[0] && (lx & 63) != 63) {
          const auto w = static_cast<std::size_t>(lx >> 6);
          const int shift = static_cast<int>(lx & 63);
          const Word both = Word(3) << shift;
          Word values[4];
          bool agree = true;
          for (int d = 0; d < 4; ++d) {
            values[d] = static_cast<Word>((cell.config >> (2 * d)) & 3) << shift;
            if (rowKnown[d]) agree &= !(rowKnown[d][w] & (rowSign[d][w] ^ values[d]) & both);
          }
          if (agree) {
            for (int d = 0; d < 4; ++d)
              if (rowKnown[d]) {
                rowKnown[d][w] |= both;
                rowSign[d][w] |= values[d];
              }
            continue;
          }
        }
        for (int v = 0; v < 8; ++v) {  // points in two words or outside the region, or a disagreement
          const auto o = cube::vertexCoords(v);
          const I3 p{i + o[0], j + o[1], k + o[2]};
          if (!r.contains(p)) continue;
          const std::size_t x = static_cast<std::size_t>(p[0] - r.lo[0]);
          const std::size_t w = static_cast<std::size_t>(r.rowIndex(p[1], p[2])) * W + x / 64;
          const Word bit = Word(1) << (x % 64), sv = ((cell.config >> v) & 1) ? bit : 0;
          if ((known[w] & bit) && (ch.sign[w] & bit) != sv)
            throw Error(
                name +
                ": the model cannot be written in format 2: cells disagree on the sign of grid point (" +
                std::to_string(p[0]) + "," + std::to_string(p[1]) + "," + std::to_string(p[2]) + ")");
          known[w] |= bit;
          ch.sign[w] |= sv;
        }
      }
    }
  // Fill rows from their decided points (a point takes the sign of the decided one before it, leading ones
  // that of the first); rows without any from adjacent rows (breadth first).
  const std::size_t used = static_cast<std::size_t>((r.n[0] + 63) / 64);
  std::vector<std::int8_t> rowSign(static_cast<std::size_t>(rows), -1);
  std::vector<std::int64_t> queue;
  for (std::int64_t row = 0; row < rows; ++row) {
    const Word* kn = &known[static_cast<std::size_t>(row) * W];
    Word* sg = &ch.sign[static_cast<std::size_t>(row) * W];
    std::int64_t from = 0;  // first point of the undecided run before the next decided point
    int last = -1;
    for (std::size_t w = 0; w < used; ++w)
      for (Word bits = kn[w]; bits; bits &= bits - 1) {
        const std::int64_t i = 64 * static_cast<std::int64_t>(w) + __builtin_ctzll(bits);
        const int value = bitAt(sg, i);
        if ((last < 0 ? value : last) == 1)
          for (std::size_t u = static_cast<std::size_t>(from >> 6);
               from < i && u <= static_cast<std::size_t>((i - 1) >> 6); ++u)
            sg[u] |= bitRange(u, from, i);
        last = value;
        from = i + 1;
      }
    if (last < 0) continue;
    if (last == 1)
      for (std::size_t u = static_cast<std::size_t>(from >> 6); from < r.n[0] && u < used; ++u)
        sg[u] |= bitRange(u, from, r.n[0]);
    rowSign[static_cast<std::size_t>(row)] = static_cast<std::int8_t>(sg[0] & 1);
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
      if (rowSign[static_cast<std::size_t>(row)])
        for (std::size_t u = 0; u < used; ++u)
          ch.sign[static_cast<std::size_t>(qr) * W + u] = bitRange(u, 0, r.n[0]);
      queue.push_back(qr);
    }
  }
}

struct ChunkSource {
  std::vector<std::int64_t> vertex;  ///< model vertex per owned vertex, or -1
  std::vector<double> side;          ///< model side coefficient per owned face
  std::vector<std::int64_t> cell;    ///< model cell per present cell
};

/// The chunk's signs (from the model's cells), sign rows, cells and exceptions, and owned crossed items.
void buildChunkFromModel(const Model& m, const Layout& L, ChunkTopology& ch, ChunkSource& src,
                         const std::string& name) {
  ModelRows rows;
  signsFromModel(m, ch, rows, name);
  ch.streams.assign(kNumStreams, {});
  encodeRows(ch, ch.streams[kRows]);
  // Present cells and the crossed ones the model leaves out.
  std::vector<std::uint32_t> nontrivial;
  std::vector<std::uint8_t> configs;
  cellsFromSigns(ch, nontrivial, configs);
  std::vector<std::uint32_t> exceptions;
  std::uint32_t row = kNone;
  std::size_t at = 0, end = 0;
  for (std::uint32_t local : nontrivial) {
    const I3 c{ch.origin[0] + cellX(local), ch.origin[1] + cellY(local), ch.origin[2] + cellZ(local)};
    if (local >> 8 != row) {
      row = local >> 8;
      std::tie(at, end) = rows.at(c[1], c[2]);
    }
    while (at < end && m.cells[at].index[0] < c[0]) ++at;
    if (at == end || m.cells[at].index[0] != c[0]) {
      exceptions.push_back(
          static_cast<std::uint32_t>(cellX(local) + L.B * (cellY(local) + L.B * cellZ(local))));
      continue;
    }
    ch.cells.push_back(local);
    ch.config.push_back(m.cells[at].config);
    src.cell.push_back(static_cast<std::int64_t>(at));
  }
  putVarint(ch.streams[kExceptions], exceptions.size());
  std::uint32_t prev = 0;
  for (std::uint32_t e : exceptions) {
    putVarint(ch.streams[kExceptions], e - prev);
    prev = e + 1;
  }
  ownedItems(L, ch);
}

/// The chunk's crossing parameters, zero normal components, pairings and side coefficients from the model.
void codeChunkItems(const Model& m, const Layout& L, const ModelFileV2Options& q, const ModelUse& use,
                    ChunkTopology& ch, ChunkSource& src, const std::string& name) {
  const std::uint16_t tMax = maxTCode(q.positionBits);
  ch.tCode.resize(ch.vertexKey.size());
  src.vertex.resize(ch.vertexKey.size());
  for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
    const int axis = static_cast<int>(ch.vertexKey[v] % 3);
    std::int64_t mv = -1;
    for (std::uint32_t u : use.vertex[ch.vertexBase + v]) {
      if (u == kNone) continue;
      if (mv >= 0 && mv != static_cast<std::int64_t>(u))
        throw Error(
            name +
            ": the model cannot be written in format 2: cells around a grid edge use different vertices");
      mv = u;
    }
    src.vertex[v] = mv;
    double t = 0.5;
    if (mv >= 0) {
      const I3 p = keyPoint(ch, L.B, ch.vertexKey[v] / 3);
      const Vec3& pos = m.vertices[static_cast<std::size_t>(mv)].position;
      t = pos[axis] - static_cast<double>(p[axis]);
      if (!(t >= 0 && t <= 1))
        throw Error(name + ": the model cannot be written in format 2: a vertex is not on its grid edge");
    }
    std::int64_t code = std::clamp<std::int64_t>(roundHalfAway(t * tMax), 0, tMax);
    // A crossing strictly inside its edge stays off the grid points: rounded onto one, its corner plane would
    // pass through a corner of the open faces there and the patch could dip through them (a hole).
    if (t > 0 && code == 0) code = 1;
    if (t < 1 && code == tMax) code = tMax - 1;
    ch.tCode[v] = static_cast<std::uint16_t>(code);
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
    bool seen = false;
    const bool ambiguous = ch.faceAmbiguous[f];
    std::uint8_t pairing = 0;
    double side = 0;
    for (int s = 0; s < 2; ++s) {
      const std::uint32_t ci = use.face[ch.faceBase + f][static_cast<std::size_t>(s)];
      if (ci == kNone) continue;
      const ModelCell& cell = m.cells[ci];
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

/// The fine part of a refined vertex's crossing parameter t (in [0, 1]) against its code tCode.
std::int32_t fineT(double t, std::uint16_t tCode, int positionBits) {
  const double units = std::ldexp(static_cast<double>(maxTCode(positionBits)), kRefineBits);
  const auto q = std::clamp<std::int64_t>(std::llround(t * units), 0, static_cast<std::int64_t>(units));
  return static_cast<std::int32_t>(q - (static_cast<std::int64_t>(tCode) << kRefineBits));
}

/// Marks a vertex refined, with the fine part of its crossing parameter from the model's.
void refineVertex(const Model& m, const Layout& L, int positionBits, ChunkTopology& ch,
                  const ChunkSource& src, std::size_t v) {
  ch.refined[v] = 1;
  if (src.vertex[v] < 0) return;
  const int axis = static_cast<int>(ch.vertexKey[v] % 3);
  const double t = m.vertices[static_cast<std::size_t>(src.vertex[v])].position[axis] -
                   static_cast<double>(keyPoint(ch, L.B, ch.vertexKey[v] / 3)[axis]);
  ch.fine[v][0] = fineT(t, ch.tCode[v], positionBits);
}

/// Sets a chunk up for refined vertices, and refines those whose crossing parameter a refined code holds
/// exactly and a plain one does not: the
/// vertices of a model read from such a file, so that writing it again keeps them (their normals are checked
/// as they are coded: refinedNormalCode).
void refineExactPositions(const Model& m, const Layout& L, int positionBits, ChunkTopology& ch,
                          const ChunkSource& src) {
  ch.refineBits = kRefineBits;
  ch.refined.assign(ch.vertexKey.size(), 0);
  ch.fine.assign(ch.vertexKey.size(), {0, 0, 0});
  const double scale = 1.0 / maxTCode(positionBits);
  for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
    if (src.vertex[v] < 0) continue;
    const int axis = static_cast<int>(ch.vertexKey[v] % 3);
    const double x = m.vertices[static_cast<std::size_t>(src.vertex[v])].position[axis],
                 p = static_cast<double>(keyPoint(ch, L.B, ch.vertexKey[v] / 3)[axis]);
    const std::int32_t f = fineT(x - p, ch.tCode[v], positionBits);
    // Compared as placeVertices places them: the grid point plus t, rounded.
    if (p + refinedT(ch.tCode[v], f, scale, kRefineBits) != x) continue;
    ch.fine[v][0] = f;
    ch.refined[v] = p + ch.tCode[v] * scale == x ? 2 : 1;  // 2: plain codes hold t too; the normal decides
  }
}

/// The paper's side coefficients are recomputed from the stored corners; where a face's coefficient is
/// ill-conditioned (the one from quantised corners differs from the built one by more than 1 + |w|), the
/// corners of the cells around that face are refined, so that the recomputed coefficients and the cells'
/// corner planes are close to the built ones. Returns whether any vertex was newly refined.
bool refineIllConditionedCells(const Model& m, const Model& sk, const CellFaces& cellFaces, Chunks& chunks,
                               const std::vector<ChunkSource>& sources, const std::vector<double>& prediction,
                               int positionBits) {
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
    for (std::uint32_t fi : cellFaces[c])
      if (fi != kNone && badFace[fi]) bad = true;
    if (!bad) continue;
    const ModelCell& cell = sk.cells[c];
    for (int k = 0; k < cell.numCorners(); ++k)
      keep[sk.corners[cell.firstCorner + static_cast<std::uint32_t>(k)]] = 1;
    any = true;
  }
  if (!any) return false;
  bool added = false;
  for (std::size_t i = 0; i < chunks.list.size(); ++i) {
    ChunkTopology& ch = chunks.list[i];
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v)
      if (keep[ch.vertexBase + v] && ch.refined[v] != 1) {
        refineVertex(m, chunks.L, positionBits, ch, sources[i], v);
        added = true;
      }
  }
  return added;
}

/// How far (voxels, estimated: surfaceShiftEstimate) a cell's stored surface may move before its corners are
/// refined (paper models) or its coefficients and then its corners (fitted): a fifth of the bound
/// docs/model-format.md states for paper models, two fifths for fitted ones, since the estimate samples the
/// cell sparsely. Fitted models' patches amplify rounding far less, and each refined cell costs bytes.
constexpr double kPaperShiftTarget = 0.002;
constexpr double kFittedShiftTarget = 0.003;

/// The fractions of openFacesNearOtherSign: a stored patch's open face is checked point by point for a hole
/// where the screen finds it within 5 % of the largest magnitude inside the face, or 1 % on its edges, of the
/// other sign (or of the other sign at a corner). On the MRI and the smoke volume these faces held every hole
/// the rounding opened (10 % inside alone let one through and checked about 6 times as many faces).
constexpr double kNearInside = 0.05, kNearBorder = 0.01;

/// Whether `stored` takes the other sign than the corners on an open face of its cell where `built` keeps
/// their sign, on the lattice of the measure of holes: a hole the rounding of the patch's numbers opened.
/// Only the faces the screen flags are checked point by point.
bool opensHole(const CornerPatch& built, const CornerPatch& stored, std::uint8_t config) {
  for (unsigned near = openFacesNearOtherSign(stored, config, kNearInside, kNearBorder); near;
       near &= near - 1) {
    const int f = __builtin_ctz(near);
    if (openFaceLeaks(stored, config, f, kOpenFaceLattice) &&
        !openFaceLeaks(built, config, f, kOpenFaceLattice))
      return true;
  }
  return false;
}

/// What estimateMovingCells keeps from one round to the next, so that a round estimates again only the cells
/// whose stored patch changed: those around the corners the last round refined, and those whose normal or
/// side predictions these moved. The other cells' estimates would repeat the last ones, number for number.
struct MovingCells {
  std::vector<std::uint8_t> moving;  ///< per cell, whether the last estimate found it moving (empty before)
  /// The stored side coefficient of each face of the file and whether it was refined. Fitted models code
  /// their sides against no prediction, so a later round codes again only the faces whose refinement changed;
  /// paper models' predictions change with their corners, so every face is coded again.
  std::vector<double> side;
  std::vector<std::uint8_t> sideRefined;
  /// Whether each cell's central coefficient was stored refined (its stored value is sk's).
  std::vector<std::uint8_t> centralRefined;
};

/// The coefficients a writer stores with kFineCoefficientBits more bits (fitted models: those of the cells
/// whose surface the plain codes would move too far): per model cell its central coefficient, per face of the
/// file its side coefficient. Empty: none.
struct FineCoefficients {
  std::vector<std::uint8_t> cell, face;
  bool any() const {
    return std::any_of(cell.begin(), cell.end(), [](std::uint8_t x) { return x != 0; }) ||
           std::any_of(face.begin(), face.end(), [](std::uint8_t x) { return x != 0; });
  }
};

/// The value a reader decodes for coefficient w stored against prediction p: p plus its code's value, and
/// with `refined` plus the finer residual, which `fine` gets.
double storedCoefficient(double w, double p, double step, int m, bool refined, std::int64_t* fine = nullptr) {
  const std::int64_t code = coefficientCode(w - p, step, m);
  const double coarse = coefficientValue(code, step, m);
  if (!refined) return p + coarse;
  // Kept short of half a code step, so that the value is nearer its own code than any other and a rewrite
  // finds the same code and residual (at half a step it could round to the neighbouring code).
  constexpr std::int64_t kMaxFine = (std::int64_t(1) << (kFineCoefficientBits - 1)) - 1;
  const std::int64_t r = std::clamp<std::int64_t>(
      roundHalfAway((w - p - coarse) / std::ldexp(codeStep(code, step, m), -kFineCoefficientBits)), -kMaxFine,
      kMaxFine);
  if (fine) *fine = r;
  return p + fineCoefficientValue(coarse, r, code, step, m, kFineCoefficientBits);
}

/// Sets `sk`'s side and central coefficients to what a reader will decode, and estimates again the cells
/// whose stored patch changed since the last call (every cell the first time; `vertexChanged` flags the
/// vertices whose position or normal changed since, empty if none did): last.moving[c] says whether cell c's
/// stored surface moves by more than the method's shift target (surfaceShiftExceeds) or, in a fitted model,
/// opens a hole the built patch does not have (opensHole).
void estimateMovingCells(const Model& m, Model& sk, const CellFaces& cellFaces, const Chunks& chunks,
                         const std::vector<ChunkSource>& sources, const std::vector<double>& prediction,
                         const ModelFileV2Options& q, const FineCoefficients& fine,
                         const std::vector<std::uint8_t>& vertexChanged, MovingCells& last) {
  const double threshold = m.method == PatchMethod::Paper ? kPaperShiftTarget : kFittedShiftTarget;
  const bool first = last.moving.empty();
  if (first) {
    last.side.assign(prediction.size(), 0.0);
    last.sideRefined.assign(prediction.size(), 0);
    last.centralRefined.assign(sk.cells.size(), 0);
  }
  // A face's stored value is a function of its coefficient, prediction and refinement: coded again only where
  // the last two may have changed (every face the first time), the same numbers as coding every face.
  const bool everyFace = first || m.method == PatchMethod::Paper;
  std::vector<double>& side = last.side;
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    const std::uint64_t base = chunks.list[i].faceBase;
    for (std::size_t f = 0; f < sources[i].side.size(); ++f) {
      const std::size_t k = base + f;
      const std::uint8_t refined = !fine.face.empty() && fine.face[k];
      if (!everyFace && refined == last.sideRefined[k]) continue;
      side[k] = storedCoefficient(sources[i].side[f], prediction[k], q.sideStep, q.sideMantissa, refined);
      last.sideRefined[k] = refined;
    }
  });
  last.moving.resize(sk.cells.size(), 0);
  std::vector<std::uint8_t>& moving = last.moving;
  tbb::parallel_for(std::size_t(0), sk.cells.size(), [&](std::size_t c) {
    ModelCell& cell = sk.cells[c];
    bool changed = first;
    for (std::size_t f = 0; f < 6; ++f) {
      const double w = cellFaces[c][f] == kNone ? 0.0 : side[cellFaces[c][f]];
      changed = changed || !sameBits(w, cell.faceCoefficient[f]);
      cell.faceCoefficient[f] = w;
    }
    const std::uint8_t refined = !fine.cell.empty() && fine.cell[c];
    if (first || refined != last.centralRefined[c]) {
      const double central =
          storedCoefficient(m.cells[c].central, 0.0, q.centralStep, q.centralMantissa, refined);
      changed = changed || !sameBits(central, cell.central);
      cell.central = central;
      last.centralRefined[c] = refined;
    }
    for (int k = 0; !changed && !vertexChanged.empty() && k < cell.numCorners(); ++k)
      changed = vertexChanged[sk.corners[cell.firstCorner + static_cast<std::uint32_t>(k)]] != 0;
    if (!changed) return;
    // sk holds the same cells as m (configurations and pairings): their loops once for both patches.
    const CellLoops loops = m.loops(c);
    const CornerPatch built = m.patch(c, loops), stored = sk.patch(c, loops);
    moving[c] = surfaceShiftExceeds(built, stored, threshold) ||
                (m.method == PatchMethod::Fitted && opensHole(built, stored, cell.config));
  });
}

/// Refines the corners of the cells estimateMovingCells found moving. Returns whether any vertex was newly
/// refined.
bool refineMovingCorners(const Model& m, const Model& sk, Chunks& chunks,
                         const std::vector<ChunkSource>& sources, int positionBits,
                         const std::vector<std::uint8_t>& moving) {
  std::vector<std::uint8_t> keep(sk.vertices.size(), 0);
  for (std::size_t c = 0; c < sk.cells.size(); ++c)
    if (moving[c])
      for (int k = 0; k < sk.cells[c].numCorners(); ++k)
        keep[sk.corners[sk.cells[c].firstCorner + static_cast<std::uint32_t>(k)]] = 1;
  bool added = false;
  for (std::size_t i = 0; i < chunks.list.size(); ++i) {
    ChunkTopology& ch = chunks.list[i];
    for (std::size_t v = 0; v < ch.vertexKey.size(); ++v)
      if (keep[ch.vertexBase + v] && ch.refined[v] != 1) {
        refineVertex(m, chunks.L, positionBits, ch, sources[i], v);
        added = true;
      }
  }
  return added;
}

/// Refines the central and side coefficients of the cells estimateMovingCells found moving. Returns whether
/// any coefficient was newly refined.
bool refineMovingCoefficients(const CellFaces& cellFaces, std::size_t faces,
                              const std::vector<std::uint8_t>& moving, FineCoefficients& fine) {
  fine.cell.resize(moving.size(), 0);
  fine.face.resize(faces, 0);
  bool added = false;
  for (std::size_t c = 0; c < moving.size(); ++c) {
    if (!moving[c]) continue;
    added = added || !fine.cell[c];
    fine.cell[c] = 1;
    for (std::uint32_t fi : cellFaces[c])
      if (fi != kNone) {
        added = added || !fine.face[fi];
        fine.face[fi] = 1;
      }
  }
  return added;
}

/// Fitted models: refines the coefficients that a refined code holds exactly and a plain one does not (those
/// of a model read from a file with refined coefficients), so that writing it again keeps them.
void refineExactCoefficients(const Model& m, const Chunks& chunks, const std::vector<ChunkSource>& sources,
                             const ModelFileV2Options& q, std::size_t faces, FineCoefficients& fine) {
  auto exactOnlyWhenRefined = [](double w, double step, int mantissa) {
    return storedCoefficient(w, 0.0, step, mantissa, false) != w &&
           storedCoefficient(w, 0.0, step, mantissa, true) == w;
  };
  fine.cell.assign(m.cells.size(), 0);
  fine.face.assign(faces, 0);
  tbb::parallel_for(std::size_t(0), m.cells.size(), [&](std::size_t c) {
    fine.cell[c] = exactOnlyWhenRefined(m.cells[c].central, q.centralStep, q.centralMantissa);
  });
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    for (std::size_t f = 0; f < sources[i].side.size(); ++f)
      fine.face[chunks.list[i].faceBase + f] =
          exactOnlyWhenRefined(sources[i].side[f], q.sideStep, q.sideMantissa);
  });
}

/// A chunk's refined coefficients (stream kFineCoefficients): its cells', then its faces'.
void writeFineCoefficients(ChunkTopology& ch, const ChunkSource& src, const Model& m,
                           const std::vector<double>& prediction, const ModelFileV2Options& q,
                           const FineCoefficients& fine) {
  std::vector<std::uint8_t>& out = ch.streams[kFineCoefficients];
  out.push_back(static_cast<std::uint8_t>(kFineCoefficientBits));
  auto put = [&out](std::size_t n, auto&& refined, auto&& residual) {
    std::size_t count = 0;
    for (std::size_t j = 0; j < n; ++j) count += refined(j);
    putVarint(out, count);
    for (std::size_t j = 0, last = 0; j < n; ++j) {
      if (!refined(j)) continue;
      putVarint(out, j - last);
      last = j + 1;
      putVarint(out, zigzag(residual(j)));
    }
  };
  put(
      src.cell.size(), [&](std::size_t j) { return fine.cell[static_cast<std::size_t>(src.cell[j])] != 0; },
      [&](std::size_t j) {
        std::int64_t r = 0;
        storedCoefficient(m.cells[static_cast<std::size_t>(src.cell[j])].central, 0.0, q.centralStep,
                          q.centralMantissa, true, &r);
        return r;
      });
  put(
      src.side.size(), [&](std::size_t f) { return fine.face[ch.faceBase + f] != 0; },
      [&](std::size_t f) {
        std::int64_t r = 0;
        storedCoefficient(src.side[f], prediction[ch.faceBase + f], q.sideStep, q.sideMantissa, true, &r);
        return r;
      });
}

/// normalCode with the prediction's own frame (frameOf: the same bits as the blocks' frames).
void normalCode(const Vec3& pred, const Vec3& n, double step, int axis, std::uint8_t flags, std::int64_t& qu,
                std::int64_t& qv) {
  Vec3 b1, b2;
  frameOf(pred, b1, b2);
  normalCode(pred, b1, b2, n, step, axis, flags, qu, qv);
}

/// normalCode, then, where the reader's correction near the minimal angle to the edge moves the normal by
/// more steps than normalCode searches, a code whose normal codes back to itself, so that a rewrite keeps it.
void stableNormalCode(const Vec3& pred, const Vec3& n, double step, int axis, std::uint8_t flags,
                      std::int64_t& qu, std::int64_t& qv) {
  normalCode(pred, n, step, axis, flags, qu, qv);
  for (int round = 0; round < 8; ++round) {
    const Vec3 decoded = normalFromCode(pred, qu, qv, step, axis, flags);
    std::int64_t ru = 0, rv = 0;
    normalCode(pred, decoded, step, axis, flags, ru, rv);
    if (normalFromCode(pred, ru, rv, step, axis, flags) == decoded) return;
    qu = ru;
    qv = rv;
  }
}

/// What refinedNormalCode last saw for a vertex (its prediction, refinement state and flags; its normal and
/// step do not change) and the state it left. The writer codes the normals again after every round of refined
/// corners, and most vertices' predictions did not change: they keep their codes without the search.
struct NormalCodeInput {
  double px = 0, py = 0, pz = 0;
  std::uint8_t refinedBefore = 0, flags = 0, refinedAfter = 0, valid = 0;
  bool sameAs(const NormalCodeInput& o) const {
    return valid && sameBits(px, o.px) && sameBits(py, o.py) && sameBits(pz, o.pz) &&
           refinedBefore == o.refinedBefore && flags == o.flags;
  }
};

/// The code of a vertex's normal: at the header's step, or for a refined vertex 2^-kRefineBits of it. A
/// vertex whose crossing parameter a plain code holds as well as a refined one (refined = 2) stays refined
/// only when its normal needs the finer step to be held exactly.
void refinedNormalCode(ChunkTopology& ch, std::size_t v, const Vec3& pred, const Vec3& n, double step,
                       std::int64_t& qu, std::int64_t& qv) {
  const int axis = static_cast<int>(ch.vertexKey[v] % 3);
  const std::uint8_t flags = ch.vertexFlags[v];
  const double fineStep = std::ldexp(step, -kRefineBits);
  if (ch.isRefined(v) && ch.refined[v] == 2) {
    normalCode(pred, n, step, axis, flags, qu, qv);
    if (normalFromCode(pred, qu, qv, step, axis, flags) == n) {
      ch.refined[v] = 0;
      return;
    }
    normalCode(pred, n, fineStep, axis, flags, qu, qv);
    ch.refined[v] = normalFromCode(pred, qu, qv, fineStep, axis, flags) == n ? 1 : 0;
  }
  stableNormalCode(pred, n, ch.isRefined(v) ? fineStep : step, axis, flags, qu, qv);
}

void compressStreams(ChunkTopology& ch, int level, std::vector<std::uint8_t>& out) {
  // One context for the chunk's streams (ZSTD_compressCCtx codes exactly as ZSTD_compress, without setting
  // up a context per stream).
  const std::unique_ptr<ZSTD_CCtx, std::size_t (*)(ZSTD_CCtx*)> context(ZSTD_createCCtx(), ZSTD_freeCCtx);
  if (!context) throw Error("zstd: cannot create a compression context");
  for (auto& s : ch.streams) {
    putRaw<std::uint32_t>(out, static_cast<std::uint32_t>(s.size()));
    if (s.empty()) {
      putRaw<std::uint32_t>(out, 0);
      continue;
    }
    std::vector<std::uint8_t> z(ZSTD_compressBound(s.size()));
    const std::size_t n = ZSTD_compressCCtx(context.get(), z.data(), z.size(), s.data(), s.size(), level);
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

/// A chunk's normal codes (a refined vertex's plain code rounded from its finer one, the rest in the refined
/// vertices' stream), corner coefficients, refined and full-precision vertices.
void writeVertexStreams(ChunkTopology& ch, const std::vector<std::array<std::int64_t, 2>>& codes,
                        const Model& sk, std::uint8_t flags) {
  std::size_t refinedCount = 0;
  for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
    std::array<std::int64_t, 2> c = codes[ch.vertexBase + v];
    if (ch.isRefined(v)) {  // the plain code rounded from the finer one, and what is left of it
      ++refinedCount;
      for (int k = 0; k < 2; ++k) {
        const std::int64_t fineCode = c[static_cast<std::size_t>(k)];
        c[static_cast<std::size_t>(k)] = (fineCode + (std::int64_t(1) << (kRefineBits - 1))) >> kRefineBits;
        ch.fine[v][static_cast<std::size_t>(k + 1)] = static_cast<std::int32_t>(
            fineCode - c[static_cast<std::size_t>(k)] * (std::int64_t(1) << kRefineBits));
      }
    }
    putVarint(ch.streams[kNormals], zigzag(c[0]));
    putVarint(ch.streams[kNormals], zigzag(c[1]));
    if (flags & kWeightsStored) putRaw<double>(ch.streams[kWeights], sk.vertices[ch.vertexBase + v].weight);
  }
  if (flags & kRefinementsStored) {
    std::vector<std::uint8_t>& r = ch.streams[kRefined];
    r.push_back(static_cast<std::uint8_t>(kRefineBits));
    putVarint(r, refinedCount);
    for (std::size_t v = 0, last = 0; v < ch.vertexKey.size(); ++v) {
      if (!ch.isRefined(v)) continue;
      putVarint(r, v - last);
      last = v + 1;
      for (std::int32_t f : ch.fine[v]) putVarint(r, zigzag(f));
    }
  }
  ch.streams.resize(static_cast<std::size_t>(chunkStreams(flags)));
  putVarint(ch.streams[kExact], ch.exact.size());
  for (std::size_t k = 0; k < ch.exact.size(); ++k) {
    putVarint(ch.streams[kExact], ch.exact[k] - (k ? ch.exact[k - 1] + 1 : 0));
    putRaw<double>(ch.streams[kExact], ch.exactT[k]);
    for (int a = 0; a < 3; ++a) putRaw<double>(ch.streams[kExact], ch.exactNormal[k][a]);
  }
}

/// The keys of the bricks that get a chunk, increasing: those with cells, and the bricks above them that own
/// their upper edges and faces. Cells come in grid order, so a brick is listed once per run of its cells in a
/// row; only cells on a brick's upper faces look further.
std::vector<std::int64_t> chunkKeys(const Model& m, const Layout& L) {
  std::vector<std::int64_t> keys;
  std::int64_t lastKey = -1, rowJ = -1, rowK = -1, xEnd = 0, bx = 0, by = 0, bz = 0;
  bool topY = false, topZ = false;
  for (const ModelCell& c : m.cells) {
    const I3 idx{c.index[0], c.index[1], c.index[2]};
    if (idx[1] != rowJ || idx[2] != rowK) {
      rowJ = idx[1];
      rowK = idx[2];
      by = rowJ / L.B;
      bz = rowK / L.B;
      topY = rowJ % L.B == L.B - 1;
      topZ = rowK % L.B == L.B - 1;
      xEnd = 0;
    }
    if (idx[0] >= xEnd || idx[0] < xEnd - L.B) {
      bx = idx[0] / L.B;
      xEnd = (bx + 1) * L.B;
    }
    const I3 b{bx, by, bz};
    const std::int64_t own = L.key(b);
    if (own != lastKey) keys.push_back(lastKey = own);
    if (!topY && !topZ && idx[0] != xEnd - 1) continue;
    for (int d = 1; d < 8; ++d) {
      const auto o = cube::vertexCoords(d);
      if ((o[0] && idx[0] != xEnd - 1) || (o[1] && !topY) || (o[2] && !topZ)) continue;
      const I3 pb = L.pointBrick({idx[0] + o[0], idx[1] + o[1], idx[2] + o[2]});
      if (pb != b) keys.push_back(L.key(pb));
    }
  }
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  return keys;
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

/// The writer's refinement (ModelFileV2Options::refineMovingCells). The first round: paper models refine the
/// corners of the cells around ill-conditioned faces, fitted models the coefficients of the cells whose
/// surface the plain codes would move too far. Then, at most three rounds, the corners of the cells whose
/// surface the codes would still move too far; after each change of corners `recode` places the vertices and
/// codes the normals again, and the paper's side predictions are made again. Returns the refined
/// coefficients.
template <class Recode>
FineCoefficients refineCells(const Model& m, Model& sk, const CellFaces& cellFaces, Chunks& chunks,
                             const std::vector<ChunkSource>& sources, std::vector<double>& sidePrediction,
                             const ModelFileV2Options& q, std::size_t faces, Recode&& recode) {
  const bool paper = m.method == PatchMethod::Paper;
  MovingCells moving;
  FineCoefficients fine;
  std::vector<std::uint8_t> changed;  // the vertices the last recode moved or turned (none: empty)
  if (!paper) refineExactCoefficients(m, chunks, sources, q, faces, fine);
  for (int round = 0; q.refineMovingCells && round < 4; ++round) {
    if (paper && round == 0) {
      refineIllConditionedCells(m, sk, cellFaces, chunks, sources, sidePrediction, q.positionBits);
    } else {
      estimateMovingCells(m, sk, cellFaces, chunks, sources, sidePrediction, q, fine, changed, moving);
      changed.clear();
      if (!paper && round == 0) {
        refineMovingCoefficients(cellFaces, faces, moving.moving, fine);
        continue;  // the corners are as they were; the next round estimates the cells whose coefficients
                   // changed
      }
      if (!refineMovingCorners(m, sk, chunks, sources, q.positionBits, moving.moving)) break;
    }
    changed = recode();
    if (paper) sidePrediction = paperSidePrediction(sk, cellFaces, faces);
  }
  return fine;
}

/// The writer's normal codes against the reader's predictions, and the normals (and weights) a reader will
/// have, put in `sk`: code() codes every vertex, recode() after a round of refined corners only what can
/// change.
class NormalCoder {
 public:
  NormalCoder(const Model& m, Model& sk, Chunks& chunks, const std::vector<ChunkSource>& sources,
              const std::vector<LoopNeighbours>& around, int positionBits, double step, bool weights)
      : codes(sk.vertices.size(), {0, 0}),
        m_(m),
        sk_(sk),
        chunks_(chunks),
        sources_(sources),
        around_(around),
        positionBits_(positionBits),
        step_(step),
        weights_(weights),
        lastInput_(sk.vertices.size()) {}

  std::vector<std::array<std::int64_t, 2>> codes;  ///< per vertex of the file, its normal code (u, v)

  /// Codes the vertices of the blocks with a vertex flagged in `only` (global vertex order), or of all.
  void code(const std::vector<std::uint8_t>* only, std::vector<std::uint8_t>* changed = nullptr) {
    decodeNormals(
        sk_, chunks_, around_, true,
        [&](std::size_t i) {
          return [this, i](std::size_t first, NormalBlock& b) { codeBlock(i, first, b); };
        },
        only, changed);
  }

  /// After a round of refined corners only some vertices' normals can change: those that moved, those whose
  /// prediction (from their loop neighbours' positions) moved with them, and those refined since their last
  /// code. Their blocks are coded and decoded again; every other block would repeat its last codes and
  /// normals bit for bit. Returns, per vertex, whether its position or normal changed.
  std::vector<std::uint8_t> recode() {
    std::vector<std::uint8_t> moved(sk_.vertices.size(), 0), again(sk_.vertices.size(), 0);
    movePlacedVertices(chunks_, positionBits_, sk_, moved);
    tbb::parallel_for(std::size_t(0), chunks_.list.size(), [&](std::size_t i) {
      const ChunkTopology& ch = chunks_.list[i];
      for (std::size_t v = 0; v < ch.vertexKey.size(); ++v) {
        const std::size_t g = ch.vertexBase + v;
        bool touched = moved[g] != 0;
        const LoopNeighbours& nbr = around_[g];
        for (int s = 0; s < 4 && !touched; ++s) {
          const std::uint32_t next = nbr.v[static_cast<std::size_t>(2 * s)];
          touched = next != kNone && (moved[next] || moved[nbr.v[static_cast<std::size_t>(2 * s + 1)]]);
        }
        // A vertex whose refinement is as its last code left it keeps that code: searched again from the
        // same prediction, refinedNormalCode gives the same code and refinement (from refinement 2 it ended
        // at 0 with a code that decodes to the normal exactly, which stableNormalCode keeps, or at the code
        // of its own last search).
        const NormalCodeInput& last = lastInput_[g];
        touched = touched ||
                  (sources_[i].vertex[v] >= 0 && !(last.valid && last.refinedAfter == ch.refinedState(v) &&
                                                   last.flags == ch.vertexFlags[v]));
        again[g] = touched;
      }
    });
    code(&again, &moved);
    return moved;
  }

 private:
  const Model& m_;
  Model& sk_;
  Chunks& chunks_;
  const std::vector<ChunkSource>& sources_;
  const std::vector<LoopNeighbours>& around_;
  int positionBits_;
  double step_;
  bool weights_;
  std::vector<NormalCodeInput> lastInput_;

  /// Chooses the codes of a block of chunk i's vertices from their predictions (a vertex whose prediction,
  /// refinement and flags are as at its last search keeps its code) and sets the block's residuals.
  void codeBlock(std::size_t i, std::size_t first, NormalBlock& b) {
    ChunkTopology& ch = chunks_.list[i];
    for (std::size_t k = 0; k < b.count; ++k) {
      const std::size_t v = first + k;
      const std::int64_t mvi = sources_[i].vertex[v];
      std::array<std::int64_t, 2>& c = codes[ch.vertexBase + v];
      if (mvi >= 0) {
        const IsoVertex& mv = m_.vertices[static_cast<std::size_t>(mvi)];
        NormalCodeInput& last = lastInput_[ch.vertexBase + v];
        const NormalCodeInput now{b.px[k], b.py[k], b.pz[k], ch.refinedState(v), ch.vertexFlags[v]};
        if (last.sameAs(now)) {
          if (!ch.refined.empty()) ch.refined[v] = last.refinedAfter;
        } else {
          refinedNormalCode(ch, v, Vec3(now.px, now.py, now.pz), mv.normal, step_, c[0], c[1]);
          last = now;
          last.refinedAfter = ch.refinedState(v);
          last.valid = 1;
        }
        sk_.vertices[ch.vertexBase + v].weight = weights_ ? mv.weight : 1.0;
      }
      // A refined vertex's code is in steps 2^-refineBits as fine.
      const double step = ch.isRefined(v) ? std::ldexp(step_, -ch.refineBits) : step_;
      b.u[k] = static_cast<double>(c[0]) * step;
      b.v[k] = static_cast<double>(c[1]) * step;
    }
  }
};

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
  const std::vector<std::int64_t> keys = chunkKeys(m, L);
  chunks.keys = keys;
  chunks.list.resize(keys.size());
  for (std::size_t i = 0; i < keys.size(); ++i) {
    const std::int64_t k = keys[i];
    setupChunk(L, {k % L.nb[0], (k / L.nb[0]) % L.nb[1], k / (L.nb[0] * L.nb[1])}, chunks.list[i]);
  }
  std::vector<ChunkSource> sources(chunks.list.size());
  tbb::parallel_for(std::size_t(0), chunks.list.size(),
                    [&](std::size_t i) { buildChunkFromModel(m, L, chunks.list[i], sources[i], name); });
  std::uint64_t vb = 0, fb = 0;
  for (ChunkTopology& ch : chunks.list) {
    ch.vertexBase = vb;
    ch.faceBase = fb;
    vb += ch.vertexKey.size();
    fb += ch.faceKey.size();
  }
  // The model as the reader will have it, to code the normals against its predictions.
  Model sk;
  sk.geometry = m.geometry;
  sk.method = m.method;
  for (ChunkTopology& ch : chunks.list) indexCellRows(ch);
  std::vector<LoopNeighbours> around;
  CellFaces cellFaces;
  {
    ModelUse use;  // sk's cells: the stored patches, which the writer checks against the built ones
    fillCells(chunks, sk, around, &cellFaces, &m, &use, true, name);
    tbb::parallel_for(std::size_t(0), chunks.list.size(),
                      [&](std::size_t i) { codeChunkItems(m, L, q, use, chunks.list[i], sources[i], name); });
  }
  const bool paper = m.method == PatchMethod::Paper;
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    refineExactPositions(m, L, q.positionBits, chunks.list[i], sources[i]);
  });
  placeVertices(chunks, q.positionBits, sk);
  const double nStep = std::ldexp(1.0, -q.normalBits);
  // Paper models always list their refined vertices (flag bit 3); fitted ones when they have some.
  std::uint8_t flags = paper ? kSidesStored | kRefinementsStored : kSidesStored;
  for (const ModelCell& c : m.cells)
    if (c.central != 0) flags |= kCentralsStored;
  if (m.method == PatchMethod::Fitted) flags |= kCentralsStored;
  for (const IsoVertex& v : m.vertices)
    if (v.weight != 1.0) flags |= kWeightsStored;
  NormalCoder coder(m, sk, chunks, sources, around, q.positionBits, nStep, (flags & kWeightsStored) != 0);
  coder.code(nullptr);
  std::vector<double> sidePrediction =
      paper ? paperSidePrediction(sk, cellFaces, fb) : std::vector<double>(fb, 0.0);
  const FineCoefficients fine =
      refineCells(m, sk, cellFaces, chunks, sources, sidePrediction, q, fb, [&] { return coder.recode(); });
  if (!paper) {
    for (const ChunkTopology& ch : chunks.list)
      for (std::size_t v = 0; v < ch.vertexKey.size(); ++v)
        if (ch.isRefined(v)) flags |= kRefinementsStored;
    if (fine.any()) flags |= kRefinementsStored | kFineCoefficientsStored;
  }
  std::vector<std::vector<std::uint8_t>> chunkBytes(chunks.list.size());
  tbb::parallel_for(std::size_t(0), chunks.list.size(), [&](std::size_t i) {
    ChunkTopology& ch = chunks.list[i];
    const ChunkSource& src = sources[i];
    // Room for the usual one or two bytes per number, so that the streams seldom grow.
    ch.streams[kNormals].reserve(4 * ch.vertexKey.size());
    ch.streams[kSides].reserve(2 * src.side.size());
    ch.streams[kCentrals].reserve(2 * src.cell.size());
    writeVertexStreams(ch, coder.codes, sk, flags);
    if (flags & kFineCoefficientsStored) writeFineCoefficients(ch, src, m, sidePrediction, q, fine);
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
  ch.sign.assign(static_cast<std::size_t>(r.n[1] * r.n[2]) * ch.words, 0);
  for (std::int64_t row = 0; row < r.n[1] * r.n[2]; ++row) {
    const std::uint64_t code = in.varint();
    const std::uint64_t transitions = code >> 1;
    if (transitions >= static_cast<std::uint64_t>(r.n[0])) in.fail("has a row with too many sign changes");
    Word* out = &ch.sign[static_cast<std::size_t>(row) * ch.words];
    // Each run of points above the isovalue sets its bits; changes come in increasing order.
    std::int64_t x = 0;
    int s = static_cast<int>(code & 1);
    for (std::uint64_t t = 0; t <= transitions; ++t) {
      std::int64_t at = r.n[0];
      if (t < transitions) {
        at = in.byte();
        if (at <= x || at >= r.n[0]) in.fail("has sign changes out of order");
      }
      if (s)
        for (std::size_t w = static_cast<std::size_t>(x >> 6); w <= static_cast<std::size_t>((at - 1) >> 6);
             ++w)
          out[w] |= bitRange(w, x, at);
      x = at;
      s ^= 1;
    }
  }
  in.expectEnd();
}

std::vector<std::uint8_t> decompress(ZSTD_DCtx* context, const std::uint8_t*& at, const std::uint8_t* end,
                                     std::size_t cap, const std::string& where) {
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
  const std::size_t n = ZSTD_decompressDCtx(context, out.data(), raw, at, stored);
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
  if (h.flags > 31) r.fail("unknown flags");
  if ((h.flags & kFineCoefficientsStored) && !(h.flags & kRefinementsStored))
    r.fail("flags: refined coefficients without refined vertices");
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

/// Adds the finer residuals of a chunk's refined coefficients (flag bit 4) to the values read: first the
/// cells', then the faces'. `centralCodes` and `sideCodes` are the codes those values came from.
void readFineCoefficients(ChunkTopology& ch, const FileHeader& h,
                          const std::vector<std::int64_t>& centralCodes,
                          const std::vector<std::int64_t>& sideCodes, const std::string& where) {
  StreamReader fr(&ch.streams[kFineCoefficients], where + ": refined coefficients");
  const int bits = fr.byte();
  if (bits < 1 || bits > 20) fr.fail("has refinement bits out of range");
  auto apply = [&](std::vector<double>& w, const std::vector<std::int64_t>& codes, double step, int m,
                   const char* items) {
    const std::uint64_t n = fr.varint();
    if (n > w.size()) fr.fail(std::string("lists more ") + items + " than the chunk has");
    std::uint64_t next = 0;
    for (std::uint64_t k = 0; k < n; ++k) {
      next += fr.varint();
      if (next >= w.size()) fr.fail(std::string("lists one of the ") + items + " the chunk does not have");
      const auto i = static_cast<std::size_t>(next++);
      const std::int64_t fine = fr.svarint();
      if (fine < -(std::int64_t(1) << bits) || fine > (std::int64_t(1) << bits))
        fr.fail("has a finer code out of range");
      w[i] = fineCoefficientValue(w[i], fine, codes[i], step, m, bits);
      if (!(std::abs(w[i]) <= std::numeric_limits<double>::max())) fr.fail("has a coefficient out of range");
    }
  };
  apply(ch.central, centralCodes, h.q.centralStep, h.q.centralMantissa, "cells");
  apply(ch.side, sideCodes, h.q.sideStep, h.q.sideMantissa, "faces");
  fr.expectEnd();
}

/// A chunk's side coefficients (per owned face; the paper method's residuals against its rule) and central
/// coefficients (per cell), with the finer parts of refined ones.
void readCoefficients(ChunkTopology& ch, const FileHeader& h, const std::string& where) {
  StreamReader sr(&ch.streams[kSides], where + ": side coefficients");
  StreamReader cr(&ch.streams[kCentrals], where + ": central coefficients");
  // Each stream's codes first, then their values; a non-finite value is reported once the stream is read.
  std::vector<std::int64_t> sideCodes, centralCodes;
  auto read = [](StreamReader& in, std::vector<std::int64_t>& codes, std::vector<double>& out, std::size_t n,
                 double step, int m, const char* what) {
    codes.resize(n);
    in.svarints(n, codes.data());
    out.resize(n);
    double* w = out.data();
    bool finite = true;
    for (std::size_t i = 0; i < n; ++i) {
      w[i] = coefficientValue(codes[i], step, m);
      finite &= std::abs(w[i]) <= std::numeric_limits<double>::max();
    }
    if (!finite) in.fail(std::string("has a ") + what + " coefficient out of range");
  };
  if (h.flags & kSidesStored)
    read(sr, sideCodes, ch.side, ch.faceKey.size(), h.q.sideStep, h.q.sideMantissa, "side");
  if (h.flags & kCentralsStored)
    read(cr, centralCodes, ch.central, ch.cells.size(), h.q.centralStep, h.q.centralMantissa, "central");
  sr.expectEnd();
  cr.expectEnd();
  if (h.flags & kFineCoefficientsStored) readFineCoefficients(ch, h, centralCodes, sideCodes, where);
}

/// A chunk's refined vertices: which, and the finer parts of their crossing parameter and normal codes.
void readRefinements(ChunkTopology& ch, int positionBits, const std::string& where) {
  StreamReader rr(&ch.streams[kRefined], where + ": refined vertices");
  ch.refineBits = rr.byte();
  if (ch.refineBits < 1 || ch.refineBits > 20) rr.fail("has refinement bits out of range");
  const std::uint64_t n = rr.varint();
  if (n > ch.vertexKey.size()) rr.fail("lists more vertices than the chunk has");
  ch.refined.assign(ch.vertexKey.size(), 0);
  ch.fine.assign(ch.vertexKey.size(), {0, 0, 0});
  const std::int64_t half = std::int64_t(1) << (ch.refineBits - 1),
                     tUnits = static_cast<std::int64_t>(maxTCode(positionBits)) << ch.refineBits;
  std::uint64_t next = 0;
  for (std::uint64_t k = 0; k < n; ++k) {
    next += rr.varint();
    if (next >= ch.vertexKey.size()) rr.fail("lists a vertex the chunk does not have");
    const auto v = static_cast<std::size_t>(next++);
    ch.refined[v] = 1;
    for (std::int32_t& f : ch.fine[v]) {
      const std::int64_t x = rr.svarint();
      if (x < -2 * half || x > 2 * half) rr.fail("has a finer code out of range");
      f = static_cast<std::int32_t>(x);
    }
    const std::int64_t t = (static_cast<std::int64_t>(ch.tCode[v]) << ch.refineBits) + ch.fine[v][0];
    if (t < 0 || t > tUnits) rr.fail("has a crossing parameter outside its edge");
  }
  rr.expectEnd();
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
                                        10 + 42 * V,
                                        11 + 31 * V,
                                        21 + 15 * (C + F)};
  const int streams = chunkStreams(h.flags);
  ch.streams.resize(static_cast<std::size_t>(streams));
  const std::unique_ptr<ZSTD_DCtx, std::size_t (*)(ZSTD_DCtx*)> context(ZSTD_createDCtx(), ZSTD_freeDCtx);
  if (!context) throw Error(where + ": cannot create a zstd context");
  for (int s = 0; s < streams; ++s)
    ch.streams[s] = decompress(context.get(), at, end, cap[s], where + ", stream " + std::to_string(s) + ",");
  if (at != end) throw Error(where + ": bytes after its last stream");
  StreamReader rows(&ch.streams[kRows], where + ": sign rows");
  decodeRows(ch, rows);
  std::vector<std::uint32_t> nontrivial;
  std::vector<std::uint8_t> configs;
  cellsFromSigns(ch, nontrivial, configs);
  StreamReader ex(&ch.streams[kExceptions], where + ": cell exceptions");
  const std::uint64_t nEx = ex.varint();
  if (nEx > nontrivial.size()) ex.fail("lists more cells than are crossed");
  std::vector<std::uint32_t> skip(nEx);
  std::uint64_t next = 0;
  for (auto& x : skip) {
    next += ex.varint();
    if (next >= static_cast<std::uint64_t>(L.B * L.B * L.B)) ex.fail("lists a cell outside the brick");
    x = packCell(static_cast<std::int64_t>(next) % L.B, static_cast<std::int64_t>(next) / L.B % L.B,
                 static_cast<std::int64_t>(next) / (L.B * L.B));
    ++next;
  }
  ex.expectEnd();
  if (skip.empty()) {
    ch.cells = std::move(nontrivial);
    ch.config = std::move(configs);
  } else {
    std::size_t k = 0;
    for (std::size_t j = 0; j < nontrivial.size(); ++j) {
      while (k < skip.size() && skip[k] < nontrivial[j]) ++k;
      if (k < skip.size() && skip[k] == nontrivial[j]) continue;
      ch.cells.push_back(nontrivial[j]);
      ch.config.push_back(configs[j]);
    }
  }
  if (ch.cells.size() != e.cells)
    throw Error(where + ": its signs give " + std::to_string(ch.cells.size()) +
                " cells, the directory says " + std::to_string(e.cells));
  ownedItems(L, ch);
  ch.sign = {};
  if (ch.vertexKey.size() != e.vertices || ch.faceKey.size() != e.faces)
    throw Error(where + ": its signs do not give the directory's vertex and face counts");
  indexCellRows(ch);
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
    if (!ch.faceAmbiguous[f]) continue;
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
  if (h.flags & kRefinementsStored) readRefinements(ch, h.q.positionBits, where);
  readCoefficients(ch, h, where);
}

/// A chunk's weights and normal codes, read in step with decodeNormals (one call per block, in order).
class NormalCodeReader {
 public:
  NormalCodeReader(const ChunkTopology& ch, const FileHeader& h, Model& m, const std::string& where)
      : ch_(ch),
        m_(m),
        weights_((h.flags & kWeightsStored) != 0),
        limit_((std::int64_t(1) << h.q.normalBits) + 1),
        step_(std::ldexp(1.0, -h.q.normalBits)),
        normals_(&ch.streams[kNormals], where + ": normals"),
        corner_(&ch.streams[kWeights], where + ": corner coefficients") {}
  void operator()(std::size_t first, NormalBlock& b) {
    for (std::size_t k = 0; k < b.count; ++k) {
      const std::size_t v = first + k;
      std::int64_t qu = normals_.svarint(), qv = normals_.svarint();
      if (std::abs(qu) > limit_ || std::abs(qv) > limit_) normals_.fail("has a normal code out of range");
      double step = step_;
      if (ch_.isRefined(v)) {  // the code in the finer steps
        qu = qu * (std::int64_t(1) << ch_.refineBits) + ch_.fine[v][1];
        qv = qv * (std::int64_t(1) << ch_.refineBits) + ch_.fine[v][2];
        step = std::ldexp(step_, -ch_.refineBits);
      }
      b.u[k] = static_cast<double>(qu) * step;
      b.v[k] = static_cast<double>(qv) * step;
      if (weights_) {
        double& w = m_.vertices[ch_.vertexBase + v].weight;
        w = corner_.f64();
        if (!std::isfinite(w)) corner_.fail("has a non-finite corner coefficient");
      }
    }
    if (first + b.count == ch_.vertexKey.size()) {
      normals_.expectEnd();
      corner_.expectEnd();
    }
  }

 private:
  const ChunkTopology& ch_;
  Model& m_;
  bool weights_;
  std::int64_t limit_;
  double step_;
  StreamReader normals_, corner_;
};

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
                                                  "full-precision vertices",
                                                  "refined vertices",
                                                  "refined coefficients"};
  Model m;
  Layout L;
  const FileHeader h = readHeader(file.data(), file.size(), "model", m, L);
  std::vector<std::pair<std::string, std::size_t>> out;
  for (const char* n : kNames) out.push_back({n, 0});
  std::size_t framing = 0;
  for (const DirectoryEntry& e : h.dir) {
    std::size_t at = e.offset;
    for (int s = 0; s < chunkStreams(h.flags); ++s) {
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

ModelTableCounts modelTableCountsV2(const std::uint8_t* data, std::size_t size, const std::string& name) {
  Model m;
  Layout L;
  const FileHeader h = readHeader(data, size, name, m, L);
  ModelTableCounts n;
  n.version = 2;
  for (const DirectoryEntry& e : h.dir) {
    n.cells += e.cells;
    n.vertices += e.vertices;
  }
  n.corners = 4 * n.vertices;
  n.cornersExact = false;
  return n;
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
  const bool paper = m.method == PatchMethod::Paper;
  std::vector<LoopNeighbours> around;
  CellFaces cellFaces;
  fillCells(chunks, m, around, paper ? &cellFaces : nullptr, nullptr, nullptr, true, name);
  placeVertices(chunks, h.q.positionBits, m);
  decodeNormals(m, chunks, around, true, [&](std::size_t i) {
    return NormalCodeReader(chunks.list[i], h, m, chunkName(name, i, h.dir[i], chunks.L.B));
  });
  if (paper) {  // the side coefficients read so far are residuals against the paper's rule
    const std::vector<double> rule = paperSidePrediction(m, cellFaces, faces);
    tbb::parallel_for(std::size_t(0), m.cells.size(), [&](std::size_t c) {
      for (int f = 0; f < 6; ++f) {
        const std::uint32_t fi = cellFaces[c][static_cast<std::size_t>(f)];
        if (fi == kNone) continue;
        double& w = m.cells[c].faceCoefficient[static_cast<std::size_t>(f)];
        w = rule[fi] + w;
        if (!std::isfinite(w))
          throw Error(name + ": damaged model file: a side coefficient of cell " + std::to_string(c) +
                      " is out of range");
      }
    });
  }
  // Vertices no cell uses (crossings next to cells the model leaves out) are dropped.
  if (std::any_of(around.begin(), around.end(), [](const LoopNeighbours& a) {
        return a.v[0] == kNone && a.v[2] == kNone && a.v[4] == kNone && a.v[6] == kNone;
      }))
    dropUnusedVertices(m);
  return m;
}

}  // namespace cip
