#include "cip/readers/nrrd_reader.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <map>
#include <memory>
#include <vector>

#include "cip/core/error.h"
#include "cip/readers/volume_input.h"

namespace cip {

namespace {

/// Inflating more than this just to skip it is refused (a bogus header could otherwise keep a reader busy).
constexpr std::int64_t kMaxCompressedSkip = std::int64_t(1) << 30;

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
    out.push_back(parseNumber(trimBlanks(inner.substr(start, comma - start)), line, field));
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
  std::vector<std::string> list;  ///< `data file: LIST`: the file names on the lines after it
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
  std::string value = trimBlanks(raw.substr(std::min(raw.size(), colon + 1)));
  if (key.empty()) fail(lineNo, "empty field name");
  if (fields.count(key)) fail(lineNo, "field '" + trimBlanks(raw.substr(0, colon)) + "' appears twice");
  fields[key] = Field{value, lineNo};
}

/// After `data file: LIST`: the remaining lines of the header (up to a blank line or the end of the text)
/// are data file names. Returns the position after them.
std::size_t readListLines(std::string_view text, std::size_t pos, int& lineNo,
                          std::vector<std::string>& names) {
  while (pos < text.size()) {
    std::size_t nl = text.find('\n', pos);
    std::size_t end = nl == std::string_view::npos ? text.size() : nl;
    std::size_t next = nl == std::string_view::npos ? text.size() : nl + 1;
    ++lineNo;
    if (next > kNrrdMaxHeaderBytes) {
      throw Error("header longer than " + std::to_string(kNrrdMaxHeaderBytes >> 20) + " MiB");
    }
    std::string name = trimBlanks(text.substr(pos, end - pos));
    pos = next;
    if (name.empty()) break;
    if (name.find('\0') != std::string::npos) fail(lineNo, "binary data in the data file list");
    if (static_cast<std::int64_t>(names.size()) >= kNrrdMaxDataFiles) {
      fail(lineNo, "more than " + std::to_string(kNrrdMaxDataFiles) + " data files");
    }
    names.push_back(name);
  }
  return pos;
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
    if (const Field* f = lines.get("datafile");
        f && f->line == lineNo && splitWords(f->value).size() >= 1 && splitWords(f->value)[0] == "LIST") {
      pos = readListLines(text, pos, lineNo, lines.list);
      break;
    }
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
    fail(f.line, "dimension " + f.value +
                     " is not supported (a volume needs 3, or 4 with one non-spatial axis, first or last)");
  }
  return static_cast<int>(d);
}

std::vector<std::int64_t> parseSizesField(const Field& f, int dimension) {
  auto t = splitWords(f.value);
  expectOneEntryPerAxis(t.size(), dimension, f.line, "sizes");
  std::vector<std::int64_t> sizes;
  for (const auto& s : t) {
    sizes.push_back(parseInteger(s, f.line, "sizes"));
    if (sizes.back() < 1) fail(f.line, "sizes: every size must be at least 1, got " + s);
  }
  return sizes;
}

/// The space a `space` field names, and its dimension (4 for the "-time" spaces, which cip does not read).
WorldSpace parseSpaceName(const Field& f) {
  static const std::map<std::string, std::pair<WorldSpace, int>> spaces = {
      {"right-anterior-superior", {WorldSpace::RAS, 3}},
      {"ras", {WorldSpace::RAS, 3}},
      {"left-anterior-superior", {WorldSpace::LAS, 3}},
      {"las", {WorldSpace::LAS, 3}},
      {"left-posterior-superior", {WorldSpace::LPS, 3}},
      {"lps", {WorldSpace::LPS, 3}},
      {"scanner-xyz", {WorldSpace::Unspecified, 3}},
      {"3d-right-handed", {WorldSpace::Unspecified, 3}},
      {"3d-left-handed", {WorldSpace::Unspecified, 3}},
      {"right-anterior-superior-time", {WorldSpace::RAS, 4}},
      {"rast", {WorldSpace::RAS, 4}},
      {"left-anterior-superior-time", {WorldSpace::LAS, 4}},
      {"last", {WorldSpace::LAS, 4}},
      {"left-posterior-superior-time", {WorldSpace::LPS, 4}},
      {"lpst", {WorldSpace::LPS, 4}},
      {"scanner-xyz-time", {WorldSpace::Unspecified, 4}},
      {"3d-right-handed-time", {WorldSpace::Unspecified, 4}},
      {"3d-left-handed-time", {WorldSpace::Unspecified, 4}}};
  auto it = spaces.find(fieldKey(f.value));
  if (it == spaces.end()) return WorldSpace::Unspecified;  // an unknown name: world coordinates of its own
  if (it->second.second != 3) {
    fail(f.line, "space '" + f.value + "' has 4 dimensions; only 3-D spaces are supported");
  }
  return it->second.first;
}

