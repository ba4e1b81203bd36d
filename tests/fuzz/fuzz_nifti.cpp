// libFuzzer target: NIfTI-1 and NIfTI-2 header parser and reader, plain (.nii) and gzip (.nii.gz) files, the
// whole file and frame 1 of a 4-D series.
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
  for (int frame : {-1, 1}) {
    try {
      cip::readNifti(path, cip::fuzz::kMaxFuzzBytes, frame);
    } catch (const cip::Error&) {
    }
  }
  unlink(path.c_str());
  return 0;
}
