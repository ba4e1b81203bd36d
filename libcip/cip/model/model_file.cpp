#include "cip/model/model_file.h"

#include <cmath>
#include <cstring>
#include <limits>

#include "cip/core/atomic_file.h"
#include "cip/core/checksum.h"
#include "cip/core/error.h"
#include "cip/core/huge_pages.h"
#include "cip/core/mapped_file.h"
#include "cip/model/model_file_header.h"
#include "cip/topology/cube_topology.h"

namespace cip {

namespace {

constexpr std::size_t kVertexBytes = 7 * 8;

/// Writes into a buffer sized beforehand (serializeModel counts the bytes first): a copy per field, no
/// growth.
class Writer {
 public:
  explicit Writer(std::size_t size) {
    resizeHuge(bytes, size);
    at_ = bytes.data();
  }
  template <class T>
  void put(T v) {
    static_assert(std::is_trivially_copyable_v<T>);
    putBytes(&v, sizeof(T));  // the file is little-endian, like every platform cip supports
  }
  void putBytes(const void* data, std::size_t n) {
    if (n > static_cast<std::size_t>(bytes.data() + bytes.size() - at_))
      throw Error("serializeModel: more bytes than counted");
    std::memcpy(at_, data, n);
    at_ += n;
  }
  std::size_t written() const { return static_cast<std::size_t>(at_ - bytes.data()); }
  std::vector<std::uint8_t> bytes;

