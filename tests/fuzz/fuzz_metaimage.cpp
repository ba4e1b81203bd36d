// libFuzzer target: MetaImage header parser and reader (.mha with the data inline; a header naming other data
// files reads them relative to the input's folder).
#include "cip/core/error.h"
#include "cip/readers/metaimage_reader.h"
#include "fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  try {
    cip::parseMetaImageHeader(text, "fuzz.mha");
  } catch (const cip::Error&) {
  }
  std::string path = cip::fuzz::writeInput(data, size, ".mha");
  for (int frame : {-1, 1}) {
    try {
      cip::readMetaImage(path, cip::fuzz::kMaxFuzzBytes, frame);
    } catch (const cip::Error&) {
    }
  }
  unlink(path.c_str());
  return 0;
}
