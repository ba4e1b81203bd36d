// libFuzzer target: the DICOM reader on one slice file (its structure check, then GDCM's parser and
// decoders).
#include "cip/core/error.h"
#include "cip/readers/dicom_reader.h"
#include "fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::string path = cip::fuzz::writeInput(data, size, ".dcm");
  try {
    cip::readDicom(path, cip::fuzz::kMaxFuzzBytes);
  } catch (const cip::Error&) {
  }
  unlink(path.c_str());
  return 0;
}
