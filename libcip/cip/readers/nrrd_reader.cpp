#include "cip/readers/nrrd_reader.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>
#include <vector>

#include "cip/core/error.h"
#include "cip/readers/volume_input.h"

namespace cip {

namespace {

/// Inflating more than this just to skip it is refused (a bogus header could otherwise keep a reader busy).
constexpr std::int64_t kMaxCompressedSkip = std::int64_t(1) << 30;

std::string trim(std::string_view s) {
  std::size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return std::string(s.substr(b, e - b));
}

std::vector<std::string> tokens(const std::string& s) {
  std::vector<std::string> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    std::size_t b = i;
    while (i < s.size() && !std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    if (i > b) out.push_back(s.substr(b, i - b));
  }
  return out;
}

/// Field name in the form used for lookup: lower case, blanks removed ("data file" and "datafile" are the
/// same).
std::string fieldKey(const std::string& name) {
  std::string key;
  for (char c : name) {
    if (!std::isspace(static_cast<unsigned char>(c)))
      key += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  }
  return key;
}

[[noreturn]] void fail(int line, const std::string& message) {
  throw Error("line " + std::to_string(line) + ": " + message);
}

double parseNumber(const std::string& token, int line, const std::string& field) {
  const char* begin = token.c_str();
  char* end = nullptr;
  errno = 0;
  double v = std::strtod(begin, &end);
  if (end == begin || *end != '\0') fail(line, field + ": '" + token + "' is not a number");
  return v;
}

std::int64_t parseInteger(const std::string& token, int line, const std::string& field) {
  const char* begin = token.c_str();
  char* end = nullptr;
  errno = 0;
  long long v = std::strtoll(begin, &end, 10);
  if (end == begin || *end != '\0') fail(line, field + ": '" + token + "' is not an integer");
  if (errno == ERANGE) fail(line, field + ": '" + token + "' is out of range");
  return static_cast<std::int64_t>(v);
}

/// Parses a vector "(a,b,c)" (blanks allowed inside); returns false for "none".
bool parseVector(const std::string& token, int line, const std::string& field, std::vector<double>& out) {
  out.clear();
  if (token == "none") return false;
  if (token.size() < 2 || token.front() != '(' || token.back() != ')') {
    fail(line, field + ": expected a vector like (1,0,0), got '" + token + "'");
  }
  std::string inner = token.substr(1, token.size() - 2);
  std::size_t start = 0;
  while (true) {
    std::size_t comma = inner.find(',', start);
    out.push_back(parseNumber(trim(inner.substr(start, comma - start)), line, field));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return true;
}

/// Splits the value of "space directions" / "space origin" into vector tokens; vectors may contain blanks.
std::vector<std::string> vectorTokens(const std::string& value, int line, const std::string& field) {
  std::vector<std::string> out;
  std::size_t i = 0;
  while (i < value.size()) {
    if (std::isspace(static_cast<unsigned char>(value[i]))) {
      ++i;
      continue;
    }
    if (value[i] == '(') {
      std::size_t close = value.find(')', i);
      if (close == std::string::npos) fail(line, field + ": unbalanced parenthesis");
      std::string vec;
      for (std::size_t k = i; k <= close; ++k) {
        if (!std::isspace(static_cast<unsigned char>(value[k]))) vec += value[k];
      }
      out.push_back(vec);
      i = close + 1;
    } else {
      std::size_t b = i;
      while (i < value.size() && !std::isspace(static_cast<unsigned char>(value[i]))) ++i;
      out.push_back(value.substr(b, i - b));
    }
  }
  return out;
}

std::string joinDims(const std::vector<std::int64_t>& sizes) {
  std::string s;
  for (std::size_t i = 0; i < sizes.size(); ++i) s += (i ? "x" : "") + std::to_string(sizes[i]);
  return s;
}

}  // namespace

NrrdHeader parseNrrdHeader(std::string_view text) {
  NrrdHeader h;
  // Split into lines up to the first blank line (or the end of the text).
  std::size_t pos = 0;
  int lineNo = 0;
  bool blank = false;
  struct Field {
    std::string value;
    int line;
  };
  std::map<std::string, Field> fields;
  while (pos < text.size()) {
    std::size_t nl = text.find('\n', pos);
    std::size_t end = nl == std::string_view::npos ? text.size() : nl;
    std::size_t next = nl == std::string_view::npos ? text.size() : nl + 1;
    ++lineNo;
    if (lineNo == 1) {
      std::string_view magic = text.substr(pos, std::min<std::size_t>(end - pos, 9));
      if (!magic.empty() && magic.back() == '\r') magic.remove_suffix(1);
      if (magic.size() != 8 || magic.substr(0, 7) != "NRRD000" || magic[7] < '1' || magic[7] > '5') {
        std::string shown;
        for (char c : text.substr(pos, std::min<std::size_t>(end - pos, 16))) {
          shown += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
        }
        throw Error("not a NRRD file (starts with '" + shown + "', expected NRRD0001..NRRD0005)");
      }
      h.version = magic[7] - '0';
      pos = next;
      continue;
    }
    if (end - pos > kNrrdMaxLineBytes) {
      fail(lineNo, "line longer than " + std::to_string(kNrrdMaxLineBytes) + " bytes (not a NRRD header?)");
    }
    if (next > kNrrdMaxHeaderBytes) {
      throw Error("header longer than " + std::to_string(kNrrdMaxHeaderBytes >> 20) +
                  " MiB or missing the blank line that ends it");
    }
    std::string_view raw = text.substr(pos, end - pos);
    if (!raw.empty() && raw.back() == '\r') raw.remove_suffix(1);
    pos = next;
    if (raw.find('\0') != std::string_view::npos) fail(lineNo, "binary data in header (missing blank line?)");
    if (raw.empty()) {
      blank = true;
      break;
    }
    if (raw[0] == '#') continue;
    std::size_t colon = raw.find(": ");
    std::size_t pair = raw.find(":=");
    if (pair != std::string_view::npos && pair < colon) continue;  // "key:=value" pair: not used
    if (colon == std::string_view::npos) {
      if (!raw.empty() && raw.back() == ':') {
        colon = raw.size() - 1;
      } else {
        fail(lineNo, "expected 'field: value', got '" + std::string(raw.substr(0, 80)) + "'");
      }
    }
    std::string key = fieldKey(std::string(raw.substr(0, colon)));
    std::string value = trim(raw.substr(std::min(raw.size(), colon + 1)));
    if (key.empty()) fail(lineNo, "empty field name");
    if (fields.count(key)) fail(lineNo, "field '" + trim(raw.substr(0, colon)) + "' appears twice");
    fields[key] = Field{value, lineNo};
  }
  if (lineNo == 0) throw Error("empty file (not a NRRD file)");
  h.headerBytes = pos;

  auto get = [&](const char* key) -> const Field* {
    auto it = fields.find(key);
    return it == fields.end() ? nullptr : &it->second;
  };
  auto require = [&](const char* key, const char* name) -> const Field& {
    const Field* f = get(key);
    if (!f) throw Error("header has no '" + std::string(name) + "' field");
    return *f;
  };

  // type
  {
    const Field& f = require("type", "type");
    std::string t = fieldKey(f.value);
    if (t == "block") fail(f.line, "type 'block' is not supported");
    if (t.find("64") != std::string::npos || t.find("long") != std::string::npos) {
      fail(f.line, "type '" + f.value + "' (64-bit integers) is not supported");
    }
    try {
      h.type = parseSampleType(f.value);
    } catch (const Error& e) {
      fail(f.line, e.what());
    }
  }
  // dimension and sizes
  int dimension = 0;
  {
    const Field& f = require("dimension", "dimension");
    std::int64_t d = parseInteger(f.value, f.line, "dimension");
    if (d != 3 && d != 4) {
      fail(f.line, "dimension " + f.value +
                       " is not supported (a volume needs 3, or 4 with a leading axis of size 1)");
    }
    dimension = static_cast<int>(d);
  }
  const int first = dimension - 3;  // index of the first spatial axis
  {
    const Field& f = require("sizes", "sizes");
    auto t = tokens(f.value);
    if (static_cast<int>(t.size()) != dimension) {
      fail(f.line,
           "sizes has " + std::to_string(t.size()) + " entries for dimension " + std::to_string(dimension));
    }
    std::vector<std::int64_t> sizes;
    for (const auto& s : t) {
      sizes.push_back(parseInteger(s, f.line, "sizes"));
      if (sizes.back() < 1) fail(f.line, "sizes: every size must be at least 1, got " + s);
    }
    if (dimension == 4 && sizes[0] != 1) {
      fail(f.line, "4-D volume " + joinDims(sizes) +
                       " has several values per voxel; only a leading axis of size 1 is supported");
    }
    for (int a = 0; a < 3; ++a) h.dims[a] = sizes[first + a];
  }
  // spacing: space directions or spacings
  const Field* dirs = get("spacedirections");
  const Field* spacings = get("spacings");
  if (dirs) {
    auto t = vectorTokens(dirs->value, dirs->line, "space directions");
    if (static_cast<int>(t.size()) != dimension) {
      fail(dirs->line, "space directions has " + std::to_string(t.size()) + " entries for dimension " +
                           std::to_string(dimension));
    }
    std::vector<double> v;
    for (int a = 0; a < 3; ++a) {
      if (!parseVector(t[first + a], dirs->line, "space directions", v)) {
        fail(dirs->line, "space directions: spatial axis " + std::to_string(a) + " is 'none'");
      }
      if (v.size() != 3) {
        fail(dirs->line, "space directions: vectors must have 3 components, got " + t[first + a]);
      }
      double length = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
      if (!std::isfinite(length) || length <= 0) {
        fail(dirs->line, "space directions: axis " + std::to_string(a) + " has a zero or invalid length");
      }
      for (int b = 0; b < 3; ++b) {
        if (b != a && std::abs(v[b]) > 1e-9 * length) {
          fail(dirs->line, "space directions are rotated or sheared (axis " + std::to_string(a) + " is " +
                               t[first + a] + "); only axis-aligned volumes are supported");
        }
      }
      h.spacing[a] = std::abs(v[a]);
    }
    if (dimension == 4 && t[0] != "none")
      fail(dirs->line, "space directions: the non-spatial axis must be 'none'");
  } else if (spacings) {
    auto t = tokens(spacings->value);
    if (static_cast<int>(t.size()) != dimension) {
      fail(spacings->line, "spacings has " + std::to_string(t.size()) + " entries for dimension " +
                               std::to_string(dimension));
    }
    for (int a = 0; a < 3; ++a) {
      double s = parseNumber(t[first + a], spacings->line, "spacings");
      if (std::isnan(s)) continue;  // unknown spacing: keep 1
      if (!std::isfinite(s) || s == 0)
        fail(spacings->line, "spacings: '" + t[first + a] + "' is not a valid spacing");
      h.spacing[a] = std::abs(s);
    }
  }
  if (const Field* f = get("spaceorigin")) {
    auto t = vectorTokens(f->value, f->line, "space origin");
    std::vector<double> v;
    if (t.size() != 1 || !parseVector(t[0], f->line, "space origin", v) || v.size() != 3) {
      fail(f->line, "space origin: expected a 3-vector like (0,0,0), got '" + f->value + "'");
    }
    for (int a = 0; a < 3; ++a) {
      if (!std::isfinite(v[a])) fail(f->line, "space origin: components must be finite");
      h.origin[a] = v[a];
    }
  }
  // encoding
  {
    const Field& f = require("encoding", "encoding");
    std::string e = fieldKey(f.value);
    if (e == "raw") {
      h.encoding = NrrdEncoding::Raw;
    } else if (e == "gzip" || e == "gz") {
      h.encoding = NrrdEncoding::Gzip;
    } else if (e == "ascii" || e == "text" || e == "txt") {
      h.encoding = NrrdEncoding::Ascii;
    } else if (e == "hex" || e == "bzip2" || e == "bz2") {
      fail(f.line, "encoding '" + f.value + "' is not supported (raw, gzip and ascii are)");
    } else {
      fail(f.line, "unknown encoding '" + f.value + "'");
    }
  }
  // endian
  if (const Field* f = get("endian")) {
    try {
      h.endian = parseEndian(f->value);
    } catch (const Error& e) {
      fail(f->line, e.what());
    }
  } else if (sampleSize(h.type) > 1 && h.encoding != NrrdEncoding::Ascii) {
    throw Error("header has no 'endian' field, needed for " + std::string(toString(h.type)) + " samples");
  }
  // data location
  if (const Field* f = get("datafile")) {
    auto t = tokens(f->value);
    if (f->value.empty()) fail(f->line, "data file: empty file name");
    if (!t.empty() && t[0] == "LIST") {
      fail(f->line, "data file: LIST (several data files) is not supported");
    }
    if (t.size() >= 4 && t[0].find('%') != std::string::npos) {
      fail(f->line, "data file: several numbered data files are not supported");
    }
    h.dataFile = f->value;
  } else if (!blank) {
    throw Error("header has no 'data file' field and no blank line before attached data");
  }
  h.attached = h.dataFile.empty();
  if (const Field* f = get("byteskip")) {
    h.byteSkip = parseInteger(f->value, f->line, "byte skip");
    if (h.byteSkip < -1) fail(f->line, "byte skip must be -1 or more");
    if (h.byteSkip == -1 && h.encoding != NrrdEncoding::Raw) fail(f->line, "byte skip -1 needs raw encoding");
    if (h.byteSkip != 0 && h.encoding == NrrdEncoding::Ascii)
      fail(f->line, "byte skip is not allowed with ascii encoding");
    if (h.encoding == NrrdEncoding::Gzip && h.byteSkip > kMaxCompressedSkip) {
      fail(f->line, "byte skip " + f->value + " is too large for compressed data (at most 1 GiB)");
    }
  }
  if (const Field* f = get("lineskip")) {
    h.lineSkip = parseInteger(f->value, f->line, "line skip");
    if (h.lineSkip < 0) fail(f->line, "line skip must be 0 or more");
  }
  return h;
}

NrrdHeader readNrrdHeader(const std::string& path) {
  std::uint64_t size = fileSizeOf(path);
  std::string text(static_cast<std::size_t>(std::min<std::uint64_t>(size, kNrrdMaxHeaderBytes + 1)), '\0');
  FileByteSource source(path, 0);
  text.resize(source.read(text.data(), text.size()));
  try {
    return parseNrrdHeader(text);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

namespace {

/// Byte offset just past `lines` newline characters counted from `start` in `path`.
std::uint64_t skipLines(const std::string& path, std::uint64_t start, std::int64_t lines) {
  if (lines == 0) return start;
  FileByteSource source(path, start);
  std::vector<char> buffer(std::size_t(64) << 10);
  std::uint64_t offset = start;
  std::int64_t seen = 0;
  while (true) {
    std::size_t got = source.read(buffer.data(), buffer.size());
    if (got == 0) {
      throw Error(path + ": line skip " + std::to_string(lines) + " goes past the end of the file (" +
                  std::to_string(seen) + " lines)");
    }
    for (std::size_t i = 0; i < got; ++i) {
      if (buffer[i] == '\n' && ++seen == lines) return offset + i + 1;
    }
    offset += got;
  }
}

/// Reads grid.values.size() numbers separated by blanks or commas; anything but blanks after them is an
/// error.
void readAsciiInto(ByteSource& source, DenseGrid& grid) {
  constexpr std::size_t kMaxToken = 128;
  std::vector<char> buffer(std::size_t(1) << 20);
  std::string token;
  std::size_t done = 0;
  const std::size_t total = grid.values.size();
  auto flush = [&] {
    if (token.empty()) return;
    if (done == total) {
      throw Error(source.path() + ": ascii data has more than the " + std::to_string(total) +
                  " values declared");
    }
    char* end = nullptr;
    double v = std::strtod(token.c_str(), &end);
    if (end == token.c_str() || *end != '\0') {
      throw Error(source.path() + ": ascii value " + std::to_string(done + 1) + " ('" + token +
                  "') is not a number");
    }
    grid.values[done++] = v;
    token.clear();
  };
  while (true) {
    std::size_t got = source.read(buffer.data(), buffer.size());
    for (std::size_t i = 0; i < got; ++i) {
      char c = buffer[i];
      if (std::isspace(static_cast<unsigned char>(c)) || c == ',') {
        flush();
      } else {
        token += c;
        if (token.size() > kMaxToken) {
          throw Error(source.path() + ": ascii value " + std::to_string(done + 1) + " is longer than " +
                      std::to_string(kMaxToken) + " characters");
        }
      }
    }
    if (got < buffer.size()) break;
  }
  flush();
  if (done < total) {
    throw Error(source.path() + ": ascii data ends after " + std::to_string(done) + " of " +
                std::to_string(total) + " values");
  }
}

}  // namespace

DenseGrid readNrrd(const std::string& path, std::size_t maxBytes) {
  NrrdHeader h = readNrrdHeader(path);
  const std::size_t size = sampleSize(h.type);
  const std::int64_t count = checkVolumeDims(path, h.dims, size, maxBytes);
  const std::uint64_t dataBytes = static_cast<std::uint64_t>(count) * size;

  std::string dataPath = path;
  std::uint64_t start = 0;
  if (h.attached) {
    start = h.headerBytes;
  } else {
    dataPath = h.dataFile;
    std::size_t slash = path.find_last_of('/');
    if (dataPath[0] != '/' && slash != std::string::npos) dataPath = path.substr(0, slash + 1) + dataPath;
    try {
      fileSizeOf(dataPath);
    } catch (const Error& e) {
      throw Error(path + ": data file " + e.what());
    }
  }
  start = skipLines(dataPath, start, h.lineSkip);
  const std::uint64_t fileBytes = fileSizeOf(dataPath);

  DenseGrid grid;
  std::unique_ptr<ByteSource> source;
  if (h.encoding == NrrdEncoding::Ascii) {
    // Every value takes at least one character and one separator: reject files too small before allocating.
    const std::uint64_t available = fileBytes > start ? fileBytes - start : 0;
    if (available + 1 < 2 * static_cast<std::uint64_t>(count)) {
      throw Error(dataPath + ": " + std::to_string(available) + " bytes of text cannot hold the " +
                  std::to_string(count) + " values declared by " + path);
    }
    grid.allocate(h.dims, maxBytes);
    FileByteSource text(dataPath, start);
    readAsciiInto(text, grid);
  } else if (h.encoding == NrrdEncoding::Raw) {
    std::uint64_t offset = start + static_cast<std::uint64_t>(std::max<std::int64_t>(h.byteSkip, 0));
    if (h.byteSkip == -1) {
      if (fileBytes < start + dataBytes) {
        throw Error(dataPath + ": data file is " + std::to_string(start + dataBytes - fileBytes) +
                    " bytes short of the " + std::to_string(dataBytes) + " bytes declared by " + path);
      }
      offset = fileBytes - dataBytes;
    } else if (fileBytes != offset + dataBytes) {
      std::string what = fileBytes < offset + dataBytes
                             ? std::to_string(offset + dataBytes - fileBytes) + " bytes short"
                             : std::to_string(fileBytes - offset - dataBytes) + " bytes longer than declared";
      throw Error(dataPath + ": data is " + what + " (" + std::to_string(h.dims[0]) + "x" +
                  std::to_string(h.dims[1]) + "x" + std::to_string(h.dims[2]) + " " + toString(h.type) +
                  " = " + std::to_string(dataBytes) + " bytes expected after byte " + std::to_string(offset) +
                  ", file has " + std::to_string(fileBytes) + ")");
    }
    grid.allocate(h.dims, maxBytes);
    source = std::make_unique<FileByteSource>(dataPath, offset);
  } else {
    grid.allocate(h.dims, maxBytes);
    source = std::make_unique<GzipByteSource>(dataPath, start);
    std::uint64_t skip = static_cast<std::uint64_t>(h.byteSkip);
    if (source->skip(skip) != skip) {
      throw Error(dataPath + ": compressed data ends within the " + std::to_string(skip) +
                  " bytes of byte skip");
    }
  }
  if (source) readSamplesInto(*source, h.type, h.endian, grid);
  if (h.encoding == NrrdEncoding::Gzip) source->expectEnd("compressed data");
  grid.geometry.spacing = h.spacing;
  grid.geometry.origin = h.origin;
  grid.description = describeDenseFile(path, "NRRD", h.type, h.dims);
  return grid;
}

}  // namespace cip
