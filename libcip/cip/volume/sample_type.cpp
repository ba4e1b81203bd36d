#include "cip/volume/sample_type.h"

#include <algorithm>
#include <cctype>
#include <cstring>

#include "cip/core/error.h"

namespace cip {

std::size_t sampleSize(SampleType type) {
  switch (type) {
    case SampleType::UInt8:
    case SampleType::Int8:
      return 1;
    case SampleType::UInt16:
    case SampleType::Int16:
      return 2;
    case SampleType::UInt32:
    case SampleType::Int32:
    case SampleType::Float32:
      return 4;
    case SampleType::Float64:
      return 8;
  }
  return 1;
}

const char* toString(SampleType type) {
  switch (type) {
    case SampleType::UInt8:
      return "uint8";
    case SampleType::Int8:
      return "int8";
    case SampleType::UInt16:
      return "uint16";
    case SampleType::Int16:
      return "int16";
    case SampleType::UInt32:
      return "uint32";
    case SampleType::Int32:
      return "int32";
    case SampleType::Float32:
      return "float32";
    case SampleType::Float64:
      return "float64";
  }
  return "unknown";
}

const char* toString(Endian endian) {
  return endian == Endian::Little ? "little" : "big";
}

namespace {

std::string normalized(const std::string& text) {
  // Lower case, surrounding blanks removed, inner runs of blanks collapsed to one space.
  std::string out;
  bool space = false;
  for (char c : text) {
    if (std::isspace(static_cast<unsigned char>(c))) {
      space = !out.empty();
      continue;
    }
    if (space) out += ' ';
    space = false;
    out += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  }
  return out;
}

struct TypeName {
  const char* name;
  SampleType type;
};

const TypeName kTypeNames[] = {
    {"uint8", SampleType::UInt8},
    {"uchar", SampleType::UInt8},
    {"unsigned char", SampleType::UInt8},
    {"uint8_t", SampleType::UInt8},
    {"u8", SampleType::UInt8},
    {"int8", SampleType::Int8},
    {"signed char", SampleType::Int8},
    {"int8_t", SampleType::Int8},
    {"i8", SampleType::Int8},
    {"uint16", SampleType::UInt16},
    {"ushort", SampleType::UInt16},
    {"unsigned short", SampleType::UInt16},
    {"unsigned short int", SampleType::UInt16},
    {"uint16_t", SampleType::UInt16},
    {"u16", SampleType::UInt16},
    {"int16", SampleType::Int16},
    {"short", SampleType::Int16},
    {"short int", SampleType::Int16},
    {"signed short", SampleType::Int16},
    {"signed short int", SampleType::Int16},
    {"int16_t", SampleType::Int16},
    {"i16", SampleType::Int16},
    {"uint32", SampleType::UInt32},
    {"uint", SampleType::UInt32},
    {"unsigned int", SampleType::UInt32},
    {"uint32_t", SampleType::UInt32},
    {"u32", SampleType::UInt32},
    {"int32", SampleType::Int32},
    {"int", SampleType::Int32},
    {"signed int", SampleType::Int32},
    {"int32_t", SampleType::Int32},
    {"i32", SampleType::Int32},
    {"float32", SampleType::Float32},
    {"float", SampleType::Float32},
    {"f32", SampleType::Float32},
    {"float64", SampleType::Float64},
    {"double", SampleType::Float64},
    {"f64", SampleType::Float64},
};

template <typename T>
void decodeAs(const unsigned char* bytes, std::size_t count, bool swap, double* out) {
  constexpr std::size_t n = sizeof(T);
  unsigned char tmp[n];
  for (std::size_t s = 0; s < count; ++s) {
    const unsigned char* p = bytes + s * n;
    if (swap) {
      for (std::size_t b = 0; b < n; ++b) tmp[b] = p[n - 1 - b];
    } else {
      std::memcpy(tmp, p, n);
    }
    T v;
    std::memcpy(&v, tmp, n);
    out[s] = static_cast<double>(v);
  }
}

}  // namespace

SampleType parseSampleType(const std::string& text) {
  std::string key = normalized(text);
  for (const auto& t : kTypeNames) {
    if (key == t.name) return t.type;
  }
  throw Error("unknown sample type '" + text +
              "' (expected uint8, int8, uint16, int16, uint32, int32, float32 or float64)");
}

Endian parseEndian(const std::string& text) {
  std::string key = normalized(text);
  if (key == "little") return Endian::Little;
  if (key == "big") return Endian::Big;
  throw Error("unknown byte order '" + text + "' (expected little or big)");
}

Endian hostEndian() {
  const std::uint16_t probe = 1;
  unsigned char first;
  std::memcpy(&first, &probe, 1);
  return first == 1 ? Endian::Little : Endian::Big;
}

void decodeSamples(const unsigned char* bytes, std::size_t count, SampleType type, Endian endian,
                   double* out) {
  const bool swap = endian != hostEndian();
  switch (type) {
    case SampleType::UInt8:
      for (std::size_t s = 0; s < count; ++s) out[s] = bytes[s];
      return;
    case SampleType::Int8:
      for (std::size_t s = 0; s < count; ++s) out[s] = static_cast<signed char>(bytes[s]);
      return;
    case SampleType::UInt16:
      return decodeAs<std::uint16_t>(bytes, count, swap, out);
    case SampleType::Int16:
      return decodeAs<std::int16_t>(bytes, count, swap, out);
    case SampleType::UInt32:
      return decodeAs<std::uint32_t>(bytes, count, swap, out);
    case SampleType::Int32:
      return decodeAs<std::int32_t>(bytes, count, swap, out);
    case SampleType::Float32:
      return decodeAs<float>(bytes, count, swap, out);
    case SampleType::Float64:
      return decodeAs<double>(bytes, count, swap, out);
  }
}

}  // namespace cip
