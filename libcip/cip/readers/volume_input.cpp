#include "cip/readers/volume_input.h"

#include <bzlib.h>
#include <sys/stat.h>
#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <limits>

#include "cip/core/error.h"

namespace cip {

std::string baseName(const std::string& path) {
  std::size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

std::string describeDenseFile(const std::string& path, const std::string& format, SampleType type,
                              const std::array<std::int64_t, 3>& dims) {
  return baseName(path) + " (" + format + " " + toString(type) + " " + std::to_string(dims[0]) + "x" +
         std::to_string(dims[1]) + "x" + std::to_string(dims[2]) + ")";
}

namespace {

constexpr std::size_t kSlabBytes = std::size_t(4) << 20;
constexpr std::size_t kInputChunk = std::size_t(256) << 10;

std::FILE* openAt(const std::string& path, std::uint64_t offset) {
  fileSizeOf(path);  // clear error for missing files and directories
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw Error(path + ": cannot open: " + std::strerror(errno));
  if (offset > 0 && ::fseeko(f, static_cast<off_t>(offset), SEEK_SET) != 0) {
    std::string reason = std::strerror(errno);
    std::fclose(f);
    throw Error(path + ": cannot seek to byte " + std::to_string(offset) + ": " + reason);
  }
  return f;
}

}  // namespace

std::uint64_t fileSizeOf(const std::string& path) {
  struct stat st;
  if (::stat(path.c_str(), &st) != 0) throw Error(path + ": cannot open: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) throw Error(path + ": cannot open: not a regular file");
  return static_cast<std::uint64_t>(st.st_size);
}

bool endsWithNoCase(const std::string& path, const std::string& suffix) {
  if (path.size() < suffix.size()) return false;
  return std::equal(suffix.begin(), suffix.end(), path.end() - static_cast<std::ptrdiff_t>(suffix.size()),
                    [](char a, char b) {
                      return std::tolower(static_cast<unsigned char>(a)) ==
                             std::tolower(static_cast<unsigned char>(b));
                    });
}

std::string trimBlanks(std::string_view s) {
  std::size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return std::string(s.substr(b, e - b));
}

std::vector<std::string> splitWords(std::string_view s) {
  std::vector<std::string> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    const std::size_t b = i;
    while (i < s.size() && !std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    if (i > b) out.emplace_back(s.substr(b, i - b));
  }
  return out;
}

std::int64_t checkVolumeFrame(const std::string& path, std::int64_t frames, int frame) {
  if (frame < 0) {
    if (frames > 1) {
      throw Error(path + ": the file holds " + std::to_string(frames) +
                  " frames (a 4-D series); choose one with --frame 0.." + std::to_string(frames - 1));
    }
    return 0;
  }
  if (frame >= frames) {
    throw Error(path + ": frame " + std::to_string(frame) + " is out of range: the file holds " +
                std::to_string(frames) +
                (frames == 1 ? " frame" : " frames (0.." + std::to_string(frames - 1) + ")"));
  }
  return frame;
}

FrameSpan checkFrameSpan(const std::string& path, const std::array<std::int64_t, 3>& dims,
                         std::size_t bytesPerSample, std::int64_t frames, int frame, std::size_t maxBytes) {
  FrameSpan span;
  span.chosen = checkVolumeFrame(path, frames, frame);
  const std::int64_t count = checkVolumeDims(path, dims, bytesPerSample, maxBytes);
  span.frameBytes = static_cast<std::uint64_t>(count) * bytesPerSample;
  if (static_cast<std::uint64_t>(frames) > (std::uint64_t(1) << 62) / span.frameBytes) {
    throw Error(path + ": " + std::to_string(frames) + " frames of " + std::to_string(span.frameBytes) +
                " bytes do not fit 64 bits");
  }
  span.allBytes = span.frameBytes * static_cast<std::uint64_t>(frames);
  return span;
}

DenseGrid readPrefixingErrors(const std::string& path, const std::function<DenseGrid()>& read) {
  try {
    return read();
  } catch (const Error& e) {
    const std::string what = e.what();
    if (what.compare(0, path.size() + 1, path + ":") == 0) throw;
    throw Error(path + ": " + what);
  }
}

std::uint64_t ByteSource::skip(std::uint64_t n) {
  std::vector<unsigned char> buffer(static_cast<std::size_t>(std::min<std::uint64_t>(n, kSlabBytes)));
  std::uint64_t done = 0;
  while (done < n) {
    std::size_t want = static_cast<std::size_t>(std::min<std::uint64_t>(n - done, buffer.size()));
    std::size_t got = read(buffer.data(), want);
    done += got;
    if (got < want) break;
  }
  return done;
}

void ByteSource::readExactly(void* buffer, std::size_t n, const std::string& what) {
  std::size_t got = read(buffer, n);
  if (got < n) {
    throw Error(path_ + ": " + what + " ends after " + std::to_string(got) + " of " + std::to_string(n) +
                " bytes");
  }
}

void ByteSource::expectEnd(const std::string& what) {
  unsigned char extra;
  std::uint64_t declared = position_;
  if (read(&extra, 1) != 0) {
    throw Error(path_ + ": " + what + " continues past its declared size of " + std::to_string(declared) +
                " bytes");
  }
}

FileByteSource::FileByteSource(const std::string& path, std::uint64_t offset)
    : ByteSource(path), file_(openAt(path, offset)) {}

FileByteSource::~FileByteSource() {
  if (file_) std::fclose(file_);
}

std::size_t FileByteSource::read(void* buffer, std::size_t n) {
  std::size_t got = std::fread(buffer, 1, n, file_);
  if (got < n && std::ferror(file_)) throw Error(path_ + ": read error: " + std::strerror(errno));
  position_ += got;
  return got;
}

namespace {

/// The input buffer of a decompressor: moves the `keep` unread bytes at `next` to the front of `buffer` and
/// fills the rest from `file`, setting `end` at the end of the file. Returns the bytes read.
template <class Byte>
std::size_t refillInput(std::FILE* file, std::vector<Byte>& buffer, const Byte* next, std::size_t keep,
                        bool& end, const std::string& path) {
  if (keep > 0 && next != buffer.data()) std::memmove(buffer.data(), next, keep);
  const std::size_t got = std::fread(buffer.data() + keep, 1, buffer.size() - keep, file);
  if (got < buffer.size() - keep) {
    if (std::ferror(file)) throw Error(path + ": read error: " + std::strerror(errno));
    end = true;
  }
  return got;
}

}  // namespace

GzipByteSource::GzipByteSource(const std::string& path, std::uint64_t offset) : ByteSource(path) {
  file_ = openAt(path, offset);
  auto* zs = new z_stream{};
  // 15 + 32: maximum window, and accept either a gzip or a zlib header.
  if (inflateInit2(zs, 15 + 32) != Z_OK) {
    delete zs;
    std::fclose(file_);
    throw Error(path + ": cannot initialise zlib");
  }
  stream_ = zs;
  input_.resize(kInputChunk);
  zs->next_in = input_.data();
  zs->avail_in = 0;
}

GzipByteSource::~GzipByteSource() {
  auto* zs = static_cast<z_stream*>(stream_);
  inflateEnd(zs);
  delete zs;
  if (file_) std::fclose(file_);
}

bool GzipByteSource::refill() {
  auto* zs = static_cast<z_stream*>(stream_);
  if (inputEnd_) return false;
  const std::size_t keep = zs->avail_in;
  const std::size_t got = refillInput(file_, input_, zs->next_in, keep, inputEnd_, path_);
  zs->next_in = input_.data();
  zs->avail_in = static_cast<uInt>(keep + got);
  return got > 0;
}

std::size_t GzipByteSource::read(void* buffer, std::size_t n) {
  auto* zs = static_cast<z_stream*>(stream_);
  auto* out = static_cast<unsigned char*>(buffer);
  std::size_t done = 0;
  while (done < n && !streamEnd_) {
    if (zs->avail_in == 0) refill();
    std::size_t want = std::min<std::size_t>(n - done, std::size_t(1) << 30);
    zs->next_out = out + done;
    zs->avail_out = static_cast<uInt>(want);
    uInt inBefore = zs->avail_in;
    int ret = inflate(zs, Z_NO_FLUSH);
    std::size_t produced = want - zs->avail_out;
    done += produced;
    if (ret == Z_STREAM_END) {
      // Another gzip member may follow (concatenated .gz files); anything else after the stream is ignored.
      if (zs->avail_in < 2) refill();
      if (zs->avail_in >= 2 && zs->next_in[0] == 0x1f && zs->next_in[1] == 0x8b) {
        inflateReset(zs);
      } else {
        streamEnd_ = true;
      }
      continue;
    }
    if (ret == Z_OK || ret == Z_BUF_ERROR) {
      // Without progress, inflate needs more input; at the end of the file the data is truncated.
      if (produced == 0 && zs->avail_in == inBefore && !refill()) {
        throw Error(path_ + ": compressed data is truncated (ends after " + std::to_string(position_ + done) +
                    " inflated bytes)");
      }
      continue;
    }
    std::string reason = zs->msg ? zs->msg : "zlib error " + std::to_string(ret);
    throw Error(path_ + ": corrupt compressed data: " + reason);
  }
  position_ += done;
  return done;
}

namespace {

bz_stream* newBzip2Stream(const std::string& path) {
  auto* bz = new bz_stream{};
  if (BZ2_bzDecompressInit(bz, 0, 0) != BZ_OK) {
    delete bz;
    throw Error(path + ": cannot initialise the bzip2 decompressor");
  }
  return bz;
}

const char* bzip2Reason(int ret) {
  switch (ret) {
    case BZ_DATA_ERROR:
      return "data integrity error";
    case BZ_DATA_ERROR_MAGIC:
      return "not bzip2 data (bad magic)";
    case BZ_MEM_ERROR:
      return "out of memory";
    default:
      return "decompressor error";
  }
}

}  // namespace

Bzip2ByteSource::Bzip2ByteSource(const std::string& path, std::uint64_t offset) : ByteSource(path) {
  file_ = openAt(path, offset);
  try {
    stream_ = newBzip2Stream(path);
  } catch (...) {
    std::fclose(file_);
    throw;
  }
  input_.resize(kInputChunk);
  auto* bz = static_cast<bz_stream*>(stream_);
  bz->next_in = input_.data();
  bz->avail_in = 0;
}

Bzip2ByteSource::~Bzip2ByteSource() {
  auto* bz = static_cast<bz_stream*>(stream_);
  BZ2_bzDecompressEnd(bz);
  delete bz;
  if (file_) std::fclose(file_);
}

bool Bzip2ByteSource::refill() {
  auto* bz = static_cast<bz_stream*>(stream_);
  if (inputEnd_) return false;
  const std::size_t keep = bz->avail_in;
  const std::size_t got = refillInput(file_, input_, bz->next_in, keep, inputEnd_, path_);
  bz->next_in = input_.data();
  bz->avail_in = static_cast<unsigned>(keep + got);
  return got > 0;
}

void Bzip2ByteSource::restart() {
  auto* old = static_cast<bz_stream*>(stream_);
  char* next = old->next_in;
  unsigned avail = old->avail_in;
  BZ2_bzDecompressEnd(old);
  *old = bz_stream{};
  if (BZ2_bzDecompressInit(old, 0, 0) != BZ_OK)
    throw Error(path_ + ": cannot initialise the bzip2 decompressor");
  old->next_in = next;
  old->avail_in = avail;
}

std::size_t Bzip2ByteSource::read(void* buffer, std::size_t n) {
  auto* bz = static_cast<bz_stream*>(stream_);
  auto* out = static_cast<char*>(buffer);
  std::size_t done = 0;
  while (done < n && !streamEnd_) {
    if (bz->avail_in == 0) refill();
    std::size_t want = std::min<std::size_t>(n - done, std::size_t(1) << 30);
    bz->next_out = out + done;
    bz->avail_out = static_cast<unsigned>(want);
    unsigned inBefore = bz->avail_in;
    int ret = BZ2_bzDecompress(bz);
    std::size_t produced = want - bz->avail_out;
    done += produced;
    if (ret == BZ_STREAM_END) {
      // Another bzip2 stream may follow (parallel compressors); anything else after the stream is ignored.
      if (bz->avail_in < 3) refill();
      if (bz->avail_in >= 3 && std::memcmp(bz->next_in, "BZh", 3) == 0) {
        restart();
      } else {
        streamEnd_ = true;
      }
      continue;
    }
    if (ret == BZ_OK) {
      if (produced == 0 && bz->avail_in == inBefore && !refill()) {
        throw Error(path_ + ": compressed data is truncated (ends after " + std::to_string(position_ + done) +
                    " decompressed bytes)");
      }
      continue;
    }
    throw Error(path_ + ": corrupt compressed data: bzip2 " + bzip2Reason(ret));
  }
  position_ += done;
  return done;
}

std::int64_t checkVolumeDims(const std::string& path, const std::array<std::int64_t, 3>& dims,
                             std::size_t bytesPerSample, std::size_t maxBytes) {
  for (auto d : dims) {
    if (d < 1) {
      throw Error(path + ": invalid volume dimensions " + std::to_string(dims[0]) + "x" +
                  std::to_string(dims[1]) + "x" + std::to_string(dims[2]) +
                  " (every extent must be at least 1)");
    }
  }
  std::int64_t count = 0;
  try {
    count = checkedVolumeSize(dims, sizeof(double), maxBytes);
    checkedVolumeSize(dims, std::max<std::size_t>(bytesPerSample, 1),
                      std::numeric_limits<std::size_t>::max());
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  return count;
}

std::unique_ptr<ByteSource> openSamplesAt(const DenseDataLayout& layout, std::uint64_t first) {
  const std::uint64_t byte = layout.offset + first * sampleSize(layout.type);
  if (layout.encoding == DataEncoding::Plain) return std::make_unique<FileByteSource>(layout.dataPath, byte);
  std::unique_ptr<ByteSource> source;
  if (layout.encoding == DataEncoding::Gzip) {
    source = std::make_unique<GzipByteSource>(layout.dataPath, layout.streamStart);
  } else {
    source = std::make_unique<Bzip2ByteSource>(layout.dataPath, layout.streamStart);
  }
  if (source->skip(byte) != byte) {
    throw Error(layout.dataPath + ": data ends before byte " + std::to_string(byte) + " (" +
                std::to_string(source->position()) + " bytes decompressed)");
  }
  return source;
}

void readSamplesInto(ByteSource& source, SampleType type, Endian endian, double* out, std::size_t total,
                     std::uint64_t before, std::uint64_t allBytes) {
  const std::size_t size = sampleSize(type);
  const std::size_t perSlab = std::max<std::size_t>(1, kSlabBytes / size);
  std::vector<unsigned char> slab(std::min(total, perSlab) * size);
  std::size_t done = 0;
  while (done < total) {
    std::size_t count = std::min(total - done, perSlab);
    std::size_t got = source.read(slab.data(), count * size);
    if (got < count * size) {
      const std::uint64_t have = before + static_cast<std::uint64_t>(done) * size + got;
      throw Error(source.path() + ": data ends after " + std::to_string(have) + " of " +
                  std::to_string(allBytes) + " bytes (" + std::to_string(allBytes - have) + " bytes short)");
    }
    decodeSamples(slab.data(), count, type, endian, out + done);
    done += count;
  }
}

void readSamplesInto(ByteSource& source, SampleType type, Endian endian, DenseGrid& grid) {
  const std::size_t total = grid.values.size();
  readSamplesInto(source, type, endian, grid.values.data(), total, 0,
                  static_cast<std::uint64_t>(total) * sampleSize(type));
}

}  // namespace cip
