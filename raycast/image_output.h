/// @file image_output.h
/// @brief Writes rendered images: a multi-channel OpenEXR and an 8-bit sRGB PNG preview, both atomically
/// (written under a temporary name in the target's directory, then renamed over the target). Through OpenEXR
/// and libpng, not OpenImageIO: the ~260 shared libraries Debian's OpenImageIO loads took about 0.45 s of
/// every run's start-up.
#pragma once
#include <string>

#include "renderer.h"

namespace cip::raycast {

/// The EXR compression raycast writes unless told otherwise: zlib at level 1, one scanline per block. On a
/// 1024x1024 render it writes 4-5 times faster than OpenEXR's default zip (level 4, 16 scanlines) for a file
/// about 5 % larger (docs/performance.md, "Rendering").
constexpr const char* kDefaultExrCompression = "zips:1";

/// Throws cip::Error unless `compression` is one of OpenEXR's lossless compressions as OpenImageIO names
/// them: none, rle, zips, zip, piz; zips and zip may carry a zlib level 1-9 (zips:1, zip:9).
void checkExrCompression(const std::string& compression);

/// EXR channels, in this order: R, G, B, A (float, linear, premultiplied), Z (float, world distance along the
/// pixel-centre ray, +inf for no hit), N.x, N.y, N.z (float, unit world normal of the centre hit, 0 for no
/// hit), id (uint32: cell index into the model's cell table, or triangle index for meshes; 0xFFFFFFFF for no
/// hit). Lossless compression `compression` (checkExrCompression), blocks compressed on `threads` threads
/// (0 = all). Written with OpenEXR directly. Throws cip::Error naming the path on failure; the target is then
/// left untouched.
void writeExr(const RenderImage& image, const std::string& path,
              const std::string& compression = kDefaultExrCompression, int threads = 0);

/// The EXR channel names, in the order above (the Python module names its arrays the same way).
constexpr const char* kExrChannels[] = {"R", "G", "B", "A", "Z", "N.x", "N.y", "N.z", "id"};

/// 8-bit sRGB RGB preview (libpng): the premultiplied colour composited over a dark grey background.
void writePng(const RenderImage& image, const std::string& path);

/// Background of the PNG preview (linear RGB).
constexpr double kPreviewBackground = 0.04;

}  // namespace cip::raycast
