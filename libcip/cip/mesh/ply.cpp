#include "cip/mesh/ply.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>

#include "cip/core/atomic_file.h"
#include "cip/core/error.h"

namespace cip {

namespace {

// ---------------------------------------------------------------------------------------------------------------
// Scalar types

enum class Type : std::uint8_t { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64, Invalid };

Type parseType(const std::string& s) {
  if (s == "char" || s == "int8") return Type::Int8;
  if (s == "uchar" || s == "uint8") return Type::UInt8;
  if (s == "short" || s == "int16") return Type::Int16;
  if (s == "ushort" || s == "uint16") return Type::UInt16;
  if (s == "int" || s == "int32") return Type::Int32;
  if (s == "uint" || s == "uint32") return Type::UInt32;
  if (s == "float" || s == "float32") return Type::Float32;
  if (s == "double" || s == "float64") return Type::Float64;
  return Type::Invalid;
}

std::size_t typeSize(Type t) {
  switch (t) {
    case Type::Int8:
    case Type::UInt8:
      return 1;
    case Type::Int16:
    case Type::UInt16:
      return 2;
    case Type::Int32:
    case Type::UInt32:
    case Type::Float32:
      return 4;
    case Type::Float64:
      return 8;
    case Type::Invalid:
      break;
  }
  return 0;
}

bool isInteger(Type t) {
  return t != Type::Float32 && t != Type::Float64 && t != Type::Invalid;
}

bool hostIsLittleEndian() {
  const std::uint16_t one = 1;
  std::uint8_t b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

// ---------------------------------------------------------------------------------------------------------------
// Header

struct Property {
  std::string name;
  Type type = Type::Invalid;       // scalar type, or list item type
  Type countType = Type::Invalid;  // list count type; Invalid for scalar properties
  bool isList() const { return countType != Type::Invalid; }
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::vector<Property> properties;
};

struct Header {
  PlyFormat format = PlyFormat::Ascii;
  std::vector<Element> elements;
  std::size_t dataOffset = 0;
};

std::vector<std::string> splitWords(const std::string& line) {
  std::vector<std::string> words;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    std::size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
    if (j > i) words.push_back(line.substr(i, j - i));
    i = j;
  }
  return words;
}

bool parseCount(const std::string& s, std::uint64_t& out) {
  if (s.empty() || s.size() > 20) return false;
  std::uint64_t v = 0;
  for (char c : s) {
    if (c < '0' || c > '9') return false;
    std::uint64_t d = static_cast<std::uint64_t>(c - '0');
    if (v > (std::numeric_limits<std::uint64_t>::max() - d) / 10) return false;
    v = v * 10 + d;
  }
  out = v;
  return true;
}

Header parseHeader(const std::uint8_t* data, std::size_t size, const std::string& name) {
  Header h;
  std::size_t pos = 0;
  int lineNo = 0;
  bool sawFormat = false;
  auto nextLine = [&](std::string& line) {
    if (pos >= size) return false;
    std::size_t end = pos;
    while (end < size && data[end] != '\n') ++end;
    if (end >= size) return false;  // the header must end with a newline
    line.assign(reinterpret_cast<const char*>(data) + pos, end - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = end + 1;
    ++lineNo;
    return true;
  };
  auto fail = [&](const std::string& why) -> Header {
    throw Error(name + ": PLY header line " + std::to_string(lineNo) + ": " + why);
  };
  std::string line;
  if (size < 4 || std::memcmp(data, "ply", 3) != 0 || !nextLine(line) || line != "ply") {
    throw Error(name + ": not a PLY file (it does not start with \"ply\")");
  }
  while (true) {
    if (!nextLine(line)) throw Error(name + ": PLY header has no end_header line");
    auto w = splitWords(line);
    if (w.empty()) continue;
    const std::string& key = w[0];
    if (key == "comment" || key == "obj_info") continue;
    if (key == "end_header") break;
    if (key == "format") {
      if (w.size() != 3) return fail("expected \"format <type> 1.0\"");
      if (w[1] == "ascii") {
        h.format = PlyFormat::Ascii;
      } else if (w[1] == "binary_little_endian") {
        h.format = PlyFormat::BinaryLittleEndian;
      } else if (w[1] == "binary_big_endian") {
        h.format = PlyFormat::BinaryBigEndian;
      } else {
        return fail("unknown format \"" + w[1] + "\"");
      }
      if (w[2] != "1.0" && w[2] != "1") return fail("unsupported PLY version " + w[2]);
      sawFormat = true;
    } else if (key == "element") {
      Element e;
      if (w.size() != 3 || !parseCount(w[2], e.count)) return fail("expected \"element <name> <count>\"");
      e.name = w[1];
      for (const auto& other : h.elements)
        if (other.name == e.name) return fail("element \"" + e.name + "\" declared twice");
      h.elements.push_back(e);
    } else if (key == "property") {
      if (h.elements.empty()) return fail("property before any element");
      Property p;
      if (w.size() == 3) {
        p.type = parseType(w[1]);
        p.name = w[2];
        if (p.type == Type::Invalid) return fail("unknown property type \"" + w[1] + "\"");
      } else if (w.size() == 5 && w[1] == "list") {
        p.countType = parseType(w[2]);
        p.type = parseType(w[3]);
        p.name = w[4];
        if (p.countType == Type::Invalid || p.type == Type::Invalid) return fail("unknown list type");
        if (!isInteger(p.countType)) return fail("list count type must be an integer type");
      } else {
        return fail("expected \"property <type> <name>\" or \"property list <count type> <type> <name>\"");
      }
      h.elements.back().properties.push_back(p);
    } else {
      return fail("unknown keyword \"" + key + "\"");
    }
  }
  if (!sawFormat) throw Error(name + ": PLY header has no format line");
  h.dataOffset = pos;
  return h;
}

// ---------------------------------------------------------------------------------------------------------------
// Body

class BodyReader {
 public:
  BodyReader(const std::uint8_t* data, std::size_t size, std::size_t pos, PlyFormat format,
             const std::string& name)
      : data_(data), size_(size), pos_(pos), format_(format), name_(name) {
    swap_ = format != PlyFormat::Ascii && ((format == PlyFormat::BinaryLittleEndian) != hostIsLittleEndian());
  }

  std::size_t remaining() const { return size_ - pos_; }
  bool ascii() const { return format_ == PlyFormat::Ascii; }

  /// Reads one value of type t (as double: every supported type converts exactly).
  double read(Type t, const char* what) {
    if (ascii()) return readAscii(t, what);
    std::size_t n = typeSize(t);
    if (remaining() < n) truncated(what);
    std::uint8_t b[8];
    std::memcpy(b, data_ + pos_, n);
    pos_ += n;
    if (swap_) std::reverse(b, b + n);
    switch (t) {
      case Type::Int8:
        return static_cast<std::int8_t>(b[0]);
      case Type::UInt8:
        return b[0];
      case Type::Int16:
        return load<std::int16_t>(b);
      case Type::UInt16:
        return load<std::uint16_t>(b);
      case Type::Int32:
        return load<std::int32_t>(b);
      case Type::UInt32:
        return load<std::uint32_t>(b);
      case Type::Float32:
        return load<float>(b);
      case Type::Float64:
        return load<double>(b);
      case Type::Invalid:
        break;
    }
    return 0;
  }

  /// Skips n values of type t (binary: checked against the remaining bytes first).
  void skip(Type t, std::uint64_t n, const char* what) {
    if (ascii()) {
      for (std::uint64_t i = 0; i < n; ++i) readAscii(t, what);
      return;
    }
    std::size_t sz = typeSize(t);
    if (n > remaining() / sz) truncated(what);
    pos_ += static_cast<std::size_t>(n) * sz;
  }

  /// A list count: a non-negative integer that the remaining data can hold (at least `minItemBytes` each).
  std::uint64_t readCount(Type t, Type itemType, const char* what) {
    double c = read(t, what);
    if (!(c >= 0)) throw Error(name_ + ": negative list count in " + what);
    auto n = static_cast<std::uint64_t>(c);
    // Binary items take their size; ASCII items at least one character and a separator (the last one none).
    if (ascii() ? n > (remaining() + 1) / 2 : n > remaining() / typeSize(itemType)) truncated(what);
    return n;
  }

  [[noreturn]] void truncated(const char* what) const {
    throw Error(name_ + ": PLY data is truncated (in " + what + ", at byte " + std::to_string(pos_) + " of " +
                std::to_string(size_) + ")");
  }

 private:
  template <typename T>
  static double load(const std::uint8_t* b) {
    T v;
    std::memcpy(&v, b, sizeof v);
    return static_cast<double>(v);
  }

  double readAscii(Type t, const char* what) {
    auto space = [](std::uint8_t c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
    while (pos_ < size_ && space(data_[pos_])) ++pos_;
    std::size_t start = pos_;
    while (pos_ < size_ && !space(data_[pos_])) ++pos_;
    if (pos_ == start) truncated(what);
    if (pos_ - start > 64) throw Error(name_ + ": overlong number in " + what);
    char buf[80];
    std::memcpy(buf, data_ + start, pos_ - start);
    buf[pos_ - start] = 0;
    char* end = nullptr;
    errno = 0;
    double v;
    if (isInteger(t)) {
      long long x = std::strtoll(buf, &end, 10);
      v = static_cast<double>(x);
      bool inRange = errno == 0;
      switch (t) {
        case Type::Int8:
          inRange &= x >= -128 && x <= 127;
          break;
        case Type::UInt8:
          inRange &= x >= 0 && x <= 255;
          break;
        case Type::Int16:
          inRange &= x >= -32768 && x <= 32767;
          break;
        case Type::UInt16:
          inRange &= x >= 0 && x <= 65535;
          break;
        case Type::Int32:
          inRange &= x >= -2147483648LL && x <= 2147483647LL;
          break;
        case Type::UInt32:
          inRange &= x >= 0 && x <= 4294967295LL;
          break;
        default:
          break;
      }
      if (*end != 0 || !inRange) {
        throw Error(name_ + ": bad integer \"" + std::string(buf) + "\" in " + what);
      }
    } else {
      v = std::strtod(buf, &end);
      if (*end != 0) throw Error(name_ + ": bad number \"" + std::string(buf) + "\" in " + what);
    }
    return v;
  }

  const std::uint8_t* data_;
  std::size_t size_, pos_;
  PlyFormat format_;
  const std::string& name_;
  bool swap_ = false;
};

/// Smallest number of bytes one record of `e` can occupy (lists counted as empty).
std::size_t minRecordBytes(const Element& e, bool ascii) {
  std::size_t n = 0;
  for (const auto& p : e.properties) n += ascii ? 2 : typeSize(p.isList() ? p.countType : p.type);
  return n;
}

int findProperty(const Element& e, const char* name) {
  for (std::size_t i = 0; i < e.properties.size(); ++i)
    if (e.properties[i].name == name) return static_cast<int>(i);
  return -1;
}

// ---------------------------------------------------------------------------------------------------------------
// Elements

/// The vertex element's x, y and z properties (scalars, or the file is refused) and its nx, ny and nz if all
/// three are scalars (else -1 each).
struct VertexProperties {
  int position[3];
  int normal[3] = {-1, -1, -1};
};

VertexProperties vertexProperties(const Element& e, const std::string& name) {
  VertexProperties vp;
  const char* axes[3] = {"x", "y", "z"};
  const char* normalAxes[3] = {"nx", "ny", "nz"};
  bool hasNormals = true;
  for (int a = 0; a < 3; ++a) {
    vp.position[a] = findProperty(e, axes[a]);
    if (vp.position[a] < 0 || e.properties[vp.position[a]].isList()) {
      throw Error(name + ": PLY vertex element lacks scalar x, y and z properties");
    }
    const int k = findProperty(e, normalAxes[a]);
    hasNormals = hasNormals && k >= 0 && !e.properties[k].isList();
  }
  if (hasNormals) {
    for (int a = 0; a < 3; ++a) vp.normal[a] = findProperty(e, normalAxes[a]);
  }
  return vp;
}

/// The face element's vertex index list ("vertex_indices", or "vertex_index"): a list of an integer type, or
/// the file is refused.
int faceIndexProperty(const Element& e, const std::string& name) {
  int k = findProperty(e, "vertex_indices");
  if (k < 0) k = findProperty(e, "vertex_index");
  if (k < 0 || !e.properties[k].isList())
    throw Error(name + ": PLY face element lacks a vertex_indices list");
  if (!isInteger(e.properties[k].type))
    throw Error(name + ": PLY face vertex indices must have an integer type");
  return k;
}

/// Structural checks of the vertex and face elements, before any data is read (so they apply to empty
/// elements too).
void checkElements(const Header& h, const std::string& name) {
  for (const Element& e : h.elements) {
    if (e.name == "vertex") vertexProperties(e, name);
    if (e.name == "face") faceIndexProperty(e, name);
  }
}

/// Refuses an element whose records cannot fit in the data that remains.
void checkRecordsFit(const Element& e, const BodyReader& r, const std::string& name) {
  const std::size_t minBytes = minRecordBytes(e, r.ascii());
  if (minBytes == 0) throw Error(name + ": PLY element \"" + e.name + "\" has records but no properties");
  if (e.count > r.remaining() / minBytes + (r.ascii() ? 1 : 0)) {
    throw Error(name + ": PLY header declares " + std::to_string(e.count) + " " + e.name +
                " records but only " + std::to_string(r.remaining()) + " bytes of data remain (at least " +
                std::to_string(minBytes) + " bytes per record)");
  }
}

/// Skips one value of a property: a scalar, or a list with its count.
void skipProperty(BodyReader& r, const Property& p, const char* listWhat, const char* scalarWhat) {
  if (p.isList()) {
    std::uint64_t n = r.readCount(p.countType, p.type, listWhat);
    r.skip(p.type, n, listWhat);
  } else {
    r.skip(p.type, 1, scalarWhat);
  }
}

void readVertices(const Element& e, BodyReader& r, const std::string& name, TriangleMesh& mesh) {
  if (e.count > std::numeric_limits<std::uint32_t>::max()) {
    throw Error(name + ": PLY file has " + std::to_string(e.count) +
                " vertices; at most 2^32-1 are supported");
  }
  const VertexProperties vp = vertexProperties(e, name);
  const bool hasNormals = vp.normal[0] >= 0;
  std::vector<int> slot(e.properties.size(), -1);  // 0..2 position, 3..5 normal
  for (int a = 0; a < 3; ++a) {
    slot[vp.position[a]] = a;
    if (hasNormals) slot[vp.normal[a]] = 3 + a;
  }
  mesh.positions.resize(static_cast<std::size_t>(e.count));
  if (hasNormals) mesh.normals.resize(static_cast<std::size_t>(e.count));
  for (std::size_t v = 0; v < e.count; ++v) {
    double val[6] = {0, 0, 0, 0, 0, 0};
    for (std::size_t k = 0; k < e.properties.size(); ++k) {
      const Property& p = e.properties[k];
      if (slot[k] >= 0) {  // a scalar (slots go to scalar properties only)
        val[slot[k]] = r.read(p.type, "vertex data");
      } else {
        skipProperty(r, p, "vertex list", "vertex data");
      }
    }
    for (double x : val) {
      if (!std::isfinite(x)) throw Error(name + ": PLY vertex " + std::to_string(v) + " is not finite");
    }
    mesh.positions[v] = Vec3(val[0], val[1], val[2]);
    if (hasNormals) mesh.normals[v] = Vec3(val[3], val[4], val[5]);
  }
}

/// Reads the faces as triangle fans (a polygon of n vertices gives n - 2 triangles).
void readFaces(const Element& e, BodyReader& r, const std::string& name, TriangleMesh& mesh) {
  const int pi = faceIndexProperty(e, name);
  mesh.triangles.reserve(static_cast<std::size_t>(e.count));
  std::vector<std::uint32_t> poly;
  for (std::uint64_t f = 0; f < e.count; ++f) {
    for (std::size_t k = 0; k < e.properties.size(); ++k) {
      const Property& p = e.properties[k];
      if (static_cast<int>(k) != pi) {
        skipProperty(r, p, "face list", "face data");
        continue;
      }
      std::uint64_t n = r.readCount(p.countType, p.type, "face vertex_indices");
      if (n < 3) {
        throw Error(name + ": PLY face " + std::to_string(f) + " has " + std::to_string(n) +
                    " vertices (at least 3 needed)");
      }
      poly.resize(static_cast<std::size_t>(n));
      for (std::uint64_t i = 0; i < n; ++i) {
        double idx = r.read(p.type, "face vertex_indices");
        if (idx < 0) throw Error(name + ": PLY face " + std::to_string(f) + " has a negative vertex index");
        poly[static_cast<std::size_t>(i)] = static_cast<std::uint32_t>(idx);
      }
      for (std::size_t i = 1; i + 1 < poly.size(); ++i)
        mesh.triangles.push_back({poly[0], poly[i], poly[i + 1]});
    }
  }
}

void skipElement(const Element& e, BodyReader& r) {
  const std::string what = "element " + e.name;
  for (std::uint64_t i = 0; i < e.count; ++i) {
    for (const Property& p : e.properties) skipProperty(r, p, what.c_str(), what.c_str());
  }
}

/// Checks, once all elements are read, that there were vertices and faces and every index names a vertex.
void checkMesh(const Header& h, const TriangleMesh& mesh, const std::string& name) {
  auto declared = [&](const char* element) {
    return std::any_of(h.elements.begin(), h.elements.end(),
                       [&](const Element& e) { return e.name == element; });
  };
  if (!declared("vertex")) throw Error(name + ": PLY file has no vertex element");
  if (!declared("face")) throw Error(name + ": PLY file has no face element");
  const std::uint64_t vertexCount = mesh.positions.size();
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    for (std::uint32_t v : mesh.triangles[t]) {
      if (v >= vertexCount) {
        throw Error(name + ": PLY face uses vertex index " + std::to_string(v) + " but there are only " +
                    std::to_string(vertexCount) + " vertices");
      }
    }
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Writer helpers

class ByteSink {
 public:
  explicit ByteSink(PlyFormat format) : format_(format) {
    swap_ = format != PlyFormat::Ascii && ((format == PlyFormat::BinaryLittleEndian) != hostIsLittleEndian());
  }
  void text(const std::string& s) {
    const std::size_t n = out.size();
    out.resize(n + s.size());
    if (!s.empty()) std::memcpy(out.data() + n, s.data(), s.size());
  }
  template <typename T>
  void binary(T v) {
    std::uint8_t b[sizeof(T)];
    std::memcpy(b, &v, sizeof v);
    if (swap_) std::reverse(b, b + sizeof(T));
    const std::size_t n = out.size();
    out.resize(n + sizeof(T));
    std::memcpy(out.data() + n, b, sizeof(T));
  }
  std::vector<std::uint8_t> out;

 private:
  PlyFormat format_;
  bool swap_ = false;
};

}  // namespace

std::vector<std::uint8_t> encodePly(const TriangleMesh& mesh, const PlyWriteOptions& options) {
  validateMesh(mesh, "PLY output");
  const bool normals = options.normals && mesh.hasNormals();
  const std::size_t nv = mesh.positions.size();
  if (nv > std::numeric_limits<std::uint32_t>::max()) throw Error("PLY output: too many vertices");
  const bool wideIndex = nv > static_cast<std::size_t>(std::numeric_limits<std::int32_t>::max());
  ByteSink s(options.format);
  s.text("ply\nformat ");
  s.text(options.format == PlyFormat::Ascii                ? "ascii"
         : options.format == PlyFormat::BinaryLittleEndian ? "binary_little_endian"
                                                           : "binary_big_endian");
  s.text(" 1.0\n");
  if (!options.comment.empty()) {
    std::string c = options.comment;
    std::replace(c.begin(), c.end(), '\n', ' ');
    std::replace(c.begin(), c.end(), '\r', ' ');
    s.text("comment " + c + "\n");
  }
  s.text("element vertex " + std::to_string(nv) + "\nproperty float x\nproperty float y\nproperty float z\n");
  if (normals) s.text("property float nx\nproperty float ny\nproperty float nz\n");
  s.text("element face " + std::to_string(mesh.triangles.size()) + "\nproperty list uchar " +
         (wideIndex ? "uint" : "int") + " vertex_indices\nend_header\n");
  const bool ascii = options.format == PlyFormat::Ascii;
  s.out.reserve(s.out.size() + (ascii ? 80 : 24) * nv + (ascii ? 40 : 13) * mesh.triangles.size());
  char buf[64];
  auto putFloat = [&](double v, bool last) {
    float f = static_cast<float>(v);
    if (ascii) {
      std::snprintf(buf, sizeof buf, last ? "%.9g\n" : "%.9g ", static_cast<double>(f));
      s.text(buf);
    } else {
      s.binary(f);
    }
  };
  for (std::size_t v = 0; v < nv; ++v) {
    const Vec3& p = mesh.positions[v];
    putFloat(p[0], false);
    putFloat(p[1], false);
    putFloat(p[2], !normals);
    if (normals) {
      const Vec3& n = mesh.normals[v];
      putFloat(n[0], false);
      putFloat(n[1], false);
      putFloat(n[2], true);
    }
  }
  for (const auto& t : mesh.triangles) {
    if (ascii) {
      std::snprintf(buf, sizeof buf, "3 %u %u %u\n", t[0], t[1], t[2]);
      s.text(buf);
    } else {
      s.binary<std::uint8_t>(3);
      for (std::uint32_t i : t) {
        if (wideIndex) {
          s.binary<std::uint32_t>(i);
        } else {
          s.binary<std::int32_t>(static_cast<std::int32_t>(i));
        }
      }
    }
  }
  return std::move(s.out);
}

std::size_t writePly(const TriangleMesh& mesh, const std::string& path, const PlyWriteOptions& options) {
  std::vector<std::uint8_t> bytes;
  try {
    bytes = encodePly(mesh, options);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  return writeFileAtomically(path, [&](std::FILE* f) { writeBytes(f, bytes.data(), bytes.size()); });
}

TriangleMesh parsePly(const std::uint8_t* data, std::size_t size, const std::string& name) {
  const Header h = parseHeader(data, size, name);
  checkElements(h, name);
  BodyReader r(data, size, h.dataOffset, h.format, name);
  TriangleMesh mesh;
  for (const Element& e : h.elements) {
    if (e.count == 0) continue;
    checkRecordsFit(e, r, name);
    if (e.name == "vertex") {
      readVertices(e, r, name, mesh);
    } else if (e.name == "face") {
      readFaces(e, r, name, mesh);
    } else {
      skipElement(e, r);
    }
  }
  checkMesh(h, mesh, name);
  return mesh;
}

TriangleMesh readPly(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw Error(path + ": cannot open: " + std::strerror(errno));
  std::vector<std::uint8_t> bytes;
  std::uint8_t buf[1 << 16];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) bytes.insert(bytes.end(), buf, buf + n);
  bool failed = std::ferror(f) != 0;
  std::fclose(f);
  if (failed) throw Error(path + ": read failed");
  return parsePly(bytes.data(), bytes.size(), path);
}

}  // namespace cip
