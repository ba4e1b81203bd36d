// The VDB reader's OpenVDB side, built as the module libcip_vdb.so (cip/core/module_loader.h) that the
// functions of readers/vdb_reader.h load on first use. OpenVDB itself is used only here.
#include <openvdb/io/GridDescriptor.h>
#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <mutex>
#include <set>

#include "cip/core/error.h"
#include "cip/core/module_loader.h"
#include "cip/readers/vdb_reader.h"
#include "cip/readers/vdb_tree_check.h"
#include "cip/readers/volume_input.h"

namespace cip {

namespace {

void initializeOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] { openvdb::initialize(); });
}

std::string gridClassName(openvdb::GridClass c) {
  switch (c) {
    case openvdb::GRID_LEVEL_SET:
      return "level set";
    case openvdb::GRID_FOG_VOLUME:
      return "fog volume";
    case openvdb::GRID_STAGGERED:
      return "staggered";
    default:
      return "unknown";
  }
}

std::string listing(const std::vector<VdbGridInfo>& infos) {
  std::string s;
  for (const auto& g : infos) s += (s.empty() ? "" : ", ") + ("'" + g.name + "' (" + g.valueType + ")");
  return s.empty() ? "none" : s;
}

/// OpenVDB reads strings and metadata values as a 32-bit size followed by that many bytes, and allocates the
/// size before it reads: a 589-byte file made it allocate 4 GB. These checks walk such fields ahead of
/// OpenVDB, reject a size larger than the rest of the file, and return to where they started. skipSized
/// leaves the stream after the field and returns its size.
std::uint32_t skipSized(std::istream& is, std::int64_t fileSize, const char* what) {
  std::uint32_t n = 0;
  is.read(reinterpret_cast<char*>(&n), sizeof n);
  const std::int64_t at = static_cast<std::int64_t>(is.tellg());
  if (static_cast<std::int64_t>(n) > fileSize - at)
    throw Error(std::string(what) + " at byte " + std::to_string(at) + " claims " + std::to_string(n) +
                " bytes, but the file has " + std::to_string(fileSize) + ": it is truncated or corrupt");
  is.seekg(static_cast<std::streamoff>(n), std::ios::cur);
  return n;
}

/// A size-prefixed string, checked as skipSized does.
std::string readSized(std::istream& is, std::int64_t fileSize, const char* what) {
  const std::uint32_t n = skipSized(is, fileSize, what);
  std::string s(n, '\0');
  is.seekg(-static_cast<std::streamoff>(n), std::ios::cur);
  is.read(s.data(), static_cast<std::streamsize>(n));
  return s;
}

