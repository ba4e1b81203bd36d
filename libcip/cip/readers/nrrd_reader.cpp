#include "cip/readers/nrrd_reader.h"

#include <algorithm>
#include <array>
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

/// A header field's value and the line it stood on.
struct Field {
  std::string value;
  int line;
};

/// The header's lines read up to the blank line that ends it: the fields by lookup key (fieldKey), the
/// magic's version, where the header ends and whether a blank line ended it (rather than the end of the
/// text).
struct HeaderLines {
  std::map<std::string, Field> fields;
  int version = 0;
  std::size_t headerBytes = 0;
  bool blank = false;

  const Field* get(const char* key) const {
    auto it = fields.find(key);
    return it == fields.end() ? nullptr : &it->second;
  }
  const Field& require(const char* key, const char* name) const {
    const Field* f = get(key);
    if (!f) throw Error("header has no '" + std::string(name) + "' field");
    return *f;
  }
};

/// The NRRD version from the first line ("NRRD0001" to "NRRD0005", line end excluded).
int parseMagic(std::string_view firstLine) {
  std::string_view magic = firstLine.substr(0, 9);
  if (!magic.empty() && magic.back() == '\r') magic.remove_suffix(1);
  if (magic.size() != 8 || magic.substr(0, 7) != "NRRD000" || magic[7] < '1' || magic[7] > '5') {
    std::string shown;
    for (char c : firstLine.substr(0, 16)) shown += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
    throw Error("not a NRRD file (starts with '" + shown + "', expected NRRD0001..NRRD0005)");
  }
  return magic[7] - '0';
}