/// `space` or `space dimension` (which must be 3); true when either is given.
bool parseSpace(const HeaderLines& lines, NrrdHeader& h) {
  const Field* name = lines.get("space");
  const Field* dimension = lines.get("spacedimension");
  if (name) h.space = parseSpaceName(*name);
  if (dimension && parseInteger(dimension->value, dimension->line, "space dimension") != 3) {
    fail(dimension->line, "space dimension " + dimension->value + " is not supported (only 3)");
  }
  return name || dimension;
}

bool spatialKind(const std::string& kind) {
  const std::string k = fieldKey(kind);
  return k == "domain" || k == "space" || k == "???" || k == "none";
}

/// The index of the non-spatial axis of a 4-D header: the one whose space direction is 'none', else whose
/// kind is not spatial, else a first or last axis of size 1.
int nonSpatialAxis(const HeaderLines& lines, const std::vector<std::int64_t>& sizes,
                   const Field& sizesField) {
  std::vector<int> axes;
  int line = sizesField.line;
  if (const Field* dirs = lines.get("spacedirections")) {
    auto t = vectorTokens(dirs->value, dirs->line, "space directions");
    expectOneEntryPerAxis(t.size(), 4, dirs->line, "space directions");
    for (int a = 0; a < 4; ++a)
      if (t[a] == "none") axes.push_back(a);
    line = dirs->line;
  } else if (const Field* kinds = lines.get("kinds")) {
    auto t = splitWords(kinds->value);
    expectOneEntryPerAxis(t.size(), 4, kinds->line, "kinds");
    for (int a = 0; a < 4; ++a)
      if (!spatialKind(t[a])) axes.push_back(a);
    line = kinds->line;
  } else if (sizes[0] == 1 || sizes[3] == 1) {
    axes.push_back(sizes[0] == 1 ? 0 : 3);
  } else {
    fail(line, "4-D volume " + joinDims(sizes) +
                   ": no 'kinds' or 'space directions' tell which axis is not spatial");
  }
  if (axes.size() != 1) {
    fail(line, "4-D volume " + joinDims(sizes) + " needs exactly one non-spatial axis, the header gives " +
                   std::to_string(axes.size()));
  }
  if (axes[0] != 0 && axes[0] != 3) {
    fail(line, "the non-spatial axis " + std::to_string(axes[0]) + " of " + joinDims(sizes) +
                   " is not supported (only the first or the last axis)");
  }
  return axes[0];
}

/// Placement from `space directions`: one 3-vector per spatial axis, 'none' for the non-spatial axis.
void parseSpaceDirections(const Field& f, int dimension, int frameAxis, NrrdHeader& h) {
  auto t = vectorTokens(f.value, f.line, "space directions");
  expectOneEntryPerAxis(t.size(), dimension, f.line, "space directions");
  Mat3 columns;
  std::vector<double> v;
  int a = 0;
  for (int axis = 0; axis < dimension; ++axis) {
    if (axis == frameAxis) continue;
    if (!parseVector(t[axis], f.line, "space directions", v)) {
      fail(f.line, "space directions: spatial axis " + std::to_string(axis) + " is 'none'");
    }
    if (v.size() != 3) fail(f.line, "space directions: vectors must have 3 components, got " + t[axis]);
    columns.col(a++) = Vec3(v[0], v[1], v[2]);
  }
  GridGeometry g;
  setAxes(g, columns, ("line " + std::to_string(f.line) + ": space directions").c_str());
  h.spacing = g.spacing;
  h.direction = g.direction;
}

