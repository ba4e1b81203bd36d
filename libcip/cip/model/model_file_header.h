/// @file model_file_header.h
/// @brief What both versions of the `.cip` file share (docs/model-format.md): the bounds-checked reader of
/// its little-endian fields and the header from the magic to the source description. Internal to model/.
#pragma once
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <type_traits>
#include <vector>

#include "cip/core/error.h"
#include "cip/model/model.h"

namespace cip {

constexpr char kModelMagic[8] = {'C', 'I', 'P', 'M', 'O', 'D', 'E', 'L'};
constexpr std::size_t kMaxModelSourceBytes = 65536;

/// Reads little-endian fields from a file's bytes; every read is checked against the end, and failures throw
/// cip::Error "<name>: damaged model file: <why>".
class ModelFileReader {
 public:
  ModelFileReader(const std::uint8_t* data, std::size_t size, const std::string& name)
      : d_(data), n_(size), name_(name) {}
  template <class T>
  T get(const char* what) {
    static_assert(std::is_trivially_copyable_v<T>);
    need(sizeof(T), what);
    T v;
    std::memcpy(&v, d_ + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  double getFinite(const char* what) {
    const double v = get<double>(what);
    if (!std::isfinite(v)) fail(std::string(what) + " is not a finite number");
    return v;
  }
  void need(std::size_t bytes, const char* what) const {
    if (bytes > n_ - pos_) fail(std::string("truncated (") + what + " runs past the end of the file)");
  }
  std::size_t remaining() const { return n_ - pos_; }
  std::size_t pos() const { return pos_; }
  const std::uint8_t* here() const { return d_ + pos_; }
  void skip(std::size_t bytes) { pos_ += bytes; }
  [[noreturn]] void fail(const std::string& why) const {
    throw Error(name_ + ": damaged model file: " + why);
  }

 private:
  const std::uint8_t* d_;
  std::size_t n_, pos_ = 0;
  const std::string& name_;
};

/// Bit of the version-defined header byte that says an orientation block follows the source description: the
/// grid's direction matrix (9 f64, column-major) and its world space (u8). Written only for grids that are
/// not axis-aligned or name an anatomical frame, so other files are unchanged.
constexpr std::uint8_t kOrientationStored = 0x80;

/// Whether the header of a model on `g` carries the orientation block.
bool hasOrientation(const GridGeometry& g);

/// Reads the fields after the magic and version, up to and including the source description and the
/// orientation block: grid geometry, isovalue, normal mode, patch method, reconstruction, one byte that the
/// version defines (returned without kOrientationStored: version 1's reserved byte, version 2's flags), the
/// source and, when flagged, the orientation. Rejects values out of range.
std::uint8_t readModelHeader(ModelFileReader& r, Model& m);

/// Appends the magic, `version` and the fields readModelHeader reads, with `versionByte` in the byte it
/// returns (the source is cut to kMaxModelSourceBytes).
void appendModelHeader(std::vector<std::uint8_t>& out, const Model& m, std::uint32_t version,
                       std::uint8_t versionByte);

}  // namespace cip
