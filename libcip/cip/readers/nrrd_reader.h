/// @file nrrd_reader.h
/// @brief NRRD volumes (.nrrd with attached data, .nhdr with detached data files): header parser and reader,
/// placing the volume where the header says (docs/volumes.md, "NRRD").
///
/// Supported: magic NRRD0001..NRRD0005; `dimension` 3, or 4 with one non-spatial axis (first or last: vector
/// components, a time series, ...; told apart by `kinds` or a `none` space direction, or a size-1 first or
/// last axis) of which one frame is read; every common spelling of the sample types in sample_type.h;
/// `sizes`; placement from `space directions` (any rotation, flip or shear: the length of each vector is the
/// spacing, its direction a column of GridGeometry::direction), `space` / `space dimension` (3-D spaces;
/// RAS, LAS and LPS kept as WorldSpace, the others Unspecified), `space origin`; without a space, `spacings`
/// (a negative spacing flips its axis) and origin 0; `endian`; `encoding` raw, gzip, bzip2, ascii or hex;
/// data attached after the header's blank line, or detached: `data file: NAME`, `data file: LIST [subdim]`
/// (the names on the header's remaining lines), or `data file: FORMAT MIN MAX STEP [subdim]` (a printf
/// pattern with one integer conversion), relative to the header's folder; several files are concatenated,
/// each with its own `byte skip` (-1 = data at the end of the file, raw only; compressed: counts
/// decompressed bytes; ascii/hex: 0 only) and `line skip`. Not supported, with a clear error: 4-D spaces
/// (`...-time`), more than one non-spatial axis, 64-bit integer and block types.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "cip/readers/volume_input.h"
#include "cip/volume/dense_grid.h"
#include "cip/volume/sample_type.h"

namespace cip {

enum class NrrdEncoding : std::uint8_t { Raw, Gzip, Bzip2, Ascii, Hex };

/// What a NRRD header says about its volume (only the fields cip uses).
struct NrrdHeader {
  int version = 0;  ///< the digit of NRRD000x
  SampleType type = SampleType::UInt8;
  std::array<std::int64_t, 3> dims{0, 0, 0};  ///< the three spatial axes, fastest first
  /// 4-D: samples along the non-spatial axis (frames), and whether that axis is the first (fastest, samples
  /// of one voxel interleaved) or the last (slowest, one volume after the other). 3-D: 1 frame.
  std::int64_t frames = 1;
  bool framesFirst = false;
  Vec3 spacing = Vec3::Ones();        ///< world length of one index step per spatial axis
  Mat3 direction = Mat3::Identity();  ///< unit world direction of each spatial index axis (columns)
  Vec3 origin = Vec3::Zero();         ///< `space origin`, world position of the first sample
  WorldSpace space = WorldSpace::Unspecified;
  Endian endian = Endian::Little;
  NrrdEncoding encoding = NrrdEncoding::Raw;
  std::vector<std::string> dataFiles;  ///< as written in the header, in data order; empty = data attached
  std::int64_t byteSkip = 0;           ///< per data file; -1 = data is at the end of the file
  std::int64_t lineSkip = 0;           ///< per data file
  std::size_t headerBytes = 0;         ///< bytes of the header including its ending blank line
  bool attached = false;               ///< the header ends with a blank line and has no `data file`
};

/// Longest header accepted, longest header line, and most detached data files.
constexpr std::size_t kNrrdMaxHeaderBytes = std::size_t(1) << 20;
constexpr std::size_t kNrrdMaxLineBytes = std::size_t(64) << 10;
constexpr std::int64_t kNrrdMaxDataFiles = 100000;

/// Parses a NRRD header from the beginning of `text` (a whole header, or the first bytes of a file: parsing
/// stops at the first blank line, or for `data file: LIST` at the end of the text). Pure function, no I/O.
/// Throws cip::Error "line N: ..." (or a whole-header message) for a bad magic, malformed or duplicate
/// fields, missing required fields, unsupported values, singular or non-finite space directions, or a
/// header over the caps.
NrrdHeader parseNrrdHeader(std::string_view text);

/// Reads and parses the header of the NRRD file `path`; errors are prefixed with the path.
NrrdHeader readNrrdHeader(const std::string& path);

/// Where the samples of the NRRD file `path` with header `h` are, in data order: `path` itself when
/// attached, else the data files, relative to the header's folder unless absolute.
std::vector<std::string> nrrdDataPaths(const std::string& path, const NrrdHeader& h);

struct NrrdReadOptions {
  std::size_t maxBytes = DenseGrid::defaultMaxBytes();  ///< limit on the samples held, as doubles
  int frame = -1;  ///< 4-D: the frame (0-based) to read; -1 = the file must hold one frame
};

/// Reads a NRRD volume (one frame of a 4-D one) and places it: geometry origin, spacing, direction and space
/// as the header says. Throws cip::Error (message starting with the path) for any header problem, a frame
/// out of range or not chosen (naming the frame count), a missing data file, data of the wrong size (raw) or
/// that decompresses to a size other than declared (stopped as soon as it goes past), corrupt compressed
/// data, or dims over `maxBytes` of doubles (checked before allocating).
DenseGrid readNrrd(const std::string& path, const NrrdReadOptions& options = {});

/// The checks of readNrrd (header, frame, dims, data file sizes) and where the chosen frame's samples lie,
/// without reading them (slab_reader.h). Data that can only be read whole (ascii or hex encoding, several
/// data files, interleaved frames) gives no layout and `whyNot` says why.
std::optional<DenseDataLayout> nrrdDataLayout(const std::string& path, const NrrdReadOptions& options,
                                              std::string& whyNot);

}  // namespace cip
