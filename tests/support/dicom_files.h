// A minimal DICOM slice writer for the reader tests, written from the standard (PS3.5/PS3.10) and independent
// of GDCM: preamble, "DICM", file meta information, then an explicit VR little endian data set of one CT
// image with 16-bit signed pixels. Decimal strings are written with at most 16 characters, and the numbers
// the test uses as truth are the ones read back from those strings (dicomNumber).
#pragma once
#include <array>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "volume_files.h"

namespace cip::test {

/// `v` as a DICOM decimal string (at most 16 characters).
inline std::string dicomDecimal(double v) {
  char text[32];
  for (int digits = 10; digits > 1; --digits) {
    std::snprintf(text, sizeof(text), "%.*g", digits, v);
    if (std::string(text).size() <= 16) break;
  }
  return text;
}

/// The value a reader gets back from dicomDecimal(v).
inline double dicomNumber(double v) {
  return std::strtod(dicomDecimal(v).c_str(), nullptr);
}

/// One slice to write.
struct DicomSlice {
  std::string series = "1.2.826.0.1.3680043.2.1125.1";
  std::array<double, 3> position{0, 0, 0};
  std::array<double, 6> orientation{1, 0, 0, 0, 1, 0};  ///< row cosine, column cosine
  std::array<double, 2> pixelSpacing{1, 1};             ///< between rows, between columns
  int rows = 4, columns = 5;
  double slope = 1, intercept = 0;
  std::vector<std::int16_t> pixels;  ///< rows*columns, row by row
  int instance = 1;
};

class DicomWriter {
 public:
  /// The bytes of a DICOM file holding `s`.
  static std::string file(const DicomSlice& s) {
    const std::string sopClass = "1.2.840.10008.5.1.4.1.1.2";  // CT Image Storage
    const std::string sopInstance = s.series + "." + std::to_string(s.instance);
    std::string meta;
    element(meta, 0x0002, 0x0001, "OB", std::string("\0\1", 2));
    element(meta, 0x0002, 0x0002, "UI", sopClass);
    element(meta, 0x0002, 0x0003, "UI", sopInstance);
    element(meta, 0x0002, 0x0010, "UI", "1.2.840.10008.1.2.1");  // explicit VR little endian
    std::string out(128, '\0');
    out += "DICM";
    element(out, 0x0002, 0x0000, "UL", le32(static_cast<std::uint32_t>(meta.size())));
    out += meta;
    element(out, 0x0008, 0x0016, "UI", sopClass);
    element(out, 0x0008, 0x0018, "UI", sopInstance);
    element(out, 0x0008, 0x0060, "CS", "CT");
    element(out, 0x0010, 0x0010, "PN", "Test^Phantom");
    element(out, 0x0020, 0x000d, "UI", "1.2.826.0.1.3680043.2.1125.9");
    element(out, 0x0020, 0x000e, "UI", s.series);
    element(out, 0x0020, 0x0013, "IS", std::to_string(s.instance));
    element(out, 0x0020, 0x0032, "DS", decimals(s.position.data(), 3));
    element(out, 0x0020, 0x0037, "DS", decimals(s.orientation.data(), 6));
    element(out, 0x0028, 0x0002, "US", le16(1));
    element(out, 0x0028, 0x0004, "CS", "MONOCHROME2");
    element(out, 0x0028, 0x0010, "US", le16(static_cast<std::uint16_t>(s.rows)));
    element(out, 0x0028, 0x0011, "US", le16(static_cast<std::uint16_t>(s.columns)));
    element(out, 0x0028, 0x0030, "DS", decimals(s.pixelSpacing.data(), 2));
    element(out, 0x0028, 0x0100, "US", le16(16));
    element(out, 0x0028, 0x0101, "US", le16(16));
    element(out, 0x0028, 0x0102, "US", le16(15));
    element(out, 0x0028, 0x0103, "US", le16(1));  // signed
    element(out, 0x0028, 0x1052, "DS", dicomDecimal(s.intercept));
    element(out, 0x0028, 0x1053, "DS", dicomDecimal(s.slope));
    std::string pixels;
    for (std::int16_t v : s.pixels) pixels += le16(static_cast<std::uint16_t>(v));
    element(out, 0x7fe0, 0x0010, "OW", pixels);
    return out;
  }
  static void write(const std::string& path, const DicomSlice& s) { writeAll(path, file(s)); }

 private:
  static std::string le16(std::uint16_t v) {
    return {static_cast<char>(v & 0xff), static_cast<char>(v >> 8)};
  }
  static std::string le32(std::uint32_t v) {
    return le16(static_cast<std::uint16_t>(v & 0xffff)) + le16(static_cast<std::uint16_t>(v >> 16));
  }
  static std::string decimals(const double* v, int n) {
    std::string s;
    for (int i = 0; i < n; ++i) s += (i ? "\\" : "") + dicomDecimal(v[i]);
    return s;
  }
  /// Appends one explicit VR little endian element; values are padded to an even length.
  static void element(std::string& out, std::uint16_t group, std::uint16_t elem, const char* vr,
                      std::string value) {
    const std::string v(vr);
    if (value.size() % 2) value += (v == "UI" || v == "OB" || v == "OW") ? '\0' : ' ';
    out += le16(group) + le16(elem) + v;
    if (v == "OB" || v == "OW") {
      out += std::string(2, '\0') + le32(static_cast<std::uint32_t>(value.size()));
    } else {
      out += le16(static_cast<std::uint16_t>(value.size()));
    }
    out += value;
  }
};

}  // namespace cip::test
