#include "volume_array.h"

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include <cstring>
#include <type_traits>

#include "cip/core/error.h"

namespace py = pybind11;

namespace cip::python {

namespace {

/// Copies every sample of type T, tile by tile: tiles of axis 0 (the grid's fastest axis) by the array's
/// fastest axis keep both the reads and the writes within a few cache lines.
template <typename T>
void convert(const char* data, const std::array<std::int64_t, 3>& strides, DenseGrid& grid) {
  const auto& n = grid.geometry.dims;
  const int fastest = std::abs(strides[2]) < std::abs(strides[1]) ? 2 : 1;  // among axes 1 and 2
  const int other = 3 - fastest;
  constexpr std::int64_t kTile = 32;
  tbb::parallel_for(
      tbb::blocked_range<std::int64_t>(0, n[other]), [&](const tbb::blocked_range<std::int64_t>& r) {
        std::array<std::int64_t, 3> p{};
        for (p[other] = r.begin(); p[other] != r.end(); ++p[other])
          for (std::int64_t f0 = 0; f0 < n[fastest]; f0 += kTile)
            for (std::int64_t i0 = 0; i0 < n[0]; i0 += kTile)
              for (p[fastest] = f0; p[fastest] < std::min(n[fastest], f0 + kTile); ++p[fastest]) {
                const char* row = data + p[1] * strides[1] + p[2] * strides[2];
                double* out = &grid.values[static_cast<std::size_t>(grid.index(0, p[1], p[2]))];
                for (std::int64_t i = i0; i < std::min(n[0], i0 + kTile); ++i) {
                  T v;
                  std::memcpy(&v, row + i * strides[0], sizeof v);
                  out[i] = static_cast<double>(v);
                }
              }
      });
}

}  // namespace

VolumeArray::VolumeArray(const py::array& array, const Vec3& spacing, const Vec3& origin) : array_(array) {
  if (array.ndim() != 3)
    throw Error("volume must be a 3-D array, got " + std::to_string(array.ndim()) + " dimension(s)");
  for (int a = 0; a < 3; ++a) {
    if (array.shape(a) < 2)
      throw Error("volume must have at least 2 samples along each axis, got shape (" +
                  std::to_string(array.shape(0)) + ", " + std::to_string(array.shape(1)) + ", " +
                  std::to_string(array.shape(2)) + ")");
    geometry_.dims[a] = array.shape(a);
    strides_[a] = array.strides(a);
  }
  for (int a = 0; a < 3; ++a)
    if (!(spacing[a] > 0) || !std::isfinite(spacing[a]) || !std::isfinite(origin[a]))
      throw Error("spacing must be three positive numbers and origin three finite numbers");
  geometry_.spacing = spacing;
  geometry_.origin = origin;
  const py::dtype dtype = array.dtype();
  kind_ = dtype.kind();
  itemSize_ = static_cast<std::size_t>(dtype.itemsize());
  const bool native = dtype.byteorder() != '>' && dtype.byteorder() != '<';  // '=' or '|'
  const bool supported = (kind_ == 'b' && itemSize_ == 1) ||
                         ((kind_ == 'i' || kind_ == 'u') &&
                          (itemSize_ == 1 || itemSize_ == 2 || itemSize_ == 4 || itemSize_ == 8)) ||
                         (kind_ == 'f' && (itemSize_ == 4 || itemSize_ == 8));
  if (!supported || !native)
    throw Error(
        "volume dtype " + dtype.attr("name").cast<std::string>() +
        " is not supported (bool, int8-int64, uint8-uint64, float32 or float64 in native byte order)");
  data_ = static_cast<const char*>(array.data());
}

DenseGrid VolumeArray::toGrid(const std::string& description) const {
  DenseGrid grid;
  grid.geometry = geometry_;
  grid.description = description;
  grid.allocate(geometry_.dims);
  visitElementType(samples().type, [&](auto sample) {
    using T = decltype(sample);
    // A bool sample is its byte, as numpy stores it.
    convert<std::conditional_t<std::is_same_v<T, bool>, std::uint8_t, T>>(data_, strides_, grid);
  });
  return grid;
}

StridedSamples VolumeArray::samples() const {
  StridedSamples s;
  s.data = data_;
  for (int a = 0; a < 3; ++a) s.shape[a] = geometry_.dims[a];
  s.strides = strides_;
  const bool isSigned = kind_ == 'i';
  switch (kind_ == 'f' ? itemSize_ + 100 : itemSize_) {
    case 1:
      s.type = kind_ == 'b' ? ElementType::Bool : isSigned ? ElementType::Int8 : ElementType::UInt8;
      break;
    case 2:
      s.type = isSigned ? ElementType::Int16 : ElementType::UInt16;
      break;
    case 4:
      s.type = isSigned ? ElementType::Int32 : ElementType::UInt32;
      break;
    case 8:
      s.type = isSigned ? ElementType::Int64 : ElementType::UInt64;
      break;
    case 104:
      s.type = ElementType::Float32;
      break;
    default:
      s.type = ElementType::Float64;
  }
  return s;
}

}  // namespace cip::python
