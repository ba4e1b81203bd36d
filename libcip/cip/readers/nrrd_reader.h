/// @file nrrd_reader.h
/// @brief NRRD volumes (.nrrd with attached data, .nhdr with a detached data file): header parser and reader.
///
/// Supported: magic NRRD0001..NRRD0005; `dimension` 3, or 4 with a leading axis of size 1 (one component per
/// voxel); every common spelling of the sample types in sample_type.h; `sizes`; `spacings` or axis-aligned
/// `space directions` (the length of each direction is the spacing; a negative direction is taken by its
/// length, i.e. axis flips are not applied); `space origin` (world position of the first sample); `endian`;
/// `encoding` raw, gzip or ascii (numbers separated by blanks or commas); `data file` (relative to the
/// header's directory) or data attached after the header's blank line; `byte skip` (-1 = data at the end of
/// the file, raw only; for gzip it counts inflated bytes; ascii: 0 only) and `line skip`. Not supported, with
/// a clear error: other encodings (hex, bzip2), multi-file data, rotated or sheared space directions, more
/// than one component per voxel, 64-bit integer and block types.
#pragma once
#include <cstdint>
#include <string>
#include <string_view>

#include "cip/volume/dense_grid.h"
#include "cip/volume/sample_type.h"

namespace cip {

enum class NrrdEncoding : std::uint8_t { Raw, Gzip, Ascii };

/// What a NRRD header says about its volume (only the fields cip uses).
struct NrrdHeader {
  int version = 0;  ///< the digit of NRRD000x
  SampleType type = SampleType::UInt8;
  std::array<std::int64_t, 3> dims{0, 0,
                                   0};  ///< spatial axes (a leading size-1 axis of a 4-D header dropped)
  Vec3 spacing = Vec3::Ones();          ///< world units per axis
  Vec3 origin = Vec3::Zero();           ///< `space origin`, world position of the first sample
  Endian endian = Endian::Little;
  NrrdEncoding encoding = NrrdEncoding::Raw;
  std::string dataFile;       ///< as written in the header; empty = data attached
  std::int64_t byteSkip = 0;  ///< -1 = data is at the end of the file
  std::int64_t lineSkip = 0;
  std::size_t headerBytes = 0;  ///< bytes of the header including its ending blank line
  bool attached = false;        ///< the header ends with a blank line and has no `data file`
};

/// Longest header accepted, and longest header line.
constexpr std::size_t kNrrdMaxHeaderBytes = std::size_t(1) << 20;
constexpr std::size_t kNrrdMaxLineBytes = std::size_t(64) << 10;

/// Parses a NRRD header from the beginning of `text` (a whole header, or the first bytes of a file: parsing
/// stops at the first blank line). Pure function, no I/O. Throws cip::Error "line N: ..." (or a whole-header
/// message) for a bad magic, malformed or duplicate fields, missing required fields, unsupported values, or a
/// header over the caps.
NrrdHeader parseNrrdHeader(std::string_view text);

/// Reads and parses the header of the NRRD file `path`; errors are prefixed with the path.
NrrdHeader readNrrdHeader(const std::string& path);

/// Where the samples of the NRRD file `path` with header `h` are: `path` itself when attached, else the data
/// file, relative to the header's folder unless absolute.
std::string nrrdDataPath(const std::string& path, const NrrdHeader& h);

/// Reads a NRRD volume. Throws cip::Error (message starting with the path) for any header problem, a missing
/// data file, data of the wrong size (raw) or that inflates to a size other than declared (gzip; stopped as
/// soon as it goes past), corrupt compressed data, or dims over `maxBytes` of doubles (checked before
/// allocating).
DenseGrid readNrrd(const std::string& path, std::size_t maxBytes = DenseGrid::defaultMaxBytes());

}  // namespace cip