/// Checks a metadata value of type `type` stored in `bytes` bytes from byte `at` (the stream is left where it
/// was). OpenVDB reads a value of a fixed-size type (bool, numbers, vectors, matrices) as that many bytes
/// whatever the stored size says, and its table for delayed loading by counts inside the value: a value that
/// does not match would make OpenVDB read past it, away from where these checks looked, or allocate by a
/// count.
void checkMetadataValue(std::istream& is, const std::string& type, std::int64_t at, std::uint32_t bytes,
                        std::int64_t fileSize) {
  static const std::map<std::string, std::uint32_t> kFixedBytes{
      {"bool", 1},   {"int32", 4},  {"int64", 8},  {"float", 4},  {"double", 8}, {"vec2i", 8},
      {"vec2s", 8},  {"vec2d", 16}, {"vec3i", 12}, {"vec3s", 12}, {"vec3d", 24}, {"vec4i", 16},
      {"vec4s", 16}, {"vec4d", 32}, {"mat4s", 64}, {"mat4d", 128}};
  auto corrupt = [&](const std::string& problem) {
    throw Error("a metadata value of type " + type + " at byte " + std::to_string(at) + " " + problem +
                ": the file is corrupt");
  };
  if (const auto it = kFixedBytes.find(type); it != kFixedBytes.end()) {
    if (bytes != it->second)
      corrupt("has " + std::to_string(bytes) + " bytes instead of " + std::to_string(it->second));
    return;
  }
  if (type != "__delayedload" || bytes == 0) return;
  // A leaf count, then a table of one byte per leaf and one of eight bytes per leaf (its stored size may be
  // 0xffffffff: no table), each raw (stored size 0) or a blosc chunk of the stored size.
  const std::streampos end = is.tellg();
  is.seekg(at);
  std::int64_t left = bytes;
  auto word = [&] {
    if (left < 4) corrupt("ends inside its fields");
    std::uint32_t v = 0;
    is.read(reinterpret_cast<char*>(&v), sizeof v);
    left -= 4;
    return v;
  };
  const std::uint32_t count = word();
  if (static_cast<std::int64_t>(count) > fileSize / 64)  // a leaf takes at least its 64-byte mask
    corrupt("lists " + std::to_string(count) + " leaves, more than the file can hold");
  auto table = [&](std::int64_t entryBytes, bool optional) {
    const std::uint32_t stored = word();
    if (optional && stored == 0xffffffffu) return;
    const std::int64_t raw = entryBytes * count;
    if (stored == 0) {
      if (raw > left) corrupt("ends inside its tables");
      is.seekg(static_cast<std::streamoff>(raw), std::ios::cur);
      left -= raw;
      return;
    }
    if (stored > left || stored < 16)
      corrupt("has a compressed table of " + std::to_string(stored) + " bytes");
    // OpenVDB pads tables under 128 bytes to 128 before compressing them.
    const BloscSizes header = readBloscHeader(is);
    if (header.uncompressed < raw || header.uncompressed > std::max<std::int64_t>(raw, 128) ||
        header.compressed > stored)
      corrupt("has a compressed table whose header does not match it");
    is.seekg(static_cast<std::streamoff>(stored) - 16, std::ios::cur);
    left -= stored;
  };
  table(1, false);
  table(8, true);
  is.seekg(end);
}

/// Checks a metadata map (count; per entry a name, a type name and a size-prefixed value).
void checkMetaMap(std::istream& is, std::int64_t fileSize) {
  const std::streampos start = is.tellg();
  std::uint32_t count = 0;
  is.read(reinterpret_cast<char*>(&count), sizeof count);
  for (std::uint32_t i = 0; i < count; ++i) {  // each entry takes at least 12 bytes: bounded by the file
    skipSized(is, fileSize, "a metadata name");
    const std::string type = readSized(is, fileSize, "a metadata type name");
    const std::int64_t valueAt = static_cast<std::int64_t>(is.tellg()) + 4;
    const std::uint32_t bytes = skipSized(is, fileSize, "a metadata value");
    checkMetadataValue(is, type, valueAt, bytes, fileSize);
  }
  is.seekg(start);
}

/// Checks the strings of a grid descriptor (unique name, type name, and the instance parent's name).
void checkGridDescriptor(std::istream& is, std::int64_t fileSize) {
  const std::streampos start = is.tellg();
  skipSized(is, fileSize, "a grid name");
  skipSized(is, fileSize, "a grid type name");
  if (openvdb::io::getFormatVersion(is) >= openvdb::OPENVDB_FILE_VERSION_GRID_INSTANCING)
    skipSized(is, fileSize, "an instance parent name");
  is.seekg(start);
}

/// Reads the one grid wanted from a VDB stream, skipping the others by their stored end offsets (files
/// written by OpenVDB's File have them; for streams without offsets, earlier grids are read and dropped). A
/// grid that shares its tree with another (an instance) is read together with every other grid, as OpenVDB's
/// Stream does.
class GridSelector : public openvdb::io::Archive {
 public:
  openvdb::io::Archive::Ptr copy() const override { return std::make_shared<GridSelector>(*this); }

