#include "cip/readers/metaimage_reader.h"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <map>
#include <memory>

#include "cip/core/error.h"
#include "cip/readers/volume_input.h"

namespace cip {

namespace {

constexpr std::size_t kMaxHeaderBytes = std::size_t(1) << 20;
constexpr std::int64_t kMaxDataFiles = std::int64_t(1) << 20;  ///< data files of one LIST or pattern

std::string lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

/// A line of the file quoted for an error message: printable characters only, at most 40.
std::string quoted(const std::string& s) {
  std::string out;
  for (char c : s.substr(0, 40)) out += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
  return "'" + out + (s.size() > 40 ? "...'" : "'");
}

double parseNumber(const std::string& word, const std::string& key) {
  errno = 0;
  char* end = nullptr;
  double v = std::strtod(word.c_str(), &end);
  if (end == word.c_str() || *end != '\0' || !std::isfinite(v))
    throw Error("MetaImage " + key + ": " + quoted(word) + " is not a finite number");
  return v;
}

std::int64_t parseInteger(const std::string& word, const std::string& key) {
  errno = 0;
  char* end = nullptr;
  long long v = std::strtoll(word.c_str(), &end, 10);
  if (end == word.c_str() || *end != '\0' || errno == ERANGE)
    throw Error("MetaImage " + key + ": " + quoted(word) + " is not an integer");
  return v;
}

/// The header's fields by lower-case key, with their spelling as written.
struct Fields {
  std::map<std::string, std::pair<std::string, std::string>> byKey;  ///< key -> (name, value)

