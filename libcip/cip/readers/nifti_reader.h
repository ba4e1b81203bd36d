/// @file nifti_reader.h
/// @brief NIfTI-1 and NIfTI-2 volumes (.nii, .nii.gz, and .hdr/.img pairs, plain or gzip-compressed): header
/// parser, reader placing the grid where the file's transform puts it, and a small float32 writer.
///
/// Read: the 348-byte NIfTI-1 or 540-byte NIfTI-2 header in either byte order (sizeof_hdr says which),
/// magic "n+1"/"n+2" (data in the same file from vox_offset) or "ni1"/"ni2" (header in .hdr, data in the
/// .img beside it); dim[0] 3 or 4 (trailing extents of 1 beyond dim[4] are allowed, 5-D data are refused);
/// datatypes uint8, int8, int16, uint16, int32, uint32, float32, float64; scl_slope/scl_inter (value = slope
/// * stored + inter, when slope is nonzero and finite). A 4-D file with dim[4] > 1 frames needs the frame to
/// read (`frame`, 0-based).
///
/// Placement, as the NIfTI-1 standard and nibabel (docs/volumes.md): the sform (srow_x/y/z) when sform_code >
/// 0; else the qform when qform_code > 0: rotation from the quaternion (b, c, d) with a = sqrt(1 - b² - c² -
/// d²) (b² + c² + d² may exceed 1 by nibabel's tolerance, 3 float epsilons for NIfTI-1, 3 double epsilons for
/// NIfTI-2, and a is then 0), times diag(pixdim[1], pixdim[2], qfac * pixdim[3]) with qfac = -1 when
/// pixdim[0] is -1 and 1 otherwise, plus (qoffset_x, qoffset_y, qoffset_z); else (both codes 0) spacing
/// |pixdim[1..3]| at the origin, axis-aligned. World coordinates of sform/qform are RAS
/// (WorldSpace::RAS); those of the pixdim-only placement are unspecified. A non-finite or singular transform,
/// an impossible quaternion or a zero pixdim is an error.
#pragma once
#include <cstdint>
#include <string>

#include "cip/readers/volume_input.h"
#include "cip/volume/dense_grid.h"
#include "cip/volume/sample_type.h"

namespace cip {

constexpr std::size_t kNiftiHeaderBytes = 348;   ///< NIfTI-1 header
constexpr std::size_t kNifti2HeaderBytes = 540;  ///< NIfTI-2 header

/// Which of the header's transforms placed the grid.
enum class NiftiPlacement : std::uint8_t { Sform, Qform, Pixdim };
const char* toString(NiftiPlacement placement);  ///< "sform", "qform", "pixdim"

/// What a NIfTI header says about its volume (only the fields cip uses).
struct NiftiHeader {
  int version = 1;                 ///< 1 or 2
  bool pair = false;               ///< magic "ni1"/"ni2": the data are in the .img file beside the .hdr
  Endian endian = Endian::Little;  ///< byte order of the header and data
  SampleType type = SampleType::UInt8;
  std::int64_t frames = 1;  ///< dim[4] of a 4-D file, else 1
  /// dims, origin, spacing, direction and world space as the selected transform says.
  GridGeometry geometry;
  NiftiPlacement placement = NiftiPlacement::Pixdim;
  std::uint64_t dataOffset = 0;  ///< vox_offset: byte of the first sample (in the inflated stream)
  double slope = 0;              ///< scl_slope (scaling applied only when nonzero and finite)
  double inter = 0;              ///< scl_inter
  int qformCode = 0;
  int sformCode = 0;
};

/// Parses the header at the start of a NIfTI-1 or NIfTI-2 file (`size` bytes available, at least the
/// header's). Pure function, no I/O. Throws cip::Error for a bad sizeof_hdr, magic, dims, datatype, spacing,
/// transform or vox_offset.
NiftiHeader parseNiftiHeader(const unsigned char* bytes, std::size_t size);

/// Reads and parses the header of `path` (plain or gzip-compressed; for a .img or .img.gz, the .hdr beside
/// it); errors are prefixed with the path.
NiftiHeader readNiftiHeader(const std::string& path);

/// The file holding the header for `path`: the .hdr (or .hdr.gz) of a .img (or .img.gz), else `path`.
std::string niftiHeaderPath(const std::string& path);
/// The file holding the samples: the .img (or .img.gz) beside the .hdr for a pair, else the header file.
std::string niftiDataPath(const std::string& headerPath, const NiftiHeader& header);

/// Reads a NIfTI volume, scaled by scl_slope/scl_inter and placed as the header says. `frame` selects the
/// frame of a 4-D file (-1: the file must hold a single frame). Throws cip::Error (message starting with the
/// path) for a header problem, a missing or out-of-range frame, data that is short, extends past the
/// declared size, or starts beyond the end of the file, corrupt compressed data, or dims over `maxBytes` of
/// doubles (checked before allocating).
DenseGrid readNifti(const std::string& path, std::size_t maxBytes = DenseGrid::defaultMaxBytes(),
                    int frame = -1);

/// The checks of readNifti (header, frame, dims, the size of plain data) and where the chosen frame's samples
/// lie, with the value scaling, without reading them (slab_reader.h). Errors start with the path.
DenseDataLayout niftiDataLayout(const std::string& path, std::size_t maxBytes = DenseGrid::defaultMaxBytes(),
                                int frame = -1);

struct NiftiWriteOptions {
  /// When nonzero, samples are stored as (value - sclInter) / sclSlope and the header carries
  /// scl_slope/scl_inter.
  double sclSlope = 0;
  double sclInter = 0;
};

/// Writes `grid` as a float32 NIfTI-1 file (vox_offset 352, pixdim = spacing), gzip-compressed when the path
/// ends in ".gz". The placement origin + direction * (spacing * index) is written as the sform (sform_code 1)
/// and, when the direction is a rotation possibly with a flip (no shear), as the qform too (qform_code 1,
/// pixdim[0] = qfac); LPS and LAS grids are turned into NIfTI's RAS. Written atomically; returns the bytes
/// written.
std::size_t writeNifti(const std::string& path, const DenseGrid& grid, const NiftiWriteOptions& options = {});

}  // namespace cip
