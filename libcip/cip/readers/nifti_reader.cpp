#include "cip/readers/nifti_reader.h"

#include <zlib.h>

#include <array>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <memory>
#include <vector>

#include "cip/core/atomic_file.h"
#include "cip/core/error.h"
#include "cip/readers/volume_input.h"

namespace cip {

namespace {

/// Byte offsets and widths of the header fields used here, for NIfTI-1 and NIfTI-2.
struct Layout {
  std::size_t headerBytes, magic, datatype, bitpix, dim, pixdim, voxOffset, sclSlope, sclInter, qformCode,
      sformCode, quatern, qoffset, srow;
  std::size_t dimBytes, realBytes, codeBytes;  ///< widths of dim[], of the real fields, of the form codes
};
constexpr Layout kNifti1{348, 344, 70, 72, 40, 76, 108, 112, 116, 252, 254, 256, 268, 280, 2, 4, 2};
constexpr Layout kNifti2{540, 4, 12, 14, 16, 104, 168, 176, 184, 344, 348, 352, 376, 400, 8, 8, 4};
constexpr std::size_t kWriteOffset = 352;  // NIfTI-1 header + 4-byte extension flag

/// Reads fields of one header layout in the file's byte order.
class FieldReader {
 public:
  FieldReader(const unsigned char* bytes, bool swap, const Layout& layout)
      : bytes_(bytes), swap_(swap), layout_(layout) {}
  template <typename T>
  T get(std::size_t offset) const {
    unsigned char tmp[sizeof(T)];
    for (std::size_t b = 0; b < sizeof(T); ++b) tmp[b] = bytes_[offset + (swap_ ? sizeof(T) - 1 - b : b)];
    T v;
    std::memcpy(&v, tmp, sizeof(T));
    return v;
  }
  /// A floating-point field: float32 in NIfTI-1, float64 in NIfTI-2.
  double real(std::size_t offset) const {
    return layout_.realBytes == 4 ? static_cast<double>(get<float>(offset)) : get<double>(offset);
  }
  /// dim[i]: int16 in NIfTI-1, int64 in NIfTI-2.
  std::int64_t dim(int i) const {
    std::size_t at = layout_.dim + layout_.dimBytes * static_cast<std::size_t>(i);
    return layout_.dimBytes == 2 ? get<std::int16_t>(at) : get<std::int64_t>(at);
  }
  double pixdim(int i) const {
    return real(layout_.pixdim + layout_.realBytes * static_cast<std::size_t>(i));
  }
  /// qform_code / sform_code: int16 in NIfTI-1, int32 in NIfTI-2.
  int code(std::size_t offset) const {
    return layout_.codeBytes == 2 ? get<std::int16_t>(offset) : get<std::int32_t>(offset);
  }
  const Layout& layout() const { return layout_; }

