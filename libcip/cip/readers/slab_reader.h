/// @file slab_reader.h
/// @brief Dense volume files (raw, NRRD, NIfTI) read a slab of z-slices at a time: the header is probed
/// without reading samples, then any run of slices [z0, z1) is read into a DenseGrid with the values the
/// whole-volume reader (volume_reader.h) gives there.
///
/// What streamed extraction reads slab by slab (model/streamed_build.h), and what a process building only a
/// z-range of the volume reads (its slices plus the halo its stencils need). Plain data is read by seeking;
/// gzip- or bzip2-compressed data is decompressed forward, so slabs are best read in increasing z: a slab
/// before the last one read starts the decompression again from the beginning of the data.
#pragma once
#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "cip/readers/volume_input.h"
#include "cip/readers/volume_reader.h"

namespace cip {

/// What a volume file's header says about reading it in slabs.
struct DenseVolumeProbe {
  VolumeFormat format = VolumeFormat::Raw;
  /// Set when the file can be read slab by slab: raw files; NRRD with raw, gzip or bzip2 data in one file
  /// (3-D, or one frame of a 4-D series stored frame after frame); NIfTI, plain or gzip-compressed.
  std::optional<DenseDataLayout> layout;
  std::string whyNot;  ///< otherwise: why the file is read whole (format, encoding, ...)
};

/// Slices of a slab that options.maxBytes must hold as doubles for a volume to be read in slabs.
constexpr std::int64_t kProbeSlabSlices = 32;

/// Reads the header of `path` and checks it as readVolume(path, options) would (format by name, frame,
/// dims, the size of plain data), without reading samples; options.maxBytes limits kProbeSlabSlices slices
/// rather than the whole volume (a slab reader holds only its slabs). Throws cip::Error (message starting
/// with the path) for what readVolume would reject, and for slices too large for options.maxBytes.
DenseVolumeProbe probeDenseVolume(const std::string& path, const VolumeReadOptions& options = {});

/// Reads slabs of z-slices of a dense volume file laid out as `layout` says.
class SlabReader {
 public:
  explicit SlabReader(DenseDataLayout layout);
  ~SlabReader();
  SlabReader(const SlabReader&) = delete;
  SlabReader& operator=(const SlabReader&) = delete;

  const DenseDataLayout& layout() const { return layout_; }
  /// Samples per slice (dims[0] * dims[1]).
  std::int64_t sliceSamples() const { return layout_.geometry.dims[0] * layout_.geometry.dims[1]; }

  /// The samples of slices [z0, z1), 0 <= z0 < z1 <= dims[2], scaled as the whole-volume reader scales
  /// them: a grid of dims (dims[0], dims[1], z1 - z0) with the volume's spacing, direction and space, whose
  /// origin is the world position of the volume's point (0, 0, z0). Throws cip::Error for a range out of
  /// bounds, or "<data file>: data ends after X of N bytes (...)" when the data is shorter than its header
  /// says (X: the position in the frame's data where it ends).
  DenseGrid read(std::int64_t z0, std::int64_t z1);
  /// The same values into `out`, which holds sliceSamples() * (z1 - z0) doubles.
  void readInto(std::int64_t z0, std::int64_t z1, double* out);

 private:
  DenseDataLayout layout_;
  std::unique_ptr<ByteSource> source_;
  std::uint64_t next_ = 0;  ///< index in the frame of the sample source_ reads next
};

}  // namespace cip
