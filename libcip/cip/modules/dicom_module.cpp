// The DICOM reader's GDCM side, built as the module libcip_dicom.so (cip/core/module_loader.h) that readDicom
// (readers/dicom_reader.h) loads on first use. GDCM itself is used only here.
#include <gdcmDicts.h>
#include <gdcmGlobal.h>
#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmStringFilter.h>
#include <gdcmTag.h>
#include <gdcmTrace.h>

#include <Eigen/Geometry>  // cross()
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <vector>

#include "cip/core/error.h"
#include "cip/core/module_loader.h"
#include "cip/readers/dicom_reader.h"
#include "cip/readers/volume_input.h"
#include "cip/volume/sample_type.h"

namespace cip {

namespace {

/// Most files looked at in one folder.
constexpr std::size_t kMaxFiles = 100000;
/// Largest relative difference of a slice step from the median step.
constexpr double kStepTolerance = 0.05;

const gdcm::Tag kSeriesUid(0x0020, 0x000e);
const gdcm::Tag kPosition(0x0020, 0x0032);
const gdcm::Tag kOrientation(0x0020, 0x0037);
const gdcm::Tag kPixelSpacing(0x0028, 0x0030);
const gdcm::Tag kRows(0x0028, 0x0010);
const gdcm::Tag kColumns(0x0028, 0x0011);
const gdcm::Tag kSamplesPerPixel(0x0028, 0x0002);
const gdcm::Tag kFrames(0x0028, 0x0008);
const gdcm::Tag kSlope(0x0028, 0x1053);
const gdcm::Tag kIntercept(0x0028, 0x1052);
const gdcm::Tag kSliceThickness(0x0018, 0x0050);
const gdcm::Tag kPixelData(0x7fe0, 0x0010);

/// What cip needs from the header of one slice file.
struct Slice {
  std::string file;
  std::string series;
  Vec3 position = Vec3::Zero();
  std::array<double, 6> orientation{};   ///< row cosine, column cosine
  std::array<double, 2> pixelSpacing{};  ///< between rows, between columns
  std::int64_t rows = 0, columns = 0;
  double slope = 1, intercept = 0, thickness = 0;
  double depth = 0;  ///< position along the series' slice normal
};

/// The numbers of a multi-valued DICOM string ("a\b\c"); empty when the value is missing or malformed.
std::vector<double> numbers(const std::string& text) {
  std::vector<double> out;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, '\\')) {
    const char* begin = item.c_str();
    while (*begin == ' ') ++begin;
    char* end = nullptr;
    const double v = std::strtod(begin, &end);
    while (end && *end == ' ') ++end;
    if (end == begin || *end != '\0' || !std::isfinite(v)) return {};
    out.push_back(v);
  }
  return out;
}

std::string trimmed(const std::string& s) {
  std::size_t b = s.find_first_not_of(" \t\r\n");
  std::size_t e = s.find_last_not_of(" \t\r\n\0");
  return b == std::string::npos ? std::string() : s.substr(b, e - b + 1);
}

/// Exactly `count` numbers of tag `name` in `slice`, or throws "<file>: <name> ...".
std::vector<double> required(const gdcm::StringFilter& filter, const gdcm::Tag& tag, std::size_t count,
                             const std::string& file, const char* name) {
  const std::string text = trimmed(filter.ToString(tag));
  std::vector<double> v = numbers(text);
  if (text.empty()) {
    char id[16];
    std::snprintf(id, sizeof(id), "(%04x,%04x)", tag.GetGroup(), tag.GetElement());
    throw Error(file + ": no " + name + " " + id);
  }
  if (v.size() != count) {
    throw Error(file + ": " + name + " '" + text + "' is not " + std::to_string(count) + " numbers");
  }
  return v;
}

double optional(const gdcm::StringFilter& filter, const gdcm::Tag& tag, double fallback) {
  const std::vector<double> v = numbers(trimmed(filter.ToString(tag)));
  return v.size() == 1 ? v[0] : fallback;
}

