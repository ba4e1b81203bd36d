/// @file nifti_reader.h
/// @brief NIfTI-1 single-file volumes (.nii, and .nii.gz detected from the gzip signature): header parser,
/// reader, and a small float32 writer.
///
/// Read: the 348-byte header in either byte order (sizeof_hdr 348, byte-swapped when the file is big endian),
/// magic "n+1", dim[0] 3 (or 4 with dim[4] == 1), datatypes uint8, int8, int16, uint16, int32, uint32,
/// float32, float64, vox_offset, pixdim[1..3] as spacing (absolute values, in the file's spatial units,
/// usually mm), scl_slope and scl_inter (value = slope * stored + inter, when slope is nonzero and finite).
/// Placement is axis-aligned only: the origin is (qoffset_x, qoffset_y, qoffset_z) when qform_code > 0, else
/// the translation column of the sform rows when sform_code > 0, else 0; rotations and flips in qform/sform
/// are ignored, so a volume stored with a rotated or flipped orientation comes out in its index axes.
#pragma once
#include <cstdint>
#include <string>

#include "cip/volume/dense_grid.h"
#include "cip/volume/sample_type.h"

namespace cip {

constexpr std::size_t kNiftiHeaderBytes = 348;

/// What a NIfTI-1 header says about its volume (only the fields cip uses).
struct NiftiHeader {
  Endian endian = Endian::Little;  ///< byte order of the header and data
  SampleType type = SampleType::UInt8;
  std::array<std::int64_t, 3> dims{0, 0, 0};
  Vec3 spacing = Vec3::Ones();
  Vec3 origin = Vec3::Zero();
  std::uint64_t dataOffset = 0;  ///< vox_offset: byte of the first sample (in the inflated stream)
  double slope = 0;              ///< scl_slope (scaling applied only when nonzero and finite)
  double inter = 0;              ///< scl_inter
  int qformCode = 0;
  int sformCode = 0;
};

/// Parses the first kNiftiHeaderBytes bytes of a NIfTI-1 file. Pure function, no I/O. Throws cip::Error for a
/// bad sizeof_hdr, magic, dims, datatype, spacing or vox_offset.
NiftiHeader parseNiftiHeader(const unsigned char* bytes, std::size_t size);

/// Reads and parses the header of `path` (plain or gzip-compressed); errors are prefixed with the path.
NiftiHeader readNiftiHeader(const std::string& path);

/// Reads a NIfTI-1 volume, scaled by scl_slope/scl_inter. Throws cip::Error (message starting with the path)
/// for a header problem, data that is short, extends past the declared size, or starts beyond the end of the
/// file, corrupt compressed data, or dims over `maxBytes` of doubles (checked before allocating).
DenseGrid readNifti(const std::string& path, std::size_t maxBytes = DenseGrid::defaultMaxBytes());

struct NiftiWriteOptions {
  /// When nonzero, samples are stored as (value - sclInter) / sclSlope and the header carries
  /// scl_slope/scl_inter.
  double sclSlope = 0;
  double sclInter = 0;
};

/// Writes `grid` as a float32 NIfTI-1 file (vox_offset 352, qform_code 1 with identity rotation and the grid
/// origin, pixdim = spacing), gzip-compressed when the path ends in ".gz". Written atomically; returns the
/// bytes written.
std::size_t writeNifti(const std::string& path, const DenseGrid& grid, const NiftiWriteOptions& options = {});

}  // namespace cip
