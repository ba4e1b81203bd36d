#include "image_output.h"

#include <OpenEXR/ImfChannelList.h>
#include <OpenEXR/ImfFrameBuffer.h>
#include <OpenEXR/ImfHeader.h>
#include <OpenEXR/ImfOutputFile.h>
#include <OpenEXR/ImfThreading.h>
#include <png.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <functional>
#include <memory>
#include <thread>
#include <vector>

#include "cip/core/error.h"

namespace cip::raycast {

namespace {

namespace fs = std::filesystem;

/// A sibling of `path` with the same extension.
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

/// OpenEXR's compression and zlib level for a name accepted by checkExrCompression (level -1: the library's).
std::pair<Imf::Compression, int> exrCompression(const std::string& compression) {
  const auto colon = compression.find(':');
  const std::string name = compression.substr(0, colon);
  const int level = colon == std::string::npos ? -1 : compression[colon + 1] - '0';
  if (name == "none") return {Imf::NO_COMPRESSION, level};
  if (name == "rle") return {Imf::RLE_COMPRESSION, level};
  if (name == "zips") return {Imf::ZIPS_COMPRESSION, level};
  if (name == "zip") return {Imf::ZIP_COMPRESSION, level};
  return {Imf::PIZ_COMPRESSION, level};
}

float linearToSrgb(float c) {
  c = std::min(1.0f, std::max(0.0f, c));
  return c <= 0.0031308f ? 12.92f * c : 1.055f * std::pow(c, 1.0f / 2.4f) - 0.055f;
}

/// libpng reports errors through a callback that must not return: it throws (Debian builds libpng, like all
/// its amd64 code, with unwind tables), and the caller's guard destroys the writer.
[[noreturn]] void pngError(png_structp, png_const_charp message) {
  throw Error(std::string("PNG: ") + message);
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

void writeExr(const RenderImage& img, const std::string& path, const std::string& compression, int threads) {
  checkExrCompression(compression);
  const auto [method, level] = exrCompression(compression);
  Imf::Header header(img.width, img.height);
  header.compression() = method;
  if (level > 0) header.zipCompressionLevel() = level;
  for (const char* name : kExrChannels)
    header.channels().insert(name, Imf::Channel(std::string(name) == "id" ? Imf::UINT : Imf::FLOAT));
  // The frame buffer reads the image's own arrays: no interleaved copy.
  const std::size_t w = static_cast<std::size_t>(img.width);
  Imf::FrameBuffer frame;
  auto slice = [&](const char* name, Imf::PixelType type, const void* base, std::size_t perPixel,
                   std::size_t bytes) {
    frame.insert(name, Imf::Slice(type, reinterpret_cast<char*>(const_cast<void*>(base)), perPixel * bytes,
                                  perPixel * bytes * w));
  };
  const char* rgba[] = {"R", "G", "B", "A"};
  for (int c = 0; c < 4; ++c) slice(rgba[c], Imf::FLOAT, img.rgba.data() + c, 4, sizeof(float));
  slice("Z", Imf::FLOAT, img.depth.data(), 1, sizeof(float));
  const char* normal[] = {"N.x", "N.y", "N.z"};
  for (int c = 0; c < 3; ++c) slice(normal[c], Imf::FLOAT, img.normal.data() + c, 3, sizeof(float));
  slice("id", Imf::UINT, img.id.data(), 1, sizeof(std::uint32_t));
  // Blocks are compressed on OpenEXR's thread pool (as many threads as the render used).
  const int n = threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  if (Imf::globalThreadCount() != n) Imf::setGlobalThreadCount(n);
  writeAtomically(path, [&](const std::string& tmp) {
    try {
      Imf::OutputFile file(tmp.c_str(), header);
      file.setFrameBuffer(frame);
      file.writePixels(img.height);
    } catch (const Error&) {
      throw;
    } catch (const std::exception& e) {
      throw Error(path + ": write failed: " + e.what());
    }
  });
}

void writePng(const RenderImage& img, const std::string& path) {
  std::vector<unsigned char> data(img.pixels() * 3);
  const float bg = static_cast<float>(kPreviewBackground);
  for (std::size_t p = 0; p < img.pixels(); ++p) {
    const float a = img.rgba[4 * p + 3];
    for (int c = 0; c < 3; ++c) {
      const float v = linearToSrgb(img.rgba[4 * p + c] + (1.0f - a) * bg);
      data[3 * p + c] = static_cast<unsigned char>(std::lround(255.0f * v));
    }
  }
  writeAtomically(path, [&](const std::string& tmp) {
    std::unique_ptr<std::FILE, int (*)(std::FILE*)> file(std::fopen(tmp.c_str(), "wb"), &std::fclose);
    if (!file) throw Error(path + ": cannot open for writing");
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, pngError, nullptr);
    if (!png) throw Error(path + ": cannot create a PNG writer");
    png_infop info = png_create_info_struct(png);
    struct Guard {
      png_structp& png;
      png_infop& info;
      ~Guard() { png_destroy_write_struct(&png, &info); }
    } guard{png, info};
    if (!info) throw Error(path + ": cannot create a PNG writer");
    try {
      png_init_io(png, file.get());
      png_set_IHDR(png, info, static_cast<png_uint_32>(img.width), static_cast<png_uint_32>(img.height), 8,
                   PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
                   PNG_FILTER_TYPE_DEFAULT);
      png_set_sRGB(png, info, PNG_sRGB_INTENT_PERCEPTUAL);
      png_write_info(png, info);
      for (int y = 0; y < img.height; ++y)
        png_write_row(png, &data[static_cast<std::size_t>(y) * 3 * img.width]);
      png_write_end(png, nullptr);
    } catch (const Error& e) {
      throw Error(path + ": " + e.what());
    }
    if (std::fflush(file.get()) != 0) throw Error(path + ": write failed");
  });
}

}  // namespace cip::raycast