  /// `wanted` empty: the first float or double grid. Fills `infos` with the grids seen (all of them unless
  /// the wanted one was found first). Returns nullptr when no grid matches. `size` is the stream's length in
  /// bytes: a grid whose stored offsets lie beyond it is rejected before OpenVDB reads its tree, which in a
  /// truncated file reads past the end and can allocate gigabytes for a few kilobytes of input.
  openvdb::GridBase::Ptr read(std::istream& is, std::int64_t size, const std::string& wanted,
                              std::vector<VdbGridInfo>& infos) {
    const std::int32_t count = readUpToGrids(is, size);
    for (std::int32_t n = 0; n < count; ++n) {
      openvdb::io::GridDescriptor gd;
      openvdb::GridBase::Ptr grid = readDescriptor(is, size, gd);
      if (!grid) return nullptr;
      const std::string valueType = grid->valueType();
      infos.push_back({gd.gridName(), valueType, "unknown"});
      const bool scalar = valueType == "float" || valueType == "double";
      const bool match = wanted.empty() ? scalar : gd.gridName() == wanted;
      if (match && gd.isInstance()) return readEverything(is, size, gd, infos);
      if (match) {
        const std::streampos start = is.tellg();
        checkGrid(is, size, gd);
        is.seekg(start);
        openvdb::io::Archive::readGrid(grid, gd, is);
        infos.back().gridClass = gridClassName(grid->getGridClass());
        return grid;
      }
      if (inputHasGridOffsets()) {
        gd.seekToEnd(is);
      } else {
        infos.back().gridClass = gridClassName(checkGrid(is, size, gd)->getGridClass());
      }
    }
    return nullptr;
  }

  /// Name, value type and class of every grid, from the grids' metadata (a stream without grid offsets is
  /// read whole).
  std::vector<VdbGridInfo> list(std::istream& is, std::int64_t size) {
    std::vector<VdbGridInfo> infos;
    const std::int32_t count = readUpToGrids(is, size);
    for (std::int32_t n = 0; n < count; ++n) {
      openvdb::io::GridDescriptor gd;
      openvdb::GridBase::Ptr grid = readDescriptor(is, size, gd);
      if (!grid) break;
      if (inputHasGridOffsets()) {
        readGridMetadata(is, size, *grid);
        gd.seekToEnd(is);
      } else {
        grid = checkGrid(is, size, gd);
      }
      infos.push_back({gd.gridName(), grid->valueType(), gridClassName(grid->getGridClass())});
    }
    return infos;
  }

 private:
  /// The stream's metadata (OpenVDB keeps a plain pointer to it in the stream while it is read).
  openvdb::io::StreamMetadata::Ptr streamMetadata_;

  /// Reads the header and the file's metadata; returns the number of grids.
  std::int32_t readUpToGrids(std::istream& is, std::int64_t size) {
    readHeader(is);
    streamMetadata_ = std::make_shared<openvdb::io::StreamMetadata>();
    openvdb::io::setStreamMetadataPtr(is, streamMetadata_, /*transfer=*/false);
    openvdb::io::setVersion(is, libraryVersion(), fileVersion());
    openvdb::io::setDataCompression(is, compression());
    openvdb::MetaMap fileMeta;
    checkMetaMap(is, size);
    fileMeta.readMeta(is);
    return readGridCount(is);
  }

  /// Reads the next grid descriptor into `gd` and returns an empty grid of its type (OpenVDB throws for
  /// unknown types). A grid whose stored offsets lie beyond the end of the file is rejected here.
  openvdb::GridBase::Ptr readDescriptor(std::istream& is, std::int64_t size,
                                        openvdb::io::GridDescriptor& gd) {
    checkGridDescriptor(is, size);
    openvdb::GridBase::Ptr grid = gd.read(is);
    const bool blockInside =  // an instance shares another grid's tree and stores no block of its own
        gd.isInstance() || (gd.getGridPos() <= gd.getBlockPos() && gd.getBlockPos() <= gd.getEndPos());
    if (inputHasGridOffsets() &&
        !(blockInside && gd.getGridPos() <= gd.getEndPos() && gd.getEndPos() <= size)) {
      throw Error("grid '" + gd.gridName() + "' is stored up to byte " + std::to_string(gd.getEndPos()) +
                  " (offsets " + std::to_string(gd.getGridPos()) + ", " + std::to_string(gd.getBlockPos()) +
                  "), but the file has " + std::to_string(size) + " bytes: it is truncated or corrupt");
    }
    return grid;
  }

