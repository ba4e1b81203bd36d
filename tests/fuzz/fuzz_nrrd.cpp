// libFuzzer target: NRRD header parser and the whole NRRD reader (attached raw and gzip payloads).
#include <string_view>

#include "cip/core/error.h"
#include "cip/readers/nrrd_reader.h"
#include "fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  try {
    cip::parseNrrdHeader(std::string_view(reinterpret_cast<const char*>(data), size));
  } catch (const cip::Error&) {
  }
  std::string path = cip::fuzz::writeInput(data, size, ".nrrd");
  try {
    cip::readNrrd(path, {cip::fuzz::kMaxFuzzBytes});
  } catch (const cip::Error&) {
  }
  unlink(path.c_str());
  return 0;
}