/// A structural walk over the elements of a DICOM file, checking that every element, sequence and item lies
/// within the file before GDCM parses it: GDCM aborts (assertions) on some truncated or malformed files
/// instead of failing. Throws "<file>: ..." for a file that does not hold together.
class DicomStructure {
 public:
  DicomStructure(std::string file, std::string bytes) : file_(std::move(file)), b_(std::move(bytes)) {}

  /// Walks the file meta information (explicit VR little endian) and then the data set in its transfer
  /// syntax (implicit or explicit VR little endian; others are refused).
  void check() {
    std::size_t pos = 132;
    std::string syntax;
    std::uint32_t last = 0;
    std::uint64_t metaEnd = 0;
    while (pos + 2 <= b_.size() && u16(pos) == 0x0002) {
      const std::size_t start = pos;
      pos = element(pos, true, 0, last);
      const std::uint32_t elem = u16(start + 2);
      if (elem == 0x0000 && pos - start == 12) metaEnd = pos + u32(start + 8);
      if (elem == 0x0010) syntax = b_.substr(start + 8, pos - start - 8);
    }
    if (metaEnd != pos) fail("malformed DICOM file meta information (its group length does not match)");
    while (!syntax.empty() && (syntax.back() == '\0' || syntax.back() == ' ')) syntax.pop_back();
    bool explicitVr = true;
    if (syntax == "1.2.840.10008.1.2") {
      explicitVr = false;
    } else if (syntax == "1.2.840.10008.1.2.2" || syntax == "1.2.840.10008.1.2.1.99" || syntax.empty()) {
      fail("transfer syntax '" + syntax + "' (big endian, deflated or none) is not supported");
    }
    if (pos >= b_.size()) fail("truncated DICOM file (no data set after the file meta information)");
    last = 0;
    while (pos < b_.size()) pos = element(pos, explicitVr, 0, last);
  }

 private:
  [[noreturn]] void fail(const std::string& what) const { throw Error(file_ + ": " + what); }
  void need(std::size_t pos, std::uint64_t n) const {
    if (pos > b_.size() || n > b_.size() - pos)
      fail("truncated or malformed DICOM file (at byte " + std::to_string(pos) + ")");
  }
  std::uint32_t u16(std::size_t p) const {
    return static_cast<unsigned char>(b_[p]) |
           (static_cast<std::uint32_t>(static_cast<unsigned char>(b_[p + 1])) << 8);
  }
  std::uint32_t u32(std::size_t p) const { return u16(p) | (u16(p + 2) << 16); }
  /// A public element whose VR the dictionary does not allow, or a single binary number of the wrong size:
  /// GDCM asserts on both when it reads the element as an attribute.
  void checkAgainstDictionary(std::uint32_t tag, const std::string& vr, std::uint32_t length, bool longForm,
                              std::size_t pos) const {
    const gdcm::Tag t(static_cast<std::uint16_t>(tag >> 16), static_cast<std::uint16_t>(tag & 0xffff));
    if (t.IsPrivate() || t.GetElement() == 0) return;
    const gdcm::DictEntry& entry = gdcm::Global::GetInstance().GetDicts().GetDictEntry(t);
    const gdcm::VR expected = entry.GetVR();
    const gdcm::VR found(gdcm::VR::GetVRType(vr.c_str()));
    const std::string where = "element (" + hex(tag) + ") at byte " + std::to_string(pos);
    if (expected != gdcm::VR::INVALID && !expected.Compatible(found)) {
      fail("malformed DICOM file: " + where + " has VR " + vr + ", the standard says " +
           gdcm::VR::GetVRString(expected));
    }
    const std::size_t size = isOneOf(vr, "US SS") ? 2 : isOneOf(vr, "UL SL FL AT") ? 4 : vr == "FD" ? 8 : 0;
    if (!longForm && size > 0 && (length % size != 0 || (entry.GetVM() == gdcm::VM::VM1 && length != size))) {
      fail("malformed DICOM file: " + where + " has " + std::to_string(length) + " bytes of " + vr);
    }
  }

