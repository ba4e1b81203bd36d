#include "cip/readers/volume_reader.h"

#include <cmath>
#include <filesystem>
#include <sstream>
#include <vector>

#include "cip/core/error.h"
#include "cip/readers/dicom_reader.h"
#include "cip/readers/metaimage_reader.h"
#include "cip/readers/nifti_reader.h"
#include "cip/readers/nrrd_reader.h"
#include "cip/readers/vdb_reader.h"
#include "cip/readers/volume_input.h"

namespace cip {

const char* toString(VolumeFormat format) {
  switch (format) {
    case VolumeFormat::Raw:
      return "raw";
    case VolumeFormat::Nrrd:
      return "NRRD";
    case VolumeFormat::Nifti:
      return "NIfTI";
    case VolumeFormat::Vdb:
      return "VDB";
    case VolumeFormat::MetaImage:
      return "MetaImage";
    case VolumeFormat::Dicom:
      return "DICOM";
  }
  return "unknown";
}

VolumeFormat volumeFormatOf(const std::string& path) {
  if (endsWithNoCase(path, ".nrrd") || endsWithNoCase(path, ".nhdr")) return VolumeFormat::Nrrd;
  for (const char* suffix : {".nii", ".nii.gz", ".hdr", ".hdr.gz", ".img", ".img.gz"})
    if (endsWithNoCase(path, suffix)) return VolumeFormat::Nifti;
  if (endsWithNoCase(path, ".mha") || endsWithNoCase(path, ".mhd")) return VolumeFormat::MetaImage;
  if (endsWithNoCase(path, ".vdb")) return VolumeFormat::Vdb;
  std::error_code ec;
  if (endsWithNoCase(path, ".dcm") || std::filesystem::is_directory(path, ec)) return VolumeFormat::Dicom;
  return VolumeFormat::Raw;
}

std::uint64_t volumeFileBytes(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    std::uint64_t bytes = 0;
    for (const auto& entry : std::filesystem::directory_iterator(path, ec)) {
      if (entry.is_regular_file(ec)) bytes += entry.file_size(ec);
    }
    return bytes;
  }
  std::uint64_t bytes = std::filesystem::file_size(path, ec);
  if (ec) return 0;
  std::vector<std::string> dataFiles;
  try {
    switch (volumeFormatOf(path)) {
      case VolumeFormat::Nrrd:
        if (const NrrdHeader h = readNrrdHeader(path); !h.attached) dataFiles = nrrdDataPaths(path, h);
        break;
      case VolumeFormat::Nifti: {
        const std::string header = niftiHeaderPath(path);
        const std::string data = niftiDataPath(header, readNiftiHeader(header));
        for (const std::string& file : {header, data})
          if (file != path) dataFiles.push_back(file);
        break;
      }
      case VolumeFormat::MetaImage:
        if (const MetaImageHeader h = readMetaImageHeader(path); !h.local) dataFiles = h.dataFiles;
        break;
      default:
        break;
    }
  } catch (const Error&) {
  }
  for (const std::string& file : dataFiles) {
    const std::uint64_t data = std::filesystem::file_size(file, ec);
    if (!ec) bytes += data;
  }
  return bytes;
}

namespace {

/// A .img (or .img.gz) file without the .hdr of a NIfTI pair beside it: raw data when a RawFormat is given.
bool isLoneImg(const std::string& path) {
  if (!endsWithNoCase(path, ".img") && !endsWithNoCase(path, ".img.gz")) return false;
  std::error_code ec;
  return !std::filesystem::exists(niftiHeaderPath(path), ec);
}

}  // namespace

SparseVolume readVolume(const std::string& path, const VolumeReadOptions& options) {
  switch (volumeFormatOf(path)) {
    case VolumeFormat::Nrrd:
      return fromDense(readNrrd(path, {options.maxBytes, options.frame}));
    case VolumeFormat::Nifti:
      if (!(options.raw && isLoneImg(path)))
        return fromDense(readNifti(path, options.maxBytes, options.frame));
      break;
    case VolumeFormat::MetaImage:
      return fromDense(readMetaImage(path, options.maxBytes, options.frame));
    case VolumeFormat::Vdb: {
      VdbReadOptions vdb;
      vdb.gridName = options.vdbGrid;
      vdb.brickCells = options.brickCells;
      vdb.apron = options.apron;
      vdb.maxBytes = options.maxBytes;
      return readVdb(path, vdb);
    }
    case VolumeFormat::Dicom:
      if (options.frame > 0)
        throw Error(path + ": frame " + std::to_string(options.frame) +
                    " is out of range: a DICOM series holds 1 frame");
      return fromDense(readDicom(path, options.maxBytes));
    case VolumeFormat::Raw:
      break;
  }
  if (!options.raw) {
    throw Error(
        path +
        ": not a .nrrd, .nhdr, .nii, .nii.gz, .hdr, .img, .mha, .mhd, .vdb or .dcm file or a DICOM folder; "
        "reading it as raw "
        "data needs its dims "
        "and sample type");
  }
  return fromDense(readRaw(path, *options.raw, options.maxBytes));
}

namespace {

/// describeVolume's text; `bricks` (the brick count) is given for sparse volumes only.
std::string describeGrid(const GridGeometry& g, const std::string& description, std::size_t bricks,
                         bool sparse) {
  std::ostringstream s;
  s << description;
  if (sparse) s << ", grid " << g.dims[0] << "x" << g.dims[1] << "x" << g.dims[2];
  s << ", spacing " << g.spacing[0] << " " << g.spacing[1] << " " << g.spacing[2];
  if (!g.axisAligned()) {
    s << ", axes";
    for (int a = 0; a < 3; ++a) {
      s << " (";
      for (int r = 0; r < 3; ++r) {
        const double v = std::round(g.direction(r, a) * 1e4) / 1e4;
        s << (r ? " " : "") << (v == 0 ? 0.0 : v);
      }
      s << ")";
    }
  }
  if (g.space != WorldSpace::Unspecified) s << ", " << toString(g.space);
  if (sparse) s << ", " << bricks << (bricks == 1 ? " brick" : " bricks");
  return s.str();
}

}  // namespace

std::string describeVolume(const SparseVolume& volume) {
  return describeGrid(volume.geometry, volume.description, volume.bricks.size(), !volume.dense());
}

std::string describeDenseVolume(const GridGeometry& geometry, const std::string& description) {
  return describeGrid(geometry, description, 1, false);
}

}  // namespace cip
