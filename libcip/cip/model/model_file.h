/// @file model_file.h
/// @brief The `.cip` model file: versioned little-endian binary, specified in docs/model-format.md.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cip/model/model.h"

namespace cip {

constexpr std::uint32_t kModelFileVersion = 1;

/// Serialises a model to bytes (the exact file contents).
std::vector<std::uint8_t> serializeModel(const Model& model);
/// Parses and validates file contents; throws cip::Error naming the first problem ("truncated", "vertex index
/// out of range", "checksum mismatch", ...). Never allocates more than the input can back.
Model parseModel(const std::uint8_t* data, std::size_t size, const std::string& name = "model");

/// Writes atomically (temporary file + rename). Returns the number of bytes written.
std::size_t writeModel(const Model& model, const std::string& path);
/// Reads and validates a model file; throws cip::Error with the path in the message.
Model readModel(const std::string& path);

}  // namespace cip
