// libFuzzer target: the raw volume reader and the parsers of its command-line description. The input's first
// line describes the layout as extract's options do, "DIMS TYPE ENDIAN [OFFSET [SX,SY,SZ [OX,OY,OZ]]]" (e.g.
// "4x3x2 uint16 big 0 1,1,2.5"); the rest of the input is the file. Dims, sample type and byte order go
// through parseDims, parseSampleType and parseEndian; the reader must turn any size that does not match, any
// dims whose product overflows or exceeds the memory cap, and any non-positive or non-finite spacing into
// cip::Error.
#include <cstdlib>
#include <sstream>
#include <string>

#include "cip/core/error.h"
#include "cip/readers/volume_reader.h"
#include "fuzz_input.h"

namespace {

/// Three comma-separated numbers (any double strtod reads, NaN and infinities included), or false.
bool parseVec3(const std::string& text, cip::Vec3& out) {
  const char* p = text.c_str();
  for (int a = 0; a < 3; ++a) {
    char* end = nullptr;
    out[a] = std::strtod(p, &end);
    if (end == p || *end != (a < 2 ? ',' : '\0')) return false;
    p = end + (a < 2 ? 1 : 0);
  }
  return true;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string input(reinterpret_cast<const char*>(data), size);
  const std::size_t eol = input.find('\n');
  if (eol == std::string::npos || eol > 256) return 0;
  std::istringstream line(input.substr(0, eol));
  std::string dims, type, endian, offset, spacing, origin;
  line >> dims >> type >> endian >> offset >> spacing >> origin;
  cip::VolumeReadOptions options;
  options.maxBytes = cip::fuzz::kMaxFuzzBytes;
  try {
    cip::RawFormat f;
    f.dims = cip::parseDims(dims);
    f.type = cip::parseSampleType(type);
    f.endian = cip::parseEndian(endian);
    if (!offset.empty()) {
      char* end = nullptr;
      f.offset = std::strtoull(offset.c_str(), &end, 10);
      if (*end != '\0') return 0;
    }
    if (!spacing.empty() && !parseVec3(spacing, f.spacing)) return 0;
    if (!origin.empty() && !parseVec3(origin, f.origin)) return 0;
    options.raw = f;
  } catch (const cip::Error&) {
    return 0;
  }
  const std::string path = cip::fuzz::writeInput(data + eol + 1, size - eol - 1, ".raw");
  try {
    cip::readVolume(path, options);
  } catch (const cip::Error&) {
  }
  unlink(path.c_str());
  return 0;
}
