/// @file byte_buffer.h
/// @brief Appending little-endian numbers and raw bytes to a byte vector: what the binary mesh writers (STL,
/// glTF binary) share, so each of them only says which numbers go where.
#pragma once
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace cip {

/// A growing byte buffer whose multi-byte numbers are stored little-endian whatever the host's byte order.
class ByteBuffer {
 public:
  template <typename T>
  void put(T value) {
    std::uint8_t b[sizeof(T)];
    std::memcpy(b, &value, sizeof value);
    if (!hostIsLittleEndian()) std::reverse(b, b + sizeof(T));
    bytes.insert(bytes.end(), b, b + sizeof(T));
  }
  void putBytes(const void* data, std::size_t size) {
    const auto* p = static_cast<const std::uint8_t*>(data);
    bytes.insert(bytes.end(), p, p + size);
  }
  void putText(const std::string& text) { putBytes(text.data(), text.size()); }
  /// Appends `fill` until the size is a multiple of `alignment`.
  void pad(std::size_t alignment, std::uint8_t fill) {
    while (bytes.size() % alignment != 0) bytes.push_back(fill);
  }
  std::size_t size() const { return bytes.size(); }

  std::vector<std::uint8_t> bytes;

 private:
  static bool hostIsLittleEndian() {
    const std::uint16_t one = 1;
    std::uint8_t b;
    std::memcpy(&b, &one, 1);
    return b == 1;
  }
};

}  // namespace cip
