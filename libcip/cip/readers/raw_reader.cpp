#include "cip/readers/raw_reader.h"

#include <cmath>
#include <sstream>

#include "cip/core/error.h"
#include "cip/readers/volume_input.h"

namespace cip {

std::array<std::int64_t, 3> parseDims(const std::string& text) {
  std::string s = text;
  for (char& c : s) {
    if (c == 'x' || c == 'X' || c == ',') c = ' ';
  }
  std::istringstream in(s);
  std::array<std::int64_t, 3> dims{};
  for (auto& d : dims) {
    if (!(in >> d) || d < 1) throw Error("invalid dims '" + text + "' (expected e.g. 103x94x161)");
  }
  std::string rest;
  if (in >> rest) throw Error("invalid dims '" + text + "' (expected three extents, e.g. 103x94x161)");
  return dims;
}

DenseDataLayout rawDataLayout(const std::string& path, const RawFormat& format, std::size_t maxBytes) {
  for (int a = 0; a < 3; ++a) {
    if (!(format.spacing[a] > 0) || !std::isfinite(format.spacing[a])) {
      throw Error(path + ": spacing must be positive and finite");
    }
    if (!std::isfinite(format.origin[a])) throw Error(path + ": origin must be finite");
  }
  const std::size_t size = sampleSize(format.type);
  const std::int64_t count = checkVolumeDims(path, format.dims, size, maxBytes);
  const std::uint64_t dataBytes = static_cast<std::uint64_t>(count) * size;
  const std::uint64_t actual = fileSizeOf(path);
  std::uint64_t expected = 0;
  if (__builtin_add_overflow(dataBytes, format.offset, &expected) || actual != expected) {
    std::string dims = std::to_string(format.dims[0]) + "x" + std::to_string(format.dims[1]) + "x" +
                       std::to_string(format.dims[2]);
    throw Error(path + ": file is " + std::to_string(actual) + " bytes, expected " +
                (format.offset ? std::to_string(format.offset) + " + " : std::string()) +
                std::to_string(dataBytes) + " for " + dims + " " + toString(format.type) + " samples (" +
                (actual < expected ? std::to_string(expected - actual) + " bytes short)"
                                   : std::to_string(actual - expected) + " bytes too many)"));
  }
  DenseDataLayout layout;
  layout.path = layout.dataPath = path;
  layout.offset = format.offset;
  layout.type = format.type;
  layout.endian = format.endian;
  layout.geometry.dims = format.dims;
  layout.geometry.spacing = format.spacing;
  layout.geometry.origin = format.origin;
  layout.description = describeDenseFile(path, "raw", format.type, format.dims);
  return layout;
}

DenseGrid readRaw(const std::string& path, const RawFormat& format, std::size_t maxBytes) {
  const DenseDataLayout layout = rawDataLayout(path, format, maxBytes);
  DenseGrid grid;
  grid.allocate(format.dims, maxBytes);
  grid.geometry = layout.geometry;
  FileByteSource source(path, format.offset);
  readSamplesInto(source, format.type, format.endian, grid);
  grid.description = layout.description;
  return grid;
}

}  // namespace cip