  /// Reads the compression flags at the grid's start (into the stream's state) and its metadata into `grid`,
  /// checking the metadata's sizes first.
  static void readGridMetadata(std::istream& is, std::int64_t fileSize, openvdb::GridBase& grid) {
    readGridCompression(is);
    checkMetaMap(is, fileSize);
    grid.readMeta(is);
  }

  /// Checks the grid that starts at the stream's position (its compression flags) through its end, where it
  /// leaves the stream: the sizes in its metadata and transform, then its tree (checkVdbTree; an instance has
  /// none). Returns a grid of the descriptor's type holding the grid's metadata and transform.
  openvdb::GridBase::Ptr checkGrid(std::istream& is, std::int64_t size,
                                   const openvdb::io::GridDescriptor& gd) {
    openvdb::GridBase::Ptr grid = openvdb::GridBase::createGrid(gd.gridType());
    grid->setSaveFloatAsHalf(gd.saveFloatAsHalf());
    readGridMetadata(is, size, *grid);
    if (fileVersion() < openvdb::OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION)
      throw Error("VDB format version " + std::to_string(fileVersion()) +
                  " is older than 222 (OpenVDB 2.0), the oldest cip reads");
    {
      const std::streampos start = is.tellg();
      skipSized(is, size, "a transform's map type name");
      is.seekg(start);
    }
    grid->readTransform(is);
    if (gd.isInstance()) return grid;
    // Bytes per value at full precision and as half floats (0: no half form), by tree type.
    static const std::map<std::string, std::pair<int, int>> kValueBytes{
        {"Tree_float_5_4_3", {4, 2}},  {"Tree_double_5_4_3", {8, 2}}, {"Tree_vec3s_5_4_3", {12, 6}},
        {"Tree_vec3d_5_4_3", {24, 6}}, {"Tree_int32_5_4_3", {4, 0}},  {"Tree_int64_5_4_3", {8, 0}},
        {"Tree_vec3i_5_4_3", {12, 0}}};
    const auto it = kValueBytes.find(grid->type());
    if (it == kValueBytes.end())
      throw Error("grid '" + gd.gridName() + "' has a tree of type " + grid->type() +
                  ", which cip cannot check before reading (it reads float and double grids, and passes over "
                  "float, double, int32, int64 and vec3 grids in files without grid offsets)");
    VdbTreeFormat format;
    format.fileVersion = fileVersion();
    format.compression = openvdb::io::getDataCompression(is);
    format.valueBytes = it->second.first;
    format.halfBytes = it->second.second;
    format.fromHalf = grid->saveFloatAsHalf();
    format.seekable = streamMetadata_->seekable();
    checkVdbTree(is, size, format);
    return grid;
  }

  /// Fallback for instances: check every grid, then read the whole stream again from the start with OpenVDB's
  /// Stream.
  openvdb::GridBase::Ptr readEverything(std::istream& is, std::int64_t size,
                                        const openvdb::io::GridDescriptor& wanted,
                                        std::vector<VdbGridInfo>& infos) {
    is.clear();
    is.seekg(0);
    const std::int32_t count = readUpToGrids(is, size);
    for (std::int32_t n = 0; n < count; ++n) {
      openvdb::io::GridDescriptor gd;
      readDescriptor(is, size, gd);
      checkGrid(is, size, gd);
      if (inputHasGridOffsets()) gd.seekToEnd(is);
    }
    is.clear();
    is.seekg(0);
    openvdb::io::Stream stream(is, /*delayLoad=*/false);
    openvdb::GridBase::Ptr found;
    infos.clear();
    for (const auto& g : *stream.getGrids()) {
      infos.push_back({g->getName(), g->valueType(), gridClassName(g->getGridClass())});
      if (!found && g->getName() == wanted.gridName()) found = g;
    }
    return found;
  }
};