 private:
  std::uint8_t* at_;
};

using Reader = ModelFileReader;

std::uint32_t crc(const std::uint8_t* data, std::size_t size) {
  return crc32Of(data, size);
}

}  // namespace

std::vector<std::uint8_t> serializeModel(const Model& m, const ModelFileOptions& options) {
  if (options.version == 2)
    return serializeModelV2(m, options.v2 ? *options.v2 : ModelFileV2Options::forMethod(m.method));
  if (options.version != 1)
    throw Error("model file version " + std::to_string(options.version) + " cannot be written");
  std::vector<std::uint8_t> header;
  appendModelHeader(header, m, 1, 0);  // the reserved byte
  // The header up to the source description, the three counts, the tables (a cell: index, three bytes, four
  // loop sizes, central, a side coefficient per crossed face; its corners are counted with the corner table)
  // and the CRC.
  std::size_t size = header.size() + 24 + m.vertices.size() * kVertexBytes + m.corners.size() * 4 + 4;
  for (const ModelCell& c : m.cells)
    size += 12 + 3 + 4 + 8 + 8 * static_cast<std::size_t>(__builtin_popcount(cube::crossedFaces(c.config)));
  Writer w(size);
  w.putBytes(header.data(), header.size());
  w.put<std::uint64_t>(m.vertices.size());
  w.put<std::uint64_t>(m.cells.size());
  w.put<std::uint64_t>(m.corners.size());
  for (const IsoVertex& v : m.vertices) {
    for (int a = 0; a < 3; ++a) w.put<double>(v.position[a]);
    for (int a = 0; a < 3; ++a) w.put<double>(v.normal[a]);
    w.put<double>(v.weight);
  }
  for (const ModelCell& c : m.cells) {
    for (auto x : c.index) w.put<std::uint32_t>(x);
    w.put<std::uint8_t>(c.config);
    w.put<std::uint8_t>(c.pairing03);
    w.put<std::uint8_t>(c.numLoops);
    for (auto s : c.loopSize) w.put<std::uint8_t>(s);
    for (int k = 0; k < c.numCorners(); ++k) w.put<std::uint32_t>(m.corners[c.firstCorner + k]);
    std::uint8_t faces = cube::crossedFaces(c.config);
    for (int f = 0; f < 6; ++f)
      if ((faces >> f) & 1) w.put<double>(c.faceCoefficient[f]);
    w.put<double>(c.central);
  }
  w.put<std::uint32_t>(crc(w.bytes.data(), w.written()));
  if (w.written() != size)
    throw Error("serializeModel: " + std::to_string(w.written()) + " bytes written, " + std::to_string(size) +
                " counted");
  return std::move(w.bytes);
}

namespace {

/// The counts of the three tables, each backed by the bytes that remain before anything is allocated.
struct TableCounts {
  std::uint64_t vertices = 0, cells = 0, corners = 0;
};

/// Magic number and version; returns the version (1 or 2).
std::uint32_t readPreamble(Reader& r, const std::uint8_t* data, const std::string& name) {
  r.need(sizeof(kModelMagic), "magic number");
  if (std::memcmp(data, kModelMagic, sizeof(kModelMagic)) != 0)
    throw Error(name + ": not a cip model file (bad magic number)");
  r.skip(sizeof(kModelMagic));
  auto version = r.get<std::uint32_t>("version");
  if (version != 1 && version != 2) {
    throw Error(name + ": model file version " + std::to_string(version) +
                " is not supported (this build reads 1 and 2)");
  }
  return version;
}

TableCounts readTableCounts(Reader& r) {
  TableCounts n;
  n.vertices = r.get<std::uint64_t>("vertex count");
  n.cells = r.get<std::uint64_t>("cell count");
  n.corners = r.get<std::uint64_t>("corner count");
  // Every count must be backed by bytes before anything is allocated.
  if (n.vertices > r.remaining() / kVertexBytes)
    r.fail("vertex count " + std::to_string(n.vertices) + " exceeds the file");
  if (n.corners > r.remaining() / 4 || n.corners > std::numeric_limits<std::uint32_t>::max())
    r.fail("corner count " + std::to_string(n.corners) + " exceeds the file");
  if (n.cells > r.remaining() / 35) r.fail("cell count " + std::to_string(n.cells) + " exceeds the file");
  if (n.vertices > std::numeric_limits<std::uint32_t>::max()) r.fail("vertex count out of range");
  return n;
}

void readVertices(Reader& r, std::uint64_t count, Model& m) {
  resizeHuge(m.vertices, count);
  for (IsoVertex& v : m.vertices) {
    for (int a = 0; a < 3; ++a) v.position[a] = r.getFinite("vertex position");
    for (int a = 0; a < 3; ++a) v.normal[a] = r.getFinite("vertex normal");
    v.weight = r.getFinite("corner coefficient");
    if (std::abs(v.normal.norm() - 1.0) > 1e-6) r.fail("vertex normal is not a unit vector");
  }
}

/// The cell's grid index (inside the grid, after the previous cell's: `prevKey`), configuration and loops
/// (which must be the ones the configuration and face pairing give). Returns those loops.
CellLoops readCellHead(Reader& r, const Model& m, std::uint64_t ci, std::uint64_t& prevKey, ModelCell& c) {
  for (int a = 0; a < 3; ++a) {
    c.index[a] = r.get<std::uint32_t>("cell index");
    if (c.index[a] + std::int64_t(1) >= m.geometry.dims[a])
      r.fail("cell " + std::to_string(ci) + " lies outside the grid");
  }
  std::uint64_t key =
      c.index[0] + static_cast<std::uint64_t>(m.geometry.dims[0]) *
                       (c.index[1] + static_cast<std::uint64_t>(m.geometry.dims[1]) * c.index[2]);
  if (ci > 0 && key <= prevKey)
    r.fail("cells are not in increasing grid order at cell " + std::to_string(ci));
  prevKey = key;
  c.config = r.get<std::uint8_t>("cell configuration");
  if (c.config == 0 || c.config == 0xFF) r.fail("cell " + std::to_string(ci) + " has an empty configuration");
  c.pairing03 = r.get<std::uint8_t>("face pairing");
  c.numLoops = r.get<std::uint8_t>("loop count");
  for (auto& s : c.loopSize) s = r.get<std::uint8_t>("loop size");
  CellLoops expected = buildCellLoops(c.config, c.pairing03);
  if (c.numLoops != expected.numLoops || c.loopSize != expected.loopSize)
    r.fail("cell " + std::to_string(ci) + " loops do not match its configuration");
  return expected;
}

/// The cell's corners, stored from `c.firstCorner`: indices into the vertex table of vertices that lie on the
/// cell edge of their loop corner.
void readCellCorners(Reader& r, Model& m, std::uint64_t ci, const CellLoops& loops, const TableCounts& counts,
                     const ModelCell& c) {
  const std::uint64_t first = c.firstCorner;
  const int n = c.numCorners();
  if (first + static_cast<std::uint64_t>(n) > counts.corners) r.fail("more corners than the corner count");
  Vec3 origin(c.index[0], c.index[1], c.index[2]);
  for (int k = 0; k < n; ++k) {
    auto vi = r.get<std::uint32_t>("corner index");
    if (vi >= counts.vertices)
      r.fail("vertex index " + std::to_string(vi) + " out of range in cell " + std::to_string(ci));
    // The vertex must lie on the cell edge this corner belongs to.
    int e = loops.edges[k];
    Vec3 local = m.vertices[vi].position - origin;
    auto start = cube::vertexCoords(cube::edgeVertex(e, 0));
    int axis = cube::edgeAxis(e);
    for (int a = 0; a < 3; ++a) {
      bool ok = a == axis ? (local[a] >= 0 && local[a] <= 1) : local[a] == start[a];
      if (!ok) r.fail("vertex " + std::to_string(vi) + " is not on its edge of cell " + std::to_string(ci));
    }
    m.corners[first + k] = vi;
  }
}

/// The cell table: per cell its head, corners and coefficients (a side coefficient per crossed face, the
/// central one).
void readCells(Reader& r, const TableCounts& counts, Model& m) {
  resizeHuge(m.cells, counts.cells);
  resizeHuge(m.corners, counts.corners);
  std::uint64_t cornersSoFar = 0;
  std::uint64_t prevKey = 0;
  for (std::uint64_t ci = 0; ci < counts.cells; ++ci) {
    ModelCell& c = m.cells[ci];
    const CellLoops loops = readCellHead(r, m, ci, prevKey, c);
    c.firstCorner = static_cast<std::uint32_t>(cornersSoFar);
    readCellCorners(r, m, ci, loops, counts, c);
    cornersSoFar += static_cast<std::uint64_t>(c.numCorners());
    std::uint8_t faces = cube::crossedFaces(c.config);
    for (int f = 0; f < 6; ++f)
      c.faceCoefficient[f] = ((faces >> f) & 1) ? r.getFinite("side coefficient") : 0.0;
    c.central = r.getFinite("central coefficient");
  }
  if (cornersSoFar != counts.corners) r.fail("corner count does not match the cells");
}

/// The checksum of everything before it, which must end the file.
void checkChecksum(Reader& r, const std::uint8_t* data) {
  std::size_t bodyEnd = r.pos();
  auto stored = r.get<std::uint32_t>("checksum");
  if (r.remaining() != 0) r.fail(std::to_string(r.remaining()) + " unexpected bytes after the checksum");
  if (stored != crc(data, bodyEnd)) r.fail("checksum mismatch");
}

/// A version 1 file's header and table counts, after the preamble.
TableCounts readVersion1Head(Reader& r, Model& m) {
  if (readModelHeader(r, m) != 0) r.fail("unknown flags in the reserved byte of a version 1 header");
  return readTableCounts(r);
}

}  // namespace

Model parseModel(const std::uint8_t* data, std::size_t size, const std::string& name) {
  Reader r(data, size, name);
  if (readPreamble(r, data, name) == 2) return parseModelV2(data, size, name);
  Model m;
  const TableCounts counts = readVersion1Head(r, m);
  readVertices(r, counts.vertices, m);
  readCells(r, counts, m);
  checkChecksum(r, data);
  return m;
}

ModelTableCounts modelTableCounts(const std::uint8_t* data, std::size_t size, const std::string& name) {
  Reader r(data, size, name);
  if (readPreamble(r, data, name) == 2) return modelTableCountsV2(data, size, name);
  Model m;
  const TableCounts counts = readVersion1Head(r, m);
  ModelTableCounts n;
  n.version = 1;
  n.vertices = counts.vertices;
  n.cells = counts.cells;
  n.corners = counts.corners;
  return n;
}

Model storedModel(const Model& model, const ModelFileOptions& options) {
  const std::vector<std::uint8_t> bytes = serializeModel(model, options);
  return parseModel(bytes.data(), bytes.size());
}

std::size_t writeModel(const Model& model, const std::string& path, const ModelFileOptions& options) {
  return writeModelBytes(serializeModel(model, options), path);
}

std::size_t writeModelBytes(const std::vector<std::uint8_t>& bytes, const std::string& path) {
  return writeFileAtomically(path, [&](std::FILE* f) { writeBytes(f, bytes.data(), bytes.size()); });
}

Model readModel(const std::string& path) {
  const MappedFile file(path);
  file.prefetch();
  return parseModel(file.data(), file.size(), path);
}

}  // namespace cip
