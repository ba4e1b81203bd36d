/// @file checksum.h
/// @brief CRC-32 (zlib's, polynomial 0xEDB88320) of a byte range of any length: the model file's checksums.
#pragma once
#include <cstddef>
#include <cstdint>

namespace cip {

/// zlib's crc32 over data[0, size), in pieces small enough for its 32-bit length argument.
std::uint32_t crc32Of(const std::uint8_t* data, std::size_t size);

}  // namespace cip
