// libFuzzer target: the OpenVDB input path as far as cip's wrapper goes (OpenVDB's own errors must come out
// as cip::Error; a crash inside OpenVDB's parser would be OpenVDB's).
#include "cip/error.h"
#include "cip/volume_reader.h"
#include "fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string path = cip::fuzz::writeInput(data, size, ".vdb");
  try {
    cip::VolumeReadOptions o;
    o.maxBytes = cip::fuzz::kMaxFuzzBytes;
    cip::readVolume(path, o);
  } catch (const cip::Error&) {
  }
  unlink(path.c_str());
  return 0;
}