/// Spacing from `spacings` ('nan' keeps an axis' spacing of 1; a negative spacing flips its axis).
void parseSpacings(const Field& f, int dimension, int frameAxis, NrrdHeader& h) {
  auto t = splitWords(f.value);
  expectOneEntryPerAxis(t.size(), dimension, f.line, "spacings");
  int a = 0;
  for (int axis = 0; axis < dimension; ++axis) {
    if (axis == frameAxis) continue;
    double s = parseNumber(t[axis], f.line, "spacings");
    if (!std::isnan(s)) {
      if (!std::isfinite(s) || s == 0) fail(f.line, "spacings: '" + t[axis] + "' is not a valid spacing");
      h.spacing[a] = std::abs(s);
      h.direction(a, a) = s < 0 ? -1 : 1;
    }
    ++a;
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

/// Type, dimension, sizes and the non-spatial axis; then the placement ("space directions", else
/// "spacings") and the origin.
void parseGridFields(const HeaderLines& lines, NrrdHeader& h) {
  h.type = parseTypeField(lines.require("type", "type"));
  const int dimension = parseDimensionField(lines.require("dimension", "dimension"));
  const Field& sizesField = lines.require("sizes", "sizes");
  const std::vector<std::int64_t> sizes = parseSizesField(sizesField, dimension);
  const int frameAxis = dimension == 4 ? nonSpatialAxis(lines, sizes, sizesField) : -1;
  int a = 0;
  for (int axis = 0; axis < dimension; ++axis) {
    if (axis != frameAxis) h.dims[a++] = sizes[axis];
  }
  h.frames = frameAxis < 0 ? 1 : sizes[frameAxis];
  h.framesFirst = frameAxis == 0;
  parseSpace(lines, h);
  if (const Field* dirs = lines.get("spacedirections")) {
    parseSpaceDirections(*dirs, dimension, frameAxis, h);
  } else if (const Field* spacings = lines.get("spacings")) {
    parseSpacings(*spacings, dimension, frameAxis, h);
  }
  if (const Field* f = lines.get("spaceorigin")) h.origin = parseSpaceOrigin(*f);
}

NrrdEncoding parseEncodingField(const Field& f) {
  std::string e = fieldKey(f.value);
  if (e == "raw") return NrrdEncoding::Raw;
  if (e == "gzip" || e == "gz") return NrrdEncoding::Gzip;
  if (e == "bzip2" || e == "bz2") return NrrdEncoding::Bzip2;
  if (e == "ascii" || e == "text" || e == "txt") return NrrdEncoding::Ascii;
  if (e == "hex") return NrrdEncoding::Hex;
  fail(f.line, "unknown encoding '" + f.value + "' (raw, gzip, bzip2, ascii and hex are supported)");
}

/// `%d`-style number formatting of `data file: FORMAT ...`: the pattern around one integer conversion with
/// optional '0'/'-' flags and a width ("%%" is a literal '%').
struct NamePattern {
  std::string prefix, suffix;
  bool zeroPad = false, left = false;
  std::size_t width = 0;

  std::string name(std::int64_t v) const {
    std::string digits = std::to_string(v < 0 ? -v : v);
    std::string sign = v < 0 ? "-" : "";
    std::size_t pad = width > digits.size() + sign.size() ? width - digits.size() - sign.size() : 0;
    if (left) return prefix + sign + digits + std::string(pad, ' ') + suffix;
    if (zeroPad) return prefix + sign + std::string(pad, '0') + digits + suffix;
    return prefix + std::string(pad, ' ') + sign + digits + suffix;
  }
};

NamePattern parseNamePattern(const std::string& format, int line) {
  NamePattern p;
  bool seen = false;
  std::string* out = &p.prefix;
  for (std::size_t i = 0; i < format.size(); ++i) {
    if (format[i] != '%') {
      *out += format[i];
      continue;
    }
    if (i + 1 < format.size() && format[i + 1] == '%') {
      *out += '%';
      ++i;
      continue;
    }
    if (seen) fail(line, "data file: '" + format + "' has more than one number conversion");
    seen = true;
    ++i;
    for (; i < format.size() && (format[i] == '0' || format[i] == '-'); ++i) {
      (format[i] == '0' ? p.zeroPad : p.left) = true;
    }
    for (; i < format.size() && std::isdigit(static_cast<unsigned char>(format[i])) && p.width < 100; ++i) {
      p.width = p.width * 10 + static_cast<std::size_t>(format[i] - '0');
    }
    if (i >= format.size() || (format[i] != 'd' && format[i] != 'i' && format[i] != 'u')) {
      fail(line, "data file: '" + format + "' needs one integer conversion like %d or %03d");
    }
    out = &p.suffix;
  }
  if (!seen) fail(line, "data file: '" + format + "' has no number conversion like %03d");
  return p;
}

/// The optional <subdim> after `LIST` or a format's numbers: how many axes each file holds, which fixes the
/// number of files to the product of the sizes of the other axes.
void checkSubdim(const std::string& token, std::size_t files, const HeaderLines& lines, int line) {
  const std::int64_t subdim = parseInteger(token, line, "data file subdimension");
  const Field& sizesField = lines.require("sizes", "sizes");
  auto sizes = splitWords(sizesField.value);
  if (subdim < 1 || subdim > static_cast<std::int64_t>(sizes.size())) {
    fail(line, "data file: subdimension " + token + " is not between 1 and the dimension");
  }
  std::int64_t expected = 1;
  for (std::size_t a = static_cast<std::size_t>(subdim); a < sizes.size(); ++a) {
    expected *= parseInteger(sizes[a], sizesField.line, "sizes");
    if (expected > kNrrdMaxDataFiles) break;
  }
  if (expected != static_cast<std::int64_t>(files)) {
    fail(line, "data file: subdimension " + token + " needs " + std::to_string(expected) +
                   " data files, the header names " + std::to_string(files));
  }
}

/// `data file: FORMAT MIN MAX STEP [SUBDIM]`: the names of the numbered files.
std::vector<std::string> numberedFiles(const std::vector<std::string>& t, const HeaderLines& lines,
                                       int line) {
  const NamePattern pattern = parseNamePattern(t[0], line);
  const std::int64_t first = parseInteger(t[1], line, "data file");
  const std::int64_t last = parseInteger(t[2], line, "data file");
  const std::int64_t step = parseInteger(t[3], line, "data file");
  if (step == 0 || (last - first) / step < 0 || std::abs(first) > (std::int64_t(1) << 40) ||
      std::abs(last) > (std::int64_t(1) << 40)) {
    fail(line, "data file: numbers " + t[1] + " to " + t[2] + " by " + t[3] + " are not a valid sequence");
  }
  const std::int64_t count = (last - first) / step + 1;
  if (count > kNrrdMaxDataFiles) {
    fail(line, "data file: " + std::to_string(count) + " numbered files, more than " +
                   std::to_string(kNrrdMaxDataFiles));
  }
  std::vector<std::string> names;
  for (std::int64_t n = 0; n < count; ++n) names.push_back(pattern.name(first + n * step));
  if (t.size() == 5) checkSubdim(t[4], names.size(), lines, line);
  return names;
}

/// "data file": one name, LIST, or a numbered format (attached data when absent, which needs the blank line).
void parseDataFile(const HeaderLines& lines, NrrdHeader& h) {
  if (const Field* f = lines.get("datafile")) {
    auto t = splitWords(f->value);
    if (f->value.empty()) fail(f->line, "data file: empty file name");
    if (t[0] == "LIST") {
      if (t.size() > 2) fail(f->line, "data file: LIST takes at most a subdimension after it");
      if (lines.list.empty()) fail(f->line, "data file: LIST names no files on the lines after it");
      h.dataFiles = lines.list;
      if (t.size() == 2) checkSubdim(t[1], h.dataFiles.size(), lines, f->line);
    } else if ((t.size() == 4 || t.size() == 5) && t[0].find('%') != std::string::npos) {
      h.dataFiles = numberedFiles(t, lines, f->line);
    } else {
      h.dataFiles = {f->value};
    }
  } else if (!lines.blank) {
    throw Error("header has no 'data file' field and no blank line before attached data");
  }
  h.attached = h.dataFiles.empty();
}

/// "byte skip" and "line skip", checked against the encoding.
void parseSkips(const HeaderLines& lines, NrrdHeader& h) {
  const bool text = h.encoding == NrrdEncoding::Ascii || h.encoding == NrrdEncoding::Hex;
  const bool compressed = h.encoding == NrrdEncoding::Gzip || h.encoding == NrrdEncoding::Bzip2;
  if (const Field* f = lines.get("byteskip")) {
    h.byteSkip = parseInteger(f->value, f->line, "byte skip");
    if (h.byteSkip < -1) fail(f->line, "byte skip must be -1 or more");
    if (h.byteSkip == -1 && h.encoding != NrrdEncoding::Raw) fail(f->line, "byte skip -1 needs raw encoding");
    if (h.byteSkip != 0 && text) fail(f->line, "byte skip is not allowed with ascii or hex encoding");
    if (compressed && h.byteSkip > kMaxCompressedSkip) {
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

/// Puts the samples of the file's data stream (all frames, in file order) that belong to the chosen frame
/// into the grid: sample n of the stream is frame n % frames of voxel n / frames when the frame axis is
/// first, frame n / count of voxel n % count when it is last.
struct FrameSink {
  DenseGrid& grid;
  std::uint64_t count;   ///< voxels per frame
  std::uint64_t frames;  ///< frames in the file
  bool framesFirst;
  std::uint64_t frame;

  /// The stream samples [n, n + k) with values `v`.
  void put(std::uint64_t n, const double* v, std::size_t k) const {
    double* out = grid.values.data();
    if (frames == 1) {
      std::copy(v, v + k, out + n);
    } else if (framesFirst) {
      for (std::size_t i = 0; i < k; ++i)
        if ((n + i) % frames == frame) out[(n + i) / frames] = v[i];
    } else {
      for (std::size_t i = 0; i < k; ++i)
        if ((n + i) / count == frame) out[(n + i) % count] = v[i];
    }
  }
  /// The stream samples of the chosen frame within [first, end): all of them when frames are interleaved.
  std::pair<std::uint64_t, std::uint64_t> wanted(std::uint64_t first, std::uint64_t end) const {
    if (frames == 1 || framesFirst) return {first, end};
    return {std::max(first, frame * count), std::min(end, (frame + 1) * count)};
  }
};

/// Numbers separated by blanks or commas, read one at a time from a ByteSource.
class AsciiNumbers {
 public:
  explicit AsciiNumbers(ByteSource& source) : source_(source), buffer_(std::size_t(1) << 20) {}

  /// The next number; false at the end of the data. Throws for a token that is no number.
  bool next(double& v) {
    constexpr std::size_t kMaxToken = 128;
    std::string token;
    while (true) {
      if (pos_ == size_ && !fill()) break;
      char c = buffer_[pos_++];
      if (std::isspace(static_cast<unsigned char>(c)) || c == ',') {
        if (!token.empty()) break;
        continue;
      }
      token += c;
      if (token.size() > kMaxToken) {
        throw Error(source_.path() + ": ascii value " + std::to_string(count_ + 1) + " is longer than " +
                    std::to_string(kMaxToken) + " characters");
      }
    }
    if (token.empty()) return false;
    char* end = nullptr;
    v = std::strtod(token.c_str(), &end);
    if (end == token.c_str() || *end != '\0') {
      throw Error(source_.path() + ": ascii value " + std::to_string(count_ + 1) + " ('" + token +
                  "') is not a number");
    }
    ++count_;
    return true;
  }

 private:
  bool fill() {
    size_ = source_.read(buffer_.data(), buffer_.size());
    pos_ = 0;
    return size_ > 0;
  }
  ByteSource& source_;
  std::vector<char> buffer_;
  std::size_t pos_ = 0, size_ = 0;
  std::uint64_t count_ = 0;
};

/// Bytes written as pairs of hex digits (blanks between them ignored), from a file.
class HexByteSource : public ByteSource {
 public:
  HexByteSource(const std::string& path, std::uint64_t offset) : ByteSource(path), text_(path, offset) {}
  std::size_t read(void* buffer, std::size_t n) override {
    auto* out = static_cast<unsigned char*>(buffer);
    std::size_t done = 0;
    int high = -1;
    while (done < n) {
      if (pos_ == size_) {
        size_ = text_.read(chunk_.data(), chunk_.size());
        pos_ = 0;
        if (size_ == 0) break;
      }
      const char c = chunk_[pos_++];
      if (std::isspace(static_cast<unsigned char>(c))) continue;
      if (!std::isxdigit(static_cast<unsigned char>(c))) {
        throw Error(path_ + ": hex data has '" +
                    std::string(1, std::isprint(static_cast<unsigned char>(c)) ? c : '?') + "' after " +
                    std::to_string(position_ + done) + " bytes, not a hex digit");
      }
      const int digit = std::isdigit(static_cast<unsigned char>(c)) ? c - '0' : std::tolower(c) - 'a' + 10;
      if (high < 0) {
        high = digit;
      } else {
        out[done++] = static_cast<unsigned char>(high * 16 + digit);
        high = -1;
      }
    }
    if (high >= 0) throw Error(path_ + ": hex data ends in the middle of a byte");
    position_ += done;
    return done;
  }

 private:
  FileByteSource text_;
  std::vector<char> chunk_ = std::vector<char>(std::size_t(64) << 10);
  std::size_t pos_ = 0, size_ = 0;
};

/// Decodes `k` binary samples from `source` in slabs and hands them to the sink as stream samples from `n`.
/// `before` bytes of the file's data were consumed before them, `fileBytes` is its declared size (messages).
void decodeBinary(ByteSource& source, const NrrdHeader& h, std::uint64_t n, std::uint64_t k,
                  const FrameSink& sink, std::uint64_t before, std::uint64_t fileBytes) {
  const std::size_t size = sampleSize(h.type);
  const std::size_t perSlab = std::max<std::size_t>(1, (std::size_t(4) << 20) / size);
  std::vector<unsigned char> slab(static_cast<std::size_t>(std::min<std::uint64_t>(k, perSlab)) * size);
  std::vector<double> values(slab.size() / size);
  for (std::uint64_t done = 0; done < k;) {
    const std::size_t count = static_cast<std::size_t>(std::min<std::uint64_t>(k - done, perSlab));
    const std::size_t got = source.read(slab.data(), count * size);
    if (got < count * size) {
      const std::uint64_t have = before + done * size + got;
      throw Error(source.path() + ": data ends after " + std::to_string(have) + " of " +
                  std::to_string(fileBytes) + " bytes (" + std::to_string(fileBytes - have) +
                  " bytes short)");
    }
    decodeSamples(slab.data(), count, h.type, h.endian, values.data());
    sink.put(n + done, values.data(), count);
    done += count;
  }
}

/// Reads the ascii numbers [0, end) of one data file, handing those from `from` on to the sink as stream
/// samples from `n + from`; with end == total, checks that no number follows.
void decodeAscii(ByteSource& source, std::uint64_t n, std::uint64_t from, std::uint64_t end,
                 std::uint64_t total, const FrameSink& sink) {
  AsciiNumbers numbers(source);
  std::vector<double> block;
  block.reserve(std::size_t(1) << 16);
  std::uint64_t flushed = from;
  for (std::uint64_t i = 0; i < end; ++i) {
    double v = 0;
    if (!numbers.next(v)) {
      throw Error(source.path() + ": ascii data ends after " + std::to_string(i) + " of " +
                  std::to_string(total) + " values");
    }
    if (i < from) continue;
    block.push_back(v);
    if (block.size() == block.capacity()) {
      sink.put(n + flushed, block.data(), block.size());
      flushed += block.size();
      block.clear();
    }
  }
  sink.put(n + flushed, block.data(), block.size());
  double extra = 0;
  if (end == total && numbers.next(extra)) {
    throw Error(source.path() + ": ascii data has more than the " + std::to_string(total) +
                " values declared");
  }
}

/// One data file of a NRRD volume: the header, its path, where its samples sit in the data stream.
struct DataFile {
  const std::string& header;  ///< the NRRD file's path
  const NrrdHeader& h;
  std::string path;
  std::uint64_t first;  ///< stream index of its first sample
  std::uint64_t count;  ///< samples it holds
};

/// The byte offset of the data in a raw data file, after checking the file's size.
std::uint64_t rawOffset(const DataFile& f, std::uint64_t start) {
  const std::uint64_t fileBytes = fileSizeOf(f.path);
  const std::uint64_t dataBytes = f.count * sampleSize(f.h.type);
  if (f.h.byteSkip == -1) {
    if (fileBytes < start + dataBytes) {
      throw Error(f.path + ": data file is " + std::to_string(start + dataBytes - fileBytes) +
                  " bytes short of the " + std::to_string(dataBytes) + " bytes declared by " + f.header);
    }
    return fileBytes - dataBytes;
  }
  const std::uint64_t offset = start + static_cast<std::uint64_t>(f.h.byteSkip);
  if (fileBytes != offset + dataBytes) {
    std::string what = fileBytes < offset + dataBytes
                           ? std::to_string(offset + dataBytes - fileBytes) + " bytes short"
                           : std::to_string(fileBytes - offset - dataBytes) + " bytes longer than declared";
    throw Error(f.path + ": data is " + what + " (" + std::to_string(f.count) + " " + toString(f.h.type) +
                " samples = " + std::to_string(dataBytes) + " bytes expected after byte " +
                std::to_string(offset) + ", file has " + std::to_string(fileBytes) + ")");
  }
  return offset;
}

/// Reads the samples of one data file that the sink wants.
void readDataFile(const DataFile& f, const FrameSink& sink) {
  const NrrdHeader& h = f.h;
  const auto [lo, hi] = sink.wanted(f.first, f.first + f.count);
  const std::size_t size = sampleSize(h.type);
  const std::uint64_t start = skipLines(f.path, h.attached ? h.headerBytes : 0, h.lineSkip);
  if (h.encoding == NrrdEncoding::Raw) {
    const std::uint64_t offset = rawOffset(f, start);
    if (lo >= hi) return;
    FileByteSource source(f.path, offset + (lo - f.first) * size);
    decodeBinary(source, h, lo, hi - lo, sink, (lo - f.first) * size, f.count * size);
    return;
  }
  if (lo >= hi) return;
  if (h.encoding == NrrdEncoding::Ascii) {
    // Every value takes at least one character and one separator: reject files too small before reading.
    const std::uint64_t bytes = fileSizeOf(f.path), available = bytes > start ? bytes - start : 0;
    if (available + 1 < 2 * f.count) {
      throw Error(f.path + ": " + std::to_string(available) + " bytes of text cannot hold the " +
                  std::to_string(f.count) + " values declared by " + f.header);
    }
    FileByteSource text(f.path, start);
    decodeAscii(text, f.first, lo - f.first, hi - f.first, f.count, sink);
    return;
  }
  std::unique_ptr<ByteSource> source;
  if (h.encoding == NrrdEncoding::Gzip) source = std::make_unique<GzipByteSource>(f.path, start);
  if (h.encoding == NrrdEncoding::Bzip2) source = std::make_unique<Bzip2ByteSource>(f.path, start);
  if (h.encoding == NrrdEncoding::Hex) source = std::make_unique<HexByteSource>(f.path, start);
  const std::uint64_t skip = static_cast<std::uint64_t>(h.byteSkip);
  if (source->skip(skip) != skip) {
    throw Error(f.path + ": data ends within the " + std::to_string(skip) + " bytes of byte skip");
  }
  const std::uint64_t before = (lo - f.first) * size;
  if (source->skip(before) != before) {
    throw Error(f.path + ": data ends before byte " + std::to_string(before) + " of " +
                std::to_string(f.count * size));
  }
  decodeBinary(*source, h, lo, hi - lo, sink, before, f.count * size);
  if (hi == f.first + f.count)
    source->expectEnd(h.encoding == NrrdEncoding::Hex ? "hex data" : "compressed data");
}

/// The frame to read: options.frame, checked against the file's frames.
std::uint64_t chooseFrame(const std::string& path, const NrrdHeader& h, int frame) {
  const std::string holds =
      "the file holds " + std::to_string(h.frames) + (h.frames == 1 ? " frame" : " frames");
  if (frame < 0 && h.frames > 1) {
    throw Error(path + ": a 4-D volume: " + holds + "; choose one of 0.." + std::to_string(h.frames - 1));
  }
  if (frame >= h.frames) {
    throw Error(path + ": frame " + std::to_string(frame) + " is out of range: " + holds +
                (h.frames > 1 ? " (0.." + std::to_string(h.frames - 1) + ")" : ""));
  }
  return static_cast<std::uint64_t>(std::max(frame, 0));
}

}  // namespace

std::vector<std::string> nrrdDataPaths(const std::string& path, const NrrdHeader& h) {
  if (h.attached) return {path};
  std::vector<std::string> paths;
  const std::size_t slash = path.find_last_of('/');
  for (const std::string& name : h.dataFiles) {
    const bool relative = name[0] != '/' && slash != std::string::npos;
    paths.push_back(relative ? path.substr(0, slash + 1) + name : name);
  }
  return paths;
}

namespace {

/// A NRRD file's header, the frame to read and its sizes, checked: what reading it whole and reading it in
/// slabs start from.
struct NrrdFrame {
  NrrdHeader header;
  std::uint64_t frame = 0, count = 0, frames = 0;  ///< the frame read, samples per frame, frames in the file
  std::size_t size = 0;                            ///< bytes per sample
  std::vector<std::string> paths;                  ///< the data files
};

NrrdFrame openNrrdFrame(const std::string& path, const NrrdReadOptions& options) {
  NrrdFrame nf;
  nf.header = readNrrdHeader(path);
  const NrrdHeader& h = nf.header;
  nf.frame = chooseFrame(path, h, options.frame);
  nf.size = sampleSize(h.type);
  nf.count = static_cast<std::uint64_t>(checkVolumeDims(path, h.dims, nf.size, options.maxBytes));
  nf.frames = static_cast<std::uint64_t>(h.frames);
  if (nf.frames > std::numeric_limits<std::uint64_t>::max() / nf.size / nf.count) {
    throw Error(path + ": " + std::to_string(nf.frames) + " frames of " + std::to_string(nf.count) +
                " samples overflow 64 bits");
  }
  nf.paths = nrrdDataPaths(path, h);
  return nf;
}

}  // namespace

std::optional<DenseDataLayout> nrrdDataLayout(const std::string& path, const NrrdReadOptions& options,
                                              std::string& whyNot) {
  const NrrdFrame nf = openNrrdFrame(path, options);
  const NrrdHeader& h = nf.header;
  const std::uint64_t frame = nf.frame, count = nf.count, frames = nf.frames;
  const std::size_t size = nf.size;
  const std::vector<std::string>& paths = nf.paths;
  if (h.encoding == NrrdEncoding::Ascii || h.encoding == NrrdEncoding::Hex) {
    whyNot = "ascii and hex data are read whole";
  } else if (paths.size() != 1) {
    whyNot = "data in several files is read whole";
  } else if (frames > 1 && h.framesFirst) {
    whyNot = "interleaved frames are read whole";
  }
  if (!whyNot.empty()) return std::nullopt;
  try {
    fileSizeOf(paths[0]);
  } catch (const Error& e) {
    throw Error(path + ": data file " + e.what());
  }
  DenseDataLayout layout;
  layout.path = path;
  layout.dataPath = paths[0];
  const std::uint64_t start = skipLines(paths[0], h.attached ? h.headerBytes : 0, h.lineSkip);
  if (h.encoding == NrrdEncoding::Raw) {
    layout.offset = rawOffset({path, h, paths[0], 0, count * frames}, start) + frame * count * size;
  } else {
    layout.encoding = h.encoding == NrrdEncoding::Gzip ? DataEncoding::Gzip : DataEncoding::Bzip2;
    layout.streamStart = start;
    layout.offset = static_cast<std::uint64_t>(h.byteSkip) + frame * count * size;
    layout.checkEnd = frame + 1 == frames;
  }
  layout.type = h.type;
  layout.endian = h.endian;
  layout.geometry.dims = h.dims;
  layout.geometry.spacing = h.spacing;
  layout.geometry.direction = h.direction;
  layout.geometry.origin = h.origin;
  layout.geometry.space = h.space;
  layout.description = describeDenseFile(path, "NRRD", h.type, h.dims);
  if (h.frames > 1)
    layout.description += " frame " + std::to_string(frame) + " of " + std::to_string(h.frames);
  return layout;
}

DenseGrid readNrrd(const std::string& path, const NrrdReadOptions& options) {
  const NrrdFrame nf = openNrrdFrame(path, options);
  const NrrdHeader& h = nf.header;
  const std::uint64_t frame = nf.frame, count = nf.count, frames = nf.frames;
  const std::vector<std::string>& paths = nf.paths;
  const std::uint64_t total = count * frames;
  if (total % paths.size() != 0) {
    throw Error(path + ": " + std::to_string(paths.size()) + " data files cannot hold equal parts of " +
                std::to_string(total) + " samples");
  }
  for (const std::string& p : paths) {
    try {
      fileSizeOf(p);
    } catch (const Error& e) {
      throw Error(path + ": data file " + e.what());
    }
  }
  DenseGrid grid;
  grid.allocate(h.dims, options.maxBytes);
  const FrameSink sink{grid, count, frames, h.framesFirst, frame};
  const std::uint64_t perFile = total / paths.size();
  for (std::size_t i = 0; i < paths.size(); ++i)
    readDataFile({path, h, paths[i], i * perFile, perFile}, sink);
  grid.geometry.spacing = h.spacing;
  grid.geometry.direction = h.direction;
  grid.geometry.origin = h.origin;
  grid.geometry.space = h.space;
  grid.description = describeDenseFile(path, "NRRD", h.type, h.dims);
  if (h.frames > 1) grid.description += " frame " + std::to_string(frame) + " of " + std::to_string(h.frames);
  return grid;
}

}  // namespace cip