using BrickKey = std::array<std::int64_t, 3>;

/// The spacing and direction of a grid's transform, which must be linear (any rotation, flip or shear):
/// OpenVDB multiplies row vectors, so row a of its matrix is the world step of one index along axis a.
GridGeometry vdbAxes(const std::string& path, const std::string& name, const openvdb::math::Transform& xf) {
  if (!xf.isLinear())
    throw Error(path + ": grid '" + name + "' has a non-linear (frustum) transform; not supported");
  const openvdb::math::Mat4d m = xf.baseMap()->getAffineMap()->getMat4();
  Mat3 columns;
  for (int a = 0; a < 3; ++a)
    for (int w = 0; w < 3; ++w) columns(w, a) = m[a][w];
  GridGeometry g;
  setAxes(g, columns, (path + ": grid '" + name + "' transform").c_str());
  if (g.axisAligned()) g.direction = Mat3::Identity();  // exactly, for the files that were always read
  return g;
}

/// The global grid: the active box plus one point on every side (all cells with an active corner lie
/// inside), as its lowest VDB coordinate and its dims. Its grid keys (point index * 3 + axis) must fit 64
/// bits and each axis a model's 32-bit cell index.
struct GlobalBox {
  std::array<std::int64_t, 3> lo, dims;
};

GlobalBox globalBox(const std::string& path, const std::string& name, const openvdb::CoordBBox& active) {
  GlobalBox box;
  for (int a = 0; a < 3; ++a) {
    box.lo[a] = static_cast<std::int64_t>(active.min()[a]) - 1;
    box.dims[a] = static_cast<std::int64_t>(active.max()[a]) + 1 - box.lo[a] + 1;
  }
  try {
    checkedVolumeSize(box.dims, 3, std::numeric_limits<std::size_t>::max());
  } catch (const Error& e) {
    throw Error(path + ": grid '" + name + "': " + e.what());
  }
  for (int a = 0; a < 3; ++a) {
    if (box.dims[a] > (std::int64_t(1) << 32)) {
      throw Error(path + ": grid '" + name + "' spans " + std::to_string(box.dims[a]) + " voxels on axis " +
                  std::to_string(a) + ", more than a model can index");
    }
  }
  return box;
}

/// How the global grid's cells are cut into bricks: brick (x,y,z) owns the cells [x*B, (x+1)*B) along x (and
/// so on), clipped to the grid, and holds an apron of up to `apron` points around them where the grid goes
/// on.
struct BrickLayout {
  std::int64_t B;                     ///< cells per brick side
  std::int64_t apron;                 ///< points around the owned cells
  std::array<std::int64_t, 3> dims;   ///< of the global grid
  std::array<std::int64_t, 3> cells;  ///< of the global grid (dims - 1)

  BrickLayout(const std::string& path, const std::array<std::int64_t, 3>& globalDims,
              const VdbReadOptions& options)
      : B(options.brickCells), apron(options.apron), dims(globalDims) {
    if (B < 1) throw Error(path + ": brick size must be at least 1 cell");
    for (int a = 0; a < 3; ++a) cells[a] = dims[a] - 1;
    if (options.apron < 1 || options.apron > 64) throw Error(path + ": brick apron must be 1 to 64 points");
  }

