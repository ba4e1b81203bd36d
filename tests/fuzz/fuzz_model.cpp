// libFuzzer target: the .cip model loader. Anything it accepts must also evaluate without faults.
#include "cip/core/error.h"
#include "cip/model/model_file.h"
#include "fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  try {
    cip::Model m = cip::parseModel(data, size, "fuzz.cip");
    for (std::size_t c = 0; c < m.cells.size() && c < 64; ++c)
      m.patch(c).derivatives(cip::Vec3(0.3, 0.5, 0.7));
  } catch (const cip::Error&) {
  }
  return 0;
}