  /// True when the two letters `vr` are one of the blank-separated `list`.
  static bool isOneOf(const std::string& vr, const std::string& list) {
    for (std::size_t i = 0; i + 2 <= list.size(); i += 3)
      if (list.compare(i, 2, vr) == 0) return true;
    return false;
  }
  static std::string hex(std::uint32_t tag) {
    char text[16];
    std::snprintf(text, sizeof(text), "%04x,%04x", tag >> 16, tag & 0xffff);
    return text;
  }

  /// One element at `pos`, after the element with tag `last` of the same data set (tags ascend); returns the
  /// position after it.
  std::size_t element(std::size_t pos, bool explicitVr, int depth, std::uint32_t& last) {
    need(pos, 8);
    const std::uint32_t tag = (u16(pos) << 16) | u16(pos + 2);
    if (u16(pos) == 0xfffe || tag < last || (tag == last && last != 0)) {
      fail("malformed DICOM file: element (" + hex(tag) + ") at byte " + std::to_string(pos) +
           " is out of order");
    }
    last = tag;
    std::size_t header = 8;
    std::uint32_t length = u32(pos + 4);
    if (explicitVr) {
      const std::string vr = b_.substr(pos + 4, 2);
      const bool longForm = isOneOf(vr, "OB OD OF OL OV OW SQ SV UC UN UR UT UV");
      if (!longForm && !isOneOf(vr, "AE AS AT CS DA DS DT FL FD IS LO LT PN SH SL SS ST TM UI UL US")) {
        fail("malformed DICOM element (" + hex(tag) + ") at byte " + std::to_string(pos));
      }
      checkAgainstDictionary(tag, vr, longForm ? 0 : u16(pos + 6), longForm, pos);
      length = longForm ? (need(pos, 12), u32(pos + 8)) : u16(pos + 6);
      header = longForm ? 12 : 8;
    }
    pos += header;
    if (length == 0xffffffffu) return items(pos, explicitVr, depth + 1);
    need(pos, length);
    return pos + length;
  }

  /// The items of a sequence or encapsulated pixel data of undefined length, up to its delimiter.
  std::size_t items(std::size_t pos, bool explicitVr, int depth) {
    if (depth > 16) fail("sequences nested deeper than 16");
    while (true) {
      need(pos, 8);
      const std::uint32_t group = u16(pos), elem = u16(pos + 2), length = u32(pos + 4);
      pos += 8;
      if (group == 0xfffe && elem == 0xe0dd) return pos;  // sequence delimiter
      if (group != 0xfffe || elem != 0xe000) fail("malformed sequence at byte " + std::to_string(pos - 8));
      if (length != 0xffffffffu) {
        need(pos, length);
        pos += length;
        continue;
      }
      std::uint32_t last = 0;
      while (true) {  // an item of undefined length: elements up to the item delimiter
        need(pos, 8);
        if (u16(pos) == 0xfffe && u16(pos + 2) == 0xe00d) {
          pos += 8;
          break;
        }
        pos = element(pos, explicitVr, depth, last);
      }
    }
  }

  std::string file_;
  std::string b_;
};

/// True when the file is DICOM: the "DICM" marker after its 128-byte preamble (files without it, such as
/// old ACR-NEMA files, are not read). Then checks its structure (DicomStructure).
bool isDicomFile(const std::string& file) {
  const std::uint64_t size = fileSizeOf(file);
  std::ifstream in(file, std::ios::binary);
  char magic[132] = {};
  in.read(magic, sizeof(magic));
  if (in.gcount() != 132 || std::memcmp(magic + 128, "DICM", 4) != 0) return false;
  if (size > (std::uint64_t(1) << 31)) throw Error(file + ": DICOM file larger than 2 GiB");
  std::string bytes(static_cast<std::size_t>(size), '\0');
  in.seekg(0);
  in.read(bytes.data(), static_cast<std::streamsize>(size));
  if (static_cast<std::uint64_t>(in.gcount()) != size) throw Error(file + ": read error");
  DicomStructure(file, std::move(bytes)).check();
  return true;
}

