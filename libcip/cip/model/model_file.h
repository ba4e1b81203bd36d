/// @file model_file.h
/// @brief The `.cip` model file: versioned little-endian binary, specified in docs/model-format.md.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cip/model/model.h"
#include "cip/model/model_file_v2.h"

namespace cip {

/// The version serializeModel writes: 2, compact and lossy within stated bounds (model_file_v2.h). Version 1
/// (every number in full precision) is still read, and written on request.
constexpr std::uint32_t kModelFileVersion = 2;

/// How to write a model file.
struct ModelFileOptions {
  std::uint32_t version = kModelFileVersion;  ///< 1 or 2
  /// Quantisation and chunking of version 2; without, ModelFileV2Options::forMethod(model.method).
  std::optional<ModelFileV2Options> v2;
};

/// Serialises a model to bytes (the exact file contents).
std::vector<std::uint8_t> serializeModel(const Model& model, const ModelFileOptions& options = {});
/// Parses and validates file contents (version 1 or 2); throws cip::Error naming the first problem
/// ("truncated", "vertex index out of range", "chunk 3 (brick 1,0,2 ...): checksum mismatch", ...). Never
/// allocates more than the input can back.
Model parseModel(const std::uint8_t* data, std::size_t size, const std::string& name = "model");
/// The model as a file of these options stores it: parseModel(serializeModel(model, options)). Everything
/// computed after writing a model (meshes, renders, fidelity figures) should use this, not the model as
/// built.
Model storedModel(const Model& model, const ModelFileOptions& options = {});

/// Writes atomically (temporary file + rename). Returns the number of bytes written.
std::size_t writeModel(const Model& model, const std::string& path, const ModelFileOptions& options = {});
/// Writes bytes serializeModel returned, atomically.
std::size_t writeModelBytes(const std::vector<std::uint8_t>& bytes, const std::string& path);
/// The table counts of a model file (version 1 or 2) from its header (and version 2's chunk directory)
/// alone, checked as parseModel checks them; throws cip::Error as parseModel does for a damaged header.
ModelTableCounts modelTableCounts(const std::uint8_t* data, std::size_t size,
                                  const std::string& name = "model");
/// Reads and validates a model file; throws cip::Error with the path in the message. The file is mapped
/// (core/mapped_file.h) and decoded from the mapping, so its bytes are not copied first.
Model readModel(const std::string& path);

}  // namespace cip
