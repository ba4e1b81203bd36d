#include "cip/model/model_file_header.h"

#include <cmath>

namespace cip {

namespace {

template <class T>
void append(std::vector<std::uint8_t>& out, T v) {
  const auto* p = reinterpret_cast<const std::uint8_t*>(&v);
  out.insert(out.end(), p, p + sizeof(T));  // the file is little-endian, like every platform cip supports
}

}  // namespace

std::uint8_t readModelHeader(ModelFileReader& r, Model& m) {
  for (int a = 0; a < 3; ++a) {
    const auto d = r.get<std::int64_t>("dims");
    if (d < 1 || d > (std::int64_t(1) << 31)) r.fail("grid dimension " + std::to_string(d) + " out of range");
    m.geometry.dims[a] = d;
  }
  for (int a = 0; a < 3; ++a) m.geometry.origin[a] = r.getFinite("origin");
  for (int a = 0; a < 3; ++a) {
    m.geometry.spacing[a] = r.getFinite("spacing");
    if (!(m.geometry.spacing[a] > 0)) r.fail("spacing must be positive");
  }
  m.isovalue = r.getFinite("isovalue");
  const auto mode = r.get<std::uint8_t>("normal mode");
  if (mode > 2) r.fail("unknown normal mode " + std::to_string(mode));
  m.normalMode = static_cast<NormalMode>(mode);
  const auto method = r.get<std::uint8_t>("method");
  if (method > static_cast<std::uint8_t>(PatchMethod::Fitted))
    r.fail("unknown patch method " + std::to_string(method));
  m.method = static_cast<PatchMethod>(method);
  const auto reconstruction = r.get<std::uint8_t>("reconstruction");
  if (reconstruction > 1 + static_cast<int>(Reconstruction::Mask) ||
      reconstruction == 1 + static_cast<int>(Reconstruction::Auto))
    r.fail("unknown reconstruction " + std::to_string(reconstruction));
  if (reconstruction > 0) m.reconstruction = static_cast<Reconstruction>(reconstruction - 1);
  const auto versionByte = r.get<std::uint8_t>("flags");
  const auto sourceLen = r.get<std::uint32_t>("source length");
  if (sourceLen > kMaxModelSourceBytes) r.fail("source description longer than 64 KiB");
  r.need(sourceLen, "source description");
  m.source.assign(reinterpret_cast<const char*>(r.here()), sourceLen);
  r.skip(sourceLen);
  if (versionByte & kOrientationStored) {
    Mat3 direction;
    for (int col = 0; col < 3; ++col)
      for (int row = 0; row < 3; ++row) direction(row, col) = r.getFinite("orientation");
    for (int col = 0; col < 3; ++col)
      if (std::abs(direction.col(col).norm() - 1) > 1e-9) r.fail("orientation axes are not unit vectors");
    if (!(std::abs(direction.determinant()) >= 1e-6)) r.fail("orientation is singular");
    const auto space = r.get<std::uint8_t>("world space");
    if (space > static_cast<std::uint8_t>(WorldSpace::LPS))
      r.fail("unknown world space " + std::to_string(space));
    m.geometry.direction = direction;
    m.geometry.space = static_cast<WorldSpace>(space);
  }
  return static_cast<std::uint8_t>(versionByte & ~kOrientationStored);
}

bool hasOrientation(const GridGeometry& g) {
  return !g.axisAligned() || g.space != WorldSpace::Unspecified;
}

void appendModelHeader(std::vector<std::uint8_t>& out, const Model& m, std::uint32_t version,
                       std::uint8_t versionByte) {
  const std::string source = m.source.substr(0, kMaxModelSourceBytes);
  out.insert(out.end(), kModelMagic, kModelMagic + 8);
  append<std::uint32_t>(out, version);
  for (auto d : m.geometry.dims) append<std::int64_t>(out, d);
  for (int a = 0; a < 3; ++a) append<double>(out, m.geometry.origin[a]);
  for (int a = 0; a < 3; ++a) append<double>(out, m.geometry.spacing[a]);
  append<double>(out, m.isovalue);
  out.push_back(static_cast<std::uint8_t>(m.normalMode));
  out.push_back(static_cast<std::uint8_t>(m.method));
  out.push_back(m.reconstruction ? static_cast<std::uint8_t>(1 + static_cast<int>(*m.reconstruction)) : 0);
  const bool oriented = hasOrientation(m.geometry);
  out.push_back(oriented ? static_cast<std::uint8_t>(versionByte | kOrientationStored) : versionByte);
  append<std::uint32_t>(out, static_cast<std::uint32_t>(source.size()));
  out.insert(out.end(), source.begin(), source.end());
  if (oriented) {
    for (int col = 0; col < 3; ++col)
      for (int row = 0; row < 3; ++row) append<double>(out, m.geometry.direction(row, col));
    out.push_back(static_cast<std::uint8_t>(m.geometry.space));
  }
}

}  // namespace cip
