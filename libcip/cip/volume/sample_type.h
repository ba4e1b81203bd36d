/// @file sample_type.h
/// @brief Voxel sample types and byte orders found in volume files, and their conversion to double.
///
/// The volume readers (raw, NRRD, NIfTI) all store samples as double in a DenseGrid; this file is the one
/// place that knows how many bytes each stored type has and how to decode a run of them in either byte order.
#pragma once
#include <cstddef>
#include <cstdint>
#include <string>

namespace cip {

/// Scalar type of the samples stored in a volume file.
enum class SampleType : std::uint8_t { UInt8, Int8, UInt16, Int16, UInt32, Int32, Float32, Float64 };

/// Byte order of multi-byte samples in a file.
enum class Endian : std::uint8_t { Little, Big };

/// Bytes per sample (1, 2, 4 or 8).
std::size_t sampleSize(SampleType type);
/// Canonical name: "uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64".
const char* toString(SampleType type);
const char* toString(Endian endian);

/// Parses a sample type name: the canonical names above and the usual C / NRRD spellings ("uchar",
/// "unsigned char", "uint8_t", "signed char", "short", "ushort", "unsigned short int", "int", "uint",
/// "float", "double", ...). Case-insensitive. Throws cip::Error naming the text and listing the canonical
/// names otherwise.
SampleType parseSampleType(const std::string& text);
/// Parses "little" or "big" (case-insensitive); throws cip::Error otherwise.
Endian parseEndian(const std::string& text);

/// Byte order of this machine.
Endian hostEndian();

/// Decodes `count` consecutive samples of `type` stored in `endian` byte order at `bytes` (no alignment
/// needed) into `out[0..count)`. Integers convert exactly; float32 widens exactly; NaN and infinities are
/// kept.
void decodeSamples(const unsigned char* bytes, std::size_t count, SampleType type, Endian endian,
                   double* out);

}  // namespace cip
