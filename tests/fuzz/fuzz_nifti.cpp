// libFuzzer target: NIfTI-1 header parser and reader, plain (.nii) and gzip (.nii.gz) files.
#include "cip/core/error.h"
#include "cip/readers/nifti_reader.h"
#include "fuzz_input.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  try {
    cip::parseNiftiHeader(data, size);
  } catch (const cip::Error&) {
  }
  // gzip data (magic 1f 8b) goes through the .nii.gz path, everything else through .nii.
  bool gz = size >= 2 && data[0] == 0x1f && data[1] == 0x8b;
  std::string path = cip::fuzz::writeInput(data, size, gz ? ".nii.gz" : ".nii");
  try {
    cip::readNifti(path, cip::fuzz::kMaxFuzzBytes);
  } catch (const cip::Error&) {
  }
  unlink(path.c_str());
  return 0;
}