/// Adds the field of one non-blank header line (`raw`, without its line end) to `fields`; comments and
/// "key:=value" pairs are skipped.
void addFieldLine(std::string_view raw, int lineNo, std::map<std::string, Field>& fields) {
  if (raw[0] == '#') return;
  std::size_t colon = raw.find(": ");
  std::size_t pair = raw.find(":=");
  if (pair != std::string_view::npos && pair < colon) return;  // "key:=value" pair: not used
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

/// Splits the text into lines up to the first blank line (or the end of the text): the magic line, then
/// fields.
HeaderLines readHeaderLines(std::string_view text) {
  HeaderLines lines;
  std::size_t pos = 0;
  int lineNo = 0;
  while (pos < text.size()) {
    std::size_t nl = text.find('\n', pos);
    std::size_t end = nl == std::string_view::npos ? text.size() : nl;
    std::size_t next = nl == std::string_view::npos ? text.size() : nl + 1;
    ++lineNo;
    if (lineNo == 1) {
      lines.version = parseMagic(text.substr(pos, end - pos));
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
      lines.blank = true;
      break;
    }
    addFieldLine(raw, lineNo, lines.fields);
  }
  if (lineNo == 0) throw Error("empty file (not a NRRD file)");
  lines.headerBytes = pos;
  return lines;
}

/// Fails unless a per-axis field has one entry per axis.
void expectOneEntryPerAxis(std::size_t entries, int dimension, int line, const std::string& field) {
  if (static_cast<int>(entries) != dimension) {
    fail(line,
         field + " has " + std::to_string(entries) + " entries for dimension " + std::to_string(dimension));
  }
}

SampleType parseTypeField(const Field& f) {
  std::string t = fieldKey(f.value);
  if (t == "block") fail(f.line, "type 'block' is not supported");
  if (t.find("64") != std::string::npos || t.find("long") != std::string::npos) {
    fail(f.line, "type '" + f.value + "' (64-bit integers) is not supported");
  }
  try {
    return parseSampleType(f.value);
  } catch (const Error& e) {
    fail(f.line, e.what());
  }
}

int parseDimensionField(const Field& f) {
  std::int64_t d = parseInteger(f.value, f.line, "dimension");
  if (d != 3 && d != 4) {
    fail(f.line,
         "dimension " + f.value + " is not supported (a volume needs 3, or 4 with a leading axis of size 1)");
  }
  return static_cast<int>(d);
}

/// The sizes of the three spatial axes (the last three of `dimension`).
std::array<std::int64_t, 3> parseSizesField(const Field& f, int dimension) {
  auto t = tokens(f.value);
  expectOneEntryPerAxis(t.size(), dimension, f.line, "sizes");
  std::vector<std::int64_t> sizes;
  for (const auto& s : t) {
    sizes.push_back(parseInteger(s, f.line, "sizes"));
    if (sizes.back() < 1) fail(f.line, "sizes: every size must be at least 1, got " + s);
  }
  if (dimension == 4 && sizes[0] != 1) {
    fail(f.line, "4-D volume " + joinDims(sizes) +
                     " has several values per voxel; only a leading axis of size 1 is supported");
  }
  const int first = dimension - 3;  // index of the first spatial axis
  return {sizes[first], sizes[first + 1], sizes[first + 2]};
}

/// The spacing from "space directions": one axis-aligned vector per spatial axis, 'none' for a leading
/// non-spatial axis.
void parseSpaceDirections(const Field& f, int dimension, Vec3& spacing) {
  const int first = dimension - 3;
  auto t = vectorTokens(f.value, f.line, "space directions");
  expectOneEntryPerAxis(t.size(), dimension, f.line, "space directions");
  std::vector<double> v;
  for (int a = 0; a < 3; ++a) {
    if (!parseVector(t[first + a], f.line, "space directions", v)) {
      fail(f.line, "space directions: spatial axis " + std::to_string(a) + " is 'none'");
    }
    if (v.size() != 3) fail(f.line, "space directions: vectors must have 3 components, got " + t[first + a]);
    double length = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    if (!std::isfinite(length) || length <= 0) {
      fail(f.line, "space directions: axis " + std::to_string(a) + " has a zero or invalid length");
    }
    for (int b = 0; b < 3; ++b) {
      if (b != a && std::abs(v[b]) > 1e-9 * length) {
        fail(f.line, "space directions are rotated or sheared (axis " + std::to_string(a) + " is " +
                         t[first + a] + "); only axis-aligned volumes are supported");
      }
    }
    spacing[a] = std::abs(v[a]);
  }
  if (dimension == 4 && t[0] != "none") fail(f.line, "space directions: the non-spatial axis must be 'none'");
}

/// The spacing from "spacings" ('nan' keeps an axis' spacing).
void parseSpacings(const Field& f, int dimension, Vec3& spacing) {
  const int first = dimension - 3;
  auto t = tokens(f.value);
  expectOneEntryPerAxis(t.size(), dimension, f.line, "spacings");
  for (int a = 0; a < 3; ++a) {
    double s = parseNumber(t[first + a], f.line, "spacings");
    if (std::isnan(s)) continue;  // unknown spacing: keep 1
    if (!std::isfinite(s) || s == 0) fail(f.line, "spacings: '" + t[first + a] + "' is not a valid spacing");
    spacing[a] = std::abs(s);
  }
}

Vec3 parseSpaceOrigin(const Field& f) {
  auto t = vectorTokens(f.value, f.line, "space origin");
  std::vector<double> v;
  if (t.size() != 1 || !parseVector(t[0], f.line, "space origin", v) || v.size() != 3) {
    fail(f.line, "space origin: expected a 3-vector like (0,0,0), got '" + f.value + "'");
  }
  Vec3 origin;
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(v[a])) fail(f.line, "space origin: components must be finite");
    origin[a] = v[a];
  }
  return origin;
}

/// Type, dimension and sizes; then the spacing ("space directions", else "spacings") and the origin.
void parseGridFields(const HeaderLines& lines, NrrdHeader& h) {
  h.type = parseTypeField(lines.require("type", "type"));
  const int dimension = parseDimensionField(lines.require("dimension", "dimension"));
  h.dims = parseSizesField(lines.require("sizes", "sizes"), dimension);
  if (const Field* dirs = lines.get("spacedirections")) {
    parseSpaceDirections(*dirs, dimension, h.spacing);
  } else if (const Field* spacings = lines.get("spacings")) {
    parseSpacings(*spacings, dimension, h.spacing);
  }
  if (const Field* f = lines.get("spaceorigin")) h.origin = parseSpaceOrigin(*f);
}

