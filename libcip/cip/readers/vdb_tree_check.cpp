#include "cip/readers/vdb_tree_check.h"

#include <array>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include "cip/core/error.h"

namespace cip {

namespace {

// Compression flags and per-node value metadata, as OpenVDB stores them (openvdb/io/Compression.h).
constexpr std::uint32_t kZip = 0x1, kActiveMask = 0x2, kBlosc = 0x4;
enum : std::int8_t {
  kNoMaskOrInactiveValues = 0,
  kNoMaskAndMinusBackground = 1,
  kNoMaskAndOneInactiveValue = 2,
  kMaskAndNoInactiveValues = 3,
  kMaskAndOneInactiveValue = 4,
  kMaskAndTwoInactiveValues = 5,
  kNoMaskAndAllValues = 6,
};
constexpr std::uint32_t kNodeMaskCompressionVersion = 222;
/// Log2 of the side of the standard tree's nodes: leaves, lower and upper internal nodes.
constexpr int kLeafLog2 = 3, kLowerLog2 = 4, kUpperLog2 = 5;
/// A blosc chunk starts with a 16-byte header: version, format version, flags, type size, then the
/// uncompressed size, the block size and the compressed size (32-bit little-endian each).
constexpr std::int64_t kBloscHeader = 16;

/// The bits of a node mask (2^(3 log2) bits, stored as 64-bit words).
struct NodeMask {
  std::vector<std::uint64_t> words;
  int count() const {
    int n = 0;
    for (std::uint64_t w : words) n += __builtin_popcountll(w);
    return n;
  }
};

class TreeWalk {
 public:
  TreeWalk(std::istream& is, std::int64_t fileSize, const VdbTreeFormat& format)
      : is_(is), fileSize_(fileSize), format_(format) {}

  void run() {
    if (format_.fileVersion < kNodeMaskCompressionVersion)
      throw Error("VDB format version " + std::to_string(format_.fileVersion) +
                  " is older than 222 (OpenVDB 2.0), the oldest cip reads");
    const std::int64_t countAt = at();
    const auto bufferCount = read<std::int32_t>("the tree's buffer count");
    if (bufferCount != 1)  // OpenVDB only warns and reads on
      fail("the tree's buffer count", "is " + std::to_string(bufferCount) + ", not 1: the file is corrupt",
           countAt);
    // Root: background, tile and child counts, tiles, then children (each an upper internal node). OpenVDB
    // keeps them in a table ordered by origin and reads the buffers in that order.
    skip(format_.valueBytes, "the background value");
    const std::uint32_t numTiles = read<std::uint32_t>("the root's tile count");
    const std::uint32_t numChildren = read<std::uint32_t>("the root's child count");
    const std::int64_t tileBytes = 12 + format_.valueBytes + 1;
    need(static_cast<std::int64_t>(numTiles) * tileBytes, "the root's tiles");
    skip(static_cast<std::int64_t>(numTiles) * tileBytes, "the root's tiles");
    need(static_cast<std::int64_t>(numChildren) * (12 + 2 * maskBytes(kUpperLog2)), "the root's children");
    std::map<std::array<std::int32_t, 3>, std::vector<std::uint16_t>> children;
    for (std::uint32_t n = 0; n < numChildren; ++n) {
      const std::int64_t originAt = at();
      std::array<std::int32_t, 3> origin{};
      for (auto& c : origin) c = read<std::int32_t>("a root child's origin");
      // OpenVDB writes its table's keys: the children's origins, each once and on a multiple of the upper
      // node's side. It would replace (and leak) a child listed twice.
      const std::int32_t side = 1 << (kUpperLog2 + kLowerLog2 + kLeafLog2);
      for (std::int32_t c : origin)
        if (c % side != 0)
          fail("a root child's origin",
               "is not a multiple of " + std::to_string(side) + ": the file is corrupt", originAt);
      if (children.count(origin))
        fail("a root child's origin", "repeats an earlier child's: the file is corrupt", originAt);
      std::vector<std::uint16_t> leaves;  // active values of each leaf, in buffer order
      internalTopology(kUpperLog2, leaves);
      children[origin] = std::move(leaves);
    }
    for (const auto& child : children)
      for (std::uint16_t active : child.second) {
        int count = active;
        if (!format_.seekable) count = loadMask(kLeafLog2, "a leaf's value mask").count();
        values(1 << (3 * kLeafLog2), count, kLeafLog2, "a leaf");
      }
  }

 private:
  std::istream& is_;
  std::int64_t fileSize_;
  VdbTreeFormat format_;

  std::int64_t at() const { return static_cast<std::int64_t>(is_.tellg()); }

  [[noreturn]] void fail(const std::string& what, const std::string& problem, std::int64_t offset) const {
    throw Error(what + " at byte " + std::to_string(offset) + " " + problem);
  }

  /// Throws unless `bytes` more bytes lie inside the file.
  void need(std::int64_t bytes, const char* what) const {
    if (bytes < 0 || bytes > fileSize_ - at())
      fail(what,
           "needs " + std::to_string(bytes) + " bytes, but the file has " + std::to_string(fileSize_) +
               ": it is truncated or corrupt",
           at());
  }
  void skip(std::int64_t bytes, const char* what) {
    need(bytes, what);
    is_.seekg(static_cast<std::streamoff>(bytes), std::ios::cur);
  }
  template <class T>
  T read(const char* what) {
    need(sizeof(T), what);
    T value{};
    is_.read(reinterpret_cast<char*>(&value), sizeof value);
    return value;
  }