/// Reads the header of `file` (up to the pixel data). Returns false when it is not DICOM, or DICOM without an
/// image; throws when it looks like DICOM but cannot be read or its image fields are unusable.
bool readSliceHeader(const std::string& file, Slice& slice) {
  if (!isDicomFile(file)) return false;
  gdcm::Reader reader;
  reader.SetFileName(file.c_str());
  if (!reader.ReadUpToTag(kPixelData)) throw Error(file + ": unreadable DICOM file (GDCM cannot parse it)");
  const gdcm::DataSet& ds = reader.GetFile().GetDataSet();
  if (!ds.FindDataElement(kRows) || !ds.FindDataElement(kColumns)) return false;  // no image
  gdcm::StringFilter filter;
  filter.SetFile(reader.GetFile());
  slice.file = file;
  slice.series = trimmed(filter.ToString(kSeriesUid));
  const double frames = optional(filter, kFrames, 1);
  if (frames != 1)
    throw Error(file + ": multi-frame DICOM files (" + std::to_string(frames) + " frames) are not supported");
  if (optional(filter, kSamplesPerPixel, 1) != 1) throw Error(file + ": colour images are not supported");
  slice.rows = static_cast<std::int64_t>(required(filter, kRows, 1, file, "Rows")[0]);
  slice.columns = static_cast<std::int64_t>(required(filter, kColumns, 1, file, "Columns")[0]);
  auto p = required(filter, kPosition, 3, file, "ImagePositionPatient");
  slice.position = Vec3(p[0], p[1], p[2]);
  auto o = required(filter, kOrientation, 6, file, "ImageOrientationPatient");
  std::copy(o.begin(), o.end(), slice.orientation.begin());
  auto s = required(filter, kPixelSpacing, 2, file, "PixelSpacing");
  if (!(s[0] > 0 && s[1] > 0)) throw Error(file + ": PixelSpacing must be positive");
  slice.pixelSpacing = {s[0], s[1]};
  slice.slope = optional(filter, kSlope, 1);
  slice.intercept = optional(filter, kIntercept, 0);
  slice.thickness = optional(filter, kSliceThickness, 0);
  return true;
}

/// The regular files to look at: the folder's (sorted by name, hidden ones skipped) or `path` itself.
std::vector<std::string> candidateFiles(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_directory(path, ec)) {
    fileSizeOf(path);  // clear error for missing files
    return {path};
  }
  std::vector<std::string> files;
  for (const auto& entry : std::filesystem::directory_iterator(path, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name[0] == '.' || !entry.is_regular_file(ec)) continue;
    if (files.size() == kMaxFiles) throw Error(path + ": more than " + std::to_string(kMaxFiles) + " files");
    files.push_back(entry.path().string());
  }
  if (ec) throw Error(path + ": cannot list the folder: " + ec.message());
  std::sort(files.begin(), files.end());
  return files;
}

/// The slices of the series with the most slices; `note` names it when the folder holds several.
std::vector<Slice> chooseSeries(std::vector<Slice> slices, std::string& note) {
  std::map<std::string, std::vector<Slice>> bySeries;
  for (auto& s : slices) bySeries[s.series].push_back(std::move(s));
  auto best = bySeries.begin();
  for (auto it = bySeries.begin(); it != bySeries.end(); ++it) {
    if (it->second.size() > best->second.size()) best = it;
  }
  if (bySeries.size() > 1) {
    note = ", series " + best->first + " (the largest of " + std::to_string(bySeries.size()) + " series)";
  }
  return std::move(best->second);
}

