/// @file volume_input.h
/// @brief Plumbing shared by the volume readers: files opened with clear errors, sequential byte sources over
/// plain, gzip/zlib- or bzip2-compressed data, checked volume sizes, and streaming sample decoding into a
/// DenseGrid.
///
/// Samples are read in slabs of a few MiB and decoded straight into the grid's double values, so a reader
/// never holds a second full copy of the volume. Compressed data is inflated through a fixed-size buffer;
/// readers ask for exactly the declared number of bytes and then check with expectEnd() that nothing follows,
/// which inflates at most one more byte: a stream that expands beyond its declared size is stopped there.
#pragma once
#include <array>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "cip/volume/dense_grid.h"
#include "cip/volume/sample_type.h"

namespace cip {

/// Size of a regular file in bytes; throws cip::Error "<path>: cannot open: <reason>" if it is missing or not
/// a file.
std::uint64_t fileSizeOf(const std::string& path);

/// The file name part of a path (after the last '/').
std::string baseName(const std::string& path);

/// Description of a dense volume file for the model's source field, e.g. "tooth.nhdr (NRRD uint8
/// 103x94x161)".
std::string describeDenseFile(const std::string& path, const std::string& format, SampleType type,
                              const std::array<std::int64_t, 3>& dims);

/// True when `path` ends with `suffix`, ignoring ASCII case.
bool endsWithNoCase(const std::string& path, const std::string& suffix);

/// `s` without leading and trailing blanks (text headers: NRRD, MetaImage).
std::string trimBlanks(std::string_view s);
/// The blank-separated words of `s`.
std::vector<std::string> splitWords(std::string_view s);

/// Sequential reader of bytes; throws cip::Error (message starts with the path) on I/O or decoding failure.
class ByteSource {
 public:
  explicit ByteSource(std::string path) : path_(std::move(path)) {}
  virtual ~ByteSource() = default;
  ByteSource(const ByteSource&) = delete;
  ByteSource& operator=(const ByteSource&) = delete;

  /// Reads up to `n` bytes into `buffer`; returns fewer only at the end of the data.
  virtual std::size_t read(void* buffer, std::size_t n) = 0;
  /// Skips up to `n` bytes; returns the number skipped (fewer only at the end of the data).
  std::uint64_t skip(std::uint64_t n);
  /// Reads exactly `n` bytes or throws "<path>: <what> ends after X of N bytes".
  void readExactly(void* buffer, std::size_t n, const std::string& what);
  /// Throws "<path>: <what> continues past its declared size of N bytes" if any byte is left.
  void expectEnd(const std::string& what);
  /// Bytes delivered (read or skipped) so far.
  std::uint64_t position() const { return position_; }
  const std::string& path() const { return path_; }

 protected:
  std::uint64_t position_ = 0;
  std::string path_;
};

/// Bytes of a file from a given offset, as stored.
class FileByteSource : public ByteSource {
 public:
  FileByteSource(const std::string& path, std::uint64_t offset);
  ~FileByteSource() override;
  std::size_t read(void* buffer, std::size_t n) override;

 private:
  std::FILE* file_ = nullptr;
};

/// Inflated bytes of gzip or zlib data (detected from its header) stored in a file from a given offset.
/// Concatenated gzip members are read as one stream. Corrupt or truncated data throws cip::Error.
class GzipByteSource : public ByteSource {
 public:
  GzipByteSource(const std::string& path, std::uint64_t offset);
  ~GzipByteSource() override;
  std::size_t read(void* buffer, std::size_t n) override;

 private:
  bool refill();
  std::FILE* file_ = nullptr;
  void* stream_ = nullptr;  ///< z_stream, kept opaque so zlib stays out of this header
  std::vector<unsigned char> input_;
  bool inputEnd_ = false;
  bool streamEnd_ = false;
};

/// Decompressed bytes of bzip2 data stored in a file from a given offset. Concatenated bzip2 streams (as
/// written by parallel bzip2 tools) are read as one. Corrupt or truncated data throws cip::Error.
class Bzip2ByteSource : public ByteSource {
 public:
  Bzip2ByteSource(const std::string& path, std::uint64_t offset);
  ~Bzip2ByteSource() override;
  std::size_t read(void* buffer, std::size_t n) override;