NrrdEncoding parseEncodingField(const Field& f) {
  std::string e = fieldKey(f.value);
  if (e == "raw") return NrrdEncoding::Raw;
  if (e == "gzip" || e == "gz") return NrrdEncoding::Gzip;
  if (e == "ascii" || e == "text" || e == "txt") return NrrdEncoding::Ascii;
  if (e == "hex" || e == "bzip2" || e == "bz2") {
    fail(f.line, "encoding '" + f.value + "' is not supported (raw, gzip and ascii are)");
  }
  fail(f.line, "unknown encoding '" + f.value + "'");
}

/// "data file": one file name (attached data when absent, which needs the blank line).
void parseDataFile(const HeaderLines& lines, NrrdHeader& h) {
  if (const Field* f = lines.get("datafile")) {
    auto t = tokens(f->value);
    if (f->value.empty()) fail(f->line, "data file: empty file name");
    if (!t.empty() && t[0] == "LIST") fail(f->line, "data file: LIST (several data files) is not supported");
    if (t.size() >= 4 && t[0].find('%') != std::string::npos) {
      fail(f->line, "data file: several numbered data files are not supported");
    }
    h.dataFile = f->value;
  } else if (!lines.blank) {
    throw Error("header has no 'data file' field and no blank line before attached data");
  }
  h.attached = h.dataFile.empty();
}

/// "byte skip" and "line skip", checked against the encoding.
void parseSkips(const HeaderLines& lines, NrrdHeader& h) {
  if (const Field* f = lines.get("byteskip")) {
    h.byteSkip = parseInteger(f->value, f->line, "byte skip");
    if (h.byteSkip < -1) fail(f->line, "byte skip must be -1 or more");
    if (h.byteSkip == -1 && h.encoding != NrrdEncoding::Raw) fail(f->line, "byte skip -1 needs raw encoding");
    if (h.byteSkip != 0 && h.encoding == NrrdEncoding::Ascii)
      fail(f->line, "byte skip is not allowed with ascii encoding");
    if (h.encoding == NrrdEncoding::Gzip && h.byteSkip > kMaxCompressedSkip) {
      fail(f->line, "byte skip " + f->value + " is too large for compressed data (at most 1 GiB)");
    }
  }
  if (const Field* f = lines.get("lineskip")) {
    h.lineSkip = parseInteger(f->value, f->line, "line skip");
    if (h.lineSkip < 0) fail(f->line, "line skip must be 0 or more");
  }
}

/// Encoding and endianness (needed for binary samples wider than a byte); then where the data is.
void parseDataFields(const HeaderLines& lines, NrrdHeader& h) {
  h.encoding = parseEncodingField(lines.require("encoding", "encoding"));
  if (const Field* f = lines.get("endian")) {
    try {
      h.endian = parseEndian(f->value);
    } catch (const Error& e) {
      fail(f->line, e.what());
    }
  } else if (sampleSize(h.type) > 1 && h.encoding != NrrdEncoding::Ascii) {
    throw Error("header has no 'endian' field, needed for " + std::string(toString(h.type)) + " samples");
  }
  parseDataFile(lines, h);
  parseSkips(lines, h);
}

}  // namespace

NrrdHeader parseNrrdHeader(std::string_view text) {
  const HeaderLines lines = readHeaderLines(text);
  NrrdHeader h;
  h.version = lines.version;
  h.headerBytes = lines.headerBytes;
  parseGridFields(lines, h);
  parseDataFields(lines, h);
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

std::string nrrdDataPath(const std::string& path, const NrrdHeader& h) {
  if (h.attached) return path;
  std::string dataPath = h.dataFile;
  const std::size_t slash = path.find_last_of('/');
  if (dataPath[0] != '/' && slash != std::string::npos) dataPath = path.substr(0, slash + 1) + dataPath;
  return dataPath;
}

DenseGrid readNrrd(const std::string& path, std::size_t maxBytes) {
  NrrdHeader h = readNrrdHeader(path);
  const std::size_t size = sampleSize(h.type);
  const std::int64_t count = checkVolumeDims(path, h.dims, size, maxBytes);
  const std::uint64_t dataBytes = static_cast<std::uint64_t>(count) * size;

  const std::string dataPath = nrrdDataPath(path, h);
  std::uint64_t start = 0;
  if (h.attached) {
    start = h.headerBytes;
  } else {
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
