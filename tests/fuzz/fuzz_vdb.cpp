// libFuzzer target: the OpenVDB input path, cip's checks of the file's sizes and tree (vdb_tree_check.h) and
// OpenVDB's parser behind them. OpenVDB's own errors must come out as cip::Error; a crash or a huge
// allocation inside OpenVDB means a size the checks let through.
#include "cip/core/error.h"
#include "cip/readers/volume_reader.h"
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