 private:
  bool refill();
  void restart();  ///< a fresh decompressor for the next concatenated stream
  std::FILE* file_ = nullptr;
  void* stream_ = nullptr;  ///< bz_stream, kept opaque so bzlib stays out of this header
  std::vector<char> input_;
  bool inputEnd_ = false;
  bool streamEnd_ = false;
};

/// Checks the dims of a volume before anything is allocated: every extent >= 1, the point count and its
/// double storage fit 64 bits and `maxBytes`, and the stored data (count * bytesPerSample) fits 64 bits.
/// Returns the number of points. Errors are "<path>: ..." and name the dims and the size.
std::int64_t checkVolumeDims(const std::string& path, const std::array<std::int64_t, 3>& dims,
                             std::size_t bytesPerSample, std::size_t maxBytes);

/// The frame of a series of `frames` frames to read: `frame` when it is in range; for frame -1 (none chosen)
/// 0 when the file holds one frame. Errors are "<path>: ..." and name the frame count.
std::int64_t checkVolumeFrame(const std::string& path, std::int64_t frames, int frame);

/// Where one frame of a series lies in its stored data, checked before anything is allocated.
struct FrameSpan {
  std::int64_t chosen = 0;       ///< the frame to read (checkVolumeFrame)
  std::uint64_t frameBytes = 0;  ///< stored bytes of one frame
  std::uint64_t allBytes = 0;    ///< stored bytes of every frame
};
/// checkVolumeFrame and checkVolumeDims for a series of `frames` frames of `dims` samples of
/// `bytesPerSample`, and the byte counts; throws "<path>: ..." when the frames' bytes do not fit 64 bits.
FrameSpan checkFrameSpan(const std::string& path, const std::array<std::int64_t, 3>& dims,
                         std::size_t bytesPerSample, std::int64_t frames, int frame, std::size_t maxBytes);

/// Runs `read`; a cip::Error whose message does not start with "<path>:" (one about a data file beside the
/// header, say) is thrown again with "<path>: " in front, so that every message starts with the path given.
DenseGrid readPrefixingErrors(const std::string& path, const std::function<DenseGrid()>& read);

/// How the stored samples of a dense volume file are encoded: as they are, or gzip/zlib- or bzip2-compressed.
enum class DataEncoding : std::uint8_t { Plain, Gzip, Bzip2 };

/// Where the samples of one frame of a dense volume file lie, found from its header alone and checked as the
/// whole-volume reader checks them (sizes of plain data, frame in range), so that any run of samples can be
/// read without the others (slab_reader.h). The samples are x fastest, then y, then z.
struct DenseDataLayout {
  std::string path;      ///< the file named by the caller (header), which error messages start with
  std::string dataPath;  ///< the file holding the samples
  DataEncoding encoding = DataEncoding::Plain;
  std::uint64_t offset = 0;  ///< byte of the frame's first sample: in the file, or in the decompressed stream
  std::uint64_t streamStart = 0;  ///< compressed: byte of the file where the compressed stream begins
  bool checkEnd = false;  ///< compressed: reading the last sample checks that no data follows (expectEnd)
  SampleType type = SampleType::UInt8;
  Endian endian = Endian::Little;
  double slope = 0;         ///< value = slope * stored + inter when slope is nonzero (NIfTI scl_slope)
  double inter = 0;         ///< NIfTI scl_inter
  GridGeometry geometry;    ///< dims and placement of the whole volume, as the whole-volume reader gives them
  std::string description;  ///< as the whole-volume reader's grid description
};

/// A byte source positioned at sample `first` of the layout's frame (plain data: by seeking; compressed: by
/// decompressing and skipping). Throws "<dataPath>: data ends before byte N ..." when the data is shorter.
std::unique_ptr<ByteSource> openSamplesAt(const DenseDataLayout& layout, std::uint64_t first);

/// Fills the already allocated `grid.values` with samples read from `source`, x fastest, in slabs of a few
/// MiB. Throws "<path>: data ends after X of N bytes" when the source runs out early.
void readSamplesInto(ByteSource& source, SampleType type, Endian endian, DenseGrid& grid);
/// Decodes the next `count` samples of `source` into `out`, the run that starts `before` bytes into data of
/// `allBytes` bytes (for the message): throws "<path>: data ends after X of N bytes" when the source runs
/// out.
void readSamplesInto(ByteSource& source, SampleType type, Endian endian, double* out, std::size_t count,
                     std::uint64_t before, std::uint64_t allBytes);

}  // namespace cip
