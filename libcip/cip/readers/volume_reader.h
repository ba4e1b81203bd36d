/// @file volume_reader.h
/// @brief One entry point for every volume format: picks the reader from the file name and returns a
/// SparseVolume that buildModel takes directly (buildModel(volume.geometry, volume.bricks, options,
/// volume.description)).
///
/// By name (case-insensitive): .nrrd/.nhdr -> NRRD, .nii/.nii.gz/.hdr/.img (and .hdr.gz/.img.gz) -> NIfTI-1
/// or NIfTI-2, .mha/.mhd -> MetaImage, .vdb -> OpenVDB (sparse bricks), a folder or .dcm -> DICOM series
/// (dicom_reader.h), anything else -> raw, which needs a RawFormat (dims, sample type, ...). A known
/// extension always wins over a RawFormat, except for a .img without a .hdr beside it, which a RawFormat
/// reads as raw data. Dense formats come back as one brick owning every cell (fromDense), placed as the file
/// says (origin, spacing, direction, world space: docs/volumes.md).
#pragma once
#include <optional>
#include <string>

#include "cip/readers/raw_reader.h"
#include "cip/volume/sparse_volume.h"

namespace cip {

enum class VolumeFormat : std::uint8_t { Raw, Nrrd, Nifti, Vdb, MetaImage, Dicom };
const char* toString(VolumeFormat format);

/// The format implied by the file name (Raw for unknown extensions; DICOM for an existing folder).
VolumeFormat volumeFormatOf(const std::string& path);

struct VolumeReadOptions {
  std::optional<RawFormat> raw;  ///< layout of a raw file (required when the name has no known extension)
  std::string vdbGrid;           ///< VDB grid name; empty = first float/double grid
  int brickCells = 32;           ///< VDB brick size in cells per side
  int apron = 1;                 ///< VDB points kept around each brick (VdbReadOptions::apron)
  std::size_t maxBytes = DenseGrid::defaultMaxBytes();  ///< limit on the samples held, as doubles
  int frame = -1;  ///< 4-D volumes: the frame (0-based) to read; -1 = the file must hold one frame
};

/// Reads any supported volume. Throws cip::Error (message starting with the path) on any failure; a raw file
/// without options.raw is an error that says which parameters are missing.
SparseVolume readVolume(const std::string& path, const VolumeReadOptions& options = {});

/// Bytes on disk of the volume file `path`: the file, plus for an NRRD header with detached data, a NIfTI
/// .hdr/.img pair or a MetaImage .mhd the data files it names, or for a folder (DICOM series) its files (a
/// header that cannot be read, or a missing data file, counts as nothing more); 0 when `path` is no file.
std::uint64_t volumeFileBytes(const std::string& path);

/// Short description for statistics, e.g. "tooth.nhdr (NRRD uint8 103x94x161), spacing 1 1 1" (followed by
/// the index axes' world directions and the world space when they are not the identity) or, for VDB,
/// "sphere.vdb grid ls_sphere (VDB float level set, ...), grid 127x127x127, spacing 0.05 0.05 0.05, 125
/// bricks".
std::string describeVolume(const SparseVolume& volume);

/// describeVolume of a dense volume given by its geometry and grid description (a volume read in slabs,
/// slab_reader.h, which is never whole in memory).
std::string describeDenseVolume(const GridGeometry& geometry, const std::string& description);

}  // namespace cip
