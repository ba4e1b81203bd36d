// libFuzzer target: the PLY reader used by `raycast --mesh`.
#include "cip/core/error.h"
#include "cip/mesh/ply.h"
#include "fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  try {
    cip::parsePly(data, size, "fuzz.ply");
  } catch (const cip::Error&) {
  }
  return 0;
}
