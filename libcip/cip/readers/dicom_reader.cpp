#include "cip/readers/dicom_reader.h"

#include "cip/core/error.h"
#include "cip/core/module_loader.h"

namespace cip {

DenseGrid readDicom(const std::string& path, std::size_t maxBytes) {
  // GDCM is loaded with the module, only when a DICOM series is read.
  const DicomReaderModule* gdcm = nullptr;
  try {
    gdcm = &moduleTable<DicomReaderModule>("cip_dicom", "cip_dicom_reader_module", "reading DICOM series");
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
  return gdcm->read(path, maxBytes);
}

}  // namespace cip
