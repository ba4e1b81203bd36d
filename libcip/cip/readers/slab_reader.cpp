#include "cip/readers/slab_reader.h"

#include <filesystem>
#include <limits>
#include <utility>

#include "cip/core/error.h"
#include "cip/readers/nifti_reader.h"
#include "cip/readers/nrrd_reader.h"
#include "cip/readers/raw_reader.h"

namespace cip {

namespace {

/// No limit on the whole volume's doubles: a slab reader never holds them all.
constexpr std::size_t kNoLimit = std::numeric_limits<std::size_t>::max();

/// A .img (or .img.gz) without the .hdr of a NIfTI pair beside it (read as raw data when a RawFormat is
/// given, as readVolume does).
bool loneImg(const std::string& path) {
  if (!endsWithNoCase(path, ".img") && !endsWithNoCase(path, ".img.gz")) return false;
  std::error_code ec;
  return !std::filesystem::exists(niftiHeaderPath(path), ec);
}

/// Throws, naming the size, when slabs of kProbeSlabSlices slices of `dims` (fewer when the volume has fewer)
/// exceed `maxBytes` as doubles: a volume whose slices alone do not fit cannot be read in slabs either.
void checkSlabsFit(const std::string& path, const std::array<std::int64_t, 3>& dims, std::size_t maxBytes) {
  checkVolumeDims(path, {dims[0], dims[1], std::min<std::int64_t>(dims[2], kProbeSlabSlices)}, 1, maxBytes);
}

}  // namespace

DenseVolumeProbe probeDenseVolume(const std::string& path, const VolumeReadOptions& options) {
  DenseVolumeProbe probe;
  probe.format = volumeFormatOf(path);
  switch (probe.format) {
    case VolumeFormat::Nrrd:
      probe.layout = nrrdDataLayout(path, {kNoLimit, options.frame}, probe.whyNot);
      if (probe.layout) checkSlabsFit(path, probe.layout->geometry.dims, options.maxBytes);
      return probe;
    case VolumeFormat::Nifti:
      if (options.raw && loneImg(path)) break;
      probe.layout = niftiDataLayout(path, kNoLimit, options.frame);
      checkSlabsFit(path, probe.layout->geometry.dims, options.maxBytes);
      return probe;
    case VolumeFormat::Raw:
      break;
    default:
      probe.whyNot = std::string(toString(probe.format)) + " volumes are read whole";
      return probe;
  }
  if (!options.raw) {
    probe.whyNot = "a raw file needs its dims and sample type";
    return probe;
  }
  probe.format = VolumeFormat::Raw;
  checkVolumeDims(path, options.raw->dims, sampleSize(options.raw->type), kNoLimit);  // overflow first
  checkSlabsFit(path, options.raw->dims, options.maxBytes);
  probe.layout = rawDataLayout(path, *options.raw, kNoLimit);
  return probe;
}

SlabReader::SlabReader(DenseDataLayout layout) : layout_(std::move(layout)) {}

SlabReader::~SlabReader() = default;

DenseGrid SlabReader::read(std::int64_t z0, std::int64_t z1) {
  const GridGeometry& g = layout_.geometry;
  if (!(0 <= z0 && z0 < z1 && z1 <= g.dims[2])) {
    throw Error(layout_.path + ": slices [" + std::to_string(z0) + ", " + std::to_string(z1) +
                ") are not within the volume's " + std::to_string(g.dims[2]));
  }
  DenseGrid grid;
  grid.allocate({g.dims[0], g.dims[1], z1 - z0}, kNoLimit);
  readInto(z0, z1, grid.values.data());
  grid.geometry.spacing = g.spacing;
  grid.geometry.direction = g.direction;
  grid.geometry.space = g.space;
  grid.geometry.origin = g.origin + g.direction.col(2) * (g.spacing[2] * static_cast<double>(z0));
  grid.description = layout_.description;
  return grid;
}

void SlabReader::readInto(std::int64_t z0, std::int64_t z1, double* out) {
  const GridGeometry& g = layout_.geometry;
  if (!(0 <= z0 && z0 < z1 && z1 <= g.dims[2])) {
    throw Error(layout_.path + ": slices [" + std::to_string(z0) + ", " + std::to_string(z1) +
                ") are not within the volume's " + std::to_string(g.dims[2]));
  }
  const auto slice = static_cast<std::uint64_t>(sliceSamples());
  const std::uint64_t first = static_cast<std::uint64_t>(z0) * slice;
  const std::uint64_t count = static_cast<std::uint64_t>(z1 - z0) * slice;
  const std::uint64_t size = sampleSize(layout_.type);
  const bool plain = layout_.encoding == DataEncoding::Plain;
  // Compressed data goes forward only: skip to a later slab, start again for an earlier one.
  if (!source_ || first < next_ || (plain && first != next_)) {
    source_ = openSamplesAt(layout_, first);
  } else if (first > next_) {
    const std::uint64_t gap = (first - next_) * size;
    if (source_->skip(gap) != gap) {
      throw Error(layout_.dataPath + ": data ends before byte " + std::to_string(first * size) + " of " +
                  std::to_string(slice * static_cast<std::uint64_t>(g.dims[2]) * size) + " (slice " +
                  std::to_string(z0) + ")");
    }
  }
  next_ = first;
  try {
    readSamplesInto(*source_, layout_.type, layout_.endian, out, static_cast<std::size_t>(count),
                    first * size, slice * static_cast<std::uint64_t>(g.dims[2]) * size);
    next_ = first + count;
    if (layout_.checkEnd && z1 == g.dims[2]) source_->expectEnd("compressed data");
  } catch (...) {
    source_.reset();  // the source stopped somewhere in the slab: the next read starts afresh
    throw;
  }
  if (layout_.slope != 0) {
    const double slope = layout_.slope, inter = layout_.inter;
    for (std::uint64_t n = 0; n < count; ++n) out[n] = slope * out[n] + inter;
  }
}

}  // namespace cip