  /// Brick `k`'s placement in the global grid into `brick`, its dims into `bdims`; returns its point count.
  std::uint64_t place(const BrickKey& k, GridBrick& brick, std::array<std::int64_t, 3>& bdims) const {
    for (int a = 0; a < 3; ++a) {
      std::int64_t c0 = k[a] * B, c1 = std::min(c0 + B, cells[a]);  // owned cells [c0, c1)
      std::int64_t apronLo = std::min(apron, c0);
      std::int64_t apronHi = std::min(apron, dims[a] - 1 - c1);
      brick.offset[a] = c0 - apronLo;
      brick.cellBegin[a] = apronLo;
      brick.cellEnd[a] = apronLo + (c1 - c0);
      bdims[a] = (c1 - c0) + 1 + apronLo + apronHi;
    }
    return static_cast<std::uint64_t>(bdims[0] * bdims[1] * bdims[2]);
  }
};

/// The bricks owning a cell with an active corner: an active point p (global) is a corner of cells p-1 and p
/// per axis. Their samples are counted as they are found, and the search stops once they exceed the limit: a
/// small file can hold active tiles that span more bricks than memory (a set entry per brick).
class ActiveBricks {
 public:
  ActiveBricks(const BrickLayout& layout, std::uint64_t maxPoints) : layout_(layout), maxPoints_(maxPoints) {}

  /// Adds the bricks of the cells with a corner in the box [pmin, pmax] of global points; false once the
  /// bricks found hold more than the limit.
  bool addRange(const std::array<std::int64_t, 3>& pmin, const std::array<std::int64_t, 3>& pmax) {
    std::array<std::int64_t, 3> b0, b1;
    for (int a = 0; a < 3; ++a) {
      b0[a] = std::max<std::int64_t>(pmin[a] - 1, 0) / layout_.B;
      b1[a] = std::min<std::int64_t>(pmax[a], layout_.cells[a] - 1) / layout_.B;
    }
    if (b0 == b1) {
      if (b0 == last_) return true;
      last_ = b0;
      return add(b0);
    }
    for (std::int64_t z = b0[2]; z <= b1[2]; ++z)
      for (std::int64_t y = b0[1]; y <= b1[1]; ++y)
        for (std::int64_t x = b0[0]; x <= b1[0]; ++x)
          if (!add({x, y, z})) return false;
    return true;
  }

  /// The keys found, moved out.
  std::set<BrickKey> takeKeys() { return std::move(keys_); }

 private:
  bool add(const BrickKey& k) {
    GridBrick unused;
    std::array<std::int64_t, 3> bdims;
    if (keys_.insert(k).second) totalPoints_ += layout_.place(k, unused, bdims);
    return totalPoints_ <= maxPoints_;
  }

  const BrickLayout& layout_;
  const std::uint64_t maxPoints_;
  std::uint64_t totalPoints_ = 0;
  std::set<BrickKey> keys_;
  BrickKey last_{-1, -1, -1};  ///< the brick of the previous single-brick range
};

/// The keys of the bricks `grid`'s active values need (ActiveBricks), `lo` being the global grid's lowest
/// VDB coordinate. Throws when their samples would exceed `maxBytes`.
template <typename GridT>
std::set<BrickKey> activeBrickKeys(const std::string& path, const GridT& grid,
                                   const openvdb::CoordBBox& active, const std::array<std::int64_t, 3>& lo,
                                   const BrickLayout& layout, std::size_t maxBytes) {
  ActiveBricks bricks(layout, maxBytes / sizeof(double));
  bool complete = true;
  for (auto it = grid.cbeginValueOn(); it && complete; ++it) {
    openvdb::CoordBBox box;
    if (it.isVoxelValue()) {
      box = openvdb::CoordBBox(it.getCoord(), it.getCoord());
    } else {
      it.getBoundingBox(box);
      box.intersect(active);
    }
    std::array<std::int64_t, 3> pmin, pmax;
    for (int a = 0; a < 3; ++a) {
      pmin[a] = static_cast<std::int64_t>(box.min()[a]) - lo[a];
      pmax[a] = static_cast<std::int64_t>(box.max()[a]) - lo[a];
    }
    complete = bricks.addRange(pmin, pmax);
  }
  if (!complete) {
    throw Error(path + ": grid '" + grid.getName() + "' needs more dense bricks than the " +
                std::to_string(maxBytes >> 20) + " MiB allowed");
  }
  return bricks.takeKeys();
}

