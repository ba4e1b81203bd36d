// The bytes by which tests compare two models: the model's file. Under the sanitizers version 1 (every number
// in full precision, so equal bytes still mean equal models) rather than version 2, whose writer searches
// every model for cells that amplify rounding and took most of these comparisons' time there
// (model_file_v2_test.cpp covers that writer, on dense and sparse models).
#pragma once

#include <cstdint>
#include <vector>

#include "cip/model/model_file.h"
#include "sanitized_build.h"

namespace cip::test {

inline std::vector<std::uint8_t> modelBytes(const Model& m) {
  ModelFileOptions o;
  if (kSanitizedBuild) o.version = 1;
  return serializeModel(m, o);
}

}  // namespace cip::test