  static std::int64_t maskBytes(int log2) { return std::int64_t{1} << (3 * log2 - 3); }
  NodeMask loadMask(int log2, const char* what) {
    NodeMask mask;
    mask.words.resize(static_cast<std::size_t>(maskBytes(log2) / 8));
    need(maskBytes(log2), what);
    is_.read(reinterpret_cast<char*>(mask.words.data()), static_cast<std::streamsize>(maskBytes(log2)));
    return mask;
  }

  /// An internal node's topology (masks, values, children), appending its leaves' active counts.
  void internalTopology(int log2, std::vector<std::uint16_t>& leaves) {
    const NodeMask childMask = loadMask(log2, "an internal node's child mask");
    const NodeMask valueMask = loadMask(log2, "an internal node's value mask");
    values(1 << (3 * log2), valueMask.count(), log2, "an internal node");
    for (std::size_t w = 0; w < childMask.words.size(); ++w)
      for (std::uint64_t bits = childMask.words[w]; bits; bits &= bits - 1) {
        if (log2 - 1 > kLeafLog2) {
          internalTopology(log2 - 1, leaves);
        } else {
          leaves.push_back(static_cast<std::uint16_t>(loadMask(kLeafLog2, "a leaf's value mask").count()));
        }
      }
  }

  /// One node's values as OpenVDB's readCompressedValues reads them: a metadata byte, up to two inactive
  /// values, a selection mask, then the values (only the active ones under mask compression).
  void values(int count, int active, int log2, const char* node) {
    const auto metadata = read<std::int8_t>("a node's value metadata");
    if (metadata == kNoMaskAndOneInactiveValue || metadata == kMaskAndOneInactiveValue ||
        metadata == kMaskAndTwoInactiveValues)
      skip(format_.valueBytes, "an inactive value");
    if (metadata == kMaskAndTwoInactiveValues) skip(format_.valueBytes, "an inactive value");
    if (metadata == kMaskAndNoInactiveValues || metadata == kMaskAndOneInactiveValue ||
        metadata == kMaskAndTwoInactiveValues)
      skip(maskBytes(log2), "a selection mask");
    if ((format_.compression & kActiveMask) && metadata != kNoMaskAndAllValues) count = active;
    if (format_.fromHalf && format_.halfBytes > 0) {
      if (count < 1) return;  // OpenVDB reads nothing then, not even a chunk size
      chunk(static_cast<std::int64_t>(count) * format_.halfBytes, node);
    } else {
      chunk(static_cast<std::int64_t>(count) * format_.valueBytes, node);
    }
  }

  /// One chunk of `bytes` bytes of values: raw, or a 64-bit stored size (negative: raw) and the zip or blosc
  /// data.
  void chunk(std::int64_t bytes, const char* node) {
    const bool blosc = format_.compression & kBlosc, zip = format_.compression & kZip;
    if (!blosc && !zip) {
      skip(bytes, node);
      return;
    }
    const std::int64_t start = at();
    const auto stored = read<std::int64_t>("a chunk size");
    const std::string what = std::string("the values of ") + node;
    if (stored <= 0) {
      if (stored != -bytes)
        fail(what,
             "have the stored size " + std::to_string(stored) + ", but uncompressed they take " +
                 std::to_string(bytes) + " bytes (stored as -" + std::to_string(bytes) +
                 "): the file is corrupt",
             start);
      skip(bytes, "an uncompressed chunk");
      return;
    }
    need(stored, "a compressed chunk");
    if (blosc) {
      if (stored < kBloscHeader)
        fail(what, "are a blosc chunk shorter than its header: the file is corrupt", start);
      const BloscSizes header = readBloscHeader(is_);
      if (header.uncompressed != bytes || header.compressed > stored || header.compressed < kBloscHeader)
        fail(what,
             "are a blosc chunk of " + std::to_string(stored) + " bytes whose header claims " +
                 std::to_string(header.compressed) + " compressed and " +
                 std::to_string(header.uncompressed) + " uncompressed bytes where " + std::to_string(bytes) +
                 " are needed: the file is corrupt",
             start);
      skip(stored - kBloscHeader, "a compressed chunk");
    } else {
      skip(stored, "a compressed chunk");
    }
  }
};

}  // namespace

BloscSizes readBloscHeader(std::istream& is) {
  unsigned char header[kBloscHeader];
  is.read(reinterpret_cast<char*>(header), kBloscHeader);
  auto field = [&](int k) {
    return std::uint32_t{header[k]} | std::uint32_t{header[k + 1]} << 8 | std::uint32_t{header[k + 2]} << 16 |
           std::uint32_t{header[k + 3]} << 24;
  };
  // Version, format version, flags and type size, then the uncompressed size, the block size and the
  // compressed size.
  return {field(4), field(12)};
}

void checkVdbTree(std::istream& is, std::int64_t fileSize, const VdbTreeFormat& format) {
  TreeWalk(is, fileSize, format).run();
}

}  // namespace cip
