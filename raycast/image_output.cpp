#include "image_output.h"

#include <OpenImageIO/imageio.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <functional>
#include <iterator>
#include <vector>

#include "cip/core/error.h"

namespace cip::raycast {

namespace {

namespace fs = std::filesystem;

/// A sibling of `path` with the same extension (image writers choose the format from it).
std::string temporarySibling(const std::string& path) {
  static std::atomic<unsigned> counter{0};
  const fs::path p(path);
  const std::string name = "." + p.stem().string() + ".tmp" + std::to_string(::getpid()) + "-" +
                           std::to_string(counter++) + p.extension().string();
  return (p.parent_path() / name).string();
}

/// Runs `write(tmp)`, then renames tmp over `path`; removes tmp and throws cip::Error on any failure.
void writeAtomically(const std::string& path, const std::function<void(const std::string&)>& write) {
  const std::string tmp = temporarySibling(path);
  try {
    write(tmp);
    std::error_code ec;
    fs::rename(tmp, path, ec);
    if (ec) throw Error(path + ": cannot rename the finished image into place: " + ec.message());
  } catch (...) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    throw;
  }
}

/// Rows of the EXR written per call: a multiple of zip's 16-row blocks, and enough blocks per call for
/// OpenEXR to compress them on several threads, while the interleaved copy stays a few megabytes.
constexpr int kExrRowsPerChunk = 128;

void writeWithOiio(const std::string& tmp, const std::string& path, const OIIO::ImageSpec& spec,
                   const void* data) {
  auto out = OIIO::ImageOutput::create(tmp);
  if (!out) throw Error(path + ": cannot create an image writer: " + OIIO::geterror());
  if (!out->open(tmp, spec)) throw Error(path + ": cannot open for writing: " + out->geterror());
  if (!out->write_image(OIIO::TypeDesc::UNKNOWN, data))
    throw Error(path + ": write failed: " + out->geterror());
  if (!out->close()) throw Error(path + ": write failed: " + out->geterror());
}

float linearToSrgb(float c) {
  c = std::min(1.0f, std::max(0.0f, c));
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
}

}  // namespace

void checkExrCompression(const std::string& compression) {
  const auto colon = compression.find(':');
  const std::string name = compression.substr(0, colon);
  bool ok = name == "none" || name == "rle" || name == "zips" || name == "zip" || name == "piz";
  if (ok && colon != std::string::npos) {
    const std::string level = compression.substr(colon + 1);
    ok = (name == "zips" || name == "zip") && level.size() == 1 && level[0] >= '1' && level[0] <= '9';
  }
  if (!ok)
    throw Error("EXR compression '" + compression +
                "' is not one of none, rle, zips, zip, piz (zips and zip may add a level 1-9, e.g. zips:1)");
}

void writeExr(const RenderImage& img, const std::string& path, const std::string& compression) {
  checkExrCompression(compression);
  constexpr int kFloats = 8, kChannels = 9;
  OIIO::ImageSpec spec(img.width, img.height, kChannels, OIIO::TypeDesc::FLOAT);
  spec.channelnames.assign(std::begin(kExrChannels), std::end(kExrChannels));
  spec.channelformats.assign(kFloats, OIIO::TypeDesc::FLOAT);
  spec.channelformats.push_back(OIIO::TypeDesc::UINT32);
  spec.alpha_channel = 3;
  spec.z_channel = 4;
  spec.attribute("compression", compression);
  spec.attribute("oiio:ColorSpace", "Linear");
  // Native per-channel layout: 8 floats then one uint32 per pixel, interleaved a chunk of rows at a time.
  constexpr std::size_t stride = kFloats * sizeof(float) + sizeof(std::uint32_t);
  const std::size_t width = static_cast<std::size_t>(img.width);
  std::vector<unsigned char> data(std::min(img.height, kExrRowsPerChunk) * width * stride);
  writeAtomically(path, [&](const std::string& tmp) {
    auto out = OIIO::ImageOutput::create(tmp);
    if (!out) throw Error(path + ": cannot create an image writer: " + OIIO::geterror());
    if (!out->open(tmp, spec)) throw Error(path + ": cannot open for writing: " + out->geterror());
    for (int y0 = 0; y0 < img.height; y0 += kExrRowsPerChunk) {
      const int y1 = std::min(img.height, y0 + kExrRowsPerChunk);
      const std::size_t first = static_cast<std::size_t>(y0) * width;
      const std::size_t count = static_cast<std::size_t>(y1 - y0) * width;
      for (std::size_t i = 0; i < count; ++i) {
        const std::size_t p = first + i;
        float f[kFloats] = {img.rgba[4 * p],       img.rgba[4 * p + 1],  img.rgba[4 * p + 2],
                            img.rgba[4 * p + 3],   img.depth[p],         img.normal[3 * p],
                            img.normal[3 * p + 1], img.normal[3 * p + 2]};
        std::memcpy(&data[i * stride], f, sizeof f);
        std::memcpy(&data[i * stride + sizeof f], &img.id[p], sizeof(std::uint32_t));
      }
      if (!out->write_scanlines(y0, y1, 0, OIIO::TypeDesc::UNKNOWN, data.data()))
        throw Error(path + ": write failed: " + out->geterror());
    }
    if (!out->close()) throw Error(path + ": write failed: " + out->geterror());
  });
}

void writePng(const RenderImage& img, const std::string& path) {
  OIIO::ImageSpec spec(img.width, img.height, 3, OIIO::TypeDesc::UINT8);
  spec.attribute("oiio:ColorSpace", "sRGB");
  std::vector<unsigned char> data(img.pixels() * 3);
  const float bg = static_cast<float>(kPreviewBackground);
  for (std::size_t p = 0; p < img.pixels(); ++p) {
    const float a = img.rgba[4 * p + 3];
    for (int c = 0; c < 3; ++c) {
      const float v = linearToSrgb(img.rgba[4 * p + c] + (1.0f - a) * bg);
      data[3 * p + c] = static_cast<unsigned char>(std::lround(255.0f * v));
    }
  }
  writeAtomically(path, [&](const std::string& tmp) { writeWithOiio(tmp, path, spec, data.data()); });
}

}  // namespace cip::raycast
