#include "cip/readers/nifti_reader.h"

#include <zlib.h>

#include <array>
#include <cmath>
#include <cstring>
#include <memory>
#include <vector>

#include "cip/core/atomic_file.h"
#include "cip/core/error.h"
#include "cip/readers/volume_input.h"

namespace cip {

namespace {

// Byte offsets of the NIfTI-1 header fields used here.
constexpr std::size_t kSizeofHdr = 0, kDim = 40, kDatatype = 70, kBitpix = 72, kPixdim = 76, kVoxOffset = 108,
                      kSclSlope = 112, kSclInter = 116, kQformCode = 252, kSformCode = 254, kQuatern = 256,
                      kQoffset = 268, kSrowX = 280, kSrowY = 296, kSrowZ = 312, kMagic = 344;
constexpr std::size_t kWriteOffset = 352;  // header + 4-byte extension flag

class FieldReader {
 public:
  FieldReader(const unsigned char* bytes, bool swap) : bytes_(bytes), swap_(swap) {}
  template <typename T>
  T get(std::size_t offset) const {
    unsigned char tmp[sizeof(T)];
    for (std::size_t b = 0; b < sizeof(T); ++b) tmp[b] = bytes_[offset + (swap_ ? sizeof(T) - 1 - b : b)];
    T v;
    std::memcpy(&v, tmp, sizeof(T));
    return v;
  }