/// The bricks of `keys`, placed and with their grids allocated (samples not yet read).
SparseVolume allocateBricks(const std::set<BrickKey>& keys, const BrickLayout& layout, const Vec3& spacing,
                            std::size_t maxBytes) {
  SparseVolume volume;
  volume.bricks.resize(keys.size());
  volume.grids.resize(keys.size());
  std::size_t next = 0;
  for (const BrickKey& k : keys) {
    GridBrick& brick = volume.bricks[next];
    std::array<std::int64_t, 3> bdims;
    layout.place(k, brick, bdims);
    DenseGrid& g = volume.grids[next++];
    g.allocate(bdims, maxBytes);
    g.geometry.spacing = spacing;
    brick.grid = &g;
  }
  return volume;
}

/// Each brick's samples and world origin from `grid`, in parallel; `lo`: the global grid's lowest VDB
/// coordinate.
template <typename GridT>
void readBricks(const GridT& grid, const std::array<std::int64_t, 3>& lo, const Vec3& origin,
                bool axisAligned, SparseVolume& volume) {
  const openvdb::math::Transform& xf = grid.transform();
  tbb::parallel_for(
      tbb::blocked_range<std::size_t>(0, volume.bricks.size()),
      [&](const tbb::blocked_range<std::size_t>& r) {
        auto acc = grid.getConstAccessor();
        for (std::size_t b = r.begin(); b != r.end(); ++b) {
          const GridBrick& brick = volume.bricks[b];
          DenseGrid& g = volume.grids[b];
          const auto& d = g.geometry.dims;
          Vec3 start(static_cast<double>(lo[0] + brick.offset[0]),
                     static_cast<double>(lo[1] + brick.offset[1]),
                     static_cast<double>(lo[2] + brick.offset[2]));
          // The brick's place in the grid frame: where the transform puts its first
          // point when the grid is axis-aligned; else (the direction is the whole
          // volume's) the volume's origin plus its offset times the spacing.
          const openvdb::Vec3d w = xf.indexToWorld(openvdb::Vec3d(start[0], start[1], start[2]));
          g.geometry.origin =
              axisAligned
                  ? Vec3(w[0], w[1], w[2])
                  : Vec3(origin + g.geometry.spacing.cwiseProduct(start - Vec3(static_cast<double>(lo[0]),
                                                                               static_cast<double>(lo[1]),
                                                                               static_cast<double>(lo[2]))));
          std::size_t n = 0;
          for (std::int64_t k = 0; k < d[2]; ++k)
            for (std::int64_t j = 0; j < d[1]; ++j)
              for (std::int64_t i = 0; i < d[0]; ++i) {
                openvdb::Coord c(static_cast<openvdb::Int32>(lo[0] + brick.offset[0] + i),
                                 static_cast<openvdb::Int32>(lo[1] + brick.offset[1] + j),
                                 static_cast<openvdb::Int32>(lo[2] + brick.offset[2] + k));
                g.values[n++] = static_cast<double>(acc.getValue(c));
              }
        }
      });
}