/// Row and column cosines of the first slice, checked for unit length and orthogonality, and every slice
/// checked to share them and the first slice's size and pixel spacing.
void checkSameGrid(const std::string& path, const std::vector<Slice>& slices, Vec3& row, Vec3& column) {
  const Slice& a = slices[0];
  row = Vec3(a.orientation[0], a.orientation[1], a.orientation[2]);
  column = Vec3(a.orientation[3], a.orientation[4], a.orientation[5]);
  if (std::abs(row.norm() - 1) > 1e-3 || std::abs(column.norm() - 1) > 1e-3 ||
      std::abs(row.dot(column)) > 1e-3) {
    throw Error(a.file + ": ImageOrientationPatient is not two orthogonal unit vectors");
  }
  for (const Slice& s : slices) {
    if (s.rows != a.rows || s.columns != a.columns) {
      throw Error(path + ": slices of mixed sizes: " + baseName(a.file) + " is " + std::to_string(a.columns) +
                  "x" + std::to_string(a.rows) + ", " + baseName(s.file) + " is " +
                  std::to_string(s.columns) + "x" + std::to_string(s.rows));
    }
    for (int c = 0; c < 6; ++c) {
      if (std::abs(s.orientation[c] - a.orientation[c]) > 1e-4) {
        throw Error(path + ": slices of mixed orientations: " + baseName(a.file) + " and " +
                    baseName(s.file) + " differ in ImageOrientationPatient");
      }
    }
    if (std::abs(s.pixelSpacing[0] - a.pixelSpacing[0]) > 1e-4 * a.pixelSpacing[0] ||
        std::abs(s.pixelSpacing[1] - a.pixelSpacing[1]) > 1e-4 * a.pixelSpacing[1]) {
      throw Error(path + ": slices of mixed pixel spacings: " + baseName(a.file) + " and " +
                  baseName(s.file));
    }
  }
}

/// Sorts the slices along the normal and returns the index-to-world step between consecutive slices,
/// checking that every step equals it (no missing or doubled slice).
Vec3 sortAndStep(const std::string& path, std::vector<Slice>& slices, const Vec3& normal) {
  for (Slice& s : slices) s.depth = normal.dot(s.position);
  std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.depth < b.depth; });
  if (slices.size() == 1) return normal * (slices[0].thickness > 0 ? slices[0].thickness : 1.0);
  std::vector<double> steps;
  for (std::size_t n = 1; n < slices.size(); ++n) steps.push_back(slices[n].depth - slices[n - 1].depth);
  std::vector<double> sorted = steps;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2),
                   sorted.end());
  const double median = sorted[sorted.size() / 2];
  const Vec3 step = (slices.back().position - slices.front().position) / double(slices.size() - 1);
  for (std::size_t n = 1; n < slices.size(); ++n) {
    if (steps[n - 1] <= 1e-6 * std::max(1.0, std::abs(median))) {
      throw Error(path + ": " + baseName(slices[n - 1].file) + " and " + baseName(slices[n].file) +
                  " lie at the same position (several images per position are not supported)");
    }
  }
  for (std::size_t n = 1; n < slices.size(); ++n) {
    const Vec3 d = slices[n].position - slices[n - 1].position;
    if ((d - step).norm() > kStepTolerance * median) {
      std::ostringstream m;
      m << path << ": irregular slice spacing: " << baseName(slices[n - 1].file) << " to "
        << baseName(slices[n].file) << " steps " << steps[n - 1] << " along the normal, the median step is "
        << median << " (a missing slice?)";
      throw Error(m.str());
    }
  }
  return step;
}

SampleType sampleTypeOf(const std::string& file, const gdcm::PixelFormat& format) {
  switch (format.GetScalarType()) {
    case gdcm::PixelFormat::UINT8:
      return SampleType::UInt8;
    case gdcm::PixelFormat::INT8:
      return SampleType::Int8;
    case gdcm::PixelFormat::UINT16:
      return SampleType::UInt16;
    case gdcm::PixelFormat::INT16:
      return SampleType::Int16;
    case gdcm::PixelFormat::UINT32:
      return SampleType::UInt32;
    case gdcm::PixelFormat::INT32:
      return SampleType::Int32;
    case gdcm::PixelFormat::FLOAT32:
      return SampleType::Float32;
    case gdcm::PixelFormat::FLOAT64:
      return SampleType::Float64;
    default:
      throw Error(file + ": pixel format " + format.GetScalarTypeAsString() + " is not supported");
  }
}