 private:
  const unsigned char* bytes_;
  bool swap_;
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

/// Whether the header's fields are in the other byte order than the host's (from sizeof_hdr, which must be
/// 348 in one of the two orders).
bool headerIsSwapped(const unsigned char* bytes) {
  std::int32_t sizeofHdr;
  std::memcpy(&sizeofHdr, bytes + kSizeofHdr, 4);
  if (sizeofHdr == 348) return false;
  if (__builtin_bswap32(static_cast<std::uint32_t>(sizeofHdr)) == 348u) return true;
  if (sizeofHdr == 540 || __builtin_bswap32(static_cast<std::uint32_t>(sizeofHdr)) == 540u) {
    throw Error("NIfTI-2 files are not supported (only NIfTI-1)");
  }
  throw Error("not a NIfTI-1 file: sizeof_hdr is " + std::to_string(sizeofHdr) + ", expected 348");
}

/// Accepts the single-file magic "n+1" only.
void checkMagic(const unsigned char* bytes) {
  const unsigned char* magic = bytes + kMagic;
  if (std::memcmp(magic, "ni1\0", 4) == 0) {
    throw Error(
        "NIfTI-1 header/image pairs (.hdr/.img, magic \"ni1\") are not supported; use a single .nii file");
  }
  if (std::memcmp(magic, "n+1\0", 4) != 0) throw Error("not a NIfTI-1 file: magic is not \"n+1\"");
}

/// dim[1..3], for a 3-D volume or a 4-D one with a single time point.
std::array<std::int64_t, 3> readDims(const FieldReader& f) {
  std::int16_t dim[8];
  for (int i = 0; i < 8; ++i) dim[i] = f.get<std::int16_t>(kDim + 2 * static_cast<std::size_t>(i));
  if (dim[0] != 3 && !(dim[0] == 4 && dim[4] == 1)) {
    if (dim[0] == 4) {
      throw Error("4-D NIfTI volume with " + std::to_string(dim[4]) +
                  " time points is not supported (dim[4] must be 1)");
    }
    throw Error("NIfTI dim[0] is " + std::to_string(dim[0]) + "; a volume needs 3 (or 4 with dim[4] = 1)");
  }
  std::array<std::int64_t, 3> dims;
  for (int a = 0; a < 3; ++a) {
    if (dim[a + 1] < 1) {
      throw Error("NIfTI dim[" + std::to_string(a + 1) + "] is " + std::to_string(dim[a + 1]) +
                  " (must be >= 1)");
    }
    dims[a] = dim[a + 1];
  }
  return dims;
}

/// The sample type from datatype, checked against bitpix (0 = not given).
SampleType readSampleType(const FieldReader& f) {
  SampleType type = SampleType::UInt8;
  int datatype = f.get<std::int16_t>(kDatatype);
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
  int bitpix = f.get<std::int16_t>(kBitpix);
  if (bitpix != 0 && bitpix != static_cast<int>(8 * sampleSize(type))) {
    throw Error("NIfTI bitpix " + std::to_string(bitpix) + " does not match datatype " + toString(type));
  }
  return type;
}

/// |pixdim[1..3]|, each positive and finite.
Vec3 readSpacing(const FieldReader& f) {
  Vec3 spacing;
  for (int a = 0; a < 3; ++a) {
    double s = std::abs(static_cast<double>(f.get<float>(kPixdim + 4 * static_cast<std::size_t>(a + 1))));
    if (!(s > 0) || !std::isfinite(s)) {
      throw Error("NIfTI pixdim[" + std::to_string(a + 1) + "] is " + std::to_string(s) +
                  " (spacing must be positive and finite)");
    }
    spacing[a] = s;
  }
  return spacing;
}

/// vox_offset: a whole number of bytes, at least the header's.
std::uint64_t readDataOffset(const FieldReader& f) {
  double voxOffset = f.get<float>(kVoxOffset);
  if (!std::isfinite(voxOffset) || voxOffset < static_cast<double>(kNiftiHeaderBytes) ||
      voxOffset != std::floor(voxOffset) || voxOffset > 9.0e15) {
    throw Error("NIfTI vox_offset " + std::to_string(voxOffset) +
                " is invalid (must be a whole number >= 348)");
  }
  return static_cast<std::uint64_t>(voxOffset);
}

/// Value scaling (non-finite slope or intercept read as 0), the form codes and the origin they select:
/// qoffset if qform_code > 0, else the translation column of the srows if sform_code > 0, else 0.
void readScalingAndOrigin(const FieldReader& f, NiftiHeader& h) {
  h.slope = f.get<float>(kSclSlope);
  h.inter = f.get<float>(kSclInter);
  if (!std::isfinite(h.slope)) h.slope = 0;
  if (!std::isfinite(h.inter)) h.inter = 0;

  h.qformCode = f.get<std::int16_t>(kQformCode);
  h.sformCode = f.get<std::int16_t>(kSformCode);
  if (h.qformCode > 0) {
    for (int a = 0; a < 3; ++a) h.origin[a] = f.get<float>(kQoffset + 4 * static_cast<std::size_t>(a));
  } else if (h.sformCode > 0) {
    h.origin = Vec3(f.get<float>(kSrowX + 12), f.get<float>(kSrowY + 12), f.get<float>(kSrowZ + 12));
  }
  for (int a = 0; a < 3; ++a) {
    if (!std::isfinite(h.origin[a])) throw Error("NIfTI origin (qoffset/srow) is not finite");
  }
}

}  // namespace

NiftiHeader parseNiftiHeader(const unsigned char* bytes, std::size_t size) {
  if (size < kNiftiHeaderBytes) {
    throw Error("too small for a NIfTI-1 header (" + std::to_string(size) + " of 348 bytes)");
  }
  const bool swap = headerIsSwapped(bytes);
  NiftiHeader h;
  h.endian = (hostEndian() == Endian::Little) != swap ? Endian::Little : Endian::Big;
  checkMagic(bytes);
  const FieldReader f(bytes, swap);
  h.dims = readDims(f);
  h.type = readSampleType(f);
  h.spacing = readSpacing(f);
  h.dataOffset = readDataOffset(f);
  readScalingAndOrigin(f, h);
  return h;
}

NiftiHeader readNiftiHeader(const std::string& path) {
  std::unique_ptr<ByteSource> source;
  if (isGzip(path)) {
    source = std::make_unique<GzipByteSource>(path, 0);
  } else {
    source = std::make_unique<FileByteSource>(path, 0);
  }
  unsigned char bytes[kNiftiHeaderBytes];
  std::size_t got = source->read(bytes, sizeof bytes);
  try {
    return parseNiftiHeader(bytes, got);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

DenseGrid readNifti(const std::string& path, std::size_t maxBytes) {
  const bool gz = isGzip(path);
  NiftiHeader h = readNiftiHeader(path);
  const std::size_t size = sampleSize(h.type);
  const std::int64_t count = checkVolumeDims(path, h.dims, size, maxBytes);
  const std::uint64_t dataBytes = static_cast<std::uint64_t>(count) * size;

  DenseGrid grid;
  std::unique_ptr<ByteSource> source;
  if (gz) {
    if (h.dataOffset > (std::uint64_t(1) << 30)) {
      throw Error(path + ": vox_offset " + std::to_string(h.dataOffset) +
                  " is too large for compressed data (at most 1 GiB)");
    }
    grid.allocate(h.dims, maxBytes);
    source = std::make_unique<GzipByteSource>(path, 0);
    if (source->skip(h.dataOffset) != h.dataOffset) {
      throw Error(path + ": data offset " + std::to_string(h.dataOffset) +
                  " is beyond the end of the data (" + std::to_string(source->position()) +
                  " bytes inflated)");
    }
  } else {
    const std::uint64_t fileBytes = fileSizeOf(path);
    if (h.dataOffset > fileBytes) {
      throw Error(path + ": data offset " + std::to_string(h.dataOffset) +
                  " is beyond the end of the file (" + std::to_string(fileBytes) + " bytes)");
    }
    if (fileBytes - h.dataOffset != dataBytes) {
      std::uint64_t have = fileBytes - h.dataOffset;
      throw Error(path + ": data is " +
                  (have < dataBytes ? std::to_string(dataBytes - have) + " bytes short"
                                    : std::to_string(have - dataBytes) + " bytes longer than declared") +
                  " (" + std::to_string(h.dims[0]) + "x" + std::to_string(h.dims[1]) + "x" +
                  std::to_string(h.dims[2]) + " " + toString(h.type) + " = " + std::to_string(dataBytes) +
                  " bytes from byte " + std::to_string(h.dataOffset) + ", file has " +
                  std::to_string(fileBytes) + ")");
    }
    grid.allocate(h.dims, maxBytes);
    source = std::make_unique<FileByteSource>(path, h.dataOffset);
  }
  readSamplesInto(*source, h.type, h.endian, grid);
  if (gz) source->expectEnd("compressed data");
  if (h.slope != 0) {
    for (double& v : grid.values) v = h.slope * v + h.inter;
  }
  grid.geometry.spacing = h.spacing;
  grid.geometry.origin = h.origin;
  grid.description = describeDenseFile(path, "NIfTI", h.type, h.dims);
  return grid;
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
  put<std::int32_t>(header, kSizeofHdr, 348);
  std::int16_t dim[8] = {3,
                         static_cast<std::int16_t>(g.dims[0]),
                         static_cast<std::int16_t>(g.dims[1]),
                         static_cast<std::int16_t>(g.dims[2]),
                         1,
                         1,
                         1,
                         1};
  std::memcpy(header + kDim, dim, sizeof dim);
  put<std::int16_t>(header, kDatatype, 16);
  put<std::int16_t>(header, kBitpix, 32);
  float pixdim[8] = {1.0f,
                     static_cast<float>(g.spacing[0]),
                     static_cast<float>(g.spacing[1]),
                     static_cast<float>(g.spacing[2]),
                     1,
                     1,
                     1,
                     1};
  std::memcpy(header + kPixdim, pixdim, sizeof pixdim);
  put<float>(header, kVoxOffset, static_cast<float>(kWriteOffset));
  put<float>(header, kSclSlope, static_cast<float>(options.sclSlope));
  put<float>(header, kSclInter, static_cast<float>(options.sclInter));
  header[123] = 2;  // xyzt_units: millimetres
  put<std::int16_t>(header, kQformCode, 1);
  put<std::int16_t>(header, kSformCode, 1);
  for (int a = 0; a < 3; ++a) {
    put<float>(header, kQuatern + 4 * static_cast<std::size_t>(a), 0.0f);
    put<float>(header, kQoffset + 4 * static_cast<std::size_t>(a), static_cast<float>(g.origin[a]));
  }
  const std::size_t rows[3] = {kSrowX, kSrowY, kSrowZ};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c)
      put<float>(header, rows[r] + 4 * static_cast<std::size_t>(c), r == c ? pixdim[r + 1] : 0.0f);
    put<float>(header, rows[r] + 12, static_cast<float>(g.origin[r]));
  }
  std::memcpy(header + kMagic, "n+1\0", 4);

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
