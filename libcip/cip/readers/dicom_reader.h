/// @file dicom_reader.h
/// @brief DICOM series (a folder of single-frame slices, or one slice file) read through GDCM into one
/// volume placed in the patient's LPS frame (docs/volumes.md, "DICOM").
///
/// The slices of one series (SeriesInstanceUID; a folder holding several series gives the one with the most
/// slices, and the description names it and how many series there were) are sorted by their
/// ImagePositionPatient projected on the slice normal (row cosine x column cosine of
/// ImageOrientationPatient). Placement: origin = position of the first slice; index axis i (along a row)
/// = row cosine * PixelSpacing[1], axis j = column cosine * PixelSpacing[0], axis k = the step between
/// consecutive slice positions (not necessarily along the normal: gantry tilt is a shear); space LPS.
/// Values = stored value * RescaleSlope + RescaleIntercept, per slice. Pixel data of any sample type GDCM
/// decodes to 8-, 16- or 32-bit integers or floats, compressed or not, one sample per pixel.
///
/// Files of a folder without the DICM marker after the 128-byte preamble and DICOM files without an image
/// (DICOMDIR, reports) are skipped. A file with the marker has its structure checked before GDCM parses it
/// (elements within the file, tags ascending, VRs as in the dictionary; little endian transfer syntaxes
/// only), because GDCM aborts on some malformed files; one that fails, or that GDCM cannot parse, is an
/// error. Other errors, all "<path>: ...": no DICOM image, slices of mixed sizes or orientations, two slices
/// at one position, slice steps that differ by more than 5% of their median (a missing slice), multi-frame
/// files, missing or malformed position/orientation/spacing, colour images, sizes over `maxBytes`.
#pragma once
#include <string>

#include "cip/volume/dense_grid.h"

namespace cip {

/// Reads the DICOM series in the folder `path` (or the single DICOM slice file `path`).
DenseGrid readDicom(const std::string& path, std::size_t maxBytes = DenseGrid::defaultMaxBytes());

/// What the module libcip_dicom.so (modules/dicom_module.cpp, the only code that uses GDCM) gives readDicom,
/// which loads it on first use through its entry point cip_dicom_reader_module (core/module_loader.h).
struct DicomReaderModule {
  DenseGrid (*read)(const std::string& path, std::size_t maxBytes);
};

}  // namespace cip