  const std::string* find(std::initializer_list<const char*> names, std::string* name = nullptr) const {
    for (const char* n : names) {
      auto it = byKey.find(lower(n));
      if (it != byKey.end()) {
        if (name) *name = it->second.first;
        return &it->second.second;
      }
    }
    return nullptr;
  }
  const std::string& require(const char* key) const {
    const std::string* v = find({key});
    if (!v) throw Error(std::string("MetaImage header has no ") + key + " field");
    return *v;
  }
  bool flag(std::initializer_list<const char*> names, bool fallback) const {
    std::string name;
    const std::string* v = find(names, &name);
    if (!v) return fallback;
    const std::string t = lower(*v);
    if (t == "true" || t == "1") return true;
    if (t == "false" || t == "0") return false;
    throw Error("MetaImage " + name + " is " + quoted(*v) + " (expected True or False)");
  }
  /// Exactly `count` numbers of the first field among `names` that is present; empty when none is.
  std::vector<double> numbers(std::initializer_list<const char*> names, std::size_t count) const {
    std::string name;
    const std::string* v = find(names, &name);
    if (!v) return {};
    std::vector<std::string> w = splitWords(*v);
    if (w.size() != count)
      throw Error("MetaImage " + name + " has " + std::to_string(w.size()) + " numbers, expected " +
                  std::to_string(count));
    std::vector<double> out;
    for (const auto& s : w) out.push_back(parseNumber(s, name));
    return out;
  }
};

SampleType elementType(const std::string& text) {
  static const std::pair<const char*, SampleType> kTypes[] = {
      {"MET_UCHAR", SampleType::UInt8},   {"MET_CHAR", SampleType::Int8},
      {"MET_USHORT", SampleType::UInt16}, {"MET_SHORT", SampleType::Int16},
      {"MET_UINT", SampleType::UInt32},   {"MET_INT", SampleType::Int32},
      {"MET_FLOAT", SampleType::Float32}, {"MET_DOUBLE", SampleType::Float64}};
  for (const auto& [name, type] : kTypes)
    if (text == name) return type;
  throw Error("MetaImage ElementType " + quoted(text) +
              " is not supported (MET_UCHAR, MET_CHAR, MET_USHORT, MET_SHORT, MET_UINT, MET_INT, MET_FLOAT, "
              "MET_DOUBLE are)");
}

/// NDims, DimSize and the frame count.
int readDims(const Fields& f, MetaImageHeader& h, std::vector<std::int64_t>& dimSize) {
  const std::int64_t nd = parseInteger(trimBlanks(f.require("NDims")), "NDims");
  if (nd != 3 && nd != 4)
    throw Error("MetaImage NDims is " + std::to_string(nd) +
                "; a volume needs 3 (or 4 for a series of frames)");
  std::vector<std::string> w = splitWords(f.require("DimSize"));
  if (w.size() != static_cast<std::size_t>(nd))
    throw Error("MetaImage DimSize has " + std::to_string(w.size()) +
                " numbers, expected NDims = " + std::to_string(nd));
  for (const auto& s : w) {
    dimSize.push_back(parseInteger(s, "DimSize"));
    if (dimSize.back() < 1)
      throw Error("MetaImage DimSize " + std::to_string(dimSize.back()) + " is invalid (must be >= 1)");
  }
  for (int a = 0; a < 3; ++a) h.geometry.dims[a] = dimSize[static_cast<std::size_t>(a)];
  h.frames = nd == 4 ? dimSize[3] : 1;
  return static_cast<int>(nd);
}

/// ElementSpacing (or ElementSize), Offset (Origin, Position) and TransformMatrix (Rotation, Orientation):
/// world = Offset + TransformMatrix * (spacing * index), the matrix listed column after column.
void readPlacement(const Fields& f, int nd, MetaImageHeader& h) {
  const auto n = static_cast<std::size_t>(nd);
  std::vector<double> spacing = f.numbers({"ElementSpacing"}, n);
  if (spacing.empty()) spacing = f.numbers({"ElementSize"}, n);
  if (spacing.empty()) spacing.assign(n, 1.0);
  for (int a = 0; a < 3; ++a) {
    if (!(spacing[static_cast<std::size_t>(a)] > 0))
      throw Error("MetaImage ElementSpacing " + std::to_string(spacing[static_cast<std::size_t>(a)]) +
                  " is invalid (must be positive)");
  }
  std::vector<double> offset = f.numbers({"Offset", "Origin", "Position"}, n);
  if (offset.empty()) offset.assign(n, 0.0);
  std::vector<double> matrix = f.numbers({"TransformMatrix", "Rotation", "Orientation"}, n * n);
  Mat3 columns;
  for (std::size_t a = 0; a < 3; ++a) {
    for (std::size_t r = 0; r < 3; ++r) {
      const double m = matrix.empty() ? (a == r ? 1.0 : 0.0) : matrix[a * n + r];
      columns(static_cast<int>(r), static_cast<int>(a)) = m * spacing[a];
    }
  }
  setAxes(h.geometry, columns, "MetaImage TransformMatrix");
  h.geometry.origin = Vec3(offset[0], offset[1], offset[2]);
  h.geometry.space = WorldSpace::LPS;
}

/// Storage fields: byte order, compression, header size, channels.
void readStorage(const Fields& f, MetaImageHeader& h) {
  h.type = elementType(trimBlanks(f.require("ElementType")));
  if (const std::string* type = f.find({"ObjectType"}); type && lower(trimBlanks(*type)) != "image")
    throw Error("MetaImage ObjectType is " + quoted(trimBlanks(*type)) + ", not Image");
  if (!f.flag({"BinaryData"}, true))
    throw Error("MetaImage BinaryData = False (ASCII samples) is not supported");
  h.endian = f.flag({"BinaryDataByteOrderMSB", "ElementByteOrderMSB"}, false) ? Endian::Big : Endian::Little;
  h.compressed = f.flag({"CompressedData"}, false);
  if (const std::string* v = f.find({"CompressedDataSize"})) {
    h.compressedBytes = parseInteger(trimBlanks(*v), "CompressedDataSize");
    if (h.compressedBytes < 0) throw Error("MetaImage CompressedDataSize is negative");
  }
  if (const std::string* v = f.find({"HeaderSize"})) {
    h.headerSize = parseInteger(trimBlanks(*v), "HeaderSize");
    if (h.headerSize < -1)
      throw Error("MetaImage HeaderSize " + std::to_string(h.headerSize) + " is invalid");
  }
  if (const std::string* v = f.find({"ElementNumberOfChannels"});
      v && parseInteger(trimBlanks(*v), "ElementNumberOfChannels") != 1)
    throw Error("MetaImage ElementNumberOfChannels is " + trimBlanks(*v) +
                "; only scalar images (1) are supported");
  if (const std::string* v = f.find({"AnatomicalOrientation"})) h.anatomicalOrientation = trimBlanks(*v);
}

/// The folder of `path` with a trailing '/', or "" for a bare file name.
std::string folderOf(const std::string& path) {
  std::size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? "" : path.substr(0, slash + 1);
}

std::string resolve(const std::string& name, const std::string& headerPath) {
  return !name.empty() && name[0] == '/' ? name : folderOf(headerPath) + name;
}

/// `pattern` with its one integer conversion (%d, %i, %u, with an optional 0 flag and width) replaced by n.
std::string formatPattern(const std::string& pattern, std::int64_t n) {
  std::string out;
  int conversions = 0;
  for (std::size_t i = 0; i < pattern.size(); ++i) {
    if (pattern[i] != '%') {
      out += pattern[i];
      continue;
    }
    if (i + 1 < pattern.size() && pattern[i + 1] == '%') {
      out += '%';
      ++i;
      continue;
    }
    std::size_t j = i + 1;
    const bool zero = j < pattern.size() && pattern[j] == '0';
    if (zero) ++j;
    std::size_t width = 0;
    while (j < pattern.size() && std::isdigit(static_cast<unsigned char>(pattern[j])) && width < 100)
      width = width * 10 + static_cast<std::size_t>(pattern[j++] - '0');
    if (j >= pattern.size() || (pattern[j] != 'd' && pattern[j] != 'i' && pattern[j] != 'u') || width > 20 ||
        ++conversions > 1)
      throw Error("MetaImage ElementDataFile pattern " + quoted(pattern) +
                  " must hold exactly one integer conversion such as %03d");
    std::string digits = std::to_string(n < 0 ? -n : n);
    std::string sign = n < 0 ? "-" : "";
    while (sign.size() + digits.size() < width) {
      if (zero)
        digits.insert(digits.begin(), '0');
      else
        sign.insert(sign.begin(), ' ');
    }
    out += sign + digits;
    i = j;
  }
  if (conversions != 1)
    throw Error("MetaImage ElementDataFile pattern " + quoted(pattern) +
                " must hold exactly one integer conversion");
  return out;
}

/// "pattern [first [last [step]]]": one file per slice of the last axis (MetaIO's numbering).
void patternFiles(const std::string& value, const std::string& path, std::int64_t count, MetaImageHeader& h) {
  if (count > kMaxDataFiles)
    throw Error("MetaImage ElementDataFile pattern would need " + std::to_string(count) +
                " data files (at most " + std::to_string(kMaxDataFiles) + ")");
  std::vector<std::string> w = splitWords(value);
  std::string pattern = w[0];
  std::vector<std::string> numbers(w.begin() + 1, w.end());
  if (w.size() >= 5) {  // a file name with spaces: the last three words are the numbers
    pattern = value.substr(0, value.find(w[w.size() - 3], w[0].size()));
    pattern = trimBlanks(pattern);
    numbers.assign(w.end() - 3, w.end());
  }
  constexpr std::int64_t kLimit = std::int64_t(1) << 40;  // file numbers, steps: far below overflow
  std::int64_t first = numbers.empty() ? 1 : parseInteger(numbers[0], "ElementDataFile");
  const std::int64_t step = numbers.size() >= 3 ? parseInteger(numbers[2], "ElementDataFile") : 1;
  const bool inRange = first >= -kLimit && first <= kLimit && step >= 1 && step <= kLimit;
  const std::int64_t last =
      numbers.size() >= 2 ? parseInteger(numbers[1], "ElementDataFile") : (inRange ? first + count - 1 : 0);
  if (!inRange || first + (count - 1) * step > last)
    throw Error("MetaImage ElementDataFile " + quoted(value) + " does not name " + std::to_string(count) +
                " files (first, last, step)");
  for (std::int64_t i = 0; i < count; ++i)
    h.dataFiles.push_back(resolve(formatPattern(pattern, first + i * step), path));
}

/// The data files named by ElementDataFile; LIST names are read from the lines from `pos` on.
void readDataFiles(const std::string& value, const std::string& text, std::size_t pos,
                   const std::string& path, const std::vector<std::int64_t>& dimSize, MetaImageHeader& h) {
  const auto nd = static_cast<int>(dimSize.size());
  std::vector<std::string> w = splitWords(value);
  if (w.empty()) throw Error("MetaImage ElementDataFile is empty");
  if (lower(value) == "local") {
    h.local = true;
    h.dataFiles = {path};
    h.dataStart = pos;
    return;
  }
  if (w[0] == "LIST") {
    int fileDims = w.size() > 1 ? std::atoi(w[1].c_str()) : 0;
    if (fileDims <= 0 || fileDims > nd) fileDims = nd - 1;
    std::int64_t count = 1;
    for (int d = fileDims; d < nd; ++d) {
      if (dimSize[static_cast<std::size_t>(d)] > kMaxDataFiles ||
          (count *= dimSize[static_cast<std::size_t>(d)]) > kMaxDataFiles)
        throw Error("MetaImage ElementDataFile LIST would need more than " + std::to_string(kMaxDataFiles) +
                    " data files");
    }
    std::size_t listed = 0;
    while (pos < text.size() && static_cast<std::int64_t>(listed) < count) {
      std::size_t end = text.find('\n', pos);
      if (end == std::string::npos) end = text.size();
      std::string name = trimBlanks(text.substr(pos, end - pos));
      pos = end + 1;
      if (name.empty()) continue;
      h.dataFiles.push_back(resolve(name, path));
      ++listed;
    }
    if (static_cast<std::int64_t>(listed) != count)
      throw Error("MetaImage ElementDataFile LIST needs " + std::to_string(count) +
                  " file names, the header lists " + std::to_string(listed));
    return;
  }
  if (value.find('%') != std::string::npos) return patternFiles(value, path, dimSize.back(), h);
  h.dataFiles = {resolve(value, path)};
}

}  // namespace

MetaImageHeader parseMetaImageHeader(const std::string& text, const std::string& path) {
  Fields fields;
  std::size_t pos = 0;
  int lineNumber = 0;
  std::string dataFile;
  bool ended = false;
  while (pos < text.size() && !ended) {
    std::size_t end = text.find('\n', pos);
    if (end == std::string::npos) end = text.size();
    std::string line = trimBlanks(text.substr(pos, end - pos));
    pos = std::min(end + 1, text.size());
    ++lineNumber;
    if (line.empty()) continue;
    std::size_t sep = line.find('=');
    if (sep == std::string::npos) sep = line.find(':');
    if (sep == std::string::npos || sep == 0)
      throw Error("not a MetaImage header: line " + std::to_string(lineNumber) + " " + quoted(line) +
                  " is not 'Key = Value'");
    std::string key = trimBlanks(line.substr(0, sep));
    std::string value = trimBlanks(line.substr(sep + 1));
    fields.byKey[lower(key)] = {key, value};
    if (lower(key) == "elementdatafile") {
      dataFile = value;
      ended = true;
    }
  }
  if (!ended) {
    throw Error(std::string("MetaImage header has no ElementDataFile field") +
                (text.size() >= kMaxHeaderBytes ? " in its first MiB" : " (it must end the header)"));
  }
  MetaImageHeader h;
  std::vector<std::int64_t> dimSize;
  const int nd = readDims(fields, h, dimSize);
  readStorage(fields, h);
  readPlacement(fields, nd, h);
  readDataFiles(dataFile, text, pos, path, dimSize, h);
  return h;
}

MetaImageHeader readMetaImageHeader(const std::string& path) {
  FileByteSource source(path, 0);
  std::string text(kMaxHeaderBytes, '\0');
  text.resize(source.read(text.data(), text.size()));
  try {
    return parseMetaImageHeader(text, path);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

namespace {

/// One stretch of samples: the bytes of one data file from `start`, plain or zlib-compressed.
struct Piece {
  std::string path;
  std::uint64_t start = 0;
  std::uint64_t bytes = 0;  ///< samples it holds (inflated)
  bool compressed = false;
};

/// The samples of a list of pieces read one after the other; each compressed piece must inflate to exactly
/// its size.
class PieceSource : public ByteSource {
 public:
  PieceSource(const std::string& path, std::vector<Piece> pieces)
      : ByteSource(path), pieces_(std::move(pieces)) {}

  /// Positions the source at logical byte `at` (skipping within a compressed piece by inflating).
  void seek(std::uint64_t at) {
    index_ = 0;
    while (index_ < pieces_.size() && at >= pieces_[index_].bytes) at -= pieces_[index_++].bytes;
    open(at);
  }

  std::size_t read(void* buffer, std::size_t n) override {
    std::size_t done = 0;
    while (done < n && current_) {
      const Piece& p = pieces_[index_];
      const auto want = static_cast<std::size_t>(std::min<std::uint64_t>(n - done, left_));
      const std::size_t got = current_->read(static_cast<unsigned char*>(buffer) + done, want);
      if (got < want) {
        throw Error(p.path + ": data ends after " + std::to_string(p.bytes - left_ + got) + " of " +
                    std::to_string(p.bytes) + " bytes");
      }
      done += got;
      left_ -= got;
      if (left_ == 0) {
        if (p.compressed) current_->expectEnd("compressed data");
        ++index_;
        open(0);
      }
    }
    position_ += done;
    return done;
  }

 private:
  void open(std::uint64_t within) {
    current_.reset();
    if (index_ >= pieces_.size()) return;
    const Piece& p = pieces_[index_];
    left_ = p.bytes - within;
    if (!p.compressed) {
      current_ = std::make_unique<FileByteSource>(p.path, p.start + within);
      return;
    }
    current_ = std::make_unique<GzipByteSource>(p.path, p.start);
    if (current_->skip(within) != within)
      throw Error(p.path + ": compressed data end after " + std::to_string(current_->position()) + " of " +
                  std::to_string(p.bytes) + " bytes");
  }

  std::vector<Piece> pieces_;
  std::size_t index_ = 0;
  std::uint64_t left_ = 0;
  std::unique_ptr<ByteSource> current_;
};

/// Where the samples of each data file start, checking the sizes of plain files.
std::vector<Piece> dataPieces(const std::string& path, const MetaImageHeader& h, std::uint64_t allBytes) {
  std::vector<Piece> pieces;
  const std::uint64_t each = allBytes / h.dataFiles.size();
  for (const std::string& file : h.dataFiles) {
    Piece p{file, h.local ? h.dataStart : 0, each, h.compressed};
    const std::uint64_t fileBytes = fileSizeOf(file);
    if (h.headerSize > 0) p.start = static_cast<std::uint64_t>(h.headerSize);
    if (h.compressed) {
      if (h.headerSize == -1) {
        if (h.compressedBytes < 0 || h.dataFiles.size() > 1)
          throw Error(path +
                      ": HeaderSize = -1 with compressed data needs CompressedDataSize (and one data file)");
        if (static_cast<std::uint64_t>(h.compressedBytes) > fileBytes)
          throw Error(path + ": CompressedDataSize " + std::to_string(h.compressedBytes) +
                      " is larger than " + file + " (" + std::to_string(fileBytes) + " bytes)");
        p.start = fileBytes - static_cast<std::uint64_t>(h.compressedBytes);
      }
      if (p.start > fileBytes)
        throw Error(file + ": data start at byte " + std::to_string(p.start) +
                    ", beyond the end of the file (" + std::to_string(fileBytes) + " bytes)");
    } else {
      if (h.headerSize == -1) p.start = fileBytes >= each ? fileBytes - each : 0;
      const std::uint64_t have = fileBytes >= p.start ? fileBytes - p.start : 0;
      if (have != each) {
        throw Error(file + ": data is " +
                    (have < each ? std::to_string(each - have) + " bytes short"
                                 : std::to_string(have - each) + " bytes longer than declared") +
                    " (" + std::to_string(each) + " bytes from byte " + std::to_string(p.start) +
                    ", file has " + std::to_string(fileBytes) + ")");
      }
    }
    pieces.push_back(p);
  }
  return pieces;
}

DenseGrid readMetaImageFile(const std::string& path, std::size_t maxBytes, int frame) {
  const MetaImageHeader h = readMetaImageHeader(path);
  const FrameSpan span = checkFrameSpan(path, h.geometry.dims, sampleSize(h.type), h.frames, frame, maxBytes);
  PieceSource source(path, dataPieces(path, h, span.allBytes));
  source.seek(static_cast<std::uint64_t>(span.chosen) * span.frameBytes);
  DenseGrid grid;
  grid.allocate(h.geometry.dims, maxBytes);
  readSamplesInto(source, h.type, h.endian, grid);
  grid.geometry = h.geometry;
  grid.description = describeDenseFile(path, "MetaImage", h.type, h.geometry.dims);
  if (h.frames > 1)
    grid.description += ", frame " + std::to_string(span.chosen) + " of " + std::to_string(h.frames);
  return grid;
}

}  // namespace

DenseGrid readMetaImage(const std::string& path, std::size_t maxBytes, int frame) {
  return readPrefixingErrors(path, [&] { return readMetaImageFile(path, maxBytes, frame); });
}

}  // namespace cip
