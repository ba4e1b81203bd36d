#include "cip/core/checksum.h"

#include <zlib.h>

#include <algorithm>

namespace cip {

std::uint32_t crc32Of(const std::uint8_t* data, std::size_t size) {
  uLong c = crc32(0L, Z_NULL, 0);
  while (size > 0) {
    const auto chunk = static_cast<uInt>(std::min<std::size_t>(size, 1u << 30));
    c = crc32(c, data, chunk);
    data += chunk;
    size -= chunk;
  }
  return static_cast<std::uint32_t>(c);
}

}  // namespace cip