 private:
  const unsigned char* bytes_;
  bool swap_;
  const Layout& layout_;
};

bool isGzip(const std::string& path) {
  unsigned char magic[2] = {0, 0};
  FileByteSource source(path, 0);
  return source.read(magic, 2) == 2 && magic[0] == 0x1f && magic[1] == 0x8b;
}

std::string datatypeName(int code) {
  switch (code) {
    case 1:
      return "binary";
    case 32:
      return "complex64";
    case 128:
      return "rgb24";
    case 1024:
      return "int64";
    case 1280:
      return "uint64";
    case 1536:
      return "float128";
    case 1792:
      return "complex128";
    case 2048:
      return "complex256";
    case 2304:
      return "rgba32";
    default:
      return "unknown";
  }
}

/// The NIfTI version (1 or 2) from sizeof_hdr (348 or 540 in either byte order) and whether the header's
/// fields are in the other byte order than the host's.
int headerVersion(const unsigned char* bytes, std::size_t size, bool& swap) {
  if (size < kNiftiHeaderBytes) {
    throw Error("too small for a NIfTI header (" + std::to_string(size) + " of at least 348 bytes)");
  }
  std::int32_t sizeofHdr;
  std::memcpy(&sizeofHdr, bytes, 4);
  const auto swapped = static_cast<std::int32_t>(__builtin_bswap32(static_cast<std::uint32_t>(sizeofHdr)));
  for (int version : {1, 2}) {
    const auto expected = static_cast<std::int32_t>(version == 1 ? kNiftiHeaderBytes : kNifti2HeaderBytes);
    if (sizeofHdr == expected || swapped == expected) {
      swap = sizeofHdr != expected;
      if (size < static_cast<std::size_t>(expected)) {
        throw Error("too small for a NIfTI-" + std::to_string(version) + " header (" + std::to_string(size) +
                    " of " + std::to_string(expected) + " bytes)");
      }
      return version;
    }
  }
  throw Error("not a NIfTI file: sizeof_hdr is " + std::to_string(sizeofHdr) +
              ", expected 348 (NIfTI-1) or 540 (NIfTI-2)");
}

/// "n+1"/"n+2": data in the same file; "ni1"/"ni2": data in the .img beside the .hdr. Returns whether it is
/// a pair.
bool readMagic(const unsigned char* bytes, int version) {
  const unsigned char* magic = bytes + (version == 1 ? kNifti1 : kNifti2).magic;
  const char digit = static_cast<char>('0' + version);
  if (magic[0] == 'n' && (magic[1] == '+' || magic[1] == 'i') && magic[2] == digit && magic[3] == 0)
    return magic[1] == 'i';
  throw Error("not a NIfTI-" + std::to_string(version) + " file: magic is not \"n+" + digit + "\" or \"ni" +
              digit + "\"");
}

/// dim[1..3] and the frame count: dim[0] 3 or 4 (or more when the extents past dim[4] are 1).
void readDims(const FieldReader& f, NiftiHeader& h) {
  const std::int64_t ndim = f.dim(0);
  if (ndim < 3 || ndim > 7) {
    throw Error("NIfTI dim[0] is " + std::to_string(ndim) +
                "; a volume needs 3 (or 4 for a series of frames)");
  }
  for (int a = 0; a < 3; ++a) {
    const std::int64_t n = f.dim(a + 1);
    if (n < 1)
      throw Error("NIfTI dim[" + std::to_string(a + 1) + "] is " + std::to_string(n) + " (must be >= 1)");
    h.geometry.dims[a] = n;
  }
  h.frames = ndim >= 4 ? f.dim(4) : 1;
  if (h.frames < 1) throw Error("NIfTI dim[4] is " + std::to_string(h.frames) + " (must be >= 1)");
  for (int d = 5; d <= ndim; ++d) {
    if (f.dim(d) != 1) {
      throw Error("NIfTI volume has " + std::to_string(ndim) + " dimensions (dim[" + std::to_string(d) +
                  "] is " + std::to_string(f.dim(d)) + "); only 3-D volumes and 4-D series are supported");
    }
  }
}

/// The sample type from datatype, checked against bitpix (0 = not given).
SampleType readSampleType(const FieldReader& f) {
  SampleType type = SampleType::UInt8;
  int datatype = f.get<std::int16_t>(f.layout().datatype);
  switch (datatype) {
    case 2:
      type = SampleType::UInt8;
      break;
    case 4:
      type = SampleType::Int16;
      break;
    case 8:
      type = SampleType::Int32;
      break;
    case 16:
      type = SampleType::Float32;
      break;
    case 64:
      type = SampleType::Float64;
      break;
    case 256:
      type = SampleType::Int8;
      break;
    case 512:
      type = SampleType::UInt16;
      break;
    case 768:
      type = SampleType::UInt32;
      break;
    default:
      throw Error("NIfTI datatype " + std::to_string(datatype) + " (" + datatypeName(datatype) +
                  ") is not supported (uint8, int8, int16, uint16, int32, uint32, float32, float64 are)");
  }
  int bitpix = f.get<std::int16_t>(f.layout().bitpix);
  if (bitpix != 0 && bitpix != static_cast<int>(8 * sampleSize(type))) {
    throw Error("NIfTI bitpix " + std::to_string(bitpix) + " does not match datatype " + toString(type));
  }
  return type;
}

/// |pixdim[1..3]|, each positive and finite.
Vec3 readPixdim(const FieldReader& f) {
  Vec3 spacing;
  for (int a = 0; a < 3; ++a) {
    double s = std::abs(f.pixdim(a + 1));
    if (!(s > 0) || !std::isfinite(s)) {
      throw Error("NIfTI pixdim[" + std::to_string(a + 1) + "] is " + std::to_string(s) +
                  " (spacing must be positive and finite)");
    }
    spacing[a] = s;
  }
  return spacing;
}

/// vox_offset: a whole number of bytes, at least the header's for a single file.
std::uint64_t readDataOffset(const FieldReader& f, bool pair) {
  const double voxOffset = f.layout().realBytes == 4
                               ? f.real(f.layout().voxOffset)
                               : static_cast<double>(f.get<std::int64_t>(f.layout().voxOffset));
  const double least = pair ? 0.0 : static_cast<double>(f.layout().headerBytes);
  if (!std::isfinite(voxOffset) || voxOffset < least || voxOffset != std::floor(voxOffset) ||
      voxOffset > 9.0e15) {
    throw Error("NIfTI vox_offset " + std::to_string(voxOffset) +
                " is invalid (must be a whole number >= " + std::to_string(static_cast<int>(least)) + ")");
  }
  return static_cast<std::uint64_t>(voxOffset);
}

Vec3 finiteOrigin(const Vec3& origin, const char* what) {
  if (!origin.allFinite()) throw Error(std::string(what) + ": the origin is not finite");
  return origin;
}

/// Rotation of the unit quaternion (a, b, c, d), as nibabel's quat2mat (normalised by its squared norm).
Mat3 quaternionRotation(double a, double b, double c, double d) {
  const double n = a * a + b * b + c * c + d * d;
  const double s = 2.0 / n;
  const double x = b * s, y = c * s, z = d * s;
  Mat3 r;
  r << 1 - (c * y + d * z), b * y - a * z, b * z + a * y,  //
      b * y + a * z, 1 - (b * x + d * z), c * z - a * x,   //
      b * z - a * y, c * z + a * x, 1 - (b * x + c * y);
  return r;
}

/// The qform: quaternion rotation times diag(pixdim[1], pixdim[2], qfac * pixdim[3]) plus qoffset.
void readQform(const FieldReader& f, NiftiHeader& h) {
  const Layout& l = f.layout();
  const double b = f.real(l.quatern), c = f.real(l.quatern + l.realBytes),
               d = f.real(l.quatern + 2 * l.realBytes);
  if (!std::isfinite(b) || !std::isfinite(c) || !std::isfinite(d))
    throw Error("NIfTI qform: the quaternion is not finite");
  // nibabel's tolerance: b² + c² + d² may exceed 1 by 3 epsilons of the header's float type.
  const double tolerance = 3 * (l.realBytes == 4 ? static_cast<double>(std::numeric_limits<float>::epsilon())
                                                 : std::numeric_limits<double>::epsilon());
  const double w2 = 1.0 - (b * b + c * c + d * d);
  if (w2 < -tolerance) {
    throw Error("NIfTI qform: the quaternion (b, c, d) = (" + std::to_string(b) + ", " + std::to_string(c) +
                ", " + std::to_string(d) + ") has b² + c² + d² = " + std::to_string(1.0 - w2) +
                " > 1: not a rotation");
  }
  const double a = w2 > 0 ? std::sqrt(w2) : 0.0;
  const Vec3 pixdim(std::abs(f.pixdim(1)), std::abs(f.pixdim(2)), std::abs(f.pixdim(3)));
  const double qfac = f.pixdim(0) == -1.0 ? -1.0 : 1.0;
  Mat3 columns = quaternionRotation(a, b, c, d) * Vec3(pixdim[0], pixdim[1], qfac * pixdim[2]).asDiagonal();
  setAxes(h.geometry, columns, "NIfTI qform");
  h.geometry.origin = finiteOrigin(
      Vec3(f.real(l.qoffset), f.real(l.qoffset + l.realBytes), f.real(l.qoffset + 2 * l.realBytes)),
      "NIfTI qform");
}

/// The sform: rows srow_x, srow_y, srow_z = [3x3 | offset].
void readSform(const FieldReader& f, NiftiHeader& h) {
  const Layout& l = f.layout();
  Mat3 columns;
  Vec3 origin;
  for (int r = 0; r < 3; ++r) {
    const std::size_t row = l.srow + 4 * l.realBytes * static_cast<std::size_t>(r);
    for (int c = 0; c < 3; ++c) columns(r, c) = f.real(row + l.realBytes * static_cast<std::size_t>(c));
    origin[r] = f.real(row + 3 * l.realBytes);
  }
  setAxes(h.geometry, columns, "NIfTI sform");
  h.geometry.origin = finiteOrigin(origin, "NIfTI sform");
}

/// Value scaling (non-finite slope or intercept read as 0), the form codes and the placement they select:
/// sform if sform_code > 0, else qform if qform_code > 0, else pixdim alone.
void readScalingAndPlacement(const FieldReader& f, NiftiHeader& h) {
  const Layout& l = f.layout();
  h.slope = f.real(l.sclSlope);
  h.inter = f.real(l.sclInter);
  if (!std::isfinite(h.slope)) h.slope = 0;
  if (!std::isfinite(h.inter)) h.inter = 0;

  h.qformCode = f.code(l.qformCode);
  h.sformCode = f.code(l.sformCode);
  if (h.sformCode > 0) {
    readSform(f, h);
    h.placement = NiftiPlacement::Sform;
    h.geometry.space = WorldSpace::RAS;
  } else if (h.qformCode > 0) {
    readQform(f, h);
    h.placement = NiftiPlacement::Qform;
    h.geometry.space = WorldSpace::RAS;
  } else {
    h.geometry.spacing = readPixdim(f);
    h.placement = NiftiPlacement::Pixdim;
  }
}

/// `path` with its last `suffix.size()` characters replaced by `suffix`, matching the case of the old one.
std::string withSuffix(const std::string& path, std::size_t oldLength, const std::string& suffix) {
  std::string stem = path.substr(0, path.size() - oldLength);
  const bool upper =
      oldLength > 1 && std::isupper(static_cast<unsigned char>(path[path.size() - oldLength + 1]));
  std::string s = suffix;
  if (upper)
    for (char& ch : s) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
  return stem + s;
}

/// The companion of a pair file: `from` (".hdr" or ".img") replaced by `to`, keeping a ".gz" suffix when the
/// file exists so, else trying the other compression.
std::string companionPath(const std::string& path, const std::string& from, const std::string& to) {
  std::string candidates[2];
  if (endsWithNoCase(path, from + ".gz")) {
    candidates[0] = withSuffix(path, from.size() + 3, to + ".gz");
    candidates[1] = withSuffix(path, from.size() + 3, to);
  } else if (endsWithNoCase(path, from)) {
    candidates[0] = withSuffix(path, from.size(), to);
    candidates[1] = withSuffix(path, from.size(), to + ".gz");
  } else {
    return "";
  }
  std::error_code ec;
  if (!std::filesystem::exists(candidates[0], ec) && std::filesystem::exists(candidates[1], ec))
    return candidates[1];
  return candidates[0];
}

}  // namespace

const char* toString(NiftiPlacement placement) {
  switch (placement) {
    case NiftiPlacement::Sform:
      return "sform";
    case NiftiPlacement::Qform:
      return "qform";
    case NiftiPlacement::Pixdim:
      break;
  }
  return "pixdim";
}

NiftiHeader parseNiftiHeader(const unsigned char* bytes, std::size_t size) {
  bool swap = false;
  NiftiHeader h;
  h.version = headerVersion(bytes, size, swap);
  h.endian = (hostEndian() == Endian::Little) != swap ? Endian::Little : Endian::Big;
  h.pair = readMagic(bytes, h.version);
  const FieldReader f(bytes, swap, h.version == 1 ? kNifti1 : kNifti2);
  readDims(f, h);
  h.type = readSampleType(f);
  h.dataOffset = readDataOffset(f, h.pair);
  readScalingAndPlacement(f, h);
  return h;
}

std::string niftiHeaderPath(const std::string& path) {
  std::string header = companionPath(path, ".img", ".hdr");
  return header.empty() ? path : header;
}

std::string niftiDataPath(const std::string& headerPath, const NiftiHeader& header) {
  if (!header.pair) return headerPath;
  std::string data = companionPath(headerPath, ".hdr", ".img");
  if (data.empty()) {
    throw Error(headerPath + ": the magic \"ni" + std::to_string(header.version) +
                "\" says the data are in a separate .img file, but this is not a .hdr file");
  }
  return data;
}

NiftiHeader readNiftiHeader(const std::string& path) {
  const std::string headerPath = niftiHeaderPath(path);
  std::unique_ptr<ByteSource> source;
  if (isGzip(headerPath)) {
    source = std::make_unique<GzipByteSource>(headerPath, 0);
  } else {
    source = std::make_unique<FileByteSource>(headerPath, 0);
  }
  unsigned char bytes[kNifti2HeaderBytes];
  std::size_t got = source->read(bytes, sizeof bytes);
  try {
    return parseNiftiHeader(bytes, got);
  } catch (const Error& e) {
    throw Error(headerPath + ": " + e.what());
  }
}

namespace {

/// The byte of frame `frame` of a plain data file, checking the file holds exactly the declared frames from
/// the header's data offset.
std::uint64_t plainFrameOffset(const std::string& path, const NiftiHeader& h, std::uint64_t frameBytes,
                               std::uint64_t allBytes, std::int64_t frame) {
  const std::uint64_t fileBytes = fileSizeOf(path);
  if (h.dataOffset > fileBytes) {
    throw Error(path + ": data offset " + std::to_string(h.dataOffset) + " is beyond the end of the file (" +
                std::to_string(fileBytes) + " bytes)");
  }
  const std::uint64_t have = fileBytes - h.dataOffset;
  if (have != allBytes) {
    const auto& d = h.geometry.dims;
    throw Error(path + ": data is " +
                (have < allBytes ? std::to_string(allBytes - have) + " bytes short"
                                 : std::to_string(have - allBytes) + " bytes longer than declared") +
                " (" + std::to_string(d[0]) + "x" + std::to_string(d[1]) + "x" + std::to_string(d[2]) +
                (h.frames > 1 ? "x" + std::to_string(h.frames) : std::string()) + " " + toString(h.type) +
                " = " + std::to_string(allBytes) + " bytes from byte " + std::to_string(h.dataOffset) +
                ", file has " + std::to_string(fileBytes) + ")");
  }
  return h.dataOffset + static_cast<std::uint64_t>(frame) * frameBytes;
}

/// Opens the inflated samples of frame `frame` of a compressed data file.
std::unique_ptr<ByteSource> openCompressedFrame(const std::string& path, const NiftiHeader& h,
                                                std::uint64_t frameBytes, std::int64_t frame) {
  if (h.dataOffset > (std::uint64_t(1) << 30)) {
    throw Error(path + ": vox_offset " + std::to_string(h.dataOffset) +
                " is too large for compressed data (at most 1 GiB)");
  }
  auto source = std::make_unique<GzipByteSource>(path, 0);
  const std::uint64_t start = h.dataOffset + static_cast<std::uint64_t>(frame) * frameBytes;
  if (source->skip(start) != start) {
    throw Error(path + ": " + (frame > 0 ? "frame " + std::to_string(frame) : std::string("data")) +
                " starts beyond the end of the data (byte " + std::to_string(start) + ", " +
                std::to_string(source->position()) + " bytes inflated)");
  }
  return source;
}

/// The grid description of frame `chosen` of the NIfTI file `path`.
std::string niftiDescription(const std::string& path, const NiftiHeader& h, std::int64_t chosen) {
  std::string d = describeDenseFile(path, h.version == 1 ? "NIfTI" : "NIfTI-2", h.type, h.geometry.dims);
  if (h.frames > 1) d += ", frame " + std::to_string(chosen) + " of " + std::to_string(h.frames);
  return d;
}

DenseGrid readNiftiFile(const std::string& path, std::size_t maxBytes, int frame) {
  const std::string headerPath = niftiHeaderPath(path);
  NiftiHeader h = readNiftiHeader(headerPath);
  const std::string dataPath = niftiDataPath(headerPath, h);
  const FrameSpan span = checkFrameSpan(path, h.geometry.dims, sampleSize(h.type), h.frames, frame, maxBytes);
  const std::int64_t chosen = span.chosen;
  const std::uint64_t frameBytes = span.frameBytes, allBytes = span.allBytes;

  const bool gz = isGzip(dataPath);
  std::unique_ptr<ByteSource> source =
      gz ? openCompressedFrame(dataPath, h, frameBytes, chosen)
         : std::make_unique<FileByteSource>(dataPath,
                                            plainFrameOffset(dataPath, h, frameBytes, allBytes, chosen));
  DenseGrid grid;
  grid.allocate(h.geometry.dims, maxBytes);
  readSamplesInto(*source, h.type, h.endian, grid);
  if (gz && chosen == h.frames - 1) source->expectEnd("compressed data");
  if (h.slope != 0) {
    for (double& v : grid.values) v = h.slope * v + h.inter;
  }
  grid.geometry = h.geometry;
  grid.description = niftiDescription(path, h, chosen);
  return grid;
}

DenseDataLayout niftiLayout(const std::string& path, std::size_t maxBytes, int frame) {
  const std::string headerPath = niftiHeaderPath(path);
  const NiftiHeader h = readNiftiHeader(headerPath);
  const std::string dataPath = niftiDataPath(headerPath, h);
  const FrameSpan span = checkFrameSpan(path, h.geometry.dims, sampleSize(h.type), h.frames, frame, maxBytes);
  DenseDataLayout layout;
  layout.path = path;
  layout.dataPath = dataPath;
  if (isGzip(dataPath)) {
    if (h.dataOffset > (std::uint64_t(1) << 30)) {
      throw Error(dataPath + ": vox_offset " + std::to_string(h.dataOffset) +
                  " is too large for compressed data (at most 1 GiB)");
    }
    layout.encoding = DataEncoding::Gzip;
    layout.offset = h.dataOffset + static_cast<std::uint64_t>(span.chosen) * span.frameBytes;
    layout.checkEnd = span.chosen == h.frames - 1;
  } else {
    fileSizeOf(dataPath);
    layout.offset = plainFrameOffset(dataPath, h, span.frameBytes, span.allBytes, span.chosen);
  }
  layout.type = h.type;
  layout.endian = h.endian;
  if (h.slope != 0) {
    layout.slope = h.slope;
    layout.inter = h.inter;
  }
  layout.geometry = h.geometry;
  layout.description = niftiDescription(path, h, span.chosen);
  return layout;
}

}  // namespace

DenseDataLayout niftiDataLayout(const std::string& path, std::size_t maxBytes, int frame) {
  DenseDataLayout layout;
  readPrefixingErrors(path, [&] {
    layout = niftiLayout(path, maxBytes, frame);
    return DenseGrid();
  });
  return layout;
}

DenseGrid readNifti(const std::string& path, std::size_t maxBytes, int frame) {
  return readPrefixingErrors(path, [&] { return readNiftiFile(path, maxBytes, frame); });
}

namespace {

/// Sink for the bytes of a file being written: plain, or deflated into gzip format.
class OutputSink {
 public:
  OutputSink(std::FILE* file, bool gzip) : file_(file), gzip_(gzip) {
    if (gzip_) {
      if (deflateInit2(&zs_, 6, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
        throw Error("cannot initialise zlib");
      }
      buffer_.resize(std::size_t(256) << 10);
    }
  }
  ~OutputSink() {
    if (gzip_) deflateEnd(&zs_);
  }
  OutputSink(const OutputSink&) = delete;
  OutputSink& operator=(const OutputSink&) = delete;

  void write(const void* data, std::size_t n) {
    if (!gzip_) return writeBytes(file_, data, n);
    zs_.next_in = static_cast<Bytef*>(const_cast<void*>(data));
    zs_.avail_in = static_cast<uInt>(n);
    pump(Z_NO_FLUSH);
  }
  void finish() {
    if (gzip_) pump(Z_FINISH);
  }

 private:
  void pump(int flush) {
    while (true) {
      zs_.next_out = buffer_.data();
      zs_.avail_out = static_cast<uInt>(buffer_.size());
      int ret = deflate(&zs_, flush);
      if (ret == Z_STREAM_ERROR) throw Error("zlib compression failed");
      writeBytes(file_, buffer_.data(), buffer_.size() - zs_.avail_out);
      if (flush == Z_FINISH ? ret == Z_STREAM_END : (zs_.avail_in == 0 && zs_.avail_out != 0)) break;
    }
  }
  std::FILE* file_;
  bool gzip_;
  z_stream zs_{};
  std::vector<unsigned char> buffer_;
};

template <typename T>
void put(unsigned char* header, std::size_t offset, T value) {
  std::memcpy(header + offset, &value, sizeof(T));
}

/// The placement of `geometry` in NIfTI's RAS world: the index-to-world columns and the origin.
void rasPlacement(const GridGeometry& geometry, Mat3& columns, Vec3& origin) {
  columns = geometry.direction * geometry.spacing.asDiagonal();
  origin = geometry.origin;
  Vec3 flip = Vec3::Ones();
  if (geometry.space == WorldSpace::LPS) flip = Vec3(-1, -1, 1);
  if (geometry.space == WorldSpace::LAS) flip = Vec3(-1, 1, 1);
  columns = flip.asDiagonal() * columns;
  origin = origin.cwiseProduct(flip);
}

/// The qform quaternion (b, c, d) and qfac of a direction that is a rotation, possibly with the third axis
/// flipped (NIfTI-1 standard, nifti_mat44_to_quatern); false for a sheared direction.
bool qformOf(Mat3 r, Vec3& bcd, double& qfac) {
  if (!((r.transpose() * r - Mat3::Identity()).cwiseAbs().maxCoeff() < 1e-6)) return false;
  qfac = r.determinant() < 0 ? -1.0 : 1.0;
  r.col(2) *= qfac;
  double a = r.trace() + 1, b, c, d;
  if (a > 0.5) {
    a = 0.5 * std::sqrt(a);
    b = 0.25 * (r(2, 1) - r(1, 2)) / a;
    c = 0.25 * (r(0, 2) - r(2, 0)) / a;
    d = 0.25 * (r(1, 0) - r(0, 1)) / a;
  } else if (1 + r(0, 0) - (r(1, 1) + r(2, 2)) > 1) {
    b = 0.5 * std::sqrt(1 + r(0, 0) - (r(1, 1) + r(2, 2)));
    c = 0.25 * (r(0, 1) + r(1, 0)) / b;
    d = 0.25 * (r(0, 2) + r(2, 0)) / b;
    a = 0.25 * (r(2, 1) - r(1, 2)) / b;
  } else if (1 + r(1, 1) - (r(0, 0) + r(2, 2)) > 1) {
    c = 0.5 * std::sqrt(1 + r(1, 1) - (r(0, 0) + r(2, 2)));
    b = 0.25 * (r(0, 1) + r(1, 0)) / c;
    d = 0.25 * (r(1, 2) + r(2, 1)) / c;
    a = 0.25 * (r(0, 2) - r(2, 0)) / c;
  } else {
    d = 0.5 * std::sqrt(1 + r(2, 2) - (r(0, 0) + r(1, 1)));
    b = 0.25 * (r(0, 2) + r(2, 0)) / d;
    c = 0.25 * (r(1, 2) + r(2, 1)) / d;
    a = 0.25 * (r(1, 0) - r(0, 1)) / d;
  }
  if (a < 0)
    bcd = Vec3(-b, -c, -d);
  else
    bcd = Vec3(b, c, d);
  return true;
}

/// Header fields of the placement: pixdim[0..3], qform and sform.
void putPlacement(unsigned char* header, const GridGeometry& g) {
  Mat3 columns;
  Vec3 origin;
  rasPlacement(g, columns, origin);
  Vec3 bcd = Vec3::Zero();
  double qfac = 1;
  const bool hasQform = qformOf(columns * g.spacing.cwiseInverse().asDiagonal(), bcd, qfac);
  float pixdim[8] = {static_cast<float>(qfac),
                     static_cast<float>(g.spacing[0]),
                     static_cast<float>(g.spacing[1]),
                     static_cast<float>(g.spacing[2]),
                     1,
                     1,
                     1,
                     1};
  std::memcpy(header + kNifti1.pixdim, pixdim, sizeof pixdim);
  put<std::int16_t>(header, kNifti1.qformCode, hasQform ? 1 : 0);
  put<std::int16_t>(header, kNifti1.sformCode, 1);
  for (int a = 0; a < 3; ++a) {
    put<float>(header, kNifti1.quatern + 4 * static_cast<std::size_t>(a), static_cast<float>(bcd[a]));
    put<float>(header, kNifti1.qoffset + 4 * static_cast<std::size_t>(a), static_cast<float>(origin[a]));
  }
  for (int r = 0; r < 3; ++r) {
    const std::size_t row = kNifti1.srow + 16 * static_cast<std::size_t>(r);
    for (int c = 0; c < 3; ++c)
      put<float>(header, row + 4 * static_cast<std::size_t>(c), static_cast<float>(columns(r, c)));
    put<float>(header, row + 12, static_cast<float>(origin[r]));
  }
}

}  // namespace

std::size_t writeNifti(const std::string& path, const DenseGrid& grid, const NiftiWriteOptions& options) {
  const auto& g = grid.geometry;
  for (int a = 0; a < 3; ++a) {
    if (g.dims[a] < 1 || g.dims[a] > 32767) {
      throw Error(path + ": NIfTI-1 stores extents from 1 to 32767, the grid has " +
                  std::to_string(g.dims[a]));
    }
  }
  if (static_cast<std::int64_t>(grid.values.size()) != g.pointCount()) {
    throw Error(path + ": grid has " + std::to_string(grid.values.size()) + " values for its dims");
  }
  if (hostEndian() != Endian::Little) throw Error(path + ": writing NIfTI needs a little-endian machine");
  unsigned char header[kWriteOffset] = {};
  put<std::int32_t>(header, 0, 348);
  std::int16_t dim[8] = {3,
                         static_cast<std::int16_t>(g.dims[0]),
                         static_cast<std::int16_t>(g.dims[1]),
                         static_cast<std::int16_t>(g.dims[2]),
                         1,
                         1,
                         1,
                         1};
  std::memcpy(header + kNifti1.dim, dim, sizeof dim);
  put<std::int16_t>(header, kNifti1.datatype, 16);
  put<std::int16_t>(header, kNifti1.bitpix, 32);
  putPlacement(header, g);
  put<float>(header, kNifti1.voxOffset, static_cast<float>(kWriteOffset));
  put<float>(header, kNifti1.sclSlope, static_cast<float>(options.sclSlope));
  put<float>(header, kNifti1.sclInter, static_cast<float>(options.sclInter));
  header[123] = 2;  // xyzt_units: millimetres
  std::memcpy(header + kNifti1.magic, "n+1\0", 4);

  const bool gzip = endsWithNoCase(path, ".gz");
  const double slope = options.sclSlope != 0 ? options.sclSlope : 1.0;
  const double inter = options.sclSlope != 0 ? options.sclInter : 0.0;
  return writeFileAtomically(path, [&](std::FILE* file) {
    OutputSink sink(file, gzip);
    sink.write(header, sizeof header);
    std::vector<float> slab(std::min<std::size_t>(grid.values.size(), std::size_t(1) << 20));
    for (std::size_t done = 0; done < grid.values.size();) {
      std::size_t n = std::min(slab.size(), grid.values.size() - done);
      for (std::size_t s = 0; s < n; ++s)
        slab[s] = static_cast<float>((grid.values[done + s] - inter) / slope);
      sink.write(slab.data(), n * sizeof(float));
      done += n;
    }
    sink.finish();
  });
}

}  // namespace cip
