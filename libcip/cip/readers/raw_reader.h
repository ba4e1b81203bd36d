/// @file raw_reader.h
/// @brief Reads a headerless ("raw") volume file: samples of one type, x fastest, described by a RawFormat.
///
/// The file must hold exactly offset + dims[0]*dims[1]*dims[2]*sampleSize bytes; any other size is an error
/// naming the expected and actual sizes (a wrong size almost always means wrong dims or type). Samples are
/// converted to double in slabs; spacing and origin are world units and are copied into the grid's geometry.
#pragma once
#include <array>
#include <cstdint>
#include <string>

#include "cip/readers/volume_input.h"
#include "cip/volume/dense_grid.h"
#include "cip/volume/sample_type.h"

namespace cip {

/// Layout of a raw volume file.
struct RawFormat {
  std::array<std::int64_t, 3> dims{0, 0, 0};  ///< grid points per axis (x, y, z)
  SampleType type = SampleType::UInt8;
  Endian endian = Endian::Little;
  Vec3 spacing = Vec3::Ones();  ///< world distance between neighbouring points, per axis (> 0)
  Vec3 origin = Vec3::Zero();   ///< world position of the first sample
  std::uint64_t offset = 0;     ///< bytes before the first sample (a header to skip)
};

/// Parses dims written as "103x94x161" (also "103,94,161" or "103 94 161"); throws cip::Error otherwise.
std::array<std::int64_t, 3> parseDims(const std::string& text);

/// The checks of readRaw (spacing, origin, dims, the file's exact size) and where its samples lie, without
/// reading them (slab_reader.h).
DenseDataLayout rawDataLayout(const std::string& path, const RawFormat& format,
                              std::size_t maxBytes = DenseGrid::defaultMaxBytes());

/// Reads `path` as described by `format`. Throws cip::Error (message starting with the path) for a missing
/// file, a size that does not match, bad dims, non-positive spacing, or a volume over `maxBytes` of doubles
/// (before allocating anything). The grid's description is the file name with its type and dims.
DenseGrid readRaw(const std::string& path, const RawFormat& format,
                  std::size_t maxBytes = DenseGrid::defaultMaxBytes());

}  // namespace cip
