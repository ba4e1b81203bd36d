#include "cip/readers/dicom_reader.h"

#include "cip/core/module_loader.h"

namespace cip {

DenseGrid readDicom(const std::string& path, std::size_t maxBytes) {
  // GDCM is loaded with the module, only when a DICOM series is read.
  return moduleTable<DicomReaderModule>("cip_dicom", "cip_dicom_reader_module",
                                        path + ": reading DICOM series")
      .read(path, maxBytes);
}

}  // namespace cip