/// Decodes the pixels of one slice into `out` (rows*columns values), rescaled.
SampleType readPixels(const Slice& slice, double* out) {
  gdcm::ImageReader reader;
  reader.SetFileName(slice.file.c_str());
  if (!reader.Read()) throw Error(slice.file + ": cannot read the image (GDCM cannot decode it)");
  const gdcm::Image& image = reader.GetImage();
  const gdcm::PixelFormat& format = image.GetPixelFormat();
  if (format.GetSamplesPerPixel() != 1) throw Error(slice.file + ": colour images are not supported");
  const SampleType type = sampleTypeOf(slice.file, format);
  const std::size_t count = static_cast<std::size_t>(slice.rows * slice.columns);
  if (image.GetBufferLength() != count * sampleSize(type)) {
    throw Error(slice.file + ": pixel data has " + std::to_string(image.GetBufferLength()) + " bytes, " +
                std::to_string(count) + " " + toString(type) + " pixels expected");
  }
  std::vector<char> buffer(image.GetBufferLength());
  if (!image.GetBuffer(buffer.data())) throw Error(slice.file + ": cannot decode the pixel data");
  decodeSamples(reinterpret_cast<const unsigned char*>(buffer.data()), count, type, Endian::Little, out);
  for (std::size_t n = 0; n < count; ++n) out[n] = out[n] * slice.slope + slice.intercept;
  return type;
}

/// The headers of every DICOM image file among `files`.
std::vector<Slice> readHeaders(const std::string& path, const std::vector<std::string>& files) {
  std::vector<Slice> slices;
  for (const std::string& file : files) {
    Slice s;
    if (readSliceHeader(file, s)) slices.push_back(std::move(s));
  }
  if (slices.empty()) {
    std::error_code ec;
    if (!std::filesystem::is_directory(path, ec)) throw Error(path + ": not a DICOM image file");
    throw Error(path + ": no DICOM image file in the folder (" + std::to_string(files.size()) +
                " files looked at)");
  }
  return slices;
}

DenseGrid readSeries(const std::string& path, std::size_t maxBytes) {
  gdcm::Trace::SetWarning(false);
  gdcm::Trace::SetError(false);
  gdcm::Trace::SetDebug(false);
  std::string note;
  std::vector<Slice> slices = chooseSeries(readHeaders(path, candidateFiles(path)), note);
  Vec3 row, column;
  checkSameGrid(path, slices, row, column);
  const Vec3 step = sortAndStep(path, slices, row.cross(column));

  const Slice& first = slices[0];
  DenseGrid grid;
  const std::array<std::int64_t, 3> dims{first.columns, first.rows, static_cast<std::int64_t>(slices.size())};
  checkVolumeDims(path, dims, sizeof(double), maxBytes);
  Mat3 columns;
  columns.col(0) = row * first.pixelSpacing[1];
  columns.col(1) = column * first.pixelSpacing[0];
  columns.col(2) = step;
  setAxes(grid.geometry, columns, (path + ": slice geometry").c_str());
  grid.geometry.origin = first.position;
  grid.geometry.space = WorldSpace::LPS;
  grid.allocate(dims, maxBytes);
  SampleType type = SampleType::UInt8;
  const std::size_t perSlice = static_cast<std::size_t>(dims[0] * dims[1]);
  for (std::size_t k = 0; k < slices.size(); ++k)
    type = readPixels(slices[k], grid.values.data() + k * perSlice);
  grid.description = describeDenseFile(path, "DICOM", type, dims) + note;
  return grid;
}

}  // namespace

}  // namespace cip

CIP_MODULE_ENTRY const cip::DicomReaderModule* cip_dicom_reader_module() {
  static const cip::DicomReaderModule table{&cip::readSeries};
  return &table;
}
