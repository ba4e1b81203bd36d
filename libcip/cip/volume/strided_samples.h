/// @file strided_samples.h
/// @brief A 3-D array of samples in memory owned by someone else (a numpy buffer): element type, shape and
/// byte strides, read in place as float32, the way scikit-image converts a volume before its marching cubes.
#pragma once
#include <array>
#include <cstdint>
#include <cstring>

namespace cip {

/// Element types of an in-memory array (native byte order).
enum class ElementType : std::uint8_t {
  Bool,
  Int8,
  UInt8,
  Int16,
  UInt16,
  Int32,
  UInt32,
  Int64,
  UInt64,
  Float32,
  Float64
};

/// A view of `shape[0] x shape[1] x shape[2]` samples; sample (i, j, k) is at data + i*strides[0] +
/// j*strides[1] + k*strides[2] bytes (strides may be negative or zero; no alignment needed).
struct StridedSamples {
  const void* data = nullptr;
  std::array<std::int64_t, 3> shape{};
  std::array<std::int64_t, 3> strides{};  ///< bytes
  ElementType type = ElementType::Float32;

  const char* at(std::int64_t i, std::int64_t j, std::int64_t k) const {
    return static_cast<const char*>(data) + i * strides[0] + j * strides[1] + k * strides[2];
  }
};

/// The element at `p` converted to float32 as numpy's astype(float32) does (round to nearest; bool 0 or 1).
template <typename T>
inline float loadFloat32(const char* p) {
  T v;
  std::memcpy(&v, p, sizeof v);
  return static_cast<float>(v);
}
template <>
inline float loadFloat32<bool>(const char* p) {
  return *reinterpret_cast<const unsigned char*>(p) != 0 ? 1.0f : 0.0f;
}

/// Calls `f(T{})` with the C++ type of `type` (bool, std::int8_t, ..., float, double) and returns its result.
template <typename F>
decltype(auto) visitElementType(ElementType type, F&& f) {
  switch (type) {
    case ElementType::Bool:
      return f(bool{});
    case ElementType::Int8:
      return f(std::int8_t{});
    case ElementType::UInt8:
      return f(std::uint8_t{});
    case ElementType::Int16:
      return f(std::int16_t{});
    case ElementType::UInt16:
      return f(std::uint16_t{});
    case ElementType::Int32:
      return f(std::int32_t{});
    case ElementType::UInt32:
      return f(std::uint32_t{});
    case ElementType::Int64:
      return f(std::int64_t{});
    case ElementType::UInt64:
      return f(std::uint64_t{});
    case ElementType::Float32:
      return f(float{});
    default:
      return f(double{});
  }
}

/// Smallest and largest sample as float32, and whether any sample is NaN or infinite.
struct Float32Range {
  float min = 0;
  float max = 0;
  bool nonFinite = false;
};
/// One pass over every sample (any layout); throws cip::Error for an empty view.
Float32Range float32Range(const StridedSamples& samples);

}  // namespace cip
