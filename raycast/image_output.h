/// @file image_output.h
/// @brief Writes rendered images: a multi-channel OpenEXR and an 8-bit sRGB PNG preview, both atomically
/// (written under a temporary name in the target's directory, then renamed over the target).
#pragma once
#include <string>

#include "renderer.h"

namespace cip::raycast {

/// EXR channels, in this order: R, G, B, A (float, linear, premultiplied), Z (float, world distance along the
/// pixel-centre ray, +inf for no hit), N.x, N.y, N.z (float, unit world normal of the centre hit, 0 for no
/// hit), id (uint32: cell index into the model's cell table, or triangle index for meshes; 0xFFFFFFFF for no
/// hit). Zip compression. Throws cip::Error naming the path on failure; the target is then left untouched.
void writeExr(const RenderImage& image, const std::string& path);

/// The EXR channel names, in the order above (the Python module names its arrays the same way).
constexpr const char* kExrChannels[] = {"R", "G", "B", "A", "Z", "N.x", "N.y", "N.z", "id"};

/// 8-bit sRGB RGB preview: the premultiplied colour composited over a dark grey background.
void writePng(const RenderImage& image, const std::string& path);

/// Background of the PNG preview (linear RGB).
constexpr double kPreviewBackground = 0.04;

}  // namespace cip::raycast