/// A VDB grid as bricks of dense samples around its active values: the placement checked, the bricks found,
/// allocated and read, the whole described.
template <typename GridT>
SparseVolume bricksOf(const std::string& path, const GridT& grid, const VdbReadOptions& options,
                      const std::string& typeName) {
  const std::string name = grid.getName();
  const openvdb::math::Transform& xf = grid.transform();
  const GridGeometry axes = vdbAxes(path, name, xf);
  const Vec3& spacing = axes.spacing;
  const openvdb::CoordBBox active = grid.evalActiveVoxelBoundingBox();
  if (active.empty()) throw Error(path + ": grid '" + name + "' has no active voxels");
  const GlobalBox global = globalBox(path, name, active);
  const BrickLayout layout(path, global.dims, options);
  const std::set<BrickKey> keys = activeBrickKeys(path, grid, active, global.lo, layout, options.maxBytes);
  SparseVolume volume = allocateBricks(keys, layout, spacing, options.maxBytes);
  const auto& lo = global.lo;
  const openvdb::Vec3d origin = xf.indexToWorld(
      openvdb::Vec3d(static_cast<double>(lo[0]), static_cast<double>(lo[1]), static_cast<double>(lo[2])));
  readBricks(grid, global.lo, Vec3(origin[0], origin[1], origin[2]), axes.axisAligned(), volume);
  volume.geometry.dims = global.dims;
  volume.geometry.origin = Vec3(origin[0], origin[1], origin[2]);
  volume.geometry.spacing = spacing;
  volume.geometry.direction = axes.direction;
  volume.isLevelSet = grid.getGridClass() == openvdb::GRID_LEVEL_SET;
  volume.background = static_cast<double>(grid.background());
  volume.description = baseName(path) + " grid " + name + " (VDB " + typeName + " " +
                       (volume.isLevelSet ? "level set" : gridClassName(grid.getGridClass())) +
                       ", active box " + std::to_string(active.dim()[0]) + "x" +
                       std::to_string(active.dim()[1]) + "x" + std::to_string(active.dim()[2]) + ", " +
                       std::to_string(grid.activeVoxelCount()) + " active voxels)";
  return volume;
}

/// Runs `read(stream, size)` on the file opened as a stream that throws at its end (OpenVDB does not notice a
/// file that ends early: its tree would silently miss values), turning every failure into an Error naming the
/// file.
template <class Read>
auto readVdbStream(const std::string& path, Read&& read) {
  const auto size = static_cast<std::int64_t>(fileSizeOf(path));
  initializeOpenVdb();
  try {
    std::ifstream in(path, std::ios::binary);
    if (!in) throw Error("cannot open");
    in.exceptions(std::ios::badbit | std::ios::failbit);
    return read(in, size);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  } catch (const openvdb::Exception& e) {
    throw Error(path + ": cannot read VDB file: " + e.what());
  } catch (const std::ios_base::failure&) {
    throw Error(path + ": cannot read VDB file: it is truncated or corrupt");
  } catch (const std::exception& e) {
    // Corrupt files can also make OpenVDB fail inside the standard library (bad sizes, allocation failures).
    throw Error(path + ": cannot read VDB file (corrupt?): " + e.what());
  }
}

std::vector<VdbGridInfo> listGrids(const std::string& path) {
  return readVdbStream(path,
                       [](std::istream& in, std::int64_t size) { return GridSelector().list(in, size); });
}

SparseVolume readScalarGrid(const std::string& path, const VdbReadOptions& options) {
  std::vector<VdbGridInfo> infos;
  openvdb::GridBase::Ptr base = readVdbStream(path, [&](std::istream& in, std::int64_t size) {
    return GridSelector().read(in, size, options.gridName, infos);
  });
  std::string name = options.gridName;
  if (!base) {
    if (name.empty())
      throw Error(path + ": no float or double grid in the file (grids: " + listing(infos) + ")");
    throw Error(path + ": no grid named '" + name + "' (grids: " + listing(infos) + ")");
  }
  name = base->getName();
  try {
    if (auto fg = openvdb::gridPtrCast<openvdb::FloatGrid>(base))
      return bricksOf(path, *fg, options, "float");
    if (auto dg = openvdb::gridPtrCast<openvdb::DoubleGrid>(base))
      return bricksOf(path, *dg, options, "double");
  } catch (const openvdb::Exception& e) {
    throw Error(path + ": grid '" + name + "': " + e.what());
  }
  throw Error(path + ": grid '" + name + "' holds " + base->valueType() +
              " values; only float and double grids can be read");
}

}  // namespace

}  // namespace cip

CIP_MODULE_ENTRY const cip::VdbReaderModule* cip_vdb_reader_module() {
  static const cip::VdbReaderModule table{&cip::listGrids, &cip::readScalarGrid};
  return &table;
}
